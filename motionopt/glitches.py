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
and 155 at 5 cm.

A glitch that wanders instead of holding an offset (a limb that swirls for a third of a
second, as the right shin of CMU salsa/15 does at 60 fps frames 1794-1812) is a
``Swirl``: for a fraction of a second the joint takes poses it takes nowhere else in the
clip, and turns faster there than a person turns it and than it turns anywhere else
(``find_swirls``). Its frames carry nothing worth keeping: ``fill_swirls`` replaces them
by the turn between the frames around the burst, which the filter and the MAP solve then
treat as the rest.
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


#: A swirl's frames lie further than this from the joint's own poses (robust standard
#: deviations of the clip, ``pose_distance``), and at least one frame further than ``_SWIRL_PEAK``.
_SWIRL_OUTSIDE = 10.0
_SWIRL_PEAK = 20.0
#: A swirl's run reaches out to the frames on either side still further than this: its
#: way in and out (CMU salsa/15's shin: 3-8 deviations for the frames around the core),
#: by at most half the core's length on each side.
_SWIRL_EDGE = 2.5
#: Around a swirl the joint turns faster than this (degrees per second; 1200 is 20
#: degrees a frame at 60 fps) and faster than ``_SWIRL_SPEED_MARGIN`` times its 99th
#: percentile elsewhere in the clip. Of the runs far outside a joint's poses in the shared
#: capture, those in ordinary motion turn at most 2.1 times it (a Bandai punch's elbow:
#: 2024 deg/s, 1.4 times); the CMU salsa glitches 4.8 to 15.6 times.
_SWIRL_MIN_SPEED = 1200.0
_SWIRL_SPEED_MARGIN = 4.0
#: The spread of a joint's poses is floored at this (radians per axis) before distances
#: are taken: a hinge's off-axis spread is near zero.
_POSE_FLOOR = np.radians(2.0)


@dataclass(frozen=True)
class Swirl:
    """Joint ``joint`` thrown for frames ``first`` to ``stop - 1`` into poses
    ``distance`` robust standard deviations from its own, turning ``degrees_per_second``
    at the fastest."""

    joint: int
    first: int
    stop: int
    distance: float
    degrees_per_second: float


def pose_distance(motion: Motion, angle_noise: float = 0.0) -> np.ndarray:
    """(T, J) how far each frame's rotation of each joint lies from the joint's rotations
    over the clip: the rotation from the joint's median one, as a rotation vector, in
    the principal axes of their spread, each axis scaled by its robust std (with a floor
    and the noise added), then the norm."""
    q = torch.from_numpy(aligned_quaternions(motion.rotations))
    out = np.zeros(q.shape[:2])
    for j in range(q.shape[1]):
        median = q[:, j].median(0).values
        v = R.quat_to_axis_angle(R.quat_multiply(R.quat_conjugate((median / median.norm()).expand_as(q[:, j])),
                                                 q[:, j])).numpy()
        centred = v - np.median(v, 0)
        _, axes = np.linalg.eigh(np.cov(centred.T))
        z = centred @ axes
        spread = np.median(np.abs(z), 0) / 0.6745
        out[:, j] = np.linalg.norm(z / np.sqrt(spread ** 2 + _POSE_FLOOR ** 2 + angle_noise ** 2), axis=-1)
    return out


def find_swirls(motion: Motion, angle_noise: float, max_seconds: float = 0.5) -> list[Swirl]:
    """The swirls of ``motion``: runs of at most ``max_seconds`` in which one joint lies
    more than ``_SWIRL_OUTSIDE`` robust standard deviations from its own poses (further
    than ``_SWIRL_PEAK`` somewhere; the run then reaches out to its neighbours further
    than ``_SWIRL_EDGE``), entered, left or crossed faster than
    ``_SWIRL_MIN_SPEED`` and than ``_SWIRL_SPEED_MARGIN`` times the joint's 99th
    percentile elsewhere in the clip (so that a short clip's own burst does not raise
    the bar), with a frame on each side to fill from. ``angle_noise``: rotation noise
    (rad per axis), which widens every joint's spread."""
    n = motion.num_frames
    if n < 2 * motion.fps:   # too short to know a joint's own poses
        return []
    distance = pose_distance(motion, angle_noise)
    # turning speed (deg/s) into frame t over 1/30 s, so that capture noise at 120 fps
    # does not pass for speed: its turn does not grow with the span, a movement's does
    k = max(1, int(round(motion.fps / 30)))
    q = torch.from_numpy(motion.rotations)
    turn = np.degrees(R.quat_angle(q[:-k], q[k:]).numpy()) * motion.fps / k
    speed = np.concatenate((np.repeat(turn[:1], k, axis=0), turn))
    longest = max(1, int(round(max_seconds * motion.fps)))
    found = []
    for j in range(distance.shape[1]):
        outside = np.concatenate(([False], distance[:, j] > _SWIRL_OUTSIDE, [False]))
        edges = np.flatnonzero(np.diff(outside.astype(int)))
        for first, stop in zip(edges[::2], edges[1::2]):
            if first == 0 or stop == n or stop - first > longest:
                continue
            reach = max(2, (stop - first) // 2)   # a real movement the burst sits in stays
            low, high = max(1, first - reach), min(n - 1, stop + reach)
            while first > low and distance[first - 1, j] > _SWIRL_EDGE:
                first -= 1
            while stop < high and distance[stop, j] > _SWIRL_EDGE:
                stop += 1
            if found and found[-1].joint == j and first < found[-1].stop:   # two cores, one burst
                first = found.pop().first
            peak = float(distance[first:stop, j].max())
            top = float(speed[first:stop + 1, j].max())
            ordinary = np.delete(speed[:, j], np.arange(max(0, first - reach), min(n, stop + 1 + reach)))
            fast = max(_SWIRL_MIN_SPEED, _SWIRL_SPEED_MARGIN * float(np.percentile(ordinary, 99)))
            if peak > _SWIRL_PEAK and top > fast:
                found.append(Swirl(j, int(first), int(stop), peak, top))
    return found


def fill_swirls(motion: Motion, swirls: list[Swirl]) -> Motion:
    """``motion`` with each swirl's frames replaced by the shortest turn from the frame
    before the burst to the frame after it (spherical interpolation)."""
    if not swirls:
        return motion
    q = torch.from_numpy(motion.rotations.copy())
    for s in swirls:
        before, after = q[s.first - 1, s.joint], q[s.stop, s.joint]
        t = torch.arange(1, s.stop - s.first + 1, dtype=q.dtype) / (s.stop - s.first + 1)
        q[s.first:s.stop, s.joint] = R.quat_slerp(before.expand(len(t), 4), after.expand(len(t), 4), t)
    return motion.with_frames(q.numpy(), motion.root, motion.translations)
