"""Hostile and odd BVH input: random valid files round-trip (hypothesis), and mutated files
(a table of odd cases, truncations, byte flips, huge files) either load correctly or raise a
BVHError that names the file and the line: never another exception, never a hang."""
from __future__ import annotations

import os
import re
import signal
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from motionopt import bvh, rotations as R
from motionopt.bvh import BVHError
from motionopt.motion import Motion, unit_scale
from clips import DATA, CMU_120

CMU = DATA / CMU_120
TIME_LIMIT_S = 10.0  # per read; a hang must fail the test, not stall CI


@contextmanager
def time_limit(seconds: float) -> Iterator[None]:
    """Raise TimeoutError in the block after ``seconds`` (where the platform has SIGALRM)."""
    if not hasattr(signal, "setitimer"):
        yield
        return

    def expire(signum: int, frame: object) -> None:
        raise TimeoutError(f"no result after {seconds} s: a hang?")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def line_count(path: Path) -> int:
    return len(re.split(rb"\r\n|\r|\n", path.read_bytes())) if path.is_file() else 0


def load_or_error(path: Path, unit: str = "cm") -> Motion | BVHError:
    """``bvh.load`` under a time limit, holding it to the contract: a sane Motion (all
    finite) or a one-line BVHError naming this file and a line inside it."""
    with time_limit(TIME_LIMIT_S):
        try:
            motion = bvh.load(path, unit=unit)
        except BVHError as err:
            assert err.path == str(path)
            assert err.line is None or 1 <= err.line <= line_count(path), err
            assert str(err).startswith(f"{path}:{err.line}: " if err.line else f"{path}: ")
            assert "\n" not in str(err) and len(err.message) < 300, err
            return err
    for a in (motion.rotations, motion.root, motion.positions(), motion.euler_hint):
        assert np.isfinite(a).all()
    return motion


# ---- random valid files round-trip ---------------------------------------------------------

NAMES = st.text(st.characters(categories=("L",)), min_size=1, max_size=10)  # unicode letters
ROTATIONS = ["Xrotation", "Yrotation", "Zrotation"]
POSITIONS = ["Xposition", "Yposition", "Zposition"]
FRAME_TIMES = st.one_of(st.sampled_from(["0.0333333", "0.00833333", "0.0166667", "0.04", "0.1"]),
                        st.floats(0.001, 1.0).map(lambda x: f"{x:.6g}"))


@dataclass
class Spec:
    """A random valid BVH file: joints in file order (pre-order), values (T, C) in file units."""

    names: list[str]
    parents: list[int]
    offsets: np.ndarray
    channels: list[tuple[str, ...]]
    end_sites: dict[int, np.ndarray]
    values: np.ndarray
    frame_time: str
    newline: str
    indent: str


@st.composite
def joint_channels(draw: st.DrawFn) -> tuple[str, ...]:
    kind = draw(st.sampled_from(["rotations", "rotations", "rotations", "six", "positions", "none"]))
    pool = {"rotations": ROTATIONS, "six": ROTATIONS + POSITIONS, "positions": POSITIONS, "none": []}[kind]
    return tuple(draw(st.permutations(pool)))


@st.composite
def specs(draw: st.DrawFn) -> Spec:
    n = draw(st.integers(1, 30))
    names = draw(st.lists(NAMES, min_size=n, max_size=n, unique=True))
    parents, open_path = [-1], [0]
    for j in range(1, n):  # a new joint hangs below a joint on the path to the last one: pre-order
        k = draw(st.integers(0, len(open_path) - 1))
        parents.append(open_path[k])
        open_path = open_path[:k + 1] + [j]
    channels = [tuple(draw(st.permutations(ROTATIONS + POSITIONS)))] + [draw(joint_channels()) for _ in range(n - 1)]
    offsets = np.array(draw(st.lists(st.floats(-100, 100), min_size=3 * n, max_size=3 * n))).reshape(n, 3)
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    ends = draw(st.lists(st.booleans(), min_size=n, max_size=n))
    end_sites = {j: rng.uniform(-50, 50, 3) for j in range(n) if ends[j]}
    kinds = [c for chans in channels for c in chans]
    n_frames = draw(st.integers(1, 40))
    values = np.where([c in ROTATIONS for c in kinds], rng.uniform(-170, 170, (n_frames, len(kinds))),
                      rng.uniform(-500, 500, (n_frames, len(kinds))))
    return Spec(names, parents, offsets, channels, end_sites, values, draw(FRAME_TIMES),
                draw(st.sampled_from(["\n", "\r\n"])), draw(st.sampled_from(["\t", "  ", ""])))


def numbers(values: np.ndarray) -> str:
    return " ".join(repr(float(v)) for v in values)  # repr: the exact double


def spec_text(s: Spec) -> str:
    """The file, written independently of ``bvh.save``."""
    lines = ["HIERARCHY"]
    open_joints: list[int] = []

    def close(j: int) -> None:
        pad = s.indent * (len(open_joints))
        if j in s.end_sites:
            lines.extend([pad + "End Site", pad + "{", pad + s.indent + "OFFSET " + numbers(s.end_sites[j]),
                          pad + "}"])
        lines.append(s.indent * (len(open_joints) - 1) + "}")

    for j, name in enumerate(s.names):
        while open_joints and open_joints[-1] != s.parents[j]:
            close(open_joints[-1])
            open_joints.pop()
        pad = s.indent * len(open_joints)
        lines += [f"{pad}{'ROOT' if j == 0 else 'JOINT'} {name}", pad + "{",
                  pad + s.indent + "OFFSET " + numbers(s.offsets[j]),
                  pad + s.indent + f"CHANNELS {len(s.channels[j])} {' '.join(s.channels[j])}"]
        open_joints.append(j)
    while open_joints:
        close(open_joints[-1])
        open_joints.pop()
    lines += ["MOTION", f"Frames: {len(s.values)}", f"Frame Time: {s.frame_time}"]
    lines += [numbers(row) for row in s.values]
    return s.newline.join(lines) + s.newline


def check_matches_spec(m: Motion, s: Spec, scale: float) -> None:
    """What was read is what was written: hierarchy, rotations (via scipy), root positions."""
    assert m.skeleton.names == tuple(s.names)
    assert m.skeleton.parents.tolist() == s.parents
    assert m.skeleton.channels == tuple(s.channels)
    np.testing.assert_array_equal(m.skeleton.offsets, s.offsets * scale)
    assert sorted(m.skeleton.end_sites) == sorted(s.end_sites)
    assert m.fps == bvh.frame_rate(float(s.frame_time))
    col = 0
    for j, chans in enumerate(s.channels):
        block = s.values[:, col:col + len(chans)]
        col += len(chans)
        rot = [k for k, c in enumerate(chans) if c in ROTATIONS]
        if rot:
            order = "".join(chans[k][0] for k in rot)
            want = Rotation.from_euler(order, block[:, rot], degrees=True).as_matrix()
            np.testing.assert_allclose(matrices(m)[:, j], want, atol=1e-12)
        if j == 0:
            np.testing.assert_allclose(m.root, block[:, [chans.index(c) for c in POSITIONS]] * scale, rtol=1e-15)


def matrices(m: Motion) -> np.ndarray:
    return R.quat_to_matrix(torch.from_numpy(m.rotations)).numpy()


def check_same_motion(a: Motion, b: Motion) -> None:
    """Same skeleton, rate and pose: world positions and rotation matrices, not Euler angles."""
    assert (b.skeleton.names, b.skeleton.channels) == (a.skeleton.names, a.skeleton.channels)
    assert b.skeleton.parents.tolist() == a.skeleton.parents.tolist()
    np.testing.assert_allclose(b.skeleton.offsets, a.skeleton.offsets, rtol=1e-9, atol=1e-12)
    assert sorted(b.skeleton.end_sites) == sorted(a.skeleton.end_sites)
    for j, e in a.skeleton.end_sites.items():
        np.testing.assert_allclose(b.skeleton.end_sites[j], e, rtol=1e-9, atol=1e-12)
    assert b.fps == a.fps
    pa = a.positions()
    np.testing.assert_allclose(b.positions(), pa, rtol=0, atol=1e-8 * max(1.0, np.abs(pa).max()))
    np.testing.assert_allclose(matrices(b), matrices(a), atol=1e-8)


@settings(max_examples=40, deadline=None)
@given(spec=specs(), unit=st.sampled_from(["cm", "m", "mm", "in"]))
def test_random_valid_files_read_as_written_and_round_trip(spec: Spec, unit: str) -> None:
    with tempfile.TemporaryDirectory() as folder:
        src = Path(folder) / "random.bvh"
        src.write_bytes(spec_text(spec).encode())
        first = bvh.load(src, unit=unit)
        check_matches_spec(first, spec, unit_scale(unit))
        again = bvh.load(bvh.save(first, Path(folder) / "saved.bvh"), unit=unit)
        check_same_motion(first, again)


# ---- the table of odd and hostile files ----------------------------------------------------

SMALL_HIERARCHY = """HIERARCHY
ROOT Hips
{
  OFFSET 0 90 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Spine
  {
    OFFSET 0 10 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 20 0
    }
  }
  JOINT Leg
  {
    OFFSET 10 -5 0
    CHANNELS 3 Xrotation Yrotation Zrotation
    End Site
    {
      OFFSET 0 -40 0
    }
  }
}
"""
SMALL_ROWS = ["1.5 2 -3 10 20 30 5 6 7 -8 9 -10",
              "2.5 3 -4 11 21 31 6 7 8 -9 10 -11",
              "3.5 4 -5 12 22 32 7 8 9 -10 11 -12"]
MOTION_LINE = SMALL_HIERARCHY.count("\n") + 1
FRAMES_LINE, FRAME_TIME_LINE, FIRST_FRAME = MOTION_LINE + 1, MOTION_LINE + 2, MOTION_LINE + 3


def small(rows: list[str] = SMALL_ROWS, frames: int | str | None = None, frame_time: str = "0.04",
          hierarchy: str = SMALL_HIERARCHY) -> str:
    header = f"MOTION\nFrames: {len(rows) if frames is None else frames}\nFrame Time: {frame_time}\n"
    return hierarchy + header + "".join(row + "\n" for row in rows)


def line_of(text: str, needle: str) -> int:
    return text[:text.index(needle)].count("\n") + 1


def set_value(row: int, col: int, value: str) -> str:
    rows = [r.split() for r in SMALL_ROWS]
    rows[row][col] = value
    return small([" ".join(r) for r in rows])


def chain(n: int, offset: str = "0 1 0") -> str:
    """A hierarchy of ``n`` joints each the child of the last, unindented, and one frame."""
    lines = ["HIERARCHY"]
    for j in range(n):
        lines += [f"{'ROOT' if j == 0 else 'JOINT'} j{j}", "{", f"OFFSET {offset}",
                  "CHANNELS 3 Zrotation Xrotation Yrotation"]
    lines += ["}"] * n + ["MOTION", "Frames: 1", "Frame Time: 0.04", " ".join(["0"] * 3 * n)]
    return "\n".join(lines) + "\n"


def fan(n: int) -> str:
    """A root with ``n - 1`` leaf children, and two frames."""
    lines = ["HIERARCHY", "ROOT root", "{", "OFFSET 0 0 0",
             "CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"]
    for j in range(1, n):
        lines += [f"JOINT leaf{j}", "{", f"OFFSET {j % 7} 1 0", "CHANNELS 3 Zrotation Xrotation Yrotation",
                  "End Site { OFFSET 0 1 0 }", "}"]
    lines += ["}", "MOTION", "Frames: 2", "Frame Time: 0.04"] + [" ".join(["1"] * 3 * (n + 1))] * 2
    return "\n".join(lines) + "\n"


@dataclass(frozen=True)
class Refused:
    """Expected: a BVHError at ``line`` (None: about the whole file; "any": some line) with ``words``."""

    line: int | None | str
    words: str


@dataclass(frozen=True)
class Loads:
    """Expected: a Motion of ``frames`` frames that passes ``check``."""

    frames: int
    check: Callable[[Motion], None] = lambda m: None


def small_rotations() -> np.ndarray:
    values = np.array([r.split() for r in SMALL_ROWS], dtype=float)
    return np.stack([Rotation.from_euler(order, values[:, c:c + 3], degrees=True).as_matrix()
                     for order, c in (("ZXY", 3), ("ZXY", 6), ("XYZ", 9))], axis=1)


def same_as_small(m: Motion) -> None:
    assert m.skeleton.names == ("Hips", "Spine", "Leg") and sorted(m.skeleton.end_sites) == [1, 2]
    np.testing.assert_allclose(m.root, np.array([r.split()[:3] for r in SMALL_ROWS], dtype=float) * 0.01)
    np.testing.assert_allclose(matrices(m), small_rotations(), atol=1e-12)


def named(name: str) -> Callable[[Motion], None]:
    def check(m: Motion) -> None:
        assert m.skeleton.names[1] == name
    return check


def no_end_sites(m: Motion) -> None:
    assert m.skeleton.end_sites == {}
    np.testing.assert_allclose(matrices(m), small_rotations(), atol=1e-12)


def spine_without_channels(m: Motion) -> None:
    assert m.skeleton.channels[1] == () and np.array_equal(m.rotations[:, 1], np.tile([1.0, 0, 0, 0], (3, 1)))


def chain_of(n: int) -> Callable[[Motion], None]:
    def check(m: Motion) -> None:
        assert m.skeleton.parents.tolist() == list(range(-1, n - 1))
        np.testing.assert_allclose(m.positions()[0, :, 1], np.arange(1, n + 1) * 0.01, atol=1e-12)
    return check


def fan_of(n: int) -> Callable[[Motion], None]:
    def check(m: Motion) -> None:
        assert m.skeleton.parents.tolist() == [-1] + [0] * (n - 1) and len(m.skeleton.end_sites) == n - 1
    return check


def huge_but_allowed(m: Motion) -> None:
    assert np.abs(m.positions()).max() > 1e4  # 9.9e6 cm reach the positions, finitely (load_or_error)


def named_pipe(folder: Path) -> Path:
    if not hasattr(os, "mkfifo"):
        pytest.skip("no named pipes here")
    os.mkfifo(folder / "pipe")
    return folder / "pipe"


def small_with(old: str, new: str) -> str:
    """The small file with the first ``old`` replaced by ``new``."""
    text = small()
    assert old in text
    return text.replace(old, new, 1)


Data = str | bytes | Callable[[Path], Path]
SPINE, SPINE_OFFSET, SPINE_CHANNELS = (line_of(SMALL_HIERARCHY, s) for s in ("Spine", "OFFSET 0 10 0", "CHANNELS 3 Z"))
LEG_OFFSET, LEG_END_SITE = line_of(SMALL_HIERARCHY, "OFFSET 10 -5 0"), line_of(SMALL_HIERARCHY, "OFFSET 0 -40 0")
POSITIVE = "positive number of seconds"

#: (name, file content or a maker of the file, expected outcome): what the reader does with odd input.
CASES: list[tuple[str, Data, Refused | Loads]] = [
    # encodings and not-text
    ("empty file", b"", Refused(1, "file ends early: expected 'HIERARCHY'")),
    ("blank lines only", "\n  \n\t\n", Refused(1, "file ends early: expected 'HIERARCHY'")),
    ("binary garbage", bytes(range(256)) * 4, Refused(1, "not a text file")),
    ("random bytes", np.random.default_rng(7).integers(0, 256, 4096, dtype=np.uint8).tobytes(),
     Refused("any", "not a text file")),
    ("NUL bytes", b"\0" * 64, Refused(1, "not a text file")),
    ("UTF-16 text", small().encode("utf-16"), Refused(1, "not a text file")),
    ("Latin-1 joint name (read as Latin-1)", small_with("Spine", "Hüfte").encode("latin-1"),
     Loads(3, named("Hüfte"))),
    ("UTF-8 joint name", small_with("Spine", "Hüfte").encode(), Loads(3, named("Hüfte"))),
    ("UTF-8 byte-order mark", "\ufeff" + small(), Loads(3, same_as_small)),
    ("megabyte token", "x" * 1_000_000, Refused(1, "expected 'HIERARCHY', found 'xxxx")),
    ("control character in a name", small_with("Spine", "Sp\x1bine"), Refused(SPINE, "not a text file")),
    ("a directory", lambda folder: folder, Refused(None, "is a directory")),
    ("a named pipe", named_pipe, Refused(None, "not a regular file")),
    # layout
    ("CRLF line endings", small().replace("\n", "\r\n"), Loads(3, same_as_small)),
    ("CR line endings", small().replace("\n", "\r"), Loads(3, same_as_small)),
    ("tabs", small().replace("  ", "\t").replace(" ", "\t"), Loads(3, same_as_small)),
    ("trailing whitespace and blank lines", small().replace("\n", "  \t\n") + "\n\n \n", Loads(3, same_as_small)),
    ("End Site on one line", small_with("End Site\n    {\n      OFFSET 0 20 0\n    }", "End Site { OFFSET 0 20 0 }"),
     Loads(3, same_as_small)),
    ("no End Sites", re.sub(r"\s*End Site\s*\{[^}]*\}", "", small()), Loads(3, no_end_sites)),
    ("joint without channels", small([" ".join(r.split()[:6] + r.split()[9:]) for r in SMALL_ROWS],
                                     hierarchy=SMALL_HIERARCHY.replace("CHANNELS 3 Zrotation Xrotation Yrotation",
                                                                       "CHANNELS 0")),
     Loads(3, spine_without_channels)),
    ("no channels at all", re.sub(r"CHANNELS \d( \w+)*", "CHANNELS 0", small()), Refused(MOTION_LINE, "no channels")),
    ("no MOTION section", SMALL_HIERARCHY, Refused(MOTION_LINE - 1, "expected 'MOTION'")),
    ("missing closing brace", small_with("}\nMOTION", "MOTION"),
     Refused(MOTION_LINE - 2, "file ends early: expected 'JOINT', 'End' or '}'")),
    ("extra closing brace", small_with("}\nMOTION", "}\n}\nMOTION"),
     Refused(MOTION_LINE, "expected 'MOTION' after the hierarchy, found '}'")),
    # frame lines and counts
    ("0 frames", small([], frames=0), Refused(FRAMES_LINE, "0 frames")),
    ("1 frame", small(SMALL_ROWS[:1]), Loads(1)),
    ("Frames header larger than the data", small(frames=5),
     Refused(FIRST_FRAME + 2, "header says 5 frames but the file has 3")),
    ("Frames header smaller than the data", small(frames=2),
     Refused(FIRST_FRAME + 2, "header says 2 frames but the file has 3")),
    ("header but no frame lines", small([], frames=3), Refused(FRAME_TIME_LINE, "no frame lines follow")),
    ("blank line between frames", small([SMALL_ROWS[0], "", SMALL_ROWS[1]]), Refused(FIRST_FRAME + 1, "found 0")),
    ("frame with too few values", small([SMALL_ROWS[0], SMALL_ROWS[1][:-4], SMALL_ROWS[2]]),
     Refused(FIRST_FRAME + 1, "expected 12 channel values, found 11")),
    ("frame with too many values", small([SMALL_ROWS[0] + " 1", *SMALL_ROWS[1:]]),
     Refused(FIRST_FRAME, "expected 12 channel values, found 13")),
    ("frame with a comma decimal", set_value(2, 4, "20,5"),
     Refused(FIRST_FRAME + 2, "Hips Xrotation (value 5), found '20,5'")),
    ("frame count of 20 digits", small(frames="9" * 20), Refused(FRAMES_LINE, "whole number of frames")),
    ("frame count of 5000 digits", small(frames="9" * 5000), Refused(FRAMES_LINE, "whole number of frames")),
    ("frame count in full-width digits", small(frames="\uff13"), Refused(FRAMES_LINE, "whole number of frames")),
    ("negative frame count", small(frames=-3), Refused(FRAMES_LINE, "whole number of frames")),
    ("Frame Time line missing", small_with("Frame Time: 0.04\n", ""),
     Refused(FRAME_TIME_LINE, "expected 'Frame Time:'")),
    ("channel count of a billion", small_with("CHANNELS 3 Z", "CHANNELS 1000000000 Z"),
     Refused(SPINE_CHANNELS, "declares 1000000000 channels; a joint has at most 6")),
    ("channel count in superscript digits", small_with("CHANNELS 3 Z", "CHANNELS \u00b3 Z"),
     Refused(SPINE_CHANNELS, "expected a channel count")),
    # numbers: finite and at most bvh.MAX_ABS_VALUE
    ("1e308 rotation", set_value(0, 3, "1e308"),
     Refused(FIRST_FRAME, "Hips Zrotation (value 4) is 1e308: more than 1e+07")),
    ("1e400 rotation", set_value(1, 3, "1e400"),
     Refused(FIRST_FRAME + 1, "Hips Zrotation (value 4) is 1e400: expected a finite number")),
    ("-1e999 position", set_value(2, 0, "-1e999"), Refused(FIRST_FRAME + 2, "Hips Xposition (value 1) is -1e999")),
    ("NaN rotation", set_value(0, 7, "NaN"), Refused(FIRST_FRAME, "Spine Xrotation (value 8) is NaN")),
    ("inf position", set_value(1, 1, "inf"), Refused(FIRST_FRAME + 1, "Hips Yposition (value 2) is inf")),
    ("-Infinity rotation", set_value(2, 11, "-Infinity"),
     Refused(FIRST_FRAME + 2, "Leg Zrotation (value 12) is -Infinity")),
    ("1e308 offset", small_with("OFFSET 0 10 0", "OFFSET 0 1e308 0"),
     Refused(SPINE_OFFSET, "OFFSET of Spine is 1e308: more than 1e+07")),
    ("1e400 offset", small_with("OFFSET 0 10 0", "OFFSET 0 1e400 0"),
     Refused(SPINE_OFFSET, "OFFSET of Spine is 1e400: expected a finite number")),
    ("NaN offset", small_with("OFFSET 10 -5 0", "OFFSET nan -5 0"), Refused(LEG_OFFSET, "OFFSET of Leg is nan")),
    ("inf End Site offset", small_with("OFFSET 0 -40 0", "OFFSET 0 -inf 0"),
     Refused(LEG_END_SITE, "End Site OFFSET of Leg is -inf")),
    ("values just under the limit",
     small_with("OFFSET 0 10 0", "OFFSET 0 9.9e6 0").replace("1.5 2 -3 10", "1.5 9.9e6 -3 9.9e6"),
     Loads(3, huge_but_allowed)),
    ("frame time 0", small(frame_time="0"), Refused(FRAME_TIME_LINE, POSITIVE)),
    ("negative frame time", small(frame_time="-0.04"), Refused(FRAME_TIME_LINE, POSITIVE)),
    ("NaN frame time", small(frame_time="nan"), Refused(FRAME_TIME_LINE, POSITIVE)),
    ("infinite frame time", small(frame_time="1e999"), Refused(FRAME_TIME_LINE, POSITIVE)),
    ("denormal frame time", small(frame_time="5e-324"), Refused(FRAME_TIME_LINE, POSITIVE)),
    ("frame time of a day", small(frame_time="86400"), Refused(FRAME_TIME_LINE, POSITIVE)),
    ("frame time not a number", small(frame_time="fast"),
     Refused(FRAME_TIME_LINE, "expected a number for the frame time")),
    # size and shape
    ("500 joints in a fan", fan(500), Loads(2, fan_of(500))),
    ("500 joints in a chain", chain(500), Loads(1, chain_of(500))),
    ("5000-level hierarchy", chain(5000), Loads(1, chain_of(5000))),
]


def write(folder: Path, data: str | bytes) -> Path:
    path = folder / "case.bvh"
    path.write_bytes(data.encode() if isinstance(data, str) else data)
    return path


def check_outcome(result: Motion | BVHError, expected: Refused | Loads) -> None:
    if isinstance(expected, Refused):
        assert isinstance(result, BVHError), f"expected a BVHError, loaded {result}"
        if expected.line != "any":
            assert result.line == expected.line, result
        assert expected.words in result.message, result
    else:
        assert isinstance(result, Motion), result
        assert result.num_frames == expected.frames
        expected.check(result)


@pytest.mark.parametrize("data,expected", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_odd_file(data: Data, expected: Refused | Loads, tmp_path: Path) -> None:
    path = data(tmp_path) if callable(data) else write(tmp_path, data)
    check_outcome(load_or_error(path), expected)


def test_a_missing_file_is_file_not_found(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        bvh.load(tmp_path / "absent.bvh")


def test_latin1_names_are_saved_as_utf8(tmp_path: Path) -> None:
    src = write(tmp_path, small_with("Spine", "Hüfte").encode("latin-1"))
    out = bvh.save(bvh.load(src), tmp_path / "out.bvh")
    assert "Hüfte" in out.read_text(encoding="utf-8")
    assert bvh.load(out).skeleton.names[1] == "Hüfte"


def test_a_deep_hierarchy_is_saved_without_recursion_and_reads_back(tmp_path: Path) -> None:
    m = bvh.load(write(tmp_path, chain(5000)), unit="cm")
    out = bvh.save(m, tmp_path / "out.bvh")
    assert out.stat().st_size < 5_000_000  # indentation stops growing: tabs to each depth would make 60 MB
    check_same_motion(m, bvh.load(out, unit="cm"))


def test_values_near_the_float_limit_never_reach_positions_as_inf_or_nan(tmp_path: Path) -> None:
    """1e308 would pass a finiteness check and overflow in forward kinematics; the bound refuses it."""
    for old, new in (("OFFSET 0 10 0", "OFFSET 0 1e308 0"), ("OFFSET 0 -40 0", "OFFSET 0 -1.7e308 0"),
                     ("1.5 2 -3", "1.5 1e308 -3"), ("5 6 7", "5 6 1e300")):
        assert isinstance(load_or_error(write(tmp_path, small_with(old, new))), BVHError)
    deep = load_or_error(write(tmp_path, chain(200, offset="0 9.9e6 0")), unit="m")  # checks all are finite
    assert isinstance(deep, Motion) and deep.positions()[0, -1, 1] == pytest.approx(200 * 9.9e6)


# ---- truncations and byte flips ------------------------------------------------------------

def test_small_file_truncated_at_every_byte(tmp_path: Path) -> None:
    data = small().encode()
    whole = load_or_error(write(tmp_path, data))
    for cut in range(len(data)):
        result = load_or_error(write(tmp_path, data[:cut]))
        if isinstance(result, Motion):  # a cut in the last number, or in the final newline
            check_prefix_of(result, whole)


def test_cmu_clip_truncated_every_two_percent_and_through_the_hierarchy(tmp_path: Path) -> None:
    data = CMU.read_bytes()
    whole = load_or_error(write(tmp_path, data))
    hierarchy_end = data.index(b"MOTION")
    cuts = sorted(set(range(0, len(data), len(data) // 50)) | set(range(1, hierarchy_end + 40, 97)))
    for cut in cuts:
        result = load_or_error(write(tmp_path, data[:cut]))
        if isinstance(result, Motion):
            check_prefix_of(result, whole)


def check_prefix_of(part: Motion, whole: Motion) -> None:
    """A cut file that still loads is the whole one, bar the last frame (cut within a number)."""
    assert part.num_frames == whole.num_frames and part.skeleton.names == whole.skeleton.names
    np.testing.assert_array_equal(part.rotations[:-1], whole.rotations[:-1])


def flipped(data: bytes, rng: np.random.Generator, within: int) -> bytes:
    """``data`` with one to three bytes (at offsets below ``within``) set to random values."""
    out = bytearray(data)
    for at in rng.integers(0, within, rng.integers(1, 4)):
        out[at] = int(rng.integers(0, 256))
    return bytes(out)


@pytest.mark.parametrize("source", ["small", "cmu"])
def test_random_byte_flips(source: str, tmp_path: Path) -> None:
    data = small().encode() if source == "small" else CMU.read_bytes()
    rng = np.random.default_rng(2024)
    outcomes = {"loads": 0, "refused": 0}
    for k in range(200 if source == "small" else 100):
        within = len(data) if k % 2 else data.index(b"MOTION")  # half of them in the hierarchy
        result = load_or_error(write(tmp_path, flipped(data, rng, within)))
        outcomes["loads" if isinstance(result, Motion) else "refused"] += 1
    assert outcomes["refused"] > 0 and outcomes["loads"] > 0, outcomes  # both paths were exercised


# ---- long files and the frame limit --------------------------------------------------------

def long_file(n_frames: int, folder: Path) -> tuple[Path, np.ndarray]:
    """The small skeleton with ``n_frames`` frames: 1000 random rows repeated."""
    rows = np.random.default_rng(5).uniform(-170, 170, (1000, 12)).round(5)
    block = "".join(" ".join(f"{v:.5f}" for v in row) + "\n" for row in rows)
    return write(folder, small([], frames=n_frames) + block * (n_frames // 1000)), rows


def test_100k_frames_load_correctly_and_fast(tmp_path: Path) -> None:
    path, rows = long_file(100_000, tmp_path)
    start = time.perf_counter()
    m = load_or_error(path)
    seconds = time.perf_counter() - start
    assert isinstance(m, Motion) and m.num_frames == 100_000
    np.testing.assert_allclose(m.root, np.tile(rows[:, :3], (100, 1)) * 0.01, rtol=1e-15)
    np.testing.assert_allclose(np.rad2deg(m.euler_hint[:, 2]), np.tile(rows[:, 9:], (100, 1)), rtol=1e-15)
    assert seconds < 5.0, f"100 000 frames took {seconds:.1f} s"


def test_max_frames_refuses_before_reading_frames(tmp_path: Path) -> None:
    path = write(tmp_path, small(["garbage"], frames=10**15))  # the frame data is never looked at
    with pytest.raises(BVHError) as info:
        bvh.load(path, max_frames=1000)
    assert info.value.line == FRAMES_LINE
    assert ("declares 1000000000000000 frames, more than the limit of 1000 (--max-frames)"
            in info.value.message)


def test_max_frames_at_or_above_the_count_loads(tmp_path: Path) -> None:
    path = write(tmp_path, small())
    assert bvh.load(path, max_frames=3).num_frames == 3
    _, values, _ = bvh.read_channels(path, max_frames=3)
    assert values.shape == (3, 12)
    with pytest.raises(BVHError, match="declares 3 frames, more than the limit of 2"):
        bvh.read_channels(path, max_frames=2)
    assert bvh.load(path).num_frames == 3  # no limit by default
