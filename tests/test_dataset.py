"""Dataset building on a tiny folder of generated clips in the CMU layout."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import torch

from motionopt.dataset import MIRRORED, Normalizer, build_dataset, default_validation, find_bvh
from clips import BANDAI_30, CMU_60, CMU_120, DATA

#: Each clip in a sub-folder of its own, as in ../shared/data/cmu.
FOLDERS = {CMU_120: "f120", CMU_60: "f60"}
A, B = f"f120/{CMU_120}", f"f60/{CMU_60}"


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    """The CMU-layout clips, one per sub-folder."""
    root = tmp_path_factory.mktemp("cmu")
    for name, sub in FOLDERS.items():
        (root / sub).mkdir()
        shutil.copy(DATA / name, root / sub / name)
    return root


@pytest.fixture(scope="module")
def dataset(folder):
    return build_dataset(folder, val=["f60/*"])


def test_clips_are_split_by_clip(dataset):
    assert list(dataset.train) == [A]
    assert list(dataset.val) == [B]
    assert not set(dataset.train) & set(dataset.val)


def test_clips_are_resampled_to_the_prior_rate_on_its_joints(dataset):
    assert dataset.spec.fps == 30.0 and len(dataset.spec.joints) == 21
    assert dataset.skeleton.names == dataset.spec.joints
    # 240 frames at 120 fps and 240 frames at 60 fps: 1.99 s and 3.98 s
    assert len(dataset.train[A]) == 60
    assert len(dataset.val[B]) == 120
    assert dataset.num_train_frames == 60 and dataset.seconds_to_build > 0


def test_frame_rate_overrides_change_the_clip_length(folder):
    ds = build_dataset(folder, val=[], fps_overrides={"f60/*": 120.0})
    assert len(ds.train[B]) == 60  # the same frames read as 1.99 s


def test_normalizer_standardises_training_features(dataset):
    norm = dataset.normalizer
    contacts = dataset.spec.slices()["contacts"]
    x = torch.cat(list(dataset.train.values()))
    z = norm.normalize(x)
    moving = x.std(0) > 1e-3
    moving[contacts] = False
    torch.testing.assert_close(z.mean(0)[moving], torch.zeros(int(moving.sum()), dtype=z.dtype), rtol=0, atol=1e-9)
    torch.testing.assert_close(z.std(0)[moving], torch.ones(int(moving.sum()), dtype=z.dtype), rtol=0, atol=1e-9)
    assert torch.equal(z[:, contacts], x[:, contacts])  # labels stay 0/1
    torch.testing.assert_close(norm.denormalize(z), x)
    assert (norm.std >= 1e-3).all()  # constant features do not blow up
    refit = Normalizer.fit(list(dataset.train.values()), dataset.spec)
    torch.testing.assert_close(refit.mean, norm.mean)


def test_windows_overlap_and_are_normalised(dataset):
    w = dataset.windows("train", length=20, stride=10)
    assert w.shape == (5, 20, dataset.spec.dim) and w.dtype == torch.float32
    x = dataset.normalizer.normalize(dataset.train[A]).float()
    torch.testing.assert_close(w[1], x[10:30])
    assert dataset.windows("val", length=120, stride=1).shape == (1, 120, dataset.spec.dim)
    with pytest.raises(ValueError, match="at least 200 frames"):
        dataset.windows("val", length=200, stride=1)


def test_default_validation_holds_out_the_last_clip_of_each_folder(folder):
    files = find_bvh(folder)
    assert default_validation(files, folder) == [A, B]
    flat = [Path(f"/x/{i:02d}.bvh") for i in range(25)]
    assert default_validation(flat, Path("/x")) == ["09.bvh", "19.bvh"]


def test_bad_folders_are_refused(folder, tmp_path):
    with pytest.raises(FileNotFoundError, match="no .bvh files"):
        build_dataset(tmp_path)
    with pytest.raises(ValueError, match="no training clips"):
        build_dataset(folder, val=["*"])
    with pytest.raises(ValueError, match=f"{CMU_120}: .* does not match"):
        build_dataset(DATA)  # two skeletons in one folder: CMU clips do not fit the spec of the Bandai one


def test_mirror_adds_each_training_clip_reflected(folder, dataset):
    ds = build_dataset(folder, val=["f60/*"], mirror=True)
    assert list(ds.train) == [A, A + MIRRORED] and list(ds.val) == [B]
    x, m = ds.train[A], ds.train[A + MIRRORED]
    s = ds.spec.slices()
    assert torch.equal(x, dataset.train[A])
    # turning left becomes turning right; the hips keep their height; left and right feet swap
    torch.testing.assert_close(m[:, s["yaw_delta"]], -x[:, s["yaw_delta"]])
    torch.testing.assert_close(m[:, s["root_height"]], x[:, s["root_height"]])
    torch.testing.assert_close(m[:, s["root_delta"]][:, 0], -x[:, s["root_delta"]][:, 0])
    names, other = ds.skeleton.names, ds.skeleton.mirror_map()
    feet = list(ds.spec.contact_joints)
    swapped = [feet.index(names[other[names.index(n)]]) for n in feet]
    assert swapped != list(range(len(feet)))
    torch.testing.assert_close(m[:, s["contacts"]], x[:, s["contacts"]][:, swapped])


def test_mirror_refuses_an_asymmetric_skeleton(tmp_path):
    shutil.copy(DATA / BANDAI_30, tmp_path / BANDAI_30)
    with pytest.raises(ValueError, match=f"{BANDAI_30}: cannot mirror .* differ by up to"):
        build_dataset(tmp_path, val=[], mirror=True)
