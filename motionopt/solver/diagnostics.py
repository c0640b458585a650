"""Figures about a sequence under a MAP objective, without optimising: the seams between
windows (``seam_report``) and every term's energy over the solver's windows
(``energies_at``, for E(clean), E(start), E(result) in benchmarks)."""
from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from ..features import RootStart, advance, decode_positions
from ..objective import MAPObjective
from .layout import WindowWalk
from .options import SolverOptions
from .result import Problem

#: Frames decoded at a time by ``seam_report`` (bounds its memory on long sequences).
SEAM_CHUNK = 256


@torch.no_grad()
def seam_report(objective: MAPObjective, x: Tensor, start: RootStart, boundaries: list[int]) -> dict[str, float]:
    """Largest mean joint acceleration (m/s^2) at window boundaries against inner frames'.

    Decodes ``SEAM_CHUNK`` frames at a time, so its memory does not grow with the length."""
    if len(boundaries) < 2:
        return {}
    norm, spec = objective.prior.normalizer, objective.spec
    n = len(x)
    acc = np.empty(max(n - 2, 0))
    state, prev_lo = start, 0     # the root state before frame prev_lo
    for a in range(0, n - 2, SEAM_CHUNK):
        lo = max(a - 2, 0)            # two frames before the chunk give its first accelerations
        if lo > 0:
            state = advance(state, norm.denormalize(x[prev_lo:lo].double()), spec)
        prev_lo = lo
        b = min(a + SEAM_CHUNK, n - 2)
        raw = norm.denormalize(x[lo:b + 2].double())
        pos = decode_positions(raw, spec, objective.skeleton, state if lo > 0 else start)
        a_chunk = ((pos[2:] - 2 * pos[1:-1] + pos[:-2]) * spec.fps ** 2).norm(dim=-1).mean(-1).numpy()
        acc[a:b] = a_chunk[a - lo:]
    at = np.zeros(len(acc), bool)
    for b in boundaries[1:]:
        at[max(b - 2, 0):min(b + 1, len(acc))] = True
    if at.all() or not at.any():
        return {}
    return {"boundary_max_acc": float(acc[at].max()), "inner_max_acc": float(acc[~at].max()),
            "inner_p99_acc": float(np.percentile(acc[~at], 99)),
            "ratio": float(acc[at].max() / max(acc[~at].max(), 1e-9))}


def energies_at(objective: MAPObjective, problem: Problem, x: Tensor,
                options: SolverOptions = SolverOptions()) -> dict[str, float]:
    """Every term's energy at the full feature sequence ``x (N, D)``, summed over the
    windows ``solve`` would use for ``problem`` (its free frames and root start) with
    ``options`` (window and overlap): each window opened on ``x`` as the solver opens
    it and evaluated at zero variables, with the prior's log-std and the contact weights
    of ``x`` itself. Overlapping frames count once per window, as in ``MAPResult.terms``.

    At a solve's result this is not its ``terms``: a local solve holds the log-std and
    the contact weights of where it started; with overlapping windows, later windows
    also change frames that earlier windows' terms were computed on. ``energies_at``
    gives one definition for every point (the clean clip, the start, the result), which
    is what tells a search failure from an objective that prefers the wrong answer."""
    x = x.float()
    free = np.asarray(problem.free, bool)
    if x.shape != (len(free), objective.spec.dim) or not bool(torch.isfinite(x).all()):
        raise ValueError(f"x must be finite features ({len(free)}, {objective.spec.dim}) for every frame of "
                         f"the problem; got shape {tuple(x.shape)}")
    walk = WindowWalk(objective, free, problem.start, options.window, options.overlap, options.basis)
    out: dict[str, float] = {}
    for s in walk.starts:
        win = walk.open(x, s)
        if win.n_vars == 0:
            continue
        walk.rebase(win)
        for k, val in win.values(win.pack()).items():
            out[k] = out.get(k, 0.0) + val
    return out
