"""Inertialization: a generated continuation carried on from the real frames before it.

A generator that completes a motion after its known frames reproduces those frames only
approximately, so its first new frame jumps away from the last real one, in pose and in
velocity. Inertialization (Bollo, GDC 2016; Holden's critically damped form) measures that
difference, offset and its rate of change, at the seam, adds it to the generated frames
and lets it fade, so the continuation starts where the real motion is going and turns
into the generated motion over a half-life. The root's horizontal offset does not fade:
the real root path says where the figure stands; only the difference in its velocity does.
"""
from __future__ import annotations

import numpy as np
import torch

from motionopt import rotations as R
from motionopt.motion import Motion


def spring_decay(x0: np.ndarray, v0: np.ndarray, t: np.ndarray, halflife: float) -> np.ndarray:
    """Offsets (len(t), *x0.shape) of a critically damped spring that starts at ``x0``
    with velocity ``v0`` and settles to zero, halving every ``halflife`` seconds."""
    y = 2 * np.log(2) / halflife
    t = t.reshape((-1,) + (1,) * np.ndim(x0))
    return (x0 + (v0 + x0 * y) * t) * np.exp(-y * t)


def held_drift(x0: np.ndarray, v0: np.ndarray, t: np.ndarray, halflife: float) -> np.ndarray:
    """Offsets that keep ``x0`` and add a velocity ``v0`` decaying at the same rate as
    ``spring_decay``'s (their integral stays): position continuity without fading back."""
    y = 2 * np.log(2) / halflife
    return x0 + v0 * ((1 - np.exp(-y * t)) / y)[:, None]


def carry_on(generated: Motion, real: Motion, seam: int, halflife: float) -> Motion:
    """``generated`` with frames before ``seam`` taken from ``real`` (same skeleton, rate and
    length at least ``seam``) and the frames from ``seam`` on carried on from them:
    joint rotations and root height by a fading offset, the root's horizontal position by a
    held one whose velocity part fades."""
    if not 2 <= seam < generated.num_frames:
        raise ValueError(f"carry_on needs 2 real frames before the seam and one after it, got seam {seam} "
                         f"of {generated.num_frames} frames")
    dt = 1.0 / generated.fps
    qg, qr = torch.from_numpy(generated.rotations), torch.from_numpy(real.rotations[:seam])

    def rotation_offset(i: int) -> np.ndarray:
        return R.quat_to_axis_angle(R.quat_multiply(qr[i], R.quat_conjugate(qg[i]))).numpy()

    t = np.arange(1, generated.num_frames - seam + 1) * dt  # time since the last real frame
    last, before = rotation_offset(seam - 1), rotation_offset(seam - 2)
    turn = spring_decay(last, (last - before) / dt, t, halflife)
    rotations = generated.rotations.copy()
    rotations[:seam] = real.rotations[:seam]
    rotations[seam:] = R.quat_multiply(R.axis_angle_to_quat(torch.from_numpy(turn)), qg[seam:]).numpy()

    r_last = real.root[seam - 1] - generated.root[seam - 1]
    r_velocity = (r_last - (real.root[seam - 2] - generated.root[seam - 2])) / dt
    shift = spring_decay(r_last, r_velocity, t, halflife)
    shift[:, [0, 2]] = held_drift(r_last[[0, 2]], r_velocity[[0, 2]], t, halflife)
    root = generated.root.copy()
    root[:seam] = real.root[:seam]
    root[seam:] += shift
    return generated.with_frames(rotations, root, generated.translations)
