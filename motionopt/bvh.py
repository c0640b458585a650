"""BVH files: ``load`` into a Motion and ``save`` back, with errors that name file and line.

Supported: any rotation channel order per joint, 3- or 6-channel joints (position
channels replace the rest offset), End Sites, tabs or spaces, Windows line endings,
trailing blank lines. Lengths are converted to metres on load and back on save; the
Euler angles read are kept (``Motion.euler_hint``) so that a file written back has the
same numbers, and rounded header frame times are read as the rate they stand for.

Hostile or odd input: whatever a file holds, ``load`` and ``read_channels`` return a
correct result or raise ``BVHError`` with the file, the line where there is one, and what
was wrong; never another exception (a missing file is the usual ``FileNotFoundError``)
and never a hang. In detail:

* Text is UTF-8, with or without a byte-order mark. A file that is not valid UTF-8 is read
  as Latin-1 throughout (old exporters wrote names such as ``Hüfte`` in a Windows code
  page). Control characters (NUL and the like) in the hierarchy mean "not a text file".
  ``save`` always writes UTF-8.
* Every number must be finite and at most ``MAX_ABS_VALUE`` (1e7) in magnitude: offsets
  and positions in file units, rotations in degrees. Larger values are corrupt data, not
  motion capture (1e7 mm is 10 km), and near the float limit they would become inf or
  NaN in unit conversion and forward kinematics. The frame time must lie between
  ``MIN_FRAME_TIME`` and ``MAX_FRAME_TIME`` seconds.
* The hierarchy may be any depth (it is read and written without recursion); a joint
  has at most six channels.
* A file needs at least one frame; the ``Frames:`` count must equal the number of frame
  lines (blank lines at the end do not count), each with one value per channel.
* With ``max_frames``, a file that declares more frames is refused before its frame
  data is read, so a runaway file costs neither time nor memory.
* Directories, pipes and devices are refused as not regular files.
"""
from __future__ import annotations

import itertools
import math
import os
import re
import stat
from pathlib import Path
from typing import TextIO

import numpy as np
import torch

from . import rotations as R
from .atomic import atomic_file
from .motion import Motion, unit_scale
from .skeleton import Skeleton

_ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")
_POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
_VALID_CHANNELS = set(_ROTATION_CHANNELS + _POSITION_CHANNELS)

#: Largest magnitude accepted for an offset, position (file units) or angle (degrees).
MAX_ABS_VALUE = 1e7
#: Accepted frame times in seconds: a million frames a second down to one an hour.
MIN_FRAME_TIME, MAX_FRAME_TIME = 1e-6, 3600.0
_MAX_COUNT_DIGITS = 18  # longer counts are refused before int() (which caps at 4300 digits)
_CONTROL = re.compile(r"[\x00-\x08\x0e-\x1f\x7f]")  # tab, newlines, \v and \f are whitespace
_QUATS_PER_CALL = 1 << 16  # Euler angles converted in blocks that stay in cache: 3x faster on long files
_MAX_INDENT = 32  # deeper joints are written at this indentation, so a long chain gives no quadratic file


class BVHError(ValueError):
    """A malformed BVH file: says which file, which line, and what was expected."""

    def __init__(self, path: str | os.PathLike, line: int | None, message: str):
        self.path, self.line, self.message = str(path), line, message
        where = f"{path}:{line}" if line else str(path)
        super().__init__(f"{where}: {message}")


def _show(text: str) -> str:
    """``repr`` of a token for a message, cut short: a garbage file may hold megabyte tokens."""
    return repr(text) if len(text) <= 40 else repr(text[:40]) + "..."


def _check_magnitude(value: float, text: str, what: str, path: str, line: int) -> None:
    if not math.isfinite(value):
        raise BVHError(path, line, f"{what} is {text}: expected a finite number")
    if abs(value) > MAX_ABS_VALUE:
        raise BVHError(path, line, f"{what} is {text}: more than {MAX_ABS_VALUE:g} in magnitude, "
                                   "too large for motion capture (a corrupt file?)")


def _count(text: str) -> int | None:
    """A whole number of at most ``_MAX_COUNT_DIGITS`` ASCII digits, or None."""
    ok = text.isascii() and text.isdigit() and len(text) <= _MAX_COUNT_DIGITS
    return int(text) if ok else None


class _Tokens:
    """Whitespace tokens of the HIERARCHY section with their line numbers."""

    def __init__(self, lines: list[str], path: str):
        self.items: list[tuple[str, int]] = []
        self.path = path
        self.end_line = 1
        for i, line in enumerate(lines, start=1):
            for tok in line.split():
                self.items.append((tok, i))
                self.end_line = i
        self.pos = 0

    def next(self, expected: str) -> tuple[str, int]:
        if self.pos >= len(self.items):
            raise BVHError(self.path, self.end_line, f"file ends early: expected {expected}")
        tok = self.items[self.pos]
        self.pos += 1
        return tok

    def expect(self, word: str) -> int:
        tok, line = self.next(repr(word))
        if tok != word:
            raise BVHError(self.path, line, f"expected {word!r}, found {_show(tok)}")
        return line

    def number(self, what: str) -> float:
        tok, line = self.next(what)
        try:
            value = float(tok)
        except ValueError:
            raise BVHError(self.path, line, f"expected a number for {what}, found {_show(tok)}") from None
        _check_magnitude(value, tok, what, self.path, line)
        return value

    def offset(self, what: str) -> np.ndarray:
        self.expect("OFFSET")
        return np.array([self.number(what) for _ in range(3)])

    def peek(self) -> str | None:
        return self.items[self.pos][0] if self.pos < len(self.items) else None


def guess_unit(offsets: np.ndarray, parents: np.ndarray) -> str:
    """Guess the length unit from the rest skeleton's size (its largest extent along an
    axis): under 5 is metres, under 500 centimetres, more is millimetres. A human is
    about 1.7 m; inches (about 67) cannot be told from centimetres, so pass the unit."""
    pos = np.zeros_like(offsets)
    for j in range(1, len(parents)):
        pos[j] = pos[parents[j]] + offsets[j]
    extent = float(np.ptp(pos, axis=0).max()) if len(pos) > 1 else 0.0
    if 0 < extent < 5.0:
        return "m"
    return "cm" if extent < 500.0 else "mm"


class _Hierarchy:
    """The joints read so far, in file order (parents before children)."""

    def __init__(self) -> None:
        self.names: list[str] = []
        self.parents: list[int] = []
        self.offsets: list[np.ndarray] = []
        self.channels: list[tuple[str, ...]] = []
        self.end_sites: dict[int, np.ndarray] = {}
        self.name_lines: dict[str, int] = {}

    def skeleton(self) -> Skeleton:
        return Skeleton(tuple(self.names), np.array(self.parents), np.array(self.offsets),
                        tuple(self.channels), self.end_sites)


def _parse_channels(tok: _Tokens, name: str) -> tuple[str, ...]:
    tok.expect("CHANNELS")
    n_tok, n_line = tok.next("a channel count")
    n = _count(n_tok)
    if n is None:
        raise BVHError(tok.path, n_line, f"expected a channel count for {name}, found {_show(n_tok)}")
    if n > 6:
        raise BVHError(tok.path, n_line, f"joint {name} declares {n} channels; a joint has at most 6")
    chans = []
    for _ in range(n):
        c, c_line = tok.next(f"a channel name of {name}")
        if c not in _VALID_CHANNELS:
            raise BVHError(tok.path, c_line, f"unknown channel {_show(c)} for joint {name}; expected one of "
                           + ", ".join(sorted(_VALID_CHANNELS)))
        chans.append(c)
    rot = [c for c in chans if c in _ROTATION_CHANNELS]
    if len(rot) not in (0, 3) or len(set(chans)) != len(chans):
        raise BVHError(tok.path, n_line, f"joint {name} must have three distinct rotation channels, got {chans}")
    return tuple(chans)


def _parse_joint_head(tok: _Tokens, h: _Hierarchy, parent: int) -> int:
    """Name, OFFSET and CHANNELS of the joint whose keyword was just read; its index."""
    name, line = tok.next("a joint name")
    if name == "{":
        raise BVHError(tok.path, line, "joint has no name")
    if name in h.name_lines:
        raise BVHError(tok.path, line, f"duplicate joint name {_show(name)} (first at line {h.name_lines[name]})")
    h.name_lines[name] = line
    tok.expect("{")
    h.names.append(name)
    h.parents.append(parent)
    h.offsets.append(tok.offset(f"OFFSET of {name}"))
    h.channels.append(_parse_channels(tok, name))
    return len(h.names) - 1


def _parse_hierarchy(tok: _Tokens) -> Skeleton:
    """The HIERARCHY section. Joints open and close on an explicit stack rather than by
    recursion, so that no depth of nesting can exhaust Python's call stack."""
    h = _Hierarchy()
    tok.expect("HIERARCHY")
    kw, line = tok.next("'ROOT'")
    if kw != "ROOT":
        raise BVHError(tok.path, line, f"expected 'ROOT', found {_show(kw)}")
    open_joints = [_parse_joint_head(tok, h, -1)]
    while open_joints:
        j = open_joints[-1]
        kw, kw_line = tok.next("'JOINT', 'End' or '}'")
        if kw == "}":
            open_joints.pop()
        elif kw == "JOINT":
            open_joints.append(_parse_joint_head(tok, h, j))
        elif kw == "End":
            tok.expect("Site")
            tok.expect("{")
            h.end_sites[j] = tok.offset(f"End Site OFFSET of {h.names[j]}")
            tok.expect("}")
        else:
            raise BVHError(tok.path, kw_line,
                           f"expected 'JOINT', 'End Site' or '}}' inside {h.names[j]}, found {_show(kw)}")
    if tok.peek() is not None:
        t, l = tok.items[tok.pos]
        raise BVHError(tok.path, l, f"expected 'MOTION' after the hierarchy, found {_show(t)}")
    return h.skeleton()


def read_channels(path: str | os.PathLike, max_frames: int | None = None) -> tuple[Skeleton, np.ndarray, float]:
    """Parse a BVH file into its skeleton (in file units), raw channel values (T, C) and frame time.

    The text is read as UTF-8, or as Latin-1 when it is not valid UTF-8 (names such as
    ``Hüfte`` from old exporters); anything malformed raises ``BVHError`` (see the module
    notes on hostile input). ``max_frames`` refuses a file that declares more frames,
    before its frame data is read.
    """
    path = str(path)
    try:
        _check_regular_file(path)
        try:
            return _read_channels(path, "utf-8-sig", max_frames)
        except UnicodeDecodeError:
            return _read_channels(path, "latin-1", max_frames)
    except FileNotFoundError:
        raise  # the usual error for a missing file, which callers already handle
    except OSError as e:
        raise BVHError(path, None, f"cannot read the file: {e.strerror or e}") from None


def _check_regular_file(path: str) -> None:
    """Refuse directories, pipes and devices, which would fail or block when read."""
    mode = os.stat(path).st_mode
    if stat.S_ISDIR(mode):
        raise BVHError(path, None, "is a directory, not a BVH file")
    if not stat.S_ISREG(mode):
        raise BVHError(path, None, "not a regular file (a pipe or a device?)")


def _read_channels(path: str, encoding: str, max_frames: int | None) -> tuple[Skeleton, np.ndarray, float]:
    """``read_channels`` with one text encoding; reads the frame lines only once the
    hierarchy and the headers are known to be good."""
    with open(path, encoding=encoding, newline=None) as f:  # newline=None: \r\n and \r read as \n
        head = _read_head(f, path)
        has_motion = bool(head) and head[-1].strip() == "MOTION"
        tok = _Tokens(head[:-1] if has_motion else head, path)
        skeleton = _parse_hierarchy(tok)
        if not has_motion:
            raise BVHError(path, tok.end_line, "file ends after the hierarchy: expected 'MOTION'")
        motion_line = len(head)
        if not any(skeleton.channels):
            raise BVHError(path, motion_line, "the hierarchy has no channels: there is no motion to read")
        n_frames, count_line = _frame_count(f, path, motion_line + 1, max_frames)
        frame_time, time_line = _frame_time(f, path, count_line + 1)
        lines = _frame_lines(f, path, n_frames, time_line + 1)
    return skeleton, _parse_frames(lines, skeleton, path, time_line + 1), frame_time


def _read_head(f: TextIO, path: str) -> list[str]:
    """Lines up to and including the MOTION line (the whole file when there is none)."""
    head: list[str] = []
    for line in f:
        head.append(line)
        bad = _CONTROL.search(line)
        if bad:
            raise BVHError(path, len(head), f"not a text file in UTF-8 or Latin-1 (control character "
                                            f"U+{ord(bad.group()):04X})")
        if line.strip() == "MOTION":
            break
    return head


def _header(f: TextIO, path: str, line_no: int, key: str) -> tuple[str, int]:
    """The text after ``key`` on the next non-blank line (line ``line_no`` or later), and
    that line's number. Blank lines before a header are skipped, as bvhio and Blender do:
    some exporters write one between ``MOTION`` and ``Frames:``."""
    after = line_no - 1  # the last line with text
    line = f.readline()
    while line and not line.strip():
        line, line_no = f.readline(), line_no + 1
    if not line:
        raise BVHError(path, after, f"file ends early: expected '{key}'")
    line = " ".join(line.split())  # "Frame\tTime:" reads as "Frame Time:"
    if not line.startswith(key):
        raise BVHError(path, line_no, f"expected '{key}', found {_show(line)}")
    return line[len(key):].strip(), line_no


def _frame_count(f: TextIO, path: str, line_no: int, max_frames: int | None) -> tuple[int, int]:
    """The declared frame count and the number of the line that holds it."""
    text, line_no = _header(f, path, line_no, "Frames:")
    n_frames = _count(text)
    if n_frames is None:
        raise BVHError(path, line_no, f"expected a whole number of frames (at most {_MAX_COUNT_DIGITS} digits), "
                                      f"found {_show(text)}")
    if n_frames == 0:
        raise BVHError(path, line_no, "empty MOTION section: the header says 0 frames")
    if max_frames is not None and n_frames > max_frames:
        raise BVHError(path, line_no, f"the file declares {n_frames} frames, more than the limit of {max_frames} "
                                      "(--max-frames); raise the limit to read it")
    return n_frames, line_no


def _frame_time(f: TextIO, path: str, line_no: int) -> tuple[float, int]:
    """The frame time in seconds and the number of the line that holds it."""
    text, line_no = _header(f, path, line_no, "Frame Time:")
    try:
        frame_time = float(text)
    except ValueError:
        raise BVHError(path, line_no, f"expected a number for the frame time, found {_show(text)}") from None
    if not MIN_FRAME_TIME <= frame_time <= MAX_FRAME_TIME:  # NaN fails this too
        raise BVHError(path, line_no, f"frame time must be a positive number of seconds from {MIN_FRAME_TIME:g} "
                                      f"to {MAX_FRAME_TIME:g}, got {_show(text)}")
    return frame_time, line_no


def _frame_lines(f: TextIO, path: str, n_frames: int, first: int) -> list[str]:
    """The frame lines (the first is line ``first``), checked against the header's count.
    At most ``n_frames`` lines are kept in memory; lines beyond are only counted."""
    lines = list(itertools.islice(f, n_frames))
    extra = 0  # lines after the declared frames, up to the last non-blank one
    for k, line in enumerate(f, start=1):
        if line.strip():
            extra = k
    count = n_frames + extra
    if not extra:
        count = len(lines)
        while count and not lines[count - 1].strip():
            count -= 1
    if count == 0:
        raise BVHError(path, first - 1,
                       f"empty MOTION section: the header says {n_frames} frames but no frame lines follow")
    if count != n_frames:
        # point at the first extra line, or at the last line of a short file
        raise BVHError(path, first - 1 + min(count, n_frames + 1),
                       f"header says {n_frames} frames but the file has {count} frame lines")
    return lines


def _parse_frames(lines: list[str], skeleton: Skeleton, path: str, first: int) -> np.ndarray:
    """Channel values (T, C) of the frame lines, all finite and of sane magnitude."""
    columns = [f"{name} {c}" for name, chans in zip(skeleton.names, skeleton.channels) for c in chans]
    values = _parse_frames_fast(lines, len(columns))
    if values is None:
        values = _parse_frames_by_line(lines, columns, path, first)
    if not np.abs(values).max() <= MAX_ABS_VALUE:  # NaN fails this too
        i, k = np.argwhere(~(np.abs(values) <= MAX_ABS_VALUE))[0]
        _check_magnitude(values[i, k], lines[i].split()[k], f"{columns[k]} (value {k + 1})", path, first + i)
    return values


def _parse_frames_fast(lines: list[str], n_channels: int) -> np.ndarray | None:
    """All values at once by numpy's C parser (it accepts a subset of what ``float``
    does), or None where it fails or finds another shape: ``_parse_frames_by_line``
    then reads the file or names the fault."""
    if not lines[0].strip():
        return None  # loadtxt skips blank lines, and warns when it finds nothing else
    try:
        values = np.loadtxt(lines, dtype=np.float64, comments=None, ndmin=2)
    except ValueError:
        return None
    return values if values.shape == (len(lines), n_channels) else None


def _parse_frames_by_line(lines: list[str], columns: list[str], path: str, first: int) -> np.ndarray:
    values = np.empty((len(lines), len(columns)))
    for i, line in enumerate(lines):
        parts = line.split()
        if len(parts) != len(columns):
            raise BVHError(path, first + i, f"expected {len(columns)} channel values, found {len(parts)}")
        try:
            values[i] = [float(p) for p in parts]
        except ValueError:
            k = next(k for k, p in enumerate(parts) if not _is_float(p))
            raise BVHError(path, first + i,
                           f"expected a number for {columns[k]} (value {k + 1}), found {_show(parts[k])}") from None
    return values


def _is_float(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def frame_rate(frame_time: float) -> float:
    """Frames per second for a header's frame time.

    Headers round the frame time (``0.0333333`` for 30 fps). When the value has five or
    more significant digits and a rate with at most three decimals gives that value to
    the digits written, that rate is returned: 30.0 rather than 30.00003, so that
    resampling lands on whole frames. Short values (``0.04``, ``0.03``) are taken as exact.
    """
    text = repr(float(frame_time))  # the shortest text that reads back as this number
    mantissa, _, exponent = text.lower().partition("e")
    raw = 1.0 / frame_time
    if len(mantissa.replace("-", "").replace(".", "").lstrip("0")) < 5:
        return raw
    half_unit = 0.5 * 10.0 ** -(len(mantissa.partition(".")[2]) - int(exponent or 0))
    for places in range(4):
        fps = round(raw, places)
        if fps > 0 and abs(1.0 / fps - frame_time) <= half_unit * (1 + 1e-6):
            return fps
    return raw


def frame_time_text(fps: float) -> str:
    """The shortest frame time text (at least six significant digits, as most files
    write it) that ``frame_rate`` reads back as ``fps``."""
    for digits in range(6, 18):
        text = f"{1.0 / fps:.{digits}g}"
        if frame_rate(float(text)) == fps:
            return text
    return repr(1.0 / fps)


def load(path: str | os.PathLike, unit: str = "auto", fps: float | None = None,
         max_frames: int | None = None) -> Motion:
    """Read a BVH file into a Motion in metres.

    Args:
        unit: length unit of the file ('cm', 'm', 'mm', 'in'), or 'auto' to guess from
            the skeleton's size (``guess_unit``).
        fps: override the frame rate stated in the file (for files with a wrong header);
            otherwise the header's, as ``frame_rate`` reads it.
        max_frames: refuse (``BVHError``) a file that declares more frames, before
            reading them; None for no limit.
    """
    skeleton, values, frame_time = read_channels(path, max_frames=max_frames)
    if unit == "auto":
        unit = guess_unit(skeleton.offsets, skeleton.parents)
    scale = unit_scale(unit)
    orders, rot_cols, pos_cols = _layout(skeleton.channels)
    hint = np.deg2rad(values[:, np.maximum(rot_cols, 0)])
    hint[:, rot_cols[:, 0] < 0] = 0.0  # joints without rotation channels
    rotations = _rotations(hint, orders)
    root = _translations(values, skeleton.offsets[:1], pos_cols[:1])[:, 0]  # the OFFSET without position channels
    moving = (pos_cols[1:] >= 0).any()
    return Motion(
        skeleton.scaled(scale),
        rotations,
        root * scale,
        fps=float(fps) if fps is not None else frame_rate(frame_time),
        translations=_translations(values, skeleton.offsets, pos_cols) * scale if moving else None,
        source_unit=unit,
        euler_hint=hint,
    )


def _layout(channels: tuple[tuple[str, ...], ...]) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Where each joint's channels are among the frame values: its Euler order ('' without
    rotation channels), the (J, 3) columns of its rotation channels in that order, and the
    (J, 3) columns of its X, Y, Z position channels; -1 where a joint has none."""
    orders: list[str] = []
    rot_cols = np.full((len(channels), 3), -1)
    pos_cols = np.full((len(channels), 3), -1)
    col = 0
    for j, chans in enumerate(channels):
        rot = [k for k, c in enumerate(chans) if c in _ROTATION_CHANNELS]
        orders.append("".join(chans[k][0] for k in rot))
        rot_cols[j, :len(rot)] = [col + k for k in rot]
        for axis, c in enumerate(_POSITION_CHANNELS):
            if c in chans:
                pos_cols[j, axis] = col + chans.index(c)
        col += len(chans)
    return orders, rot_cols, pos_cols


def _translations(values: np.ndarray, offsets: np.ndarray, pos_cols: np.ndarray) -> np.ndarray:
    """(T, J, 3) local translations: position channel values where a joint has them, its offset elsewhere."""
    out = np.broadcast_to(offsets, (len(values),) + offsets.shape).copy()
    has = pos_cols >= 0
    out[:, has] = values[:, pos_cols[has]]
    return out


def _rotations(hint: np.ndarray, orders: list[str]) -> np.ndarray:
    """Quaternions (T, J, 4) for Euler angles (T, J, 3) in radians in each joint's order
    (identity for a joint without one). One torch call per Euler order, not per joint
    (small calls are costly on a busy CPU), and per block of frames (blocks that stay in
    cache make long files several times faster)."""
    rotations = np.zeros(hint.shape[:-1] + (4,))
    rotations[..., 0] = 1.0
    groups = [(o, [j for j, x in enumerate(orders) if x == o]) for o in sorted(set(orders) - {""})]
    step = max(1, _QUATS_PER_CALL // hint.shape[1])
    for t in range(0, len(hint), step):
        for order, joints in groups:
            angles = torch.from_numpy(hint[t:t + step, joints])
            rotations[t:t + step, joints] = R.euler_to_quat(angles, order).numpy()
    return rotations


def motion_to_channels(motion: Motion, unit: str | None = None) -> np.ndarray:
    """Channel values (T, C) for a Motion in its skeleton's channel layout.

    Of the equivalent Euler triples, each frame takes the one nearest the motion's
    ``euler_hint`` (the angles it was read with) or, without a hint, the one nearest the
    previous frame's, so curves do not jump by 360 degrees.
    """
    scale = 1.0 / unit_scale(unit or motion.source_unit)
    sk = motion.skeleton
    trans = motion.local_translations() * scale
    by_order: dict[str, list[int]] = {}
    for j, chans in enumerate(sk.channels):
        rot_names = [c for c in chans if c in _ROTATION_CHANNELS]
        if rot_names:
            by_order.setdefault("".join(c[0] for c in rot_names), []).append(j)
    degrees = np.zeros((motion.num_frames, sk.num_joints, 3))
    for order, joints in by_order.items():
        eul = R.quat_to_euler(torch.from_numpy(motion.rotations[:, joints]), order)
        if motion.euler_hint is not None:
            eul = R.euler_nearest(eul, torch.from_numpy(motion.euler_hint[:, joints]))
        else:
            eul = _continuous(eul)
        degrees[:, joints] = np.rad2deg(eul.numpy())
    blocks = []
    for j, chans in enumerate(sk.channels):
        rot_names = [c for c in chans if c in _ROTATION_CHANNELS]
        block = np.zeros((motion.num_frames, len(chans)))
        for k, c in enumerate(rot_names):
            block[:, chans.index(c)] = degrees[:, j, k]
        for axis, c in enumerate(_POSITION_CHANNELS):
            if c in chans:
                block[:, chans.index(c)] = trans[:, j, axis]
        blocks.append(block)
    return np.concatenate(blocks, axis=1)


def _continuous(eul: torch.Tensor) -> torch.Tensor:
    """Each frame's Euler triples (T, ..., 3) nearest the previous frame's (a loop over frames)."""
    alt = torch.stack((eul[..., 0] + math.pi, math.pi - eul[..., 1], eul[..., 2] + math.pi), dim=-1).numpy()
    cur = eul.numpy().copy()
    two_pi = 2 * math.pi
    for t in range(1, len(cur)):
        ref = cur[t - 1]
        a = cur[t] - two_pi * np.round((cur[t] - ref) / two_pi)
        b = alt[t] - two_pi * np.round((alt[t] - ref) / two_pi)
        closer = ((b - ref) ** 2).sum(-1, keepdims=True) < ((a - ref) ** 2).sum(-1, keepdims=True)
        cur[t] = np.where(closer, b, a)
    return torch.from_numpy(cur)


def save(motion: Motion, path: str | os.PathLike, unit: str | None = None, force: bool = False,
         precision: int = 10) -> Path:
    """Write a Motion as BVH in UTF-8 (in ``unit``, default the unit it was read in).

    Refuses to replace an existing file unless ``force``; writes to a temporary file
    in the same folder and renames it, so an interrupted run leaves no half file.
    """
    path = Path(path)
    if path.exists() and not force:
        raise FileExistsError(f"{path} exists; pass force=True (--force) to overwrite it")
    unit = unit or motion.source_unit
    lines = _hierarchy_lines(motion.skeleton, 1.0 / unit_scale(unit), precision)
    values = motion_to_channels(motion, unit)
    lines += ["MOTION", f"Frames: {motion.num_frames}", f"Frame Time: {frame_time_text(motion.fps)}"]
    body = "\n".join(lines) + "\n"
    with atomic_file(path) as f:
        f.write(body)
        np.savetxt(f, values, fmt=f"%.{precision}g")
    return path


def _hierarchy_lines(sk: Skeleton, scale: float, precision: int) -> list[str]:
    """The HIERARCHY section, written from an explicit stack (no recursion, so any depth)."""
    def fmt(v: np.ndarray) -> str:
        return " ".join(f"{x:.{precision}g}" for x in v * scale)

    children: list[list[int]] = [[] for _ in sk.names]
    depth = [0] * sk.num_joints
    for j in range(1, sk.num_joints):
        children[sk.parents[j]].append(j)
        depth[j] = depth[sk.parents[j]] + 1
    lines = ["HIERARCHY"]
    todo = [(0, False)]  # (joint, whether to close it)
    while todo:
        j, close = todo.pop()
        pad = "\t" * min(depth[j], _MAX_INDENT)
        if close:
            if j in sk.end_sites:
                lines += [f"{pad}\tEnd Site", f"{pad}\t{{", f"{pad}\t\tOFFSET {fmt(sk.end_sites[j])}", f"{pad}\t}}"]
            lines.append(f"{pad}}}")
            continue
        lines += [f"{pad}{'ROOT' if j == 0 else 'JOINT'} {sk.names[j]}", f"{pad}{{",
                  f"{pad}\tOFFSET {fmt(sk.offsets[j])}",
                  f"{pad}\tCHANNELS {len(sk.channels[j])} {' '.join(sk.channels[j])}".rstrip()]
        todo.append((j, True))
        todo += [(c, False) for c in reversed(children[j])]
    return lines
