"""BVH files: ``load`` into a Motion and ``save`` back, with errors that name file and line.

Supported: any rotation channel order per joint, 3- or 6-channel joints (position
channels replace the rest offset), End Sites, tabs or spaces, Windows line endings,
trailing blank lines. Lengths are converted to metres on load and back on save; the
Euler angles read are kept (``Motion.euler_hint``) so that a file written back has the
same numbers, and rounded header frame times are read as the rate they stand for.
"""
from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path

import numpy as np
import torch

from . import rotations as R
from .motion import Motion, unit_scale
from .skeleton import Skeleton

_ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")
_POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
_VALID_CHANNELS = set(_ROTATION_CHANNELS + _POSITION_CHANNELS)


class BVHError(ValueError):
    """A malformed BVH file: says which file, which line, and what was expected."""

    def __init__(self, path: str | os.PathLike, line: int | None, message: str):
        self.path, self.line, self.message = str(path), line, message
        where = f"{path}:{line}" if line else str(path)
        super().__init__(f"{where}: {message}")


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
            raise BVHError(self.path, line, f"expected {word!r}, found {tok!r}")
        return line

    def number(self, what: str) -> float:
        tok, line = self.next(what)
        try:
            value = float(tok)
        except ValueError:
            raise BVHError(self.path, line, f"expected a number for {what}, found {tok!r}") from None
        if not math.isfinite(value):
            raise BVHError(self.path, line, f"{what} is not finite ({tok})")
        return value

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


def _parse_hierarchy(tok: _Tokens):
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[tuple[str, ...]] = []
    end_sites: dict[int, np.ndarray] = {}
    name_lines: dict[str, int] = {}

    tok.expect("HIERARCHY")
    kw, line = tok.next("'ROOT'")
    if kw != "ROOT":
        raise BVHError(tok.path, line, f"expected 'ROOT', found {kw!r}")

    def parse_joint(parent: int, keyword_line: int) -> None:
        name, line = tok.next("a joint name")
        if name == "{":
            raise BVHError(tok.path, line, "joint has no name")
        if name in name_lines:
            raise BVHError(tok.path, line, f"duplicate joint name {name!r} (first at line {name_lines[name]})")
        name_lines[name] = line
        j = len(names)
        names.append(name)
        parents.append(parent)
        tok.expect("{")
        tok.expect("OFFSET")
        offsets.append([tok.number(f"OFFSET of {name}") for _ in range(3)])
        tok.expect("CHANNELS")
        n_tok, n_line = tok.next("a channel count")
        if not n_tok.isdigit():
            raise BVHError(tok.path, n_line, f"expected a channel count for {name}, found {n_tok!r}")
        chans = []
        for _ in range(int(n_tok)):
            c, c_line = tok.next(f"a channel name of {name}")
            if c not in _VALID_CHANNELS:
                raise BVHError(tok.path, c_line, f"unknown channel {c!r} for joint {name}; expected one of "
                               + ", ".join(sorted(_VALID_CHANNELS)))
            chans.append(c)
        rot = [c for c in chans if c in _ROTATION_CHANNELS]
        if len(rot) not in (0, 3) or len(set(chans)) != len(chans):
            raise BVHError(tok.path, n_line, f"joint {name} must have three distinct rotation channels, got {chans}")
        channels.append(tuple(chans))
        while True:
            kw, kw_line = tok.next("'JOINT', 'End' or '}'")
            if kw == "}":
                return
            if kw == "JOINT":
                parse_joint(j, kw_line)
            elif kw == "End":
                tok.expect("Site")
                tok.expect("{")
                tok.expect("OFFSET")
                end_sites[j] = np.array([tok.number(f"End Site OFFSET of {name}") for _ in range(3)])
                tok.expect("}")
            else:
                raise BVHError(tok.path, kw_line, f"expected 'JOINT', 'End Site' or '}}' inside {name}, found {kw!r}")

    parse_joint(-1, line)
    if tok.peek() is not None:
        t, l = tok.items[tok.pos]
        raise BVHError(tok.path, l, f"expected 'MOTION' after the hierarchy, found {t!r}")
    return names, parents, offsets, channels, end_sites


def read_channels(path: str | os.PathLike) -> tuple[Skeleton, np.ndarray, float]:
    """Parse a BVH file into its skeleton (in file units), raw channel values (T, C) and frame time."""
    path = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8-sig", errors="strict")
    except UnicodeDecodeError as e:
        raise BVHError(path, None, f"not a text file ({e.reason})") from None
    except (IsADirectoryError, PermissionError) as e:
        raise BVHError(path, None, f"cannot read the file: {e.strerror}") from None
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    while lines and not lines[-1].strip():
        lines.pop()
    motion_at = next((i for i, l in enumerate(lines) if l.strip() == "MOTION"), None)
    tok = _Tokens(lines if motion_at is None else lines[:motion_at], path)
    names, parents, offsets, channels, end_sites = _parse_hierarchy(tok)
    if motion_at is None:
        raise BVHError(path, tok.end_line, "file ends after the hierarchy: expected 'MOTION'")
    skeleton = Skeleton(tuple(names), np.array(parents), np.array(offsets), tuple(channels), end_sites)

    def header(idx: int, key: str) -> str:
        if idx >= len(lines):
            raise BVHError(path, idx, f"file ends early: expected '{key}'")
        line = " ".join(lines[idx].split())  # "Frame\tTime:" reads as "Frame Time:"
        if not line.startswith(key):
            raise BVHError(path, idx + 1, f"expected '{key}', found {line[:40]!r}")
        return line[len(key):].strip()

    frames_txt = header(motion_at + 1, "Frames:")
    if not frames_txt.isdigit():
        raise BVHError(path, motion_at + 2, f"expected a whole number of frames, found {frames_txt!r}")
    n_frames = int(frames_txt)
    ft_txt = header(motion_at + 2, "Frame Time:")
    try:
        frame_time = float(ft_txt)
    except ValueError:
        raise BVHError(path, motion_at + 3, f"expected a number for the frame time, found {ft_txt!r}") from None
    if not (frame_time > 0 and math.isfinite(frame_time)):
        raise BVHError(path, motion_at + 3, f"frame time must be a positive number of seconds, got {ft_txt}")

    first = motion_at + 3
    data_lines = lines[first:]
    n_channels = sum(len(c) for c in channels)
    if n_frames == 0:
        raise BVHError(path, motion_at + 2, "empty MOTION section: the header says 0 frames")
    if not data_lines:
        raise BVHError(path, first, f"empty MOTION section: the header says {n_frames} frames but no frame lines follow")
    if len(data_lines) != n_frames:
        # point at the first extra line, or at the last line of a short file
        raise BVHError(path, first + min(len(data_lines), n_frames + 1),
                       f"header says {n_frames} frames but the file has {len(data_lines)} frame lines")
    columns = [f"{name} {c}" for name, chans in zip(names, channels) for c in chans]
    values = np.empty((n_frames, n_channels))
    for i, line in enumerate(data_lines):
        parts = line.split()
        if len(parts) != n_channels:
            raise BVHError(path, first + i + 1, f"expected {n_channels} channel values, found {len(parts)}")
        try:
            values[i] = np.array(parts, dtype=np.float64)
        except ValueError:
            k = next(k for k, p in enumerate(parts) if not _is_float(p))
            raise BVHError(path, first + i + 1,
                           f"expected a number for {columns[k]} (value {k + 1}), found {parts[k]!r}") from None
    bad = np.argwhere(~np.isfinite(values))
    if len(bad):
        i, k = bad[0]
        raise BVHError(path, first + i + 1,
                       f"{columns[k]} (value {k + 1}) is {data_lines[i].split()[k]}: expected a finite number")
    return skeleton, values, frame_time


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


def load(path: str | os.PathLike, unit: str = "auto", fps: float | None = None) -> Motion:
    """Read a BVH file into a Motion in metres.

    Args:
        unit: length unit of the file ('cm', 'm', 'mm', 'in'), or 'auto' to guess from
            the skeleton's size (``guess_unit``).
        fps: override the frame rate stated in the file (for files with a wrong header);
            otherwise the header's, as ``frame_rate`` reads it.
    """
    skeleton, values, frame_time = read_channels(path)
    if unit == "auto":
        unit = guess_unit(skeleton.offsets, skeleton.parents)
    scale = unit_scale(unit)
    n_frames, n_joints = values.shape[0], skeleton.num_joints
    rotations = np.zeros((n_frames, n_joints, 4))
    rotations[..., 0] = 1.0
    translations = np.broadcast_to(skeleton.offsets, (n_frames, n_joints, 3)).copy()
    hint = np.zeros((n_frames, n_joints, 3))
    by_order: dict[str, list[int]] = {}
    has_positions = False
    col = 0
    for j, chans in enumerate(skeleton.channels):
        block = values[:, col:col + len(chans)]
        col += len(chans)
        rot_names = [c for c in chans if c in _ROTATION_CHANNELS]
        if rot_names:
            hint[:, j] = np.deg2rad(np.stack([block[:, chans.index(c)] for c in rot_names], axis=-1))
            by_order.setdefault("".join(c[0] for c in rot_names), []).append(j)
        for axis, c in enumerate(_POSITION_CHANNELS):
            if c in chans:
                translations[:, j, axis] = block[:, chans.index(c)]
                has_positions |= j > 0
    # one conversion per Euler order, not per joint: small torch calls are costly on a busy CPU
    for order, joints in by_order.items():
        rotations[:, joints] = R.euler_to_quat(torch.from_numpy(hint[:, joints]), order).numpy()
    root = translations[:, 0].copy()  # the root's OFFSET where it has no position channels
    return Motion(
        skeleton.scaled(scale),
        rotations,
        root * scale,
        fps=float(fps) if fps is not None else frame_rate(frame_time),
        translations=translations * scale if has_positions else None,
        source_unit=unit,
        euler_hint=hint,
    )


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
    """Write a Motion as BVH (in ``unit``, default the unit it was read in).

    Refuses to replace an existing file unless ``force``; writes to a temporary file
    in the same folder and renames it, so an interrupted run leaves no half file.
    """
    path = Path(path)
    if path.exists() and not force:
        raise FileExistsError(f"{path} exists; pass force=True (--force) to overwrite it")
    unit = unit or motion.source_unit
    scale = 1.0 / unit_scale(unit)
    sk = motion.skeleton
    lines = ["HIERARCHY"]

    def fmt(v: np.ndarray) -> str:
        return " ".join(f"{x:.{precision}g}" for x in v)

    def write_joint(j: int, depth: int) -> None:
        pad = "\t" * depth
        kw = "ROOT" if j == 0 else "JOINT"
        lines.append(f"{pad}{kw} {sk.names[j]}")
        lines.append(f"{pad}{{")
        lines.append(f"{pad}\tOFFSET {fmt(sk.offsets[j] * scale)}")
        lines.append(f"{pad}\tCHANNELS {len(sk.channels[j])} {' '.join(sk.channels[j])}".rstrip())
        for c in sk.children(j):
            write_joint(c, depth + 1)
        if j in sk.end_sites:
            lines.append(f"{pad}\tEnd Site")
            lines.append(f"{pad}\t{{")
            lines.append(f"{pad}\t\tOFFSET {fmt(sk.end_sites[j] * scale)}")
            lines.append(f"{pad}\t}}")
        lines.append(f"{pad}}}")

    write_joint(0, 0)
    values = motion_to_channels(motion, unit)
    lines += ["MOTION", f"Frames: {motion.num_frames}", f"Frame Time: {frame_time_text(motion.fps)}"]
    body = "\n".join(lines) + "\n"
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent or ".")
    try:
        with os.fdopen(fd, "w", newline="\n") as f:
            f.write(body)
            np.savetxt(f, values, fmt=f"%.{precision}g")
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes owner-only files; give the usual mode
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path
