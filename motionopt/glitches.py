"""Capture glitches: one joint's rotation thrown off by a near-constant turn for a
fraction of a second (a marker swap, a solver flip), found and turned back.

A glitch enters with a one-frame jump and leaves with the opposite jump, and between the
two the joint keeps moving as it did, turned by the same offset. Real motion does not do
that: a joint's velocity does not leap for one frame and fall back (the "spike" below,
a frame's step less the mean of its neighbours' steps, measures that leap), and the
acceleration that starts a fast kick has the opposite sign to the one that ends it. So
a burst of frames is a glitch when its entering spike and its leaving spike are the same
turn, larger than ``min_degrees``, than the joint's own spikes in ordinary motion and
than the noise can make them. A low-pass filter smears such a burst into its
neighbours; turned back first, it leaves the filter and the MAP solve only the noise.

Measured (``bench/glitches.py``): on 1853 s of real capture (CMU at 60-120 fps, Bandai at
30 fps), clean and with 1, 3 and 5 cm of noise, 5, 5, 2 and 1 bursts found, all in one
clip of a furious wave (forearm and hand jumping 30-40 degrees a frame at 30 fps); of
166 injected glitches of 30-45 degrees lasting 0.1-0.4 s, all found up to 3 cm of noise
and 155 at 5 cm. A glitch that wanders instead of holding an offset (a limb that swirls
for half a second) is not of this kind and is not found.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from . import rotations as R
from .motion import Motion
from .smoothing import aligned_quaternions

#: Median size of a spike (radians) that white rotation noise of std 1 rad per axis makes:
#: a spike is (q[t-1] - 3 q[t] + 3 q[t+1] - q[t+2]) / 2 (variance 5 per axis), and the
#: median of a 3-axis norm is 1.54 times the per-axis std.
_SPIKE_NOISE = 1.54 * np.sqrt(5.0)
#: A glitch's spike is at least this many times the joint's median spike in ordinary
#: motion, and this many times the noise's median spike.
_MOTION_MARGIN = 8.0
_NOISE_MARGIN = 4.0
#: The entering and leaving offsets agree within this fraction of their size, plus twice
#: the joint's median motion spike and three times the noise's.
_AGREEMENT = 0.3


@dataclass(frozen=True)
class Glitch:
    """Joint ``joint`` seen turned by ``offset_in`` at frame ``first`` and by
    ``offset_out`` at frame ``stop - 1`` (unit quaternions in the joint's own frame:
    ``q_seen = q_true * offset``); ``degrees`` is the larger of the two angles."""

    joint: int
    first: int
    stop: int
    offset_in: np.ndarray
    offset_out: np.ndarray
    degrees: float


def find_glitches(motion: Motion, angle_noise: float, min_degrees: float = 25.0,
                  min_seconds: float = 0.1, max_seconds: float = 0.5) -> list[Glitch]:
    """The glitches of ``motion``: bursts of ``min_seconds`` (at least 3 frames) to
    ``max_seconds`` in which one joint is turned by more than ``min_degrees`` by an
    offset that it enters and leaves with the same turn, larger than rotation noise of
    ``angle_noise`` rad per axis (``problems.denoise.estimate_noise``) can fake."""
    shortest = max(3, int(round(min_seconds * motion.fps)))
    longest = max(shortest, int(round(max_seconds * motion.fps)))
    q_all = torch.from_numpy(aligned_quaternions(motion.rotations))
    found: list[Glitch] = []
    if len(q_all) < shortest + 4:
        return found
    noise = _SPIKE_NOISE * angle_noise
    steps = R.quat_to_axis_angle(R.quat_multiply(R.quat_conjugate(q_all[:-1]), q_all[1:]))  # [t]: frame t -> t+1
    spikes = torch.zeros_like(steps)
    spikes[1:-1] = steps[1:-1] - 0.5 * (steps[:-2] + steps[2:])
    sizes = spikes.norm(dim=-1)                                                              # (T-1, J)
    for j in range(q_all.shape[1]):
        spike, size = spikes[:, j], sizes[:, j]
        ordinary = float(np.sqrt(max(float(size.median()) ** 2 - noise ** 2, 0.0)))
        floor = max(np.radians(min_degrees), _MOTION_MARGIN * ordinary, _NOISE_MARGIN * noise)
        slack = 2 * ordinary + 3 * noise
        after = -1                                        # the last frame of the last glitch found
        for t in torch.nonzero(size > floor).flatten().tolist():
            if t <= after or t >= len(spike) - 1 - shortest:
                continue
            leaving = _leaving_step(spike, size, t, shortest, longest, floor, slack)
            if leaving is None:
                continue
            o_in, o_out = R.axis_angle_to_quat(spike[t]), R.axis_angle_to_quat(-spike[leaving])
            found.append(Glitch(j, t + 1, leaving + 1, o_in.numpy(), o_out.numpy(),
                                float(np.degrees(float(torch.maximum(size[t], size[leaving]))))))
            after = leaving
    return found


def _leaving_step(spike: torch.Tensor, size: torch.Tensor, t: int, shortest: int, longest: int, floor: float,
                  slack: float) -> int | None:
    """The step that leaves the burst entered at step ``t``: the one within ``shortest``
    to ``longest`` frames whose spike undoes ``spike[t]`` best, within the tolerance;
    None when none does."""
    stops = torch.arange(t + shortest, min(t + longest, len(spike) - 2) + 1)
    if len(stops) == 0:
        return None
    gap = (spike[t] + spike[stops]).norm(dim=-1)
    ok = (size[stops] > floor) & (gap < _AGREEMENT * torch.minimum(size[stops], size[t]) + slack)
    if not ok.any():
        return None
    return int(stops[ok][gap[ok].argmin()])


def turn_back(motion: Motion, glitches: list[Glitch]) -> Motion:
    """``motion`` with each glitch turned back: the burst's frames turned by the inverse
    of an offset that goes from the entering to the leaving one across the burst."""
    if not glitches:
        return motion
    q = torch.from_numpy(motion.rotations.copy())
    for g in glitches:
        length = g.stop - g.first
        s = torch.linspace(0.0, 1.0, length, dtype=q.dtype)   # one frame: [0], the entering offset
        o_in = torch.from_numpy(g.offset_in).expand(length, 4)
        o_out = torch.from_numpy(g.offset_out).expand(length, 4)
        offset = R.quat_slerp(o_in, o_out, s)
        q[g.first:g.stop, g.joint] = R.quat_multiply(q[g.first:g.stop, g.joint], R.quat_conjugate(offset))
    return motion.with_frames(q.numpy(), motion.root, motion.translations)
