"""Inversion of a latent prior (``motionopt.prior.LatentMotionPrior``): from motion features
to W+ codes and back, for clips of any length.

1. Encoder initialisation: the clip is cut into windows of the prior's length that
   overlap by ``overlap`` frames; each is encoded (with the masked encoder when some
   frames are unseen) in one batched pass.
2. Optional particle swarm (``swarm.particle_swarm``) on a low-dimensional subspace:
   offsets along the first principal components of single codes, one set per window,
   shared by all codes of the window.
3. Optional L-BFGS refinement of all W+ codes against task terms plus a regulariser
   that keeps every code near the training codes' distribution (squared whitened
   distance to the mean code, per dimension).

Generated windows are blended into one sequence with linear cross-fades over the
overlaps; the blend is differentiable, so task terms see the whole clip.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import torch
from torch import Tensor

from ..prior import LatentMotionPrior
from .options import InversionOptions
from .swarm import particle_swarm

#: A task term: normalised features (T, D) of the whole clip -> scalar energy.
TaskTerm = Callable[[Tensor], Tensor]


@dataclass
class InversionResult:
    """Blended features (T, D) of the generated clip, the W+ codes per window, and a report."""

    x: Tensor
    wplus: Tensor
    starts: list[int]
    objective_start: float | None = None
    objective: float | None = None
    nit: int = 0
    timings: dict[str, float] = field(default_factory=dict)


def clip_window_starts(n_frames: int, window: int, overlap: int) -> list[int]:
    """First frames of windows covering ``n_frames``; consecutive windows overlap by at
    least ``overlap`` frames and the last one ends at the clip's end. A clip shorter than
    a window gets one window (padded by the caller)."""
    if not 0 <= overlap < window:
        raise ValueError(f"overlap must be in [0, {window}), got {overlap}")
    if n_frames <= window:
        return [0]
    step = window - overlap
    starts = list(range(0, n_frames - window, step))
    starts.append(n_frames - window)
    return starts


def pad_to_window(x: Tensor, mask: Tensor, window: int) -> tuple[Tensor, Tensor]:
    """Clips shorter than a window: repeat the last frame, marked unseen."""
    if len(x) >= window:
        return x, mask
    extra = window - len(x)
    return (torch.cat((x, x[-1:].expand(extra, -1))), torch.cat((mask, torch.zeros(extra, dtype=mask.dtype))))


def cut_windows(x: Tensor, starts: list[int], window: int) -> Tensor:
    return torch.stack([x[s:s + window] for s in starts])


def blend_weights(starts: list[int], window: int, n_frames: int, dtype=torch.float32) -> Tensor:
    """(N, window) weights that sum to one per frame: linear ramps over overlaps."""
    w = torch.ones(len(starts), window, dtype=dtype)
    for i in range(1, len(starts)):
        ov = starts[i - 1] + window - starts[i]
        if ov > 0:
            ramp = torch.arange(1, ov + 1, dtype=dtype) / (ov + 1)
            w[i, :ov] = ramp
            w[i - 1, window - ov:] = 1 - ramp
    return w


def blend(windows: Tensor, starts: list[int], n_frames: int) -> Tensor:
    """One sequence (n_frames, D) from overlapping windows (N, window, D)."""
    window = windows.shape[1]
    total = max(n_frames, starts[-1] + window)
    w = blend_weights(starts, window, total, windows.dtype)
    out = windows.new_zeros(total, windows.shape[-1])
    for i, s in enumerate(starts):
        out = out.index_add(0, torch.arange(s, s + window), windows[i] * w[i, :, None])
    return out[:n_frames]


def regulariser(prior: LatentMotionPrior, wplus: Tensor) -> Tensor:
    """Mean squared whitened distance of every code to the mean code (about 1 for the
    training windows' codes): keeps refined codes where the generator was trained."""
    return prior.whiten(wplus).pow(2).mean()


def encode_clip(prior: LatentMotionPrior, x: Tensor, mask: Tensor | None, starts: list[int]) -> Tensor:
    """W+ codes (N, num_ws, w_dim) of the windows of a (padded) clip."""
    win = cut_windows(x, starts, prior.window)
    if mask is None or bool(mask.all()):
        return prior.encode(win)
    return prior.encode_masked(win, cut_windows(mask, starts, prior.window))


def invert(prior: LatentMotionPrior, x: Tensor, mask: Tensor | None = None, terms: list[TaskTerm] | None = None,
           options: InversionOptions = InversionOptions(), wplus: Tensor | None = None) -> InversionResult:
    """Features of the latent prior's motion nearest ``x (T, D)`` (normalised) under ``terms``.

    Args:
        mask: (T,) true where a frame of ``x`` is seen; unseen frames go through the masked
            encoder and are what the generator fills in.
        terms: task energies of the blended features; needed for PSO and refinement.
        wplus: start from these codes instead of the encoder's (same windows).
    """
    t0 = time.perf_counter()
    n = len(x)
    seen = torch.ones(n, dtype=torch.bool) if mask is None else mask.bool()
    xp, mp = pad_to_window(x.float(), seen, prior.window)
    starts = clip_window_starts(len(xp), prior.window, options.overlap)
    with torch.no_grad():
        codes = encode_clip(prior, xp, mp, starts) if wplus is None else wplus.float()
    timings = {"encode": time.perf_counter() - t0}
    terms = list(terms or [])
    if (options.refine_iters or options.pso_iters) and not terms:
        raise ValueError("refinement and PSO need task terms to minimise")

    def energy(codes_: Tensor) -> Tensor:
        out = blend(prior.generate(codes_), starts, len(xp))[:n]
        return sum(t(out) for t in terms) + options.reg_weight * regulariser(prior, codes_)

    result = InversionResult(x=x, wplus=codes, starts=starts, timings=timings)
    if terms:
        with torch.no_grad():
            result.objective_start = float(energy(codes))
    if options.pso_iters:
        t1 = time.perf_counter()
        codes = pso_subspace(prior, codes, energy, options)
        timings["pso"] = time.perf_counter() - t1
    if options.refine_iters:
        t1 = time.perf_counter()
        codes, result.nit = refine(codes, energy, options.refine_iters)
        timings["refine"] = time.perf_counter() - t1
    with torch.no_grad():
        result.x = blend(prior.generate(codes), starts, len(xp))[:n]
        if terms:
            result.objective = float(energy(codes))
    result.wplus = codes.detach()
    timings["total"] = time.perf_counter() - t0
    return result


def refine(codes: Tensor, energy: Callable[[Tensor], Tensor], iters: int) -> tuple[Tensor, int]:
    """L-BFGS (strong Wolfe line search) on all W+ codes; returns the best codes seen."""
    param = codes.detach().clone().requires_grad_(True)
    opt = torch.optim.LBFGS([param], lr=1.0, max_iter=iters, history_size=10, line_search_fn="strong_wolfe",
                            tolerance_grad=1e-9, tolerance_change=1e-12)
    best = {"f": float("inf"), "x": codes.detach().clone()}

    def closure() -> Tensor:
        opt.zero_grad()
        f = energy(param)
        f.backward()
        value = float(f.detach())
        if value < best["f"]:
            best["f"], best["x"] = value, param.detach().clone()
        return f

    opt.step(closure)
    return best["x"], int(opt.state[opt._params[0]].get("n_iter", 0))


def pso_subspace(prior: LatentMotionPrior, codes: Tensor, energy: Callable[[Tensor], Tensor],
                 options: InversionOptions) -> Tensor:
    """Particle swarm over offsets along the first ``pso_components`` principal directions
    of single codes (in standard deviations, within +-``pso_bound``), one offset per
    window added to all its codes. The encoder's codes are one particle, so the result is never worse.
    Needs the prior's principal directions ``w_components`` and scales ``w_scales``."""
    k = options.pso_components
    basis = (prior.w_components[:k] * prior.w_scales[:k, None]).to(codes)  # (k, w_dim)
    n_win = len(codes)

    def codes_of(c: Tensor) -> Tensor:
        return codes + (c.reshape(n_win, k) @ basis)[:, None, :]

    @torch.no_grad()
    def cost(particles: np.ndarray) -> np.ndarray:
        return np.array([float(energy(codes_of(torch.from_numpy(p).to(codes)))) for p in particles])

    _, best = particle_swarm(cost, n_win * k, particles=options.pso_particles, iterations=options.pso_iters,
                             bound=options.pso_bound, seed=options.seed)
    return codes_of(torch.from_numpy(best).to(codes)).detach()
