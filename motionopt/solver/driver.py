"""The windowed MAP driver: ``solve(objective, problem, options)``, and ``solve_from`` several starts.

It optimises the normalised features of the free frames of a sequence, window by window
(B frames, overlap b, laid out by ``layout``). Each window is conditioned on the solved
frames before it; its overlap starts from the previous window's solution and its new
frames from a rollout of the prior (steered by ``swarm`` when enabled); a local
optimiser of ``optimizers`` then solves it. The call and the result are shaped like
``scipy.optimize.minimize``.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import replace
from typing import Callable, Sequence

import numpy as np
import torch
from threadpoolctl import threadpool_limits

from ..objective import MAPObjective, NonFiniteTermError
from .optimizers import OPTIMIZERS
from .diagnostics import seam_report
from .layout import WindowWalk
from .options import SolverOptions
from .result import MAPResult, Problem, StopSolve
from .swarm import rollout_swarm

log = logging.getLogger(__name__)


def solve(objective: MAPObjective, problem: Problem, options: SolverOptions = SolverOptions()) -> MAPResult:
    """Solve the MAP problem window by window; see the module docstring.

    numpy's BLAS runs on one thread meanwhile: the optimisers' vector updates are far too
    small to share, and on a busy machine its spinning threads cost L-BFGS-B about
    20 ms per iteration (60 times its own work). And torch flushes denormal floats to
    zero (``torch.set_flush_denormal``; torch's default, off, is restored after): the
    prior's backward pass met enough of them that denoising 1071 frames took 32.5 s with
    them and 27 s without, on one thread."""
    with threadpool_limits(1, user_api="blas"):
        torch.set_flush_denormal(True)
        try:
            return _solve(objective, problem, options)
        finally:
            torch.set_flush_denormal(False)


def solve_from(objective: MAPObjective, problems: Sequence[Problem], options: SolverOptions = SolverOptions(),
               faults: Callable[[MAPResult], int] | None = None) -> MAPResult:
    """``solve`` from each of ``problems`` (one sequence: the same free frames and root
    start, different starting features) and the result of the lowest objective, with
    every start's final objective in ``MAPResult.starts_fun``. The local optimiser stays
    in the basin it starts in; seeds that differ in kind (an autoregressive rollout, a
    masked encoder's fill) reach basins that one of them alone does not.

    ``faults`` counts what is wrong with a result that the objective does not see (a
    task's seconds outside the range of human motion): the lowest objective is then kept
    among the results of fewest faults, and every start's count is in
    ``MAPResult.starts_faults``."""
    if not problems:
        raise ValueError("solve_from needs at least one start")
    first = problems[0]
    for p in problems[1:]:
        if p.x0.shape != first.x0.shape or not np.array_equal(p.free, first.free) or p.start != first.start:
            raise ValueError("the starts of solve_from must share the sequence's shape, free frames and root start")
    results = [solve(objective, p, options) for p in problems]
    counts = [faults(r) for r in results] if faults is not None and len(results) > 1 else []
    best = min(range(len(results)), key=lambda i: (counts[i] if counts else 0, results[i].fun))
    timings = {k: sum(r.timings[k] for r in results) for k in results[best].timings}  # the work of every start
    return replace(results[best], timings=timings, starts_fun=[r.fun for r in results], starts_faults=counts)


def _solve(objective: MAPObjective, problem: Problem, opts: SolverOptions) -> MAPResult:
    prior, spec = objective.prior, objective.spec
    x = problem.x0.clone().float()
    n, d = x.shape
    free = np.asarray(problem.free, bool)
    if d != spec.dim or free.shape != (n,):
        raise ValueError(f"the problem has x0 of shape {tuple(x.shape)} and free of shape {free.shape}; the prior "
                         f"needs x0 (N, {spec.dim}) and free (N,)")
    known = ~torch.isnan(x).any(-1).numpy()
    rf = prior.receptive_field
    p = spec.pose_dim
    temperature = opts.temperature_for(prior)
    walk = WindowWalk(objective, free, problem.start, opts.window, opts.overlap, opts.basis)
    starts = walk.starts
    local_solve = OPTIMIZERS[opts.optimizer]
    t_total = time.perf_counter()
    timings = {"pso": 0.0, "lbfgs": 0.0, "prior": 0.0, "rollout": 0.0, "objective": 0.0}
    terms_start: dict[str, float] = {}
    terms_end: dict[str, float] = {}
    nit = nfev = 0
    messages: list[str] = []
    warns: list[str] = []
    windows: list[dict] = []
    success = True
    stopped = False
    for w_i, s in enumerate(starts):
        e = min(s + opts.window, n)
        win = walk.open(x, s)
        free_local = win.free_np
        if win.n_vars == 0:
            continue
        # new frames: a rollout of the prior, steered by the particle swarm when enabled
        unknown = np.nonzero(~known[s:e])[0]
        info: dict = {"frames": (int(s), int(e))}
        pso_evals = 0
        if len(unknown):
            first = int(unknown[0])
            ctx = x[max(0, s + first - rf):s + first]
            if len(ctx) == 0:
                raise ValueError("the first frame to synthesise has no context: give at least one known frame before it")
            fill = torch.from_numpy(~known[s + first:e])
            gen = torch.Generator().manual_seed(opts.seed * 100003 + w_i)
            base = torch.randn(e - s - first, p, generator=gen)
            t0 = time.perf_counter()
            if opts.pso is not None:
                roll, info["fun_pso"], pso_evals = rollout_swarm(win, prior, ctx, first, fill, base, opts.pso,
                                                                 temperature, opts.seed * 7919 + w_i)
                timings["pso"] += time.perf_counter() - t0
            else:
                roll = prior.sample(ctx, e - s - first, temperature=temperature, noise=base)
                timings["rollout"] += time.perf_counter() - t0
            win.x[first:] = torch.where(fill[:, None], roll, win.x[first:])
            x[s:e] = win.x
            known[s + first:e] = True
        walk.rebase(win)
        v0 = win.pack()
        t0 = time.perf_counter()

        def stop(v: np.ndarray) -> str | None:
            if opts.callback is not None:
                try:
                    if opts.callback({"window": w_i, "frames": (int(s), int(e)), "x": v, "best": win.best[0]}):
                        return "stopped by callback"
                except StopSolve:
                    return "stopped by callback"
            if opts.time_budget is not None and time.perf_counter() - t0 >= opts.time_budget:
                return "time budget reached"
            return None

        try:
            v, it, ok, msg = local_solve(win, v0, opts, stop)
        except NonFiniteTermError as err:
            v = win.best[1] if win.best[1] is not None else v0
            it, ok, msg = 0, False, str(err)
            warns.append(f"window {w_i} (frames {s}-{e - 1}): {err}; kept the best iterate")
        timings["lbfgs"] += time.perf_counter() - t0
        # the optimisers start with v0, so the first evaluation holds the starting values
        start_vals = win.first_terms if win.first_terms is not None else win.values(v0)
        if win.best[1] is not None:   # keep the best point evaluated (where the optimiser ends, normally)
            f_end = win.seen.get(hash(v.tobytes()), math.inf)
            if f_end > win.best[0] + 1e-6 * abs(win.best[0]) and not msg.startswith("term "):
                warns.append(f"window {w_i}: the optimiser ended above its best iterate; kept the best")
            v, end_vals = win.best[1], win.best_terms
        else:
            end_vals = win.values(v)
        for k, val in start_vals.items():
            terms_start[k] = terms_start.get(k, 0.0) + val
        info["fun_start"] = sum(start_vals.values())
        stopped = msg == "stopped by callback"
        timings["prior"] += win.prior_seconds
        timings["objective"] += win.objective_seconds
        nit += it
        nfev += win.nfev + pso_evals
        success &= ok
        if not ok:
            messages.append(f"window {w_i}: {msg}")
        # write the window back, its contact features the weights the solve held (the prior
        # reads them as history; it was trained on kinematic labels like them)
        with torch.no_grad():
            xw = win.unpack(torch.from_numpy(v).float())
        xw[:, p:] = torch.where(torch.from_numpy(free_local)[:, None], (win.contacts > 0.5).float(), xw[:, p:])
        x[s:e] = xw
        for k, val in end_vals.items():
            terms_end[k] = terms_end.get(k, 0.0) + val
        info.update(fun=sum(end_vals.values()), nit=it, nfev=win.nfev, message=msg)
        windows.append(info)
        if opts.progress:
            log.info("window %d/%d frames %d-%d: %.1f -> %.1f", w_i + 1, len(starts), s, e - 1,
                     info["fun_start"], info["fun"])
        if stopped:
            messages.append("stopped by callback")
            break
    timings["total"] = time.perf_counter() - t_total
    seam = seam_report(objective, x, problem.start, [w["frames"][0] for w in windows])
    return MAPResult(
        x=x, fun=sum(terms_end.values()), fun_start=sum(terms_start.values()), terms_start=terms_start,
        terms=terms_end, nit=nit, nfev=nfev, success=success and not stopped,
        message="; ".join(messages) if messages else "converged in every window",
        warnings=warns, timings=timings, windows=windows, seam=seam,
    )
