"""Settling a made motion under the autoregressive prior: a MAP solve that keeps the
motion within centimetres of itself while the prior, as trained, makes it likely.

What the latent generator makes from codes it never saw (the middle of an interpolation,
a variation) can lie a few centimetres from natural motion and yet score far outside the
held-out data's range under the autoregressive prior: the middle of a walk-to-run blend
scored 114 nats per frame against the inputs' -82 and -2. The prior knows the difference;
this solve lets it mend the motion within the fidelity's sigmas.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from motionopt.motion import Motion
from motionopt.objective import MAPObjective, PoseFidelityTerm
from motionopt.solver import Problem, SolverOptions, solve

from .common import (FLOOR_SIGMA, SKATING_SIGMA, SUPPORT_SIGMA, TaskResult, TermSigmas, judged, prepare, splice,
                     standard_terms)
from .denoise import denoise_options
from .ranges import at_model_rate

#: Fidelity sigmas of the settle solve: root position (m) and joint rotations (rad).
SETTLE_SIGMA_ROOT = 0.05
SETTLE_SIGMA_ANGLE = 0.1
#: Joint acceleration sigma (m/s^2) of the settle solve. The prior as trained likes jerky
#: motion it is unsure of: settled without this term, held-out variations had 1.2 (Bandai)
#: and 1.9 (CMU) times their inputs' jerk; with the tasks' sigmas from the data (at most
#: 14), 0.8 and 0.5 times; with 20, 1.0 and 0.8; with 30, 1.1 and 1.0.
SETTLE_ACCELERATION_SIGMA = 30.0


def nll_per_frame(prior, x: torch.Tensor) -> float:
    """Mean NLL per frame of normalised features ``x (T, D)`` after the first, under ``prior`` as trained."""
    with torch.no_grad():
        return float(prior.nll(x[1:], context=x[:1]).mean())


def settle_sigmas() -> TermSigmas:
    """The settle solve's standard terms: contacts, accelerations, feet gliding near the
    floor, the lowest foot on it where the prior expects a planted foot and none through
    it. Without the last two the prior lifted a settled walk-to-run middle 8-15 cm off
    the floor: bench/latent.py section 6 counted 19 of 24 Bandai middle seconds and 89 of
    92 variation seconds within the held-out data's range (CMU 35 of 40, 148 of 160);
    with them 23 and 92 (CMU 40 and 149)."""
    return TermSigmas(smoothness=SETTLE_ACCELERATION_SIGMA, skating=SKATING_SIGMA, support=SUPPORT_SIGMA,
                      support_where="expected", support_from_floor=False, floor=FLOOR_SIGMA)


@dataclass
class Settle:
    """MAP solve of ``motion`` under ``prior`` (autoregressive) as trained: no floor on its
    predicted spread, which follows every iterate (``MAPObjective.hold_prior_spread``
    off), held to the motion's own root and joint rotations (``sigma_root`` m,
    ``sigma_angle`` rad) with the standard contact, acceleration and skating terms,
    starting from the motion itself. Every frame is free but those where ``held`` (one bool
    per frame of ``motion``) is true, which the output keeps exactly: a completion's
    prefix, which the settled frames then meet without a seam."""

    motion: Motion
    prior: object
    sigma_root: float = SETTLE_SIGMA_ROOT
    sigma_angle: float = SETTLE_SIGMA_ANGLE
    sigmas: TermSigmas = field(default_factory=settle_sigmas)
    options: SolverOptions = field(default_factory=denoise_options)
    held: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.held is not None:
            self.held = np.asarray(self.held, bool)
            if self.held.shape != (self.motion.num_frames,):
                raise ValueError(f"held must have one entry per frame ({self.motion.num_frames}), "
                                 f"got {self.held.shape}")
        for name in ("sigma_root", "sigma_angle"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")

    def solve(self) -> TaskResult:
        t0 = time.perf_counter()
        prep = prepare(self.motion, self.prior)
        n = len(prep.x)
        if n < 3:
            raise ValueError(f"the motion has {n} frames at the prior's rate; settling needs at least 3")
        fidelity = PoseFidelityTerm(prep.model.root, prep.model.rotations, self.sigma_root, self.sigma_angle)
        terms = [fidelity] + standard_terms(prep, self.prior, self.sigmas, prep.x)
        objective = MAPObjective(self.prior, prep.model.skeleton, terms, prior_min_log_std=None,
                                 prior_min_std_raw=None, hold_prior_spread=False)
        held = np.zeros(n, bool) if self.held is None else at_model_rate(self.held, self.motion.fps,
                                                                           self.prior.spec.fps, n)
        result = solve(objective, Problem(prep.x.clone(), ~held, prep.start), self.options)
        model = prep.codec.motion(result.x.double(), prep.start, like=prep.original)
        moved = np.linalg.norm(model.positions() - prep.model.positions(), axis=-1)
        metrics = {"settle_change_cm": float(moved[~held].mean() * 100),
                   "settle_nll_start": nll_per_frame(self.prior, prep.x),
                   "settle_nll": nll_per_frame(self.prior, result.x),
                   "settle_seconds": time.perf_counter() - t0}
        settings = {"sigma_root": self.sigma_root, "sigma_angle": self.sigma_angle}
        out = prep.to_file(model)
        if self.held is not None:
            out = splice(out, self.motion, self.held)
        return judged(TaskResult(out, model, result, metrics, settings), self.prior, prep.start.ground)
