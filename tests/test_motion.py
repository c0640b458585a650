"""The Motion type on real excerpts: slicing, resampling, mirroring, removing joints, units, saving."""
from __future__ import annotations

import os
import stat
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from motionopt import bvh
from motionopt.motion import Motion
from clips import DATA, CMU_120, CMU_60, BANDAI_30

MARTIAL = DATA / CMU_120
SALSA = DATA / CMU_60
BANDAI = DATA / BANDAI_30


@pytest.fixture(scope="module")
def martial() -> Motion:
    return bvh.load(MARTIAL)


@pytest.fixture(scope="module")
def bandai() -> Motion:
    return bvh.load(BANDAI)


def same_rotations(a: np.ndarray, b: np.ndarray, atol: float) -> None:
    sign = np.sign((a * b).sum(-1, keepdims=True))
    np.testing.assert_allclose(a * sign, b, atol=atol)


def test_slice_selects_frames_and_keeps_positions(martial):
    part = martial[10:50]
    assert part.num_frames == 40 and part.fps == martial.fps
    np.testing.assert_array_equal(part.rotations, martial.rotations[10:50])
    np.testing.assert_array_equal(part.euler_hint, martial.euler_hint[10:50])
    np.testing.assert_allclose(part.positions(), martial.positions()[10:50])
    every_other = martial[::2]
    assert every_other.fps == pytest.approx(martial.fps / 2) and every_other.num_frames == 120
    with pytest.raises(TypeError, match="slice"):
        martial[3]


def test_resample_by_whole_factor_keeps_the_frames_it_lands_on(martial):
    down = martial.resample(30.0)
    assert down.fps == 30.0
    assert down.num_frames == int(np.floor(martial.duration * 30 + 1e-6)) + 1
    same_rotations(down.rotations, martial.rotations[::4][:down.num_frames], 1e-12)
    np.testing.assert_allclose(down.root, martial.root[::4][:down.num_frames], atol=1e-12)


def test_resample_matches_scipy_slerp_and_linear_root(martial):
    clip = martial[:60]
    out = clip.resample(50.0)
    times_src = np.arange(clip.num_frames) / clip.fps
    times = np.arange(out.num_frames) / 50.0
    assert times[-1] <= times_src[-1] + 1e-9
    for j in (0, 8, 38):
        ref = Slerp(times_src, Rotation.from_quat(clip.rotations[:, j], scalar_first=True))(times)
        same_rotations(out.rotations[:, j], ref.as_quat(scalar_first=True), 1e-9)
    for axis in range(3):
        np.testing.assert_allclose(out.root[:, axis], np.interp(times, times_src, clip.root[:, axis]), atol=1e-12)


def test_resample_up_and_back_down_is_identity():
    salsa = bvh.load(SALSA)
    back = salsa.resample(salsa.fps * 2).resample(salsa.fps)
    assert back.num_frames == salsa.num_frames
    same_rotations(back.rotations, salsa.rotations, 1e-9)
    np.testing.assert_allclose(back.root, salsa.root, atol=1e-12)


def test_resample_keeps_bandai_joint_translations(bandai):
    out = bandai.resample(60.0)
    assert out.translations is not None and out.num_frames == 2 * bandai.num_frames - 1
    np.testing.assert_allclose(out.positions()[::2], bandai.positions(), atol=1e-9)


def test_mirror_twice_is_identity(martial, bandai):
    for m in (martial, bandai):
        twice = m.mirror().mirror()
        np.testing.assert_allclose(twice.rotations, m.rotations, atol=0)
        np.testing.assert_allclose(twice.root, m.root, atol=0)
        np.testing.assert_allclose(twice.positions(), m.positions(), atol=1e-12)


def symmetric(m: Motion) -> Motion:
    """The motion on a left/right symmetric version of its skeleton."""
    sk = m.skeleton
    mp = sk.mirror_map()
    offsets = sk.offsets.copy()
    for j in range(sk.num_joints):
        if mp[j] == j:
            offsets[j, 0] = 0.0
        elif mp[j] > j:
            offsets[mp[j]] = offsets[j] * [-1.0, 1.0, 1.0]
    return replace(m, skeleton=replace(sk, offsets=offsets))


def test_mirror_reflects_world_positions_and_swaps_sides(martial):
    m = symmetric(martial)
    mp = m.skeleton.mirror_map()
    names = m.skeleton.names
    assert names[mp[names.index("lFoot")]] == "rFoot" and names[mp[names.index("leftEye")]] == "rightEye"
    pos, mirrored = m.positions(), m.mirror().positions()
    np.testing.assert_allclose(mirrored[:, mp] * [-1.0, 1.0, 1.0], pos, atol=1e-12)


def test_remove_leaf_joints_keeps_world_positions(martial):
    out = martial.remove_joints(["*Thumb*", "*Index*", "*Mid*", "*Ring*", "*Pinky*", "*Eye"])
    assert out.skeleton.num_joints == 21 and out.translations is None
    idx = [martial.skeleton.index(n) for n in out.skeleton.names]
    np.testing.assert_array_equal(out.positions(), martial.positions()[:, idx])
    # the hands and head become leaves with an End Site
    for name in ("rHand", "lHand", "head"):
        assert out.skeleton.index(name) in out.skeleton.end_sites


@pytest.mark.parametrize("drop", [["abdomen"], ["rShin", "lThigh"], ["chest", "*Collar"]])
def test_remove_inner_joints_keeps_world_positions_through_a_file(martial, drop, tmp_path):
    out = martial.remove_joints(drop)
    idx = [martial.skeleton.index(n) for n in out.skeleton.names]
    np.testing.assert_allclose(out.positions(), martial.positions()[:, idx], atol=1e-12)
    bvh.save(out, tmp_path / "out.bvh")
    back = bvh.load(tmp_path / "out.bvh")
    assert back.skeleton.names == out.skeleton.names
    np.testing.assert_allclose(back.positions(), martial.positions()[:, idx], atol=1e-7)


def test_remove_joints_on_six_channel_skeleton(bandai):
    out = bandai.remove_joints(["Spine", "Toes_*"])
    idx = [bandai.skeleton.index(n) for n in out.skeleton.names]
    np.testing.assert_allclose(out.positions(), bandai.positions()[:, idx], atol=1e-12)


def test_remove_joints_refuses_the_root(martial):
    with pytest.raises(ValueError, match="root"):
        martial.remove_joints("hip")
    assert martial.remove_joints("no-such-joint") is martial


def test_reroot_and_bake_keep_world_positions(bandai):
    rerooted = bandai.reroot()
    assert rerooted.skeleton.names[0] == "Hips"
    np.testing.assert_allclose(rerooted.positions(), bandai.positions()[:, 1:], atol=1e-12)
    baked = rerooted.bake_translations(tolerance=1e-4)
    assert baked.translations is None
    np.testing.assert_allclose(baked.positions(), bandai.positions()[:, 1:], atol=1e-4)


def test_units_cm_and_m_on_load_and_save(tmp_path):
    cm = bvh.load(SALSA)  # CMU clips are in centimetres
    assert cm.source_unit == "cm"
    as_m = bvh.load(SALSA, unit="m")
    np.testing.assert_allclose(as_m.root, cm.root * 100)
    np.testing.assert_allclose(as_m.skeleton.offsets, cm.skeleton.offsets * 100)
    hip_height = cm.positions()[:, 0, 1].mean()
    assert 0.7 < hip_height < 1.1  # metres inside
    # written back in metres, the numbers in the file are a hundredth of the centimetre file's
    bvh.save(cm, tmp_path / "m.bvh", unit="m")
    sk_cm, values_cm, _ = bvh.read_channels(SALSA)
    sk_m, values_m, _ = bvh.read_channels(tmp_path / "m.bvh")
    np.testing.assert_allclose(sk_m.offsets, sk_cm.offsets / 100, atol=1e-12)
    np.testing.assert_allclose(values_m[:, :3], values_cm[:, :3] / 100, atol=1e-12)
    np.testing.assert_allclose(values_m[:, 3:], values_cm[:, 3:], atol=1e-9)  # angles are not lengths
    back = bvh.load(tmp_path / "m.bvh")
    assert back.source_unit == "m"
    np.testing.assert_allclose(back.positions(), cm.positions(), atol=1e-9)
    # saved without a unit, a motion goes back to the unit it was read in
    bvh.save(cm, tmp_path / "cm.bvh")
    np.testing.assert_allclose(bvh.read_channels(tmp_path / "cm.bvh")[1], values_cm, rtol=1e-9)


def test_save_refuses_to_overwrite_without_force_and_leaves_no_temp_file(martial, tmp_path):
    out = tmp_path / "out.bvh"
    out.write_text("precious")
    with pytest.raises(FileExistsError, match="force"):
        bvh.save(martial, out)
    assert out.read_text() == "precious"
    bvh.save(martial, out, force=True)
    assert bvh.load(out).num_frames == martial.num_frames
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.bvh"]
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(out.stat().st_mode) == 0o666 & ~umask


def test_interrupted_save_leaves_the_old_file_and_no_temp_file(martial, tmp_path, monkeypatch):
    out = tmp_path / "out.bvh"
    out.write_text("precious")

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "savetxt", interrupted)
    with pytest.raises(KeyboardInterrupt):
        bvh.save(martial, out, force=True)
    assert out.read_text() == "precious"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.bvh"]


def test_with_frames_keeps_the_euler_hint_only_for_the_same_length(martial):
    same = martial.with_frames(martial.rotations.copy(), martial.root.copy())
    assert same.euler_hint is martial.euler_hint
    shorter = martial.with_frames(martial.rotations[:10], martial.root[:10])
    assert shorter.euler_hint is None and shorter.num_frames == 10


def test_inconsistent_arrays_are_refused(martial):
    with pytest.raises(ValueError, match="root"):
        Motion(martial.skeleton, martial.rotations, martial.root[:-1], 30.0)
    with pytest.raises(ValueError, match="frame rate"):
        Motion(martial.skeleton, martial.rotations, martial.root, 0.0)
