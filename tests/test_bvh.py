"""BVH reading and writing: every feature on small hand-made files, every malformed case,
round trips on generated clips in the CMU and Bandai layouts and (marked slow) on every
shared clip."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from clips import BANDAI_30, CMU_120, DATA
from motionopt import bvh
from motionopt.bvh import BVHError

HERE = Path(__file__).parent
GENERATED = sorted(DATA.glob("*.bvh"))
SHARED = HERE.parent.parent / "shared" / "data"

#: A small skeleton that uses all six rotation orders, 6-channel joints (root and LeftLeg,
#: with positions in an unusual order), End Sites, and an End Site written on one line.
HIERARCHY = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Spine
  {
    OFFSET 0 10 0
    CHANNELS 3 Xrotation Yrotation Zrotation
    JOINT Head
    {
      OFFSET 0 10 0
      CHANNELS 3 Yrotation Zrotation Xrotation
      End Site
      {
        OFFSET 0 5 0
      }
    }
  }
  JOINT LeftLeg
  {
    OFFSET 5 0 0
    CHANNELS 6 Zrotation Zposition Xposition Xrotation Yposition Yrotation
    JOINT LeftFoot
    {
      OFFSET 0 -40 0
      CHANNELS 3 Zrotation Yrotation Xrotation
      End Site { OFFSET 0 0 5 }
    }
  }
  JOINT RightLeg
  {
    OFFSET -5 0 0
    CHANNELS 3 Yrotation Xrotation Zrotation
    End Site
    {
      OFFSET 0 -40 0
    }
  }
}
"""
NAMES = ("Hips", "Spine", "Head", "LeftLeg", "LeftFoot", "RightLeg")
ORDERS = ("ZXY", "XYZ", "YZX", "XZY", "ZYX", "YXZ")
N_CHANNELS = 24
HEADER_LINES = HIERARCHY.count("\n")  # MOTION is on the next line


def frame_values(n: int = 4, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    values = rng.uniform(-170, 170, size=(n, N_CHANNELS)).round(4)
    values[:, :3] = rng.normal(0, 20, size=(n, 3)).round(4)  # root position
    return values


def bvh_text(values: np.ndarray, frame_time: str = "0.04", frames: int | None = None) -> str:
    rows = "\n".join(" ".join(f"{v:.10g}" for v in row) for row in values)
    return HIERARCHY + f"MOTION\nFrames: {len(values) if frames is None else frames}\nFrame Time: {frame_time}\n" + rows + "\n"


def write(tmp_path: Path, text: str, name: str = "clip.bvh", newline: str = "\n") -> Path:
    path = tmp_path / name
    path.write_bytes(text.replace("\n", newline).encode())
    return path


def check_layout(motion, values: np.ndarray) -> None:
    """Rotations and translations of the hand-made skeleton match the channel values."""
    rot = {"Hips": (3, "ZXY"), "Spine": (6, "XYZ"), "Head": (9, "YZX"), "LeftFoot": (18, "ZYX"), "RightLeg": (21, "YXZ")}
    for name, (col, order) in rot.items():
        ref = Rotation.from_euler(order, values[:, col:col + 3], degrees=True).as_quat(scalar_first=True)
        got = motion.rotations[:, NAMES.index(name)]
        np.testing.assert_allclose(got * np.sign((got * ref).sum(-1, keepdims=True)), ref, atol=1e-12)
    # LeftLeg: Zrotation Zposition Xposition Xrotation Yposition Yrotation -> rotation Z X Y, position x y z
    leg = values[:, 12:18]
    ref = Rotation.from_euler("ZXY", leg[:, [0, 3, 5]], degrees=True).as_quat(scalar_first=True)
    got = motion.rotations[:, 3]
    np.testing.assert_allclose(got * np.sign((got * ref).sum(-1, keepdims=True)), ref, atol=1e-12)
    np.testing.assert_allclose(motion.translations[:, 3], leg[:, [2, 4, 1]] * 0.01, atol=1e-12)
    np.testing.assert_allclose(motion.root, values[:, :3] * 0.01, atol=1e-12)


def test_reads_every_feature_of_a_hand_made_file(tmp_path):
    values = frame_values()
    m = bvh.load(write(tmp_path, bvh_text(values)), unit="cm")
    assert m.skeleton.names == NAMES
    assert list(m.skeleton.parents) == [-1, 0, 1, 0, 3, 0]
    assert m.num_frames == 4 and m.fps == pytest.approx(25.0)
    assert m.skeleton.channels[3] == ("Zrotation", "Zposition", "Xposition", "Xrotation", "Yposition", "Yrotation")
    np.testing.assert_allclose(m.skeleton.offsets[1], [0, 0.1, 0])
    assert sorted(m.skeleton.end_sites) == [2, 4, 5]
    np.testing.assert_allclose(m.skeleton.end_sites[4], [0, 0, 0.05])
    check_layout(m, values)


@pytest.mark.parametrize("variant", ["tabs", "crlf", "cr", "trailing blank lines", "blank lines and spaces",
                                     "bom", "blank line after MOTION", "blank lines between the headers"])
def test_whitespace_variants_read_the_same(tmp_path, variant):
    values = frame_values()
    text = bvh_text(values)
    newline = "\n"
    if variant == "tabs":
        text = "\n".join(line.replace("  ", "\t").replace(" ", "\t") for line in text.split("\n"))
    elif variant == "crlf":
        newline = "\r\n"
    elif variant == "cr":
        newline = "\r"
    elif variant == "trailing blank lines":
        text += "\n\n   \n\t\n"
    elif variant == "blank lines and spaces":
        text = text.replace("{\n", "{  \n\n").replace("MOTION", "  MOTION  ")
    elif variant == "bom":
        text = "\ufeff" + text
    elif variant == "blank line after MOTION":  # a common exporter writes this; bvhio reads it
        text = text.replace("MOTION\n", "MOTION\n\n")
    elif variant == "blank lines between the headers":
        text = text.replace("MOTION\n", "MOTION\n \n").replace("\nFrame Time", "\n\t\n\nFrame Time")
    path = write(tmp_path, text, newline=newline)
    m = bvh.load(path, unit="cm")
    assert m.skeleton.names == NAMES and m.num_frames == 4
    check_layout(m, values)


def channels_equal(a: np.ndarray, b: np.ndarray, rtol: float = 1e-6) -> None:
    """Channel values equal to ``rtol`` relative (values near zero: to ``rtol`` absolute)."""
    np.testing.assert_array_less(np.abs(a - b), rtol * np.maximum(np.abs(a), 1.0))


def check_round_trip(src: Path, dst: Path) -> None:
    sk, values, ft = bvh.read_channels(src)
    bvh.save(bvh.load(src), dst)
    sk2, values2, ft2 = bvh.read_channels(dst)
    assert sk2.names == sk.names and np.array_equal(sk2.parents, sk.parents)
    assert sk2.channels == sk.channels
    np.testing.assert_allclose(sk2.offsets, sk.offsets, rtol=1e-9, atol=1e-9)
    assert sorted(sk2.end_sites) == sorted(sk.end_sites)
    assert ft2 == pytest.approx(ft, rel=1e-9)
    assert values2.shape == values.shape
    channels_equal(values, values2)


def test_hand_made_file_round_trips(tmp_path):
    src = write(tmp_path, bvh_text(frame_values(20, seed=1)), newline="\r\n")
    check_round_trip(src, tmp_path / "out.bvh")


def test_round_trip_outside_the_principal_euler_range(tmp_path):
    """Angles beyond +-180 and middle angles beyond +-90 come back as written (euler_hint)."""
    values = frame_values(5, seed=2)
    values[:, 3:] += np.array([360.0, -200.0, 540.0] * 7)
    src = write(tmp_path, bvh_text(values))
    check_round_trip(src, tmp_path / "out.bvh")


@pytest.mark.parametrize("path", GENERATED, ids=[p.name for p in GENERATED])
def test_generated_clips_round_trip(path, tmp_path):
    check_round_trip(path, tmp_path / path.name)


def test_generated_clips_have_the_layouts_of_real_files():
    cmu, bandai = bvh.load(DATA / CMU_120), bvh.load(DATA / BANDAI_30)
    assert cmu.skeleton.num_joints == 43 and cmu.fps == 120.0 and cmu.source_unit == "cm"
    assert {"leftEye", "rThumb2", "lPinky1"} <= set(cmu.skeleton.names)
    assert all(c == ("Zrotation", "Xrotation", "Yrotation") for c in cmu.skeleton.channels[1:])
    assert bandai.skeleton.names[:2] == ("joint_Root", "Hips") and bandai.skeleton.num_joints == 22
    assert all(len(c) == 6 for c in bandai.skeleton.channels)
    assert bandai.translations is not None and bandai.source_unit == "cm"


def shared_clips(folder: str) -> list[Path]:
    return sorted((SHARED / folder).rglob("*.bvh")) if (SHARED / folder).is_dir() else []


ALL_SHARED = shared_clips("cmu") + shared_clips("bandai")


@pytest.mark.skipif(not ALL_SHARED, reason="../shared/data is absent")
@pytest.mark.parametrize("folder", ["cmu", "bandai"])
def test_one_full_shared_clip_per_dataset_round_trips(folder, tmp_path):
    clips = shared_clips(folder)
    if not clips:
        pytest.skip(f"../shared/data/{folder} is absent")
    check_round_trip(min(clips, key=lambda p: p.stat().st_size), tmp_path / "out.bvh")


@pytest.mark.slow
@pytest.mark.skipif(not ALL_SHARED, reason="../shared/data is absent")
@pytest.mark.parametrize("path", ALL_SHARED, ids=[str(p.relative_to(SHARED)) for p in ALL_SHARED])
def test_every_shared_clip_round_trips(path, tmp_path):
    check_round_trip(path, tmp_path / path.name)


# ---- malformed files: one error type naming the file, the line and what was expected ----------

def lines_of(text: str) -> list[str]:
    return text.split("\n")


def replace_line(text: str, number: int, new: str) -> str:
    lines = lines_of(text)
    lines[number - 1] = new
    return "\n".join(lines)


def first_frame_line() -> int:
    return HEADER_LINES + 4  # MOTION, Frames, Frame Time, then the first frame


def malformed_cases() -> dict[str, tuple[str, int, str]]:
    """name -> (file text, line the error must name, words the message must hold)."""
    values = frame_values()
    good = bvh_text(values)
    f1 = first_frame_line()
    row = " ".join(f"{v:.10g}" for v in values[1])
    cut_hierarchy = "\n".join(lines_of(good)[:12]) + "\n"
    cases = {
        "truncated in the hierarchy": (cut_hierarchy, 12, "file ends early"),
        "truncated after the hierarchy": (HIERARCHY, HEADER_LINES, "expected 'MOTION'"),
        "truncated in the last frame": (good.rstrip("\n")[:-25] + "\n", f1 + 3, f"expected {N_CHANNELS} channel values"),
        "truncated: frames missing": ("\n".join(lines_of(good)[:f1 + 1]) + "\n", f1 + 1, "header says 4 frames"),
        "frame count mismatch: extra frame": (good + row + "\n", f1 + 4, "header says 4 frames but the file has 5"),
        "wrong channel count in a frame": (replace_line(good, f1 + 1, row + " 1.0"), f1 + 1,
                                           f"expected {N_CHANNELS} channel values, found {N_CHANNELS + 1}"),
        "non-numeric value": (replace_line(good, f1 + 2, row.replace(row.split()[5], "abc", 1)), f1 + 2,
                              "Hips Yrotation (value 6), found 'abc'"),
        "NaN": (replace_line(good, f1 + 1, row.replace(row.split()[7], "nan", 1)), f1 + 1,
                "Spine Yrotation (value 8) is nan"),
        "infinite value": (replace_line(good, f1, row.replace(row.split()[0], "inf", 1)), f1, "Hips Xposition"),
        "unknown channel": (good.replace("CHANNELS 3 Yrotation Zrotation Xrotation", "CHANNELS 3 Yrotation Zrot Xrotation"),
                            13, "unknown channel 'Zrot' for joint Head"),
        "duplicate joint names": (good.replace("JOINT RightLeg", "JOINT LeftLeg"), 31,
                                  "duplicate joint name 'LeftLeg' (first at line 20)"),
        "empty MOTION section": (HIERARCHY + "MOTION\nFrames: 0\nFrame Time: 0.04\n\n", HEADER_LINES + 2, "0 frames"),
        "MOTION without frame lines": (HIERARCHY + "MOTION\nFrames: 4\nFrame Time: 0.04\n", HEADER_LINES + 3,
                                       "no frame lines"),
        "MOTION with nothing after it": (HIERARCHY + "MOTION\n\n", HEADER_LINES + 1, "file ends early: expected 'Frames:'"),
        "frame count not a number": (good.replace("Frames: 4", "Frames: four"), HEADER_LINES + 2,
                                     "whole number of frames"),
        "zero frame time": (good.replace("Frame Time: 0.04", "Frame Time: 0"), HEADER_LINES + 3, "positive"),
        "offset not a number": (good.replace("OFFSET 0 10 0", "OFFSET 0 ten 0", 1), 8, "expected a number"),
        "channel count not a number": (good.replace("CHANNELS 3 Xrotation", "CHANNELS x Xrotation"), 9,
                                       "expected a channel count"),
        "two rotation channels": (good.replace("CHANNELS 3 Xrotation Yrotation Zrotation",
                                               "CHANNELS 3 Xrotation Yrotation Xposition"), 9,
                                  "three distinct rotation channels"),
        "missing brace": (good.replace("  JOINT Spine\n  {", "  JOINT Spine\n", 1), 8, "expected '{'"),
        "not a BVH file": ("Hello, this is not motion\n", 1, "expected 'HIERARCHY'"),
        "no ROOT": (good.replace("ROOT Hips", "JOINT Hips"), 2, "expected 'ROOT'"),
    }
    return cases


CASES = malformed_cases()


@pytest.mark.parametrize("name", list(CASES))
def test_malformed_file_raises_bvh_error_with_file_and_line(name, tmp_path):
    text, line, words = CASES[name]
    path = write(tmp_path, text, name="bad.bvh")
    with pytest.raises(BVHError) as info:
        bvh.load(path)
    err = info.value
    assert err.path == str(path)
    assert err.line == line, f"{name}: {err}"
    assert words in err.message, f"{name}: {err}"
    assert str(err).startswith(f"{path}:{line}: ")
    assert "\n" not in str(err)


def test_binary_file_is_refused(tmp_path):
    path = tmp_path / "binary.bvh"
    path.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(BVHError, match="not a text file"):
        bvh.load(path)


def test_save_writes_tabs_and_end_sites_and_reads_back(tmp_path):
    m = bvh.load(write(tmp_path, bvh_text(frame_values())), unit="cm")
    out = bvh.save(m, tmp_path / "out.bvh")
    text = out.read_text()
    assert "\tJOINT Spine" in text and text.count("End Site") == 3 and "\r" not in text
    check_layout(bvh.load(out, unit="cm"), frame_values())


def test_guess_unit_from_skeleton_size():
    parents = np.array([-1, 0, 1])
    for height, unit in ((1.7, "m"), (170.0, "cm"), (1700.0, "mm")):
        offsets = np.array([[0, 0, 0], [0, height / 2, 0], [0, height / 2, 0]])
        assert bvh.guess_unit(offsets, parents) == unit


@pytest.mark.parametrize("text,fps", [("0.0333333", 30.0), ("0.00833333", 120.0), ("0.0166667", 60.0),
                                      ("0.0333667", 29.97), ("0.04", 25.0), ("0.03", 100 / 3),
                                      ("0.0123456789", 1 / 0.0123456789)])
def test_rounded_frame_times_give_the_intended_rate_and_write_back_the_same(text, fps):
    assert bvh.frame_rate(float(text)) == pytest.approx(fps, rel=1e-12)
    assert bvh.frame_time_text(bvh.frame_rate(float(text))) == text


def test_frame_rate_override_and_header_rate(tmp_path):
    path = write(tmp_path, bvh_text(frame_values(), frame_time="0.0333333"))
    assert bvh.load(path).fps == 30.0  # exactly: resampling lands on whole frames
    assert bvh.load(path, fps=60.0).fps == 60.0
    with pytest.raises(ValueError, match="frame rate must be positive"):
        bvh.load(path, fps=0)
    out = bvh.save(bvh.load(path, fps=60.0), tmp_path / "out.bvh")
    assert "Frame Time: 0.0166667\n" in out.read_text()
