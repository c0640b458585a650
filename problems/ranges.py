"""Kept frame ranges of in-betweening and completion: parsed from the command line,
checked against a clip, what becomes of the frames after the last one, and the gaps
between them."""
from __future__ import annotations

import numpy as np


def parse_ranges(text: str) -> list[tuple[int, int | None]]:
    """'0:30,60:90' -> [(0, 30), (60, 90)] (half-open, like Python slices); as in a slice,
    a missing start is frame 0 and a missing stop (None) the clip's end ('60:')."""
    out = []
    for part in text.split(","):
        part = part.strip()
        if ":" not in part:
            raise ValueError(f"keep range {part!r} must look like START:STOP, e.g. 0:30 (or 60: to the end)")
        a, b = (side.strip() for side in part.split(":", 1))
        try:
            out.append((int(a) if a else 0, int(b) if b else None))
        except ValueError:
            raise ValueError(f"keep range {part!r} must hold whole frame numbers") from None
    return out


def _written(a: int, b: int | None) -> str:
    """A range as the user wrote it (an open stop stays open)."""
    return f"{a}:" if b is None else f"{a}:{b}"


def check_ranges(ranges: list[tuple[int, int | None]], n_frames: int) -> list[tuple[int, int]]:
    """Sorted, validated ranges, a stop of None made the clip's end; errors name the
    offending range as it was written."""
    if not ranges:
        raise ValueError("give at least one frame range to keep")
    for a, b in ranges:
        if a < 0 or (b is not None and b < 0):
            raise ValueError(f"keep range {_written(a, b)} has a negative frame: frames count from 0 "
                             f"(this clip's are 0:{n_frames}); counting back from the end is not read")
        if not a < (n_frames if b is None else b) <= n_frames:
            raise ValueError(f"keep range {_written(a, b)} is outside the clip's frames 0:{n_frames} or empty")
    written = sorted(ranges, key=lambda r: r[0])
    resolved = [(a, n_frames if b is None else b) for a, b in written]
    for k in range(1, len(written)):
        if resolved[k][0] < resolved[k - 1][1]:
            raise ValueError(f"keep ranges {_written(*written[k - 1])} and {_written(*written[k])} overlap")
    if resolved[0][0] != 0:
        raise ValueError(f"the first kept range starts at frame {resolved[0][0]}: keep frame 0, because the "
                         "prior synthesises forward in time from what comes before")
    return resolved


#: What ``Inbetween`` may do with the frames after the last kept range (``after``).
AFTER_LAST_RANGE = ("keep", "drop", "synthesise")


def after_last_range(keep: list[tuple[int, int]], n_frames: int, after: str) -> tuple[list[tuple[int, int]], int]:
    """The ranges ``keep`` (checked and sorted, ``check_ranges``) of an ``n_frames`` input
    and the output's length, with ``after`` (of ``AFTER_LAST_RANGE``) applied to the frames
    after the last range: "keep" extends that range to the end, "drop" ends the output
    there, "synthesise" leaves them to be synthesised."""
    if after not in AFTER_LAST_RANGE:
        raise ValueError(f"after must be one of {', '.join(AFTER_LAST_RANGE)}, got {after!r}")
    if after == "keep":
        return [*keep[:-1], (keep[-1][0], n_frames)], n_frames
    return keep, (keep[-1][1] if after == "drop" else n_frames)


def require_a_gap(keep: list[tuple[int, int]], n_frames: int) -> None:
    """Refuse ranges that keep every one of the output's ``n_frames``: nothing would be filled."""
    if not (~kept_mask(keep, n_frames)).any():
        raise ValueError(f"the kept ranges cover every frame of the output (0:{n_frames}): nothing to fill; "
                         "leave a gap between two ranges")


def kept_mask(ranges: list[tuple[int, int]], n_frames: int) -> np.ndarray:
    """(n_frames,) True on the frames inside the half-open ``ranges``."""
    mask = np.zeros(n_frames, bool)
    for a, b in ranges:
        mask[a:b] = True
    return mask


def gaps(kept: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) of each run of frames that are not kept."""
    d = np.diff(np.concatenate(([0], (~kept).astype(np.int8), [0])))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))


def at_model_rate(seen: np.ndarray, fps: float, model_fps: float, n: int) -> np.ndarray:
    """``seen`` (one bool per frame at ``fps``) at the ``n`` frames of the prior's rate: each
    model frame takes the nearest file frame's."""
    idx = np.minimum(np.round(np.arange(n) * fps / model_fps).astype(int), len(seen) - 1)
    return seen[idx]
