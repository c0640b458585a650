"""Denoising captured motion (Wang et al. 2019, section 5.4): stay close to the noisy
input's root and joint angles while the prior makes it natural and contacts clean."""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from motionopt import rotations as R
from motionopt.codec import Codec
from motionopt.features import to_file_motion
from motionopt.glitches import Glitch, Swirl, fill_swirls, find_glitches, find_swirls, turn_back
from motionopt.metrics import foot_skating, jerk
from motionopt.motion import Motion
from motionopt.smoothing import aligned_quaternions, butterworth, denoising_family, least_risk
from motionopt.objective import MAPObjective, PoseFidelityTerm
from motionopt.solver import Problem, SolverOptions, solve

from .common import (ACCELERATION_SIGMA, Prepared, TaskResult, TermSigmas, judged, plant_feet, prepare,
                     standard_terms)

#: Noise std (robust, from fourth differences) over the std of white noise's fourth difference.
_D4 = 1.4826 / np.sqrt(70.0)


def estimate_noise(motion: Motion) -> tuple[float, float]:
    """White-noise level of a clip: per-axis std of rotation noise (radians) and of root
    noise (metres), from the median absolute fourth difference over time, where smooth
    motion contributes little and white noise of std s has std sqrt(70) s."""
    q = aligned_quaternions(motion.rotations)[..., 1:]  # vector parts move by half the angle
    d4q = np.diff(q, n=4, axis=0)
    d4r = np.diff(motion.root, n=4, axis=0)
    return float(2 * _D4 * np.median(np.abs(d4q))), float(_D4 * np.median(np.abs(d4r)))


def low_pass(motion: Motion, cutoff_hz: float | None = None, angle_sigma: float = 0.01,
             root_sigma: float = 0.01) -> tuple[Motion, dict[str, str]]:
    """Zero-phase smoothing of rotations (aligned quaternions, renormalised) and root
    positions, and the smoother used for each joint (by name; "root" for the position).
    With ``cutoff_hz`` None each joint (and the root) gets the smoother of least estimated
    risk for its noise level (``smoothing.least_risk`` over ``denoising_family``): fast
    limbs keep more bandwidth than a slow spine. Else all get a Butterworth low-pass at
    ``cutoff_hz``."""
    n = motion.num_frames
    if n <= 15:
        return motion, {}
    q = aligned_quaternions(motion.rotations)
    if cutoff_hz is None:
        family = denoising_family(motion.fps)
        per_joint = least_risk(q[..., 1:], angle_sigma / 2, family)
        (root_smoother,) = least_risk(motion.root[:, None], max(root_sigma, 1e-6), family)
    else:
        root_smoother = butterworth(cutoff_hz, motion.fps)
        per_joint = [root_smoother] * q.shape[1]
    out_q = np.empty_like(q)
    for j, smoother in enumerate(per_joint):
        out_q[:, j] = smoother.apply(q[:, j])
    out_q /= np.linalg.norm(out_q, axis=-1, keepdims=True)
    chosen = dict(zip(motion.skeleton.names, (s.label for s in per_joint)), root=root_smoother.label)
    return motion.with_frames(out_q, root_smoother.apply(motion.root), motion.translations), chosen


def with_change(motion: Motion, before: Motion, after: Motion) -> Motion:
    """``motion`` (any skeleton and rate holding the prior's joints) with the change from
    ``before`` to ``after`` (model motions at the prior's rate) added: each modelled
    joint turned by its change in its own frame, the root moved by the root's change,
    both resampled to ``motion``'s rate. Joints the prior does not model keep
    ``motion``'s values; with ``after`` equal to ``before`` the result is ``motion``."""
    a, b = to_file_motion(before, motion), to_file_motion(after, motion)
    turn = R.quat_multiply(R.quat_conjugate(torch.from_numpy(a.rotations)), torch.from_numpy(b.rotations))
    rot = R.quat_multiply(torch.from_numpy(motion.rotations), turn).numpy()
    moved = None if motion.translations is None else (
        motion.translations + b.local_translations() - a.local_translations())  # joints above the model root
    return motion.with_frames(rot, motion.root + (b.root - a.root), moved)


#: A file recorded faster than the prior's rate is low-passed at this fraction of the
#: prior's frame rate (below its Nyquist rate) before it becomes the MAP fidelity target.
ANTI_ALIAS = 0.4
#: Noise bandwidth of the order-2 zero-phase Butterworth (``smoothing.butterworth``), in
#: units of its cutoff: the integral of its squared gain (|H|^4 of order 2).
_BUTTER2_NOISE_BAND = 3 * np.pi / (16 * np.sin(np.pi / 4))


def fidelity_target(motion: Motion, prior, prep: Prepared) -> tuple[Prepared, float]:
    """What the MAP solve stays close to, at the prior's rate, and by how much its noise
    is smaller than the input's. At the prior's rate or below, the input itself (``prep``)
    and 1. A faster file (120 fps against 30) resampled as it is would hand the solver
    one noisy frame in four, undoing the filter that saw all four: it is low-passed just
    below the prior's Nyquist rate first (``ANTI_ALIAS``), which keeps every movement the
    prior's frames can hold and leaves the fraction of the noise in that band (CMU at 120
    fps, 3 cm noise: 1.27 cm with the plain resampling, against 1.01 for the filter)."""
    if motion.fps <= 1.5 * prior.spec.fps:
        return prep, 1.0
    cutoff = ANTI_ALIAS * prior.spec.fps
    smoothed, _ = low_pass(motion, cutoff)
    return prepare(smoothed, prior), float(np.sqrt(2 * _BUTTER2_NOISE_BAND * cutoff / motion.fps))


@dataclass
class DenoiseSetup:
    """A denoising's MAP solve before it runs: the noisy input (glitches turned back,
    swirls filled in) as the prior sees it, its filtered copy (the file's joints and rate, and as the prior
    sees it), the objective (fidelity to the input, prior, contacts), the problem (every
    frame free, starting from the filtered copy), the settings and the glitches and swirls found."""

    prep: Prepared
    filtered: Motion
    start: Prepared
    objective: MAPObjective
    problem: Problem
    settings: dict
    glitches: list[Glitch]
    swirls: list[Swirl]


@dataclass
class Denoise:
    """Remove capture noise from ``motion``: a MAP solve under the prior, started from a
    per-joint filter.

    The noise level is estimated from the clip's high-frequency energy
    (``estimate_noise``); each joint is smoothed by the Butterworth or Savitzky-Golay
    filter of least estimated risk for that level (``low_pass``; ``cutoff_hz`` forces one
    Butterworth cutoff for all). With ``refine`` (the default) the MAP solver then starts
    from that filtered motion and trades fidelity to the noisy input (``sigma_root`` m,
    ``sigma_angle`` rad; default: the estimated noise) against the prior (times
    ``prior_weight``), the contact terms and joint accelerations (``sigmas.smoothness``,
    m/s^2); ``setup`` builds that objective and problem. Without ``refine`` the filter's
    output is the result.

    Why these terms (bench/tasks.py, held-out clips, 3 cm noise, 30 L-BFGS iterations per
    window): the prior with fidelity and contacts alone left the result further from the
    clean clips than the filter (Bandai 1.27 cm against 1.20), and started from the clean
    clip the solver drifted 1.1 cm away from it: the prior tolerates jerky joints. With the
    acceleration term the solve reaches 1.09 cm on Bandai (best Butterworth 1.23) with
    jitter and foot sliding at the clean clips' level. The same solve without the prior
    reaches 1.09 cm too, and 1.06 against 1.05 with 100 iterations: with the shipped
    priors, the acceleration and contact terms do the work (bench/results/tasks*.txt).

    Why 30 iterations per window (``SolverOptions.max_iter``): on held-out Bandai clips at
    the prior's rate 30 / 45 / 60 / 100 give 1.087 / 1.066 / 1.045 / 1.040 cm at 3 cm of
    noise and 1.728 / 1.681 / 1.670 / 1.648 cm at 5 cm (17 / 12 / 10 / 6 frames per second),
    but on Bandai files whose every joint is noisy (the ground joint's rotation moves the
    whole body, so the root is noisy too) the longer solve moves the root away from the
    filter's: 60 iterations end at 0.95 cm against 0.76 for 30 and 0.69 for the filter
    alone at 3 cm (one file: root error 0.42 cm filtered, 0.63 after 30, 0.96 after 60,
    with the local pose unchanged), and a root target taken from the filter does not stop
    it. Until that drift is mended the shorter solve is the default.

    With ``clean_feet`` the foot contacts the prior predicts are then planted by leg IK:
    no sliding, at a cost in fidelity (the IK moves planted feet to where they stand on
    average, centimetres on real captures), so it is off by default.
    """

    motion: Motion
    prior: object
    sigma_root: float | None = None
    sigma_angle: float | None = None
    sigmas: TermSigmas = field(default_factory=lambda: TermSigmas(smoothness=ACCELERATION_SIGMA))
    options: SolverOptions = field(default_factory=lambda: SolverOptions(pso=None))
    cutoff_hz: float | None = None
    clean_feet: bool = False
    refine: bool = True
    repair_glitches: bool = True
    prior_weight: float = 0.5
    prior_min_log_std: float | None = -2.5

    def __post_init__(self) -> None:
        for name in ("sigma_root", "sigma_angle", "cutoff_hz"):
            v = getattr(self, name)
            if v is not None and not v > 0:
                raise ValueError(f"{name} must be positive, got {v}")
        if not self.prior_weight >= 0:
            raise ValueError(f"prior_weight must be 0 or more, got {self.prior_weight}")

    def setup(self) -> DenoiseSetup:
        """The input as the prior sees it, its filtered copy (the solver's start), and the
        MAP objective and problem over it (what ``solve`` refines, and what benchmarks
        evaluate E(clean), E(start) and E(result) with)."""
        prior = self.prior
        glitches, swirls, source = [], [], self.motion
        if self.repair_glitches and self.motion.num_frames > 8:
            noise = self.sigma_angle or estimate_noise(self.motion)[0]
            glitches = find_glitches(self.motion, noise)
            source = turn_back(self.motion, glitches)
            swirls = find_swirls(source, noise)
            source = fill_swirls(source, swirls)
        prep = prepare(source, prior)
        n = len(prep.x)
        if n < 3:
            raise ValueError(f"the clip has {n} frames at the prior's {prior.spec.fps:g} fps; denoising needs at least 3")
        est_angle, est_root = estimate_noise(prep.model) if n > 8 else (0.01, 0.01)
        sigma_angle = self.sigma_angle or max(est_angle, 1e-3)
        sigma_root = self.sigma_root or max(est_root, 1e-3)
        # every joint of the file at its own rate; the solver starts from its model-rate copy
        filtered, smoothers = low_pass(source, self.cutoff_hz, sigma_angle, est_root)
        start = prepare(filtered, prior)
        target, shrink = fidelity_target(source, prior, prep)
        fidelity = PoseFidelityTerm(target.model.root, target.model.rotations, sigma_root * shrink,
                                    sigma_angle * shrink, name="fidelity")
        objective = MAPObjective(prior, prep.model.skeleton, [fidelity] + standard_terms(prep, prior, self.sigmas),
                                 prior_weight=self.prior_weight, prior_min_log_std=self.prior_min_log_std)
        settings = {"sigma_root": sigma_root, "sigma_angle": sigma_angle, "cutoff_hz": self.cutoff_hz,
                    "refine": self.refine, "prior_weight": self.prior_weight,
                    "smoothness_sigma": self.sigmas.smoothness, "estimated_angle_noise": est_angle,
                    "estimated_root_noise": est_root, "smoothers": smoothers, "fidelity_noise_scale": shrink,
                    "repair_glitches": self.repair_glitches,
                    "glitches": [{"joint": self.motion.skeleton.names[g.joint], "frames": [g.first, g.stop - 1],
                                  "degrees": round(g.degrees, 1)} for g in glitches],
                    "swirls": [{"joint": self.motion.skeleton.names[w.joint], "frames": [w.first, w.stop - 1],
                                "degrees_per_second": round(w.degrees_per_second)} for w in swirls]}
        return DenoiseSetup(prep, filtered, start, objective, Problem(start.x.clone(), np.ones(n, bool), start.start),
                            settings, glitches, swirls)

    def solve(self) -> TaskResult:
        prior = self.prior
        t0 = time.perf_counter()
        setup = self.setup()
        prep, start = setup.prep, setup.start
        n = len(prep.x)
        model, x, result = start.model, start.x, None
        if self.refine:
            result = solve(setup.objective, setup.problem, self.options)
            x = result.x
            model = start.codec.motion(x.double(), start.start, like=prep.original)
        if self.clean_feet:
            model = plant_feet(model, prior, x, prep.planted_height, slice(0, n), slow=0.0)
        # the filtered file, plus what the prior changed
        output = with_change(setup.filtered, start.model, model)
        model = start.codec.model_motion(output)
        seconds = time.perf_counter() - t0
        fps = prior.spec.fps
        cidx = prior.spec.contact_indices()
        repaired = setup.glitches or setup.swirls
        seen = Codec.of(prior).model_motion(self.motion) if repaired else prep.model  # the input as given
        before = torch.from_numpy(seen.positions())
        after = torch.from_numpy(model.positions())
        metrics = {
            "jerk_input_m_per_s3": float(jerk(before, fps)),
            "jerk_output_m_per_s3": float(jerk(after, fps)),
            "foot_skating_input_cm_per_s": float(foot_skating(before, fps, cidx) * 100),
            "foot_skating_output_cm_per_s": float(foot_skating(after, fps, cidx) * 100),
            "mean_change_cm": float((after - before).norm(dim=-1).mean() * 100),
            "frames_per_second": n / max(seconds, 1e-9),
        }
        return judged(TaskResult(output, model, result, metrics, setup.settings), prior, prep.start.ground)

    def summary(self, result: TaskResult) -> list[str]:
        """The metrics of ``result`` (of ``solve``) in sentences, for the command line."""
        m = result.metrics
        found = result.settings["glitches"]
        glitches = [f"glitches turned back: {len(found)}"
                    + "".join(f"; {g['joint']} frames {g['frames'][0]}-{g['frames'][1]} ({g['degrees']:.0f} deg)"
                              for g in found[:5]) + ("; ..." if len(found) > 5 else "")] if found else []
        swirls = result.settings["swirls"]
        glitches += [f"swirls filled in: {len(swirls)}"
                     + "".join(f"; {w['joint']} frames {w['frames'][0]}-{w['frames'][1]} "
                               f"({w['degrees_per_second']:.0f} deg/s)" for w in swirls[:5])
                     + ("; ..." if len(swirls) > 5 else "")] if swirls else []
        return glitches + [f"jitter (mean jerk): {m['jerk_input_m_per_s3']:.0f} -> {m['jerk_output_m_per_s3']:.0f} m/s^3, "
                "input -> output",
                f"foot skating: {m['foot_skating_input_cm_per_s']:.1f} -> {m['foot_skating_output_cm_per_s']:.1f} "
                "cm/s, input -> output",
                f"joints moved {m['mean_change_cm']:.2f} cm on average",
                f"speed: {m['frames_per_second']:.0f} frames per second"]
