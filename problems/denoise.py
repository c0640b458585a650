"""Denoising captured motion (Wang et al. 2019, section 5.4): stay close to the noisy
input's root and joint angles while the prior makes it natural and contacts clean."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
from scipy.signal import butter, filtfilt

from motionopt.metrics import foot_skating, jerk
from motionopt.motion import Motion
from motionopt.objective import PoseFidelityTerm
from motionopt.solver import SolverOptions

from .common import TaskResult, TermSigmas, back_to_file, plant_feet, prepare, run, standard_terms

#: Noise std (robust, from fourth differences) over the std of white noise's fourth difference.
_D4 = 1.4826 / np.sqrt(70.0)


def aligned_quaternions(q: np.ndarray) -> np.ndarray:
    """Quaternions (T, J, 4) with signs flipped so consecutive frames agree (q ~ -q)."""
    q = q.copy()
    for t in range(1, len(q)):
        q[t, (q[t] * q[t - 1]).sum(-1) < 0] *= -1
    return q


def estimate_noise(motion: Motion) -> tuple[float, float]:
    """White-noise level of a clip: per-axis std of rotation noise (radians) and of root
    noise (metres), from the median absolute fourth difference over time, where smooth
    motion contributes little and white noise of std s has std sqrt(70) s."""
    q = aligned_quaternions(motion.rotations)[..., 1:]  # vector parts move by half the angle
    d4q = np.diff(q, n=4, axis=0)
    d4r = np.diff(motion.root, n=4, axis=0)
    return float(2 * _D4 * np.median(np.abs(d4q))), float(_D4 * np.median(np.abs(d4r)))


def low_pass(motion: Motion, cutoff_hz: float) -> Motion:
    """4th-order zero-phase Butterworth low-pass of rotations (aligned quaternions,
    renormalised) and root positions."""
    if len(motion.rotations) <= 15:
        return motion
    b, a = butter(4, min(cutoff_hz / (motion.fps / 2), 0.99))
    q = filtfilt(b, a, aligned_quaternions(motion.rotations), axis=0)
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return motion.with_frames(np.ascontiguousarray(q), np.ascontiguousarray(filtfilt(b, a, motion.root, axis=0)),
                              motion.translations)


def cutoff_for(angle_sigma: float) -> float:
    """Low-pass cutoff (Hz) of the starting point for a rotation noise level: lower for
    more noise (about 5 Hz at 0.01 rad, 2.5 Hz at 0.05 rad on the held-out locomotion)."""
    return float(np.clip(5.0 - 1.6 * np.log(max(angle_sigma, 1e-4) / 0.01), 2.0, 8.0))


@dataclass
class Denoise:
    """Remove capture noise from ``motion``.

    ``sigma_root`` (m) and ``sigma_angle`` (rad) say how far the result may move from the
    input: about the noise level, which is estimated from the clip's high-frequency
    energy when left as None (``estimate_noise``). The solver starts from a low-pass
    filtered copy of the input (``cutoff_hz``, default from the noise level) and trades
    fidelity to the noisy input against the prior; the prior's foot contacts are then
    planted by leg IK. Particle swarm is off: there are no new frames to steer.
    """

    motion: Motion
    prior: object
    sigma_root: float | None = None
    sigma_angle: float | None = None
    sigmas: TermSigmas = field(default_factory=TermSigmas)
    options: SolverOptions = field(default_factory=lambda: SolverOptions(pso=None))
    cutoff_hz: float | None = None
    clean_feet: bool = True
    prior_min_log_std: float | None = None

    def __post_init__(self) -> None:
        for name in ("sigma_root", "sigma_angle", "cutoff_hz"):
            v = getattr(self, name)
            if v is not None and not v > 0:
                raise ValueError(f"{name} must be positive, got {v}")

    def solve(self) -> TaskResult:
        prior = self.prior
        prep = prepare(self.motion, prior)
        n = len(prep.x)
        if n < 3:
            raise ValueError(f"the clip has {n} frames at the prior's {prior.spec.fps:g} fps; denoising needs at least 3")
        est_angle, est_root = estimate_noise(prep.model) if n > 8 else (0.01, 0.01)
        sigma_angle = self.sigma_angle or max(est_angle, 1e-3)
        sigma_root = self.sigma_root or max(est_root, sigma_angle * 0.5, 1e-3)
        cutoff = self.cutoff_hz or cutoff_for(sigma_angle)
        start = prepare(low_pass(prep.model, cutoff), prior)
        fidelity = PoseFidelityTerm(prep.model.root, prep.model.rotations, sigma_root, sigma_angle, name="fidelity")
        terms = [fidelity] + standard_terms(prep, prior, self.sigmas)
        result, model = run(prior, start, start.x.clone(), np.ones(n, bool), terms, self.options,
                            prior_min_log_std=self.prior_min_log_std)
        if self.clean_feet:
            model = plant_feet(model, prior, result.x, prep.planted_height, slice(0, n))
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
                          {"sigma_root": sigma_root, "sigma_angle": sigma_angle, "cutoff_hz": cutoff,
                           "estimated_angle_noise": est_angle, "estimated_root_noise": est_root})
