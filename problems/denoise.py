"""Denoising captured motion (Wang et al. 2019, section 5.4): stay close to the noisy
input's root and joint angles while the prior makes it natural and contacts clean."""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
import torch

from motionopt import rotations as R
from motionopt.codec import Codec
from motionopt.features import to_file_motion
from motionopt.glitches import Glitch, Swirl, fill_swirls, find_glitches, find_swirls, turn_back
from motionopt.metrics import acceleration, foot_skating, jerk
from motionopt.motion import Motion
from motionopt.smoothing import aligned_quaternions, butterworth, denoising_family, least_risk
from motionopt.objective import MAPObjective, PoseFidelityTerm
from motionopt.solver import Problem, SolverOptions, solve

from .common import (ACCELERATION_FLOOR, Prepared, TaskResult, TermSigmas, acceleration_sigmas, judged, judged_under,
                     plant_feet, prepare, standard_terms)

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
    joint turned by its change in its own frame, the file's root moved by the root's
    change, both resampled to ``motion``'s rate. Joints the prior does not model keep
    ``motion``'s values, and so do the positions of joints above the model root (the
    hips under a ground joint such as Bandai's joint_Root, whose noisy turn moves the
    whole body): there the solve's root path ended further from the clean one than the
    filter's (held-out Bandai files, 3 cm of noise, before the constant joined the
    filter's smoothers: 0.89 cm with it moved, 0.69 without; the filter alone 0.69), while on files whose root is the model's it helped (CMU at
    120 fps: 0.87 against 0.91). With ``after`` equal to ``before`` the result is
    ``motion``."""
    a, b = to_file_motion(before, motion), to_file_motion(after, motion)
    turn = R.quat_multiply(R.quat_conjugate(torch.from_numpy(a.rotations)), torch.from_numpy(b.rotations))
    rot = R.quat_multiply(torch.from_numpy(motion.rotations), turn).numpy()
    return motion.with_frames(rot, motion.root + (b.root - a.root), motion.translations)


#: Joint acceleration sigmas of denoising's MAP solve, in units of each joint's RMS
#: acceleration over the prior's training clips (``common.acceleration_sigmas``).
#: Measured on held-out clips (``bench/tasks.py``, see ``Denoise``).
ACCELERATION_SCALE = 1.0
#: ... and at most this times the joint's RMS acceleration in the filtered start, the
#: clip's own estimate (empirical Bayes): the training clips' RMS is a run's, and under
#: it a slow walk's hands kept noise that the filter had removed (held-out Bandai walk,
#: 3 cm noise: hand jerk 4 times the clean clip's). The filtered start's RMS runs 1-3
#: times the clean clip's; measured on 3 held-out Bandai clips at 1/3/5 cm (MPJPE cm,
#: jerk over the clean clips'): without the cap 0.479/1.04/1.58 at the prior's rate and
#: files' jerk 1.14/1.29/1.33; 1.0: 0.469/1.027/1.581, files 1.09/1.18/1.23; 0.8:
#: 0.471/1.031/1.604, files 1.07/1.17/1.20; 0.5 smoothed the hips below the clean clips'.
CLIP_ACCELERATION_SCALE = 0.7


def denoise_options(**changes) -> SolverOptions:
    """Denoising's solver settings (``changes`` applied): no particle swarm (there are no
    new frames to steer), 30 L-BFGS corrections kept and 16 cosine steps per window, which
    the long acceleration coupling of a clean clip needs (held-out Bandai clips at 3 cm
    noise: 1.062 cm with the solver's 10 and 8, 1.050 with these)."""
    return SolverOptions(**{"pso": None, "history": 30, "basis": 16, **changes})


#: A file recorded faster than 1.5 times the prior's rate leaves denoising low-passed at
#: this cutoff (Hz): above the prior's band only the per-joint filter, chosen for least
#: position error, cleaned it, and at 120 fps what it leaves there is jitter and sliding
#: feet (held-out CMU files, every joint, 1/3/5 cm of noise: without it, mean jerk 1.4-3.8
#: times the clean captures'; at 20 Hz, jerk 0.47-0.65 times but planted feet sliding
#: 1.07/1.42/1.35 times; at 14 Hz 1.00/1.17/1.13 and at 10 Hz 0.96/1.02/0.99, with MPJPE
#: 0.401/0.885/1.25 cm at 20 Hz, 0.421/0.889/1.25 at 14 and 0.462/0.899/1.25 at 10).
OUTPUT_CUTOFF = 12.0

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
    m/s^2; by default each joint's sigma is ``acceleration_scale`` times its RMS
    acceleration over the prior's training clips, ``common.acceleration_sigmas``, and at
    most ``clip_acceleration_scale`` times its RMS acceleration in the filtered start);
    ``setup`` builds that objective and problem. The solve's change is added to the
    filtered file (``with_change``).
    Without ``refine`` the filter's output is the result.

    Why these terms (bench/tasks.py, held-out clips, 3 cm noise, 30 L-BFGS iterations per
    window): the prior with fidelity and contacts alone left the result further from the
    clean clips than the filter (Bandai 1.27 cm against 1.20), and started from the clean
    clip the solver drifted 1.1 cm away from it: the prior tolerates jerky joints. One
    acceleration sigma of 10 m/s^2 for every joint brought Bandai to 1.09 cm (best
    Butterworth 1.23); a sigma per joint from the data (the trunk about 6.5, hands and
    feet 10-18, capped at 14) with 30 L-BFGS corrections and 16 cosine steps per window
    (``denoise_options``) brings it to 1.04 cm, and 1.58 at 5 cm noise (1.73 before), with
    jitter and foot sliding within 1.2 times the clean clips'. The same solve without the
    prior ends close to it: with the shipped priors, the acceleration and contact terms
    do most of the work (bench/results/tasks*.txt).

    Why 30 iterations per window (``SolverOptions.max_iter``): 60 halve the speed for
    0.01-0.04 cm on held-out Bandai clips (bench/tasks.py, "--iterations 60").

    With ``clean_feet`` the foot contacts the prior predicts are then planted by leg IK:
    no sliding, at a cost in fidelity (the IK moves planted feet to where they stand on
    average, centimetres on real captures), so it is off by default.
    """

    motion: Motion
    prior: object
    sigma_root: float | None = None
    sigma_angle: float | None = None
    sigmas: TermSigmas = field(default_factory=TermSigmas)
    acceleration_scale: float | None = ACCELERATION_SCALE
    clip_acceleration_scale: float | None = CLIP_ACCELERATION_SCALE
    options: SolverOptions = field(default_factory=denoise_options)
    cutoff_hz: float | None = None
    clean_feet: bool = False
    refine: bool = True
    repair_glitches: bool = True
    prior_weight: float = 0.5
    prior_min_log_std: float | None = -2.5
    #: An autoregressive prior whose held-out range judges each second of the output
    #: (``common.judged``); None: the prior solved under (a latent density carries none).
    judge_prior: object | None = None

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
        evaluate E(clean), E(start) and E(result) with). A pooled prior scores through its
        change model alone (``CCNetPrior.unpooled``): every frame here is observed."""
        prior = self.prior.unpooled() if hasattr(self.prior, "unpooled") else self.prior
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
        sigmas = self.sigmas
        if sigmas.smoothness is None and self.acceleration_scale:
            sigmas = replace(sigmas, smoothness=self._acceleration_sigmas(start))
        objective = MAPObjective(prior, prep.model.skeleton, [fidelity] + standard_terms(prep, prior, sigmas),
                                 prior_weight=self.prior_weight, prior_min_log_std=self.prior_min_log_std)
        settings = {"sigma_root": sigma_root, "sigma_angle": sigma_angle, "cutoff_hz": self.cutoff_hz,
                    "refine": self.refine, "prior_weight": self.prior_weight,
                    "smoothness_sigma": sigmas.smoothness, "estimated_angle_noise": est_angle,
                    "estimated_root_noise": est_root, "smoothers": smoothers, "fidelity_noise_scale": shrink,
                    "repair_glitches": self.repair_glitches,
                    "glitches": [{"joint": self.motion.skeleton.names[g.joint], "frames": [g.first, g.stop - 1],
                                  "degrees": round(g.degrees, 1)} for g in glitches],
                    "swirls": [{"joint": self.motion.skeleton.names[w.joint], "frames": [w.first, w.stop - 1],
                                "degrees_per_second": round(w.degrees_per_second)} for w in swirls]}
        return DenoiseSetup(prep, filtered, start, objective, Problem(start.x.clone(), np.ones(n, bool), start.start),
                            settings, glitches, swirls)

    def _acceleration_sigmas(self, start: Prepared) -> list[float]:
        """Per model joint: the training clips' RMS acceleration (``acceleration_scale``
        times), capped by the filtered start's own (``clip_acceleration_scale`` times),
        within ``ACCELERATION_FLOOR`` and ``ACCELERATION_CAP``."""
        sigmas = acceleration_sigmas(self.prior, self.acceleration_scale)
        if isinstance(sigmas, float):
            sigmas = [sigmas] * start.model.skeleton.num_joints
        if not self.clip_acceleration_scale or start.model.num_frames < 3:
            return sigmas
        acc = acceleration(torch.from_numpy(start.model.positions()), self.prior.spec.fps)
        own = acc.pow(2).sum(-1).mean(0).sqrt() * self.clip_acceleration_scale
        return [min(s, max(float(o), ACCELERATION_FLOOR)) for s, o in zip(sigmas, own)]

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
        if self.motion.fps > 1.5 * prior.spec.fps:   # the detail above the prior's band: see OUTPUT_CUTOFF
            output, _ = low_pass(output, OUTPUT_CUTOFF)
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
        result = TaskResult(output, model, result, metrics, setup.settings)
        if self.judge_prior is None:
            return judged(result, prior, prep.start.ground)
        return judged_under(result, self.judge_prior, self.motion)

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
