"""Time alignment of two motions (dynamic time warping) and the play times of their blends.

Blending two walks frame by frame blends a left step with a right one as soon as their
phases or cadences differ: the classic remedy (registration curves, Kovar and Gleicher
2003) plays both along a common time axis on which like poses meet. ``align`` finds that
correspondence, ``blend_times`` where each input is at every frame of a blend.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: The steps an alignment may take, (frames of A, frames of B): one input plays at most
#: twice as fast as the other, relative to the pace that covers both in full, so no
#: pose is held while the other motion runs on.
STEPS = ((1, 1), (1, 2), (2, 1))

#: Longest clip (frames) aligned frame by frame; longer ones are aligned at a coarser rate.
MAX_ALIGN_FRAMES = 1500


@dataclass(frozen=True)
class Alignment:
    """Corresponding frames ``a[k]`` of A and ``b[k]`` of B (fractional, both increasing,
    from (0, 0) to both last frames)."""

    a: np.ndarray
    b: np.ndarray


def frames_at(f: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Frames ``f (T, F)`` at fractional frame numbers ``times``, linearly interpolated."""
    lo = np.floor(times).astype(int).clip(0, max(len(f) - 2, 0))
    frac = (times - lo)[:, None]
    return f[lo] * (1 - frac) + f[np.minimum(lo + 1, len(f) - 1)] * frac


def played_in(f: np.ndarray, n: int) -> np.ndarray:
    """Frames ``f (T, F)`` linearly resampled to ``n`` frames over the same span."""
    return frames_at(f, np.linspace(0, len(f) - 1, n))


def align(fa: np.ndarray, fb: np.ndarray) -> Alignment:
    """The alignment of features ``fa (Ta, F)`` and ``fb (Tb, F)`` of least summed squared
    distance between corresponding frames, taking the ``STEPS``. B is first played in A's
    number of frames, so the slope limit is relative to the pace that covers both clips
    and clips of any two lengths align; clips longer than ``MAX_ALIGN_FRAMES`` are aligned
    at a coarser rate (the tables grow with the square of the length)."""
    ta, tb = len(fa), len(fb)
    if ta < 2 or tb < 2:
        raise ValueError("both motions need at least two frames to be aligned")
    m = min(ta, MAX_ALIGN_FRAMES)
    fa_m, fb_m = played_in(fa, m), played_in(fb, m)
    cost = ((fa_m ** 2).sum(-1)[:, None] + (fb_m ** 2).sum(-1)[None, :] - 2 * fa_m @ fb_m.T).clip(min=0)
    total = np.full((m, m), np.inf)
    choice = np.zeros((m, m), np.int8)
    total[0, 0] = cost[0, 0]
    for i in range(1, m):
        options = np.full((len(STEPS), m), np.inf)
        for s, (di, dj) in enumerate(STEPS):
            if i - di < 0:
                continue
            via = np.zeros(m)  # the cell a two-frame step passes over
            if di == 2:
                via = cost[i - 1]
            elif dj == 2:
                via = np.concatenate(([np.inf], cost[i, :-1]))
            options[s, dj:] = total[i - di, :-dj] + via[dj:]
        choice[i] = options.argmin(0)
        total[i] = cost[i] + options.min(0)
    i, j, path = m - 1, m - 1, [(m - 1, m - 1)]   # the diagonal always reaches the corner
    while (i, j) != (0, 0):
        di, dj = STEPS[choice[i, j]]
        i, j = i - di, j - dj
        path.append((i, j))
    knots = np.array(path[::-1], float) / (m - 1)
    return Alignment(knots[:, 0] * (ta - 1), knots[:, 1] * (tb - 1))


def blend_times(alignment: Alignment, alpha: float, n_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """Where A and B are (fractional frames) at each of ``n_frames`` frames of the blend
    ``alpha`` of the way from A to B: the blend's clock runs at ``(1 - alpha)`` times A's
    plus ``alpha`` times B's along the alignment, so alpha 0 plays A as it is and alpha 1
    plays B as it is. (Smoothing these times by a 6-frame local line fit, or charging the
    alignment for changes of pace, made held-out Bandai middles less likely under the
    autoregressive prior, not more.)"""
    clock = (1 - alpha) * alignment.a + alpha * alignment.b
    t = np.linspace(clock[0], clock[-1], n_frames)
    return np.interp(t, clock, alignment.a), np.interp(t, clock, alignment.b)
