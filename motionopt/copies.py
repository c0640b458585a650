"""Degraded copies of a motion: what a prior must score as less natural than the motion.

A maximum-a-posteriori solver drifts toward whatever its prior prefers; a prior that
scores a still pose, an over-smoothed or a retimed copy of a walk above the walk leads it
there. These are the copies the prior benchmark and ``motionopt score --copies`` check,
each of the same length as the motion it is made from (where the source allows).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy.signal import butter, filtfilt

from .motion import Motion
from .noise import position_noise


def low_passed(motion: Motion, cutoff_hz: float, order: int = 2) -> Motion:
    """Zero-phase Butterworth low-pass of every rotation (quaternions kept on one
    hemisphere frame to frame, then renormalised) and of the root path."""
    b, a = butter(order, cutoff_hz / (motion.fps / 2))
    q = motion.rotations.copy()
    flip = np.cumprod(np.where((q[1:] * q[:-1]).sum(-1) < 0, -1.0, 1.0), axis=0)
    q[1:] *= flip[..., None]
    pad = min(3 * max(len(a), len(b)), motion.num_frames - 1)
    q = filtfilt(b, a, q, axis=0, padlen=pad)
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    root = np.ascontiguousarray(filtfilt(b, a, motion.root, axis=0, padlen=pad))
    return motion.with_frames(np.ascontiguousarray(q), root, motion.translations)


def frozen(motion: Motion) -> Motion:
    """The first frame held for the motion's length."""
    return motion[0:1].with_frames(np.repeat(motion.rotations[:1], motion.num_frames, 0),
                                   np.repeat(motion.root[:1], motion.num_frames, 0),
                                   None if motion.translations is None
                                   else np.repeat(motion.translations[:1], motion.num_frames, 0))


def retimed(motion: Motion, factor: float) -> Motion:
    """The motion played ``factor`` times as fast at its own frame rate (slerp between
    frames); a faster copy has fewer frames."""
    return replace(motion.resample(motion.fps / factor), fps=motion.fps)


@dataclass(frozen=True)
class Copy:
    """How one kind of copy is made: ``whole`` turns the whole motion into that copy, ``at``
    says where a window starting at frame ``s`` of the motion begins in it, and ``window``
    finishes the window cut from it."""

    whole: Callable[[Motion], Motion]
    at: Callable[[int], int] = lambda s: s
    window: Callable[[Motion], Motion] = lambda m: m


#: The copies a prior must score worse than the motion, by name.
COPIES: dict[str, Copy] = {
    "noise 1 cm": Copy(lambda m: position_noise(m, 0.01, seed=1)[0]),
    "low-pass 2 Hz": Copy(lambda m: low_passed(m, 2.0)),
    "low-pass 1 Hz": Copy(lambda m: low_passed(m, 1.0)),
    "frozen": Copy(lambda m: m, window=frozen),  # the window's own first frame, held
    "half speed": Copy(lambda m: retimed(m, 0.5), at=lambda s: 2 * s),
    "double speed": Copy(lambda m: retimed(m, 2.0), at=lambda s: s // 2),
}


def window_copies(motion: Motion, starts: list[int], length: int) -> list[dict[str, Motion]]:
    """For each window ``motion[s:s + length]``, its copy of every kind in ``COPIES``, each
    cut from that copy of the whole motion (so a low-pass has no edge at the window's
    start, and a double-speed window covers twice the time, where the motion has it)."""
    whole = {name: c.whole(motion) for name, c in COPIES.items()}
    return [{name: c.window(whole[name][c.at(s):c.at(s) + length]) for name, c in COPIES.items()} for s in starts]
