"""Denoising captured motion (Wang et al. 2019, section 5.4): stay close to the noisy
input's root and joint angles while the prior makes it natural and contacts clean."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from motionopt.metrics import foot_skating, jerk
from motionopt.motion import Motion
from motionopt.objective import PoseFidelityTerm
from motionopt.solver import SolverOptions

from .common import TaskResult, TermSigmas, back_to_file, prepare, run, standard_terms


@dataclass
class Denoise:
    """Remove capture noise from ``motion``.

    ``sigma_root`` (m) and ``sigma_angle`` (rad) say how far the result may move from the
    input: about the noise level you expect. Particle swarm is off by default: the
    input is already a good start and there are no new frames to steer.
    """

    motion: Motion
    prior: object
    sigma_root: float = 0.03
    sigma_angle: float = 0.08
    sigmas: TermSigmas = field(default_factory=TermSigmas)
    options: SolverOptions = field(default_factory=lambda: SolverOptions(pso=None))

    def __post_init__(self) -> None:
        if not (self.sigma_root > 0 and self.sigma_angle > 0):
            raise ValueError("sigma_root and sigma_angle must be positive")

    def solve(self) -> TaskResult:
        prior = self.prior
        prep = prepare(self.motion, prior)
        n = len(prep.x)
        if n < 3:
            raise ValueError(f"the clip has {n} frames at the prior's {prior.spec.fps:g} fps; denoising needs at least 3")
        fidelity = PoseFidelityTerm(prep.model.root, prep.model.rotations, self.sigma_root, self.sigma_angle,
                                    name="fidelity")
        terms = [fidelity] + standard_terms(prep, prior, self.sigmas)
        result, model = run(prior, prep, prep.x.clone(), np.ones(n, bool), terms, self.options)
        fps = prior.spec.fps
        cidx = [prior.spec.joints.index(j) for j in prior.spec.contact_joints]
        before, after = torch.from_numpy(prep.model.positions()), torch.from_numpy(model.positions())
        metrics = {
            "jerk_input_m_per_s3": float(jerk(before, fps)),
            "jerk_output_m_per_s3": float(jerk(after, fps)),
            "foot_skating_input_cm_per_s": float(foot_skating(before, fps, cidx) * 100),
            "foot_skating_output_cm_per_s": float(foot_skating(after, fps, cidx) * 100),
            "mean_change_cm": float((after - before).norm(dim=-1).mean() * 100),
            "frames_per_second": n / max(result.timings["total"], 1e-9),
        }
        return TaskResult(back_to_file(model, prep), model, result, metrics,
                          {"sigma_root": self.sigma_root, "sigma_angle": self.sigma_angle})
