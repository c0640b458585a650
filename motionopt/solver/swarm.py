"""Particle swarms (pyswarms' GlobalBestPSO): the one helper ``particle_swarm``, and the
MAP solver's swarm over rollouts of the prior (``rollout_swarm``).

One random-state rule for every swarm: ``seed`` gives the initial positions (a numpy
Generator) and pyswarms' own draws (numpy's global generator, seeded with it and put
back as it was afterwards). The first particle starts at the origin, so a swarm never
ends worse than its caller's starting point.
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np
import torch
from torch import Tensor

from ..prior import MotionPrior
from .options import PSOOptions
from .window import Window, dct_basis


def particle_swarm(cost: Callable[[np.ndarray], np.ndarray], dims: int, *, particles: int, iterations: int,
                   bound: float, seed: int, c1: float = 0.5, c2: float = 0.3, w: float = 0.7
                   ) -> tuple[float, np.ndarray]:
    """Minimise ``cost`` (particles (P, dims) -> costs (P,)) within +-``bound`` per
    dimension; initial positions uniform within half the bound, the first at zero.
    Returns the best cost and position."""
    import pyswarms as ps

    rng = np.random.default_rng(seed)
    init = rng.uniform(-bound, bound, (particles, dims)) * 0.5
    init[0] = 0.0
    state = np.random.get_state()
    np.random.seed(seed)  # pyswarms draws its velocities from numpy's global generator
    try:
        optimizer = ps.single.GlobalBestPSO(n_particles=particles, dimensions=dims,
                                            options={"c1": c1, "c2": c2, "w": w},
                                            bounds=(np.full(dims, -bound), np.full(dims, bound)), init_pos=init)
        best_cost, best_pos = optimizer.optimize(cost, iters=iterations, verbose=False)
    finally:
        np.random.set_state(state)
    return float(best_cost), best_pos


def rollout_swarm(win: Window, prior: MotionPrior, context: Tensor, first: int, unknown: Tensor, base_noise: Tensor,
                  opts: PSOOptions, temperature: float, seed: int) -> tuple[Tensor, float, int]:
    """Particle swarm over the prior's sampling noise of the window's new frames.

    A particle is ``3 * n_coeffs`` DCT coefficients added to the standard normal draws of
    the root displacement and yaw-change features (``base_noise`` elsewhere), so each
    particle is a whole coherent rollout from window frame ``first``, used where
    ``unknown``; its cost is the window objective. Returns the best rollout (n_new, D),
    its cost and the number of evaluations.
    """
    n_new = base_noise.shape[0]
    basis = dct_basis(n_new, opts.n_coeffs)
    best: list = [None, math.inf]

    def cost(c: np.ndarray) -> np.ndarray:
        coef = torch.from_numpy(c).float().reshape(len(c), 3, opts.n_coeffs)
        eps = base_noise.expand(len(c), -1, -1).clone()
        eps[..., :3] += torch.einsum("pck,kn->pnc", coef, basis)
        roll = prior.sample(context.expand(len(c), *context.shape), n_new, temperature=temperature, noise=eps)
        xw = win.x.expand(len(c), *win.x.shape).clone()
        xw[:, first:] = torch.where(unknown[:, None], roll, xw[:, first:])
        with torch.no_grad():
            st = win.obj.window_state(xw, win.frames, win.context, win.lead_raw, win.start)
            total = sum(win.obj.energies(st).values())
        total = torch.nan_to_num(total, nan=1e30, posinf=1e30)
        i = int(total.argmin())
        if float(total[i]) < best[1]:
            best[:] = [roll[i], float(total[i])]
        return total.double().numpy()

    particle_swarm(cost, 3 * opts.n_coeffs, particles=opts.particles, iterations=opts.iterations, bound=opts.bound,
                   seed=seed, c1=opts.c1, c2=opts.c2, w=opts.w)
    return best[0], best[1], opts.particles * opts.iterations
