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


@dataclass(frozen=True)
class Alignment:
    """Corresponding frames ``a[k]`` of A and ``b[k]`` of B (fractional, both increasing,
    from (0, 0) to both last frames)."""

    a: np.ndarray
    b: np.ndarray


def align(fa: np.ndarray, fb: np.ndarray) -> Alignment:
    """The alignment of features ``fa (Ta, F)`` and ``fb (Tb, F)`` of least summed squared
    distance between corresponding frames, taking the ``STEPS``. B is first played in A's
    number of frames, so the slope limit is relative to the pace that covers both clips
    and clips of any two lengths align."""
    ta, tb = len(fa), len(fb)
    if ta < 2 or tb < 2:
        raise ValueError("both motions need at least two frames to be aligned")
    tb_scaled = np.linspace(0, tb - 1, ta)
    lo = np.floor(tb_scaled).astype(int).clip(max=tb - 2)
    frac = (tb_scaled - lo)[:, None]
    fb_at_a = fb[lo] * (1 - frac) + fb[lo + 1] * frac
    cost = ((fa ** 2).sum(-1)[:, None] + (fb_at_a ** 2).sum(-1)[None, :] - 2 * fa @ fb_at_a.T).clip(min=0)
    total = np.full((ta, ta), np.inf)
    choice = np.zeros((ta, ta), np.int8)
    total[0, 0] = cost[0, 0]
    for i in range(1, ta):
        options = np.full((len(STEPS), ta), np.inf)
        for s, (di, dj) in enumerate(STEPS):
            if i - di < 0:
                continue
            via = np.zeros(ta)  # the cell a two-frame step passes over
            if di == 2:
                via = cost[i - 1]
            elif dj == 2:
                via = np.concatenate(([np.inf], cost[i, :-1]))
            options[s, dj:] = total[i - di, :-dj] + via[dj:]
        choice[i] = options.argmin(0)
        total[i] = cost[i] + options.min(0)
    if not np.isfinite(total[-1, -1]):
        raise ValueError("the motions cannot be aligned within the allowed change of pace")
    i, j, path = ta - 1, ta - 1, [(ta - 1, ta - 1)]
    while (i, j) != (0, 0):
        di, dj = STEPS[choice[i, j]]
        i, j = i - di, j - dj
        path.append((i, j))
    knots = np.array(path[::-1], float)
    return Alignment(knots[:, 0], knots[:, 1] * (tb - 1) / (ta - 1))


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
