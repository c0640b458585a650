"""Tasks solved by inverting the latent prior (MoDi section 4): reconstruction (denoising,
cleaning), fusion of two motions, completion and in-betweening with the masked encoder,
semantic editing, interpolation, and variations.

Each task turns the user's motion into normalised features, finds W+ codes (encoder,
optionally PSO and L-BFGS against the task's fidelity terms, see
``motionopt.solver.inversion``), edits the codes when the task says so, generates, and puts
the result back on the user's skeleton, frame rate and unit.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import torch
from torch import Tensor

from motionopt import naturalness
from motionopt import rotations as R
from motionopt.codec import Codec
from motionopt.features import RootStart, heading_angle, to_file_motion, wrap_angle
from motionopt.inertialization import carry_on
from motionopt.motion import Motion
from motionopt.solver import InversionOptions, InversionResult, SolverOptions, blend, invert
from motionopt.smoothing import gaussian_smooth, local_linear, smoothstep
from motionopt.timewarp import align, blend_times, frames_at
from priors.checkpoint import load_prior_of_kind
from priors.latent import LatentPrior
from priors.latent_density import LatentDensity
from priors.semantic import Direction, directions_of, fit_attribute_directions

from .common import (Prepared, completion_sigmas, gap_sigmas, join_terms, judged_under, prepare, run, splice,
                     standard_terms)
from .ranges import at_model_rate, check_ranges, gaps, kept_mask, require_a_gap
from .settle import Settle


def load_latent_for(motion: Motion, path: str | None = None) -> LatentPrior:
    """The named latent checkpoint (a file or a shipped checkpoint's name), or the shipped
    one whose skeleton matches the motion."""
    return load_prior_of_kind(motion.skeleton, path, "LatentPrior", "a latent task")[0]


class FidelityTerm:
    """Closeness of generated features to a target on weighted frames: mean squared error
    of the normalised pose features plus squared joint position error over sigma^2
    (positions from frame 0 of the clip, so root drift counts)."""

    name = "fidelity"

    def __init__(self, prior: LatentPrior, target: Tensor, weights: Tensor, position_sigma: float):
        self.prior, self.target = prior, target.float()
        self.codec = Codec.of(prior)
        self.weights = weights.float() / weights.float().sum().clamp_min(1e-9)
        self.sigma = position_sigma
        self.target_pos = self.positions(self.target).detach()

    def positions(self, x: Tensor) -> Tensor:
        return self.codec.positions(x)

    def __call__(self, x: Tensor) -> Tensor:
        p = self.prior.spec.pose_dim
        feat = (x[:, :p] - self.target[:, :p]).pow(2).mean(-1)
        pos = (self.positions(x) - self.target_pos).pow(2).sum(-1).mean(-1) / self.sigma ** 2
        return (self.weights * (feat + pos)).sum()


@dataclass
class LatentTaskResult:
    """An output motion on the user's skeleton, its model-skeleton version, the inversion
    report and task figures."""

    motion: Motion
    model_motion: Motion
    inversion: InversionResult
    metrics: dict = field(default_factory=dict)
    #: Each second measured and judged under an autoregressive prior's data range, as a
    #: ``TaskResult``'s (``common.judged``; empty when nothing judged it).
    per_second: list[dict] = field(default_factory=list)
    human_range: naturalness.HumanRange | None = None
    naturalness_warnings: list[str] = field(default_factory=list)

    def naturalness_line(self) -> str | None:
        """How many seconds stay in the data's range, in one sentence (None: not judged)."""
        return naturalness.summary_line(self.per_second, self.human_range) if self.per_second else None

    def report(self) -> dict:
        inv = self.inversion
        return {"metrics": self.metrics, "frames": self.motion.num_frames, "fps": self.motion.fps,
                "windows": len(inv.starts), "objective_start": inv.objective_start, "objective": inv.objective,
                "nit": inv.nit, "timings": inv.timings, "per_second": self.per_second,
                "human_range": None if self.human_range is None else self.human_range.to_dict(),
                "warnings": self.naturalness_warnings}


def result_of(prior: LatentPrior, x: Tensor, start: RootStart, original: Motion, inv: InversionResult,
              metrics: dict | None = None, n_frames: int | None = None,
              anchor: tuple[Motion, np.ndarray] | None = None, anchor_height: bool = True) -> LatentTaskResult:
    """Decode features and put them on the original's skeleton with ``n_frames`` frames at the
    original's rate (default: as many as the features last). ``anchor`` (the input at the
    model rate, its known frames): take the root's slow motion from it (``anchor_root``;
    its height too with ``anchor_height``), and where the known frames stop before the
    end (completion), carry the generated frames on from them (``continued``).
    The model motion is held one frame longer so that resampling covers the last file frame."""
    model = Codec.of(prior).motion(x.double(), start, like=original)
    if anchor is not None:
        model = continued(anchor_root(model, *anchor, height=anchor_height), *anchor)
    if n_frames is None:
        n_frames = int(round((model.num_frames - 1) * original.fps / model.fps)) + 1
    motion = to_file_motion(hold_last_frame(model, model.num_frames + 1), original)[:n_frames]
    return LatentTaskResult(motion, model, inv, dict(metrics or {}))


#: Half-life (s) over which a completion's jump from the last known frame fades
#: (``motionopt.inertialization``). The masked encoder reproduces the prefix only
#: approximately (12-43 mm off at the seam on held-out CMU clips). On the second after a
#: 1 s prefix of held-out clips (mm, the encoder's output): CMU 108.6 as generated,
#: 100.7 / 93.3 / 87.4 / 84.5 at 0.1 / 0.2 / 0.4 / 0.8 s; Bandai 112.3, then 111.1 / 110.6 /
#: 111.7 / 116.6.
SEAM_HALFLIFE = 0.4


def continued(motion: Motion, reference: Motion, seen: np.ndarray, halflife: float = SEAM_HALFLIFE) -> Motion:
    """``motion`` carried on from ``reference`` after its last ``seen`` frame, when seen
    frames stop before the end (prefix completion; ``carry_on``); otherwise unchanged."""
    known = np.flatnonzero(seen)
    if len(known) < 2 or seen[-1] or not seen[: known[-1] + 1].all():
        return motion
    return carry_on(motion, reference, int(known[-1]) + 1, halflife)


#: Root drift slower than this (Hz) is taken from the input's root path and heading.
ROOT_ANCHOR_HZ = 0.5


def anchor_root(motion: Motion, reference: Motion, seen: np.ndarray, cutoff_hz: float = ROOT_ANCHOR_HZ,
                height: bool = True) -> Motion:
    """``motion`` with the slow part of its root's departure from ``reference`` removed.

    The generator predicts root velocities window by window, so its root path drifts:
    over 8 s clips the encoder alone lands metres away. Where the input's root is known
    (``seen`` frames at the model rate), its path and heading are the better estimate of
    the slow root motion: the differences in heading and position on seen frames, held
    across unseen ones, are smoothed below ``cutoff_hz`` (``local_linear``) and
    added, so the generated motion keeps its own fast root motion (steps, sway) and
    follows the input's path. Without ``height`` the root's height is left as generated
    (an edit that lowers the hips keeps them low).
    """
    seen = np.asarray(seen, bool)
    if len(seen) != motion.num_frames or len(reference.root) != motion.num_frames or not seen.any():
        raise ValueError("anchor_root needs motion, reference and seen of the same length, with a seen frame")
    t, s = np.arange(motion.num_frames), np.flatnonzero(seen)
    sigma = np.sqrt(np.log(2)) / (2 * np.pi * cutoff_hz) * motion.fps  # Gaussian half-power at cutoff_hz

    def slow(diff: np.ndarray) -> np.ndarray:
        held = np.stack([np.interp(t, s, d[s]) for d in np.atleast_2d(diff.T)], axis=-1)
        return local_linear(held, sigma)

    root_q = torch.from_numpy(motion.rotations[:, 0])
    turn = wrap_angle(heading_angle(torch.from_numpy(reference.rotations[:, 0])) - heading_angle(root_q)).numpy()
    turn = slow(np.unwrap(turn))[:, 0]
    rotations = motion.rotations.copy()
    rotations[:, 0] = R.quat_multiply(R.yaw_quat(torch.from_numpy(turn)), root_q).numpy()
    axes = [0, 1, 2] if height else [0, 2]
    root = motion.root.copy()
    root[:, axes] += slow(reference.root[:, axes] - motion.root[:, axes])
    return motion.with_frames(rotations, root, motion.translations)


def _model_frame(prior: LatentPrior, motion: Motion, frame: int) -> int:
    """A frame index of the file, in the prior's frame rate."""
    return int(round(frame * prior.spec.fps / motion.fps))


def reconstruct(prior: LatentPrior, motion: Motion, options: InversionOptions = InversionOptions()) -> LatentTaskResult:
    """G(I(m)), optionally refined toward the input: denoising and cleaning (MoDi 4)."""
    prep = prepare(motion, prior)
    term = FidelityTerm(prior, prep.x, torch.ones(len(prep.x)), options.position_sigma)
    inv = invert(prior, prep.x, terms=[term], options=options)
    return result_of(prior, inv.x, prep.start, motion, inv, n_frames=motion.num_frames,
                     anchor=(prep.model, np.ones(len(prep.x), bool)))


def fuse(prior: LatentPrior, a: Motion, b: Motion, at: int, options: InversionOptions = InversionOptions(),
         blend_frames: int = 8) -> LatentTaskResult:
    """A's frames before ``at`` (a frame of A) followed by B's frames from the same time
    into B (MoDi's fusion), joined through the encoder and generator. B's root continues
    from A's. (Counting ``at`` in each file's own frames instead, as before, handed over
    from A's second 1 to B's second 2 with A at 120 fps and B at 60.)

    The generated motion G(I(.)) replaces the two parts within ``blend_frames`` of the seam
    and fades back into them over as many frames again (``smoothstep``), so that beyond
    that the output is each input as it was: generated whole, every frame carried the
    round trip's error (held-out clips, encoder alone: 1.2-2.7 cm of local joint error
    on the parts, up to 3.5 cm on one). Refinement fits the codes to both parts outside
    the seam's ``blend_frames``."""
    pa, pb = prepare(a, prior), prepare(b, prior)
    t = _model_frame(prior, a, at)
    if not 0 < t < len(pa.x) or not t < len(pb.x) - 1:
        accepted = [f for f in range(a.num_frames)
                    if 0 < _model_frame(prior, a, f) < min(len(pa.x), len(pb.x) - 1)]
        span = f"frames {accepted[0]}-{accepted[-1]} of A" if accepted else "no frame: a clip is too short"
        raise ValueError(f"--at {at} ({at / a.fps:.2f} s) must fall inside both clips, with a model frame "
                         f"({prior.spec.fps:g} fps) on each side (A lasts {a.duration:.2f} s, {a.num_frames} "
                         f"frames; B {b.duration:.2f} s); accepted: {span}")
    x = torch.cat((pa.x[:t], pb.x[t:]))
    weights = torch.ones(len(x))
    weights[max(0, t - blend_frames):t + blend_frames] = 0.0
    term = FidelityTerm(prior, x, weights, options.position_sigma)
    inv = invert(prior, x, terms=[term], options=options)
    away = (np.abs(np.arange(len(x)) - t + 0.5) - blend_frames) / blend_frames  # 0 at the band's edge, 1 a band beyond
    generated = torch.from_numpy(1.0 - smoothstep(away)).to(x)[:, None]
    fused = x + generated * (inv.x - x)
    return result_of(prior, fused, pa.start, a, inv, {"seam_frame_model": t})


def infill(prior: LatentPrior, motion: Motion, seen: np.ndarray, options: InversionOptions = InversionOptions()
           ) -> LatentTaskResult:
    """Fill the frames of ``motion`` where ``seen`` (one bool per file frame) is false with
    the masked encoder: prefix completion (seen = a prefix) and in-betweening (seen =
    keyframe ranges). Refinement matches the seen frames only."""
    seen = np.asarray(seen, bool)
    if seen.shape != (motion.num_frames,):
        raise ValueError(f"seen must have one entry per frame ({motion.num_frames}), got {seen.shape}")
    prep = prepare(motion, prior)
    mask = torch.from_numpy(at_model_rate(seen, motion.fps, prior.spec.fps, len(prep.x)))
    if not bool(mask.any()):
        raise ValueError("no frame is seen: give at least one known frame")
    term = FidelityTerm(prior, prep.x, mask.float(), options.position_sigma)
    inv = invert(prior, prep.x, mask=mask, terms=[term], options=options)
    return result_of(prior, inv.x, prep.start, motion, inv, n_frames=motion.num_frames,
                     anchor=(prep.model, mask.numpy()))


def solve_unseen(prior: LatentPrior, motion: Motion, seen: np.ndarray, filled: LatentTaskResult,
                 options: SolverOptions, others: Sequence[LatentTaskResult] = ()) -> LatentTaskResult:
    """The unseen frames of ``filled`` (``infill``'s output for ``motion``) solved by the MAP
    solver with the latent prior as its prior term (``priors.latent_density``) and the
    autoregressive tasks' terms: joint accelerations, contacts, feet gliding near the floor
    and, where a gap meets a seen frame, fidelity to it (in-betweening, as
    ``problems.inbetween.Inbetween``); or, after the last seen frame, the feet gliding and
    supporting the body (prefix completion, as ``problems.inbetween.complete``). Seen
    frames are the input's exactly. Each of ``others`` (other fills of the same frames)
    is a further start in the gaps of ``long_gaps``, ``filled`` elsewhere; the lowest
    objective is kept (``solve_from``).

    On held-out clips (1.5 s gaps, the first 8 s of 4 CMU clips, error on the gap) the
    masked encoder refined by 200 L-BFGS iterations left 125 mm, this solve 116 (the
    autoregressive task 112); on 3 Bandai clips 108 and 107 (96)."""
    density = LatentDensity(prior)
    prep = prepare(motion, density)
    n = len(prep.x)
    kept = at_model_rate(seen, motion.fps, prior.spec.fps, n)
    x0 = prep.codec.features(filled.model_motion, prep.start.ground)[:n].clone()
    x0[torch.from_numpy(kept)] = prep.x[torch.from_numpy(kept)]
    starts = [with_long_gaps_from(x0, prep.codec.features(other.model_motion, prep.start.ground)[:n], kept,
                                  prior.spec.fps) for other in others]
    join = np.zeros(n, bool)
    join[1:] = kept[1:] & ~kept[:-1]
    sigmas = gap_sigmas() if kept[-1] else completion_sigmas()
    terms = join_terms(prep.model.root, prep.model.rotations, join) + standard_terms(prep, density, sigmas, x0)
    result, model = run(density, prep, x0, ~kept, terms, options, other_starts=starts)
    out = splice(prep.to_file(model)[:motion.num_frames], motion, seen)
    metrics = {**filled.metrics, "map_objective_start": result.fun_start, "map_objective": result.fun,
               "map_iterations": result.nit, "map_starts_objective": result.starts_fun}
    return LatentTaskResult(out, model, filled.inversion, metrics)


#: Shortest gap (s) that the masked encoder's fills seed: in ``Inbetween.latent``'s solve
#: under the autoregressive prior, and as ``LatentTask``'s second start (the fill from the
#: encoder alone). Held-out LAFAN1-style gaps, Inbetween (the rollouts alone against the
#: lowest objective from them and the fills, L2P m): 5 frames CMU 0.0438 against 0.0462
#: (20 cases), Bandai 0.0984 against 0.1024 (17 cases of 6 clips); longer gaps gain
#: (bench/tasks.py section 3, all cases): 15 frames CMU 0.171 either way, Bandai 0.227 ->
#: 0.202; 30 frames CMU 0.417 -> 0.340, Bandai 0.415 -> 0.281. The two inversions take
#: about 2 s a case. LatentTask's figures are in its docstring.
LATENT_SEED_MIN_SECONDS = 0.3


def long_gaps(kept: np.ndarray, fps: float) -> list[tuple[int, int]]:
    """The gaps between ``kept`` frames (at ``fps``) with a kept frame after them that last
    at least ``LATENT_SEED_MIN_SECONDS``: those the masked encoder's fills seed."""
    return [(a, b) for a, b in gaps(kept) if b < len(kept) and (b - a) / fps >= LATENT_SEED_MIN_SECONDS]


def with_long_gaps_from(x: Tensor, other: Tensor, kept: np.ndarray, fps: float, step: slice | None = None) -> Tensor:
    """A start of a MAP solve: features ``x (T, D)`` with each of ``long_gaps(kept, fps)``
    taken from ``other`` (T, D) and, with ``step``, those channels of the kept frame after
    the gap too (the other's own step onto it)."""
    out = x.clone()
    for a, b in long_gaps(kept, fps):
        out[a:b] = other[a:b].to(x)
        if step is not None:
            out[b, step] = other[b, step].to(x)
    return out


#: L-BFGS iterations of the inversion before in-betweening's MAP solve (``gap_inversion_options``).
#: 1.5 s gaps of held-out clips (bench/latent.py section 4; error on the gap, mm; the MAP
#: solve after): with 200, Bandai 50.2 (29 clips) and CMU 99.9 (4 clips); the masked encoder
#: alone before the solve, Bandai 65.0 and CMU 116. Completion keeps the encoder alone:
#: refined toward the first second, CMU's next second went from 109 to 114 mm (Bandai 112 to 106).
GAP_REFINE_ITERS = 200


def gap_inversion_options() -> InversionOptions:
    """The inversion settings in-betweening starts from (``GAP_REFINE_ITERS``)."""
    return InversionOptions(refine_iters=GAP_REFINE_ITERS)


def masked_fills(prior: LatentPrior, motion: Motion, seen: np.ndarray) -> list[Motion]:
    """The masked encoder's fills of the frames of ``motion`` where ``seen`` is false, on
    the file's skeleton and rate: refined toward the seen frames (``gap_inversion_options``)
    and from the encoder alone. In-betweening's MAP solve under the autoregressive prior
    starts from each besides its own rollout (``problems.inbetween.Inbetween.latent``)."""
    return [infill(prior, motion, seen, options).motion for options in (gap_inversion_options(), InversionOptions())]


def hold_last_frame(motion: Motion, n_frames: int) -> Motion:
    """The motion lengthened to ``n_frames`` by repeating its last frame (for completion)."""
    if n_frames <= motion.num_frames:
        return motion
    idx = np.minimum(np.arange(n_frames), motion.num_frames - 1)
    tr = None if motion.translations is None else motion.translations[idx]
    return Motion(motion.skeleton, motion.rotations[idx], motion.root[idx], motion.fps, tr, motion.source_unit)


def complete(prior: LatentPrior, motion: Motion, prefix: int, n_frames: int,
             options: InversionOptions = InversionOptions()) -> LatentTaskResult:
    """Prefix completion (MoDi 4): keep the first ``prefix`` frames, generate up to ``n_frames``."""
    return LatentTask.completion(motion, prefix, n_frames, prior, options).solve()


@dataclass
class LatentTask:
    """A task solved by inverting the latent prior, as an object that the commands run like
    the autoregressive tasks (``options``, ``solve``, ``summary``): with ``keep`` None,
    ``reconstruct`` the whole of ``motion`` (denoising); else ``infill`` the frames outside
    ``keep``, half-open ranges of the input's frames with the first from frame 0 (as
    ``problems.ranges.check_ranges`` takes them): in-betweening, and prefix completion
    (``LatentTask.completion``).

    In-betweening's MAP solve of gaps of ``long_gaps`` starts from the fill of ``options``
    and from the encoder's alone, and keeps the lowest objective: on held-out LAFAN1-style
    gaps (L2P m, from the refined fill alone -> from both) CMU 15 frames 0.233 -> 0.205, 30
    frames 0.384 -> 0.355 (20 cases each), Bandai 15 frames 0.208 -> 0.209, 30 frames 0.272
    -> 0.261 (32 and 30 cases); on 5-frame gaps the encoder's fill made it worse (CMU 0.064
    -> 0.072), which ``LATENT_SEED_MIN_SECONDS`` keeps out."""

    motion: Motion
    prior: LatentPrior
    keep: list[tuple[int, int]] | None = None
    options: InversionOptions = field(default_factory=InversionOptions)
    #: The MAP solve of the filled frames (``solve_unseen``); None: the inversion's output.
    map_options: SolverOptions | None = field(default_factory=lambda: SolverOptions(pso=None))
    #: An autoregressive prior that settles the synthesised frames after that solve
    #: (``settled``, the kept frames held); None: as the latent prior made them.
    settle_prior: object | None = None
    #: An autoregressive prior whose checkpoint's held-out range judges each second of the
    #: output (``common.judged``), as the autoregressive tasks' are; None: not judged.
    judge_prior: object | None = None

    def __post_init__(self) -> None:
        if self.keep is not None:
            self.keep = check_ranges(list(self.keep), self.motion.num_frames)
            require_a_gap(*self.output_ranges())

    @classmethod
    def completion(cls, motion: Motion, prefix: int, n_frames: int, prior: LatentPrior,
                   options: InversionOptions = InversionOptions(), settle_prior=None,
                   judge_prior=None) -> LatentTask:
        """Prefix completion: keep the first ``prefix`` frames, generate up to ``n_frames``,
        settled under ``settle_prior`` and judged under ``judge_prior`` when given."""
        if not 0 < prefix <= motion.num_frames:
            raise ValueError(f"--prefix {prefix} must be between 1 and the clip's {motion.num_frames} frames")
        if n_frames <= prefix:
            raise ValueError(f"--frames {n_frames} must be larger than --prefix {prefix}")
        return cls(hold_last_frame(motion[:prefix], n_frames), prior, [(0, prefix)], options,
                   settle_prior=settle_prior, judge_prior=judge_prior)

    def output_ranges(self) -> tuple[list[tuple[int, int]], int]:
        """The ranges the output copies from the input and its length (input frames), as
        ``problems.inbetween.Inbetween.output_ranges`` gives them: the whole motion when
        it is reconstructed."""
        n = self.motion.num_frames
        return (self.keep if self.keep is not None else [(0, n)]), n

    def solve(self) -> LatentTaskResult:
        result = self._solved()
        return result if self.judge_prior is None else judged_under(result, self.judge_prior, self.motion)

    def _solved(self) -> LatentTaskResult:
        if self.keep is None:
            return reconstruct(self.prior, self.motion, self.options)
        seen = kept_mask(self.keep, self.motion.num_frames)
        result = infill(self.prior, self.motion, seen, self.options)
        if self.map_options:
            encoder_alone = InversionOptions()
            others = [infill(self.prior, self.motion, seen, encoder_alone)] if (
                self.options != encoder_alone and long_gaps(seen, self.motion.fps)) else []
            result = solve_unseen(self.prior, self.motion, seen, result, self.map_options, others)
        return result if self.settle_prior is None else settled(result, self.settle_prior, held=seen)

    def summary(self, result: LatentTaskResult) -> list[str]:
        """How the inversion of ``result`` (of ``solve``) went, in a sentence for the command line."""
        inv = result.inversion
        how = f"refined in {inv.nit} iterations" if inv.nit else "from the encoder alone"
        fit = "" if inv.objective is None else f"; fidelity objective {inv.objective_start:.4g} -> {inv.objective:.4g}"
        m = result.metrics
        starts = m.get("map_starts_objective", [])
        among = (f", the lowest of {len(starts)} starts (the refined fill and the encoder's own in gaps of "
                 f"{LATENT_SEED_MIN_SECONDS:g} s or more)") if len(starts) > 1 else ""
        solved = [f"then the MAP solve of the filled frames under the latent prior: objective "
                  f"{m['map_objective_start']:.4g} -> {m['map_objective']:.4g} in {m['map_iterations']} iterations"
                  f"{among}"] if "map_objective" in m else []
        settled_ = [f"then settled under the autoregressive prior, kept frames held: the synthesised frames moved "
                    f"{m['settle_change_cm']:.1f} cm on average, prior NLL per frame {m['settle_nll_start']:.1f} -> "
                    f"{m['settle_nll']:.1f}"] if "settle_change_cm" in m else []
        return [f"latent codes of {len(inv.starts)} windows {how}{fit}", *solved, *settled_]


def directions(prior: LatentPrior) -> dict[str, Direction]:
    """Stored directions, or the computed-attribute ones fitted now when none are stored."""
    found = directions_of(prior)
    if not found:
        found = fit_attribute_directions(prior)
        prior.metadata["attribute_directions"] = {k: d.to_dict() for k, d in found.items()}
    return found


def invert_input(prior: LatentPrior, motion: Motion, options: InversionOptions) -> tuple[Prepared, InversionResult]:
    prep = prepare(motion, prior)
    term = FidelityTerm(prior, prep.x, torch.ones(len(prep.x)), options.position_sigma)
    return prep, invert(prior, prep.x, terms=[term] if options.refine_iters or options.pso_iters else None,
                        options=options)


def generate_clip(prior: LatentPrior, codes: Tensor, inv: InversionResult, n_frames: int) -> Tensor:
    """The clip (n_frames, D) that W+ codes of ``inv``'s windows generate, blended over the overlaps."""
    return blend(prior.generate(codes), inv.starts, max(n_frames, inv.starts[-1] + prior.window))[:n_frames]


def played_at(prior: LatentPrior, x: Tensor, times: np.ndarray) -> Tensor:
    """Normalised features ``x (T, D)`` played at fractional frames ``times`` (increasing):
    every channel interpolated linearly in time (``timewarp.frames_at``), and the per-frame
    root steps and turns scaled by the local pace, so that the clip covers the same path
    and turns as before."""
    out = torch.from_numpy(frames_at(Codec.of(prior).raw(x.double()).numpy(), times))
    s = prior.spec.slices()
    pace = torch.from_numpy(np.gradient(times) if len(times) > 1 else np.ones(1))[:, None]
    for k in ("root_delta", "yaw_delta"):
        out[:, s[k]] *= pace
    return prior.normalizer.normalize(out).float()


def settled(result: LatentTaskResult, prior, held: np.ndarray | None = None) -> LatentTaskResult:
    """``result`` settled under the autoregressive ``prior`` (``problems.settle``): a MAP
    solve within centimetres of it that makes it likely, the frames where ``held`` is true
    kept as they are; its figures join the metrics."""
    s = Settle(result.motion, prior, held=held).solve()
    return replace(result, motion=s.motion, model_motion=s.model_motion, metrics={**result.metrics, **s.metrics})


def between(a: RootStart, b: RootStart, alpha: float) -> RootStart:
    """The start ``alpha`` of the way from ``a`` to ``b``: positions and floor linearly,
    the heading the short way round."""
    turn = float(wrap_angle(torch.tensor(b.yaw - a.yaw)))
    return RootStart(a.yaw + alpha * turn, a.x + alpha * (b.x - a.x), a.z + alpha * (b.z - a.z),
                     a.ground + alpha * (b.ground - a.ground))


def interpolate(prior: LatentPrior, a: Motion, b: Motion, steps: int, options: InversionOptions = InversionOptions(),
                settle_prior=None) -> list[LatentTaskResult]:
    """``steps`` motions whose codes go linearly from A's to B's; the first is G(I(A)), the
    last G(I(B)); step i starts at the blend of where and facing where A and B start
    (``between``), so that each end stands where its input does.

    Like poses meet: A and B are aligned in time on their joint rotations
    (``timewarp.align``), and step i plays both along that alignment (``blend_times``,
    ``played_at``: same path and turns, locally faster or slower) before their codes are
    blended, so a left step is never blended with a right one. Each step lasts the linear
    blend of the two lengths: clips of different lengths are handled so. On 4 held-out
    Bandai pairs blended frame by frame, the middle's NLL per frame under the
    autoregressive prior moved by 60-230 nats with a shift of B by 8-24 frames. Each step's
    slow root path is that of the inputs' blended features (``anchor_root``): the ends
    follow their inputs' paths.

    With ``settle_prior`` (an autoregressive prior) every step between the ends is then
    settled under it (``settled``): blended codes the generator never saw made held-out
    Bandai middles score 55 nats per frame against their inputs' -63 (a walk-to-run
    middle 114), which the settle solve brings to -158 within 3.6 cm, with 23 of their 24
    seconds within the held-out data's range (7 generated; bench/latent.py section 6).
    The ends stay the inputs' round trips."""
    if steps < 2:
        raise ValueError("--steps must be at least 2 (the two ends)")
    pa, pb = prepare(a, prior), prepare(b, prior)
    rotations = prior.spec.slices()["joint_rotations"]
    alignment = align(pa.x[:, rotations].double().numpy(), pb.x[:, rotations].double().numpy())
    out = []
    for i in range(steps):
        alpha = i / (steps - 1)
        n = int(round((1 - alpha) * len(pa.x) + alpha * len(pb.x)))
        at_a, at_b = blend_times(alignment, alpha, n)
        xa, xb = played_at(prior, pa.x, at_a), played_at(prior, pb.x, at_b)
        inv = [invert(prior, x, options=options) for x, weight in ((xa, 1 - alpha), (xb, alpha)) if weight > 0]
        codes = torch.lerp(inv[0].wplus, inv[-1].wplus, alpha) if len(inv) == 2 else inv[0].wplus
        with torch.no_grad():
            x = generate_clip(prior, codes, inv[0], n)
        frames = int(round((1 - alpha) * a.num_frames + alpha * b.num_frames * a.fps / b.fps))
        start = between(pa.start, pb.start, alpha)
        path = Codec.of(prior).motion(torch.lerp(xa, xb, alpha).double(), start, like=a)
        step = result_of(prior, x, start, a, inv[0], {"alpha": alpha, "frames_model": n},
                         n_frames=frames, anchor=(path, np.ones(n, bool)))
        out.append(settled(step, settle_prior) if settle_prior is not None and 0 < i < steps - 1 else step)
    return out


#: Gaussian smoothing (frames at the prior's rate) of a variation's change from the input:
#: its generated difference carries the generator's frame-to-frame jitter. On 4 held-out
#: Bandai clips (10 s, sigma 0.3) the variations' NLL per frame under the autoregressive
#: prior was -42 unsmoothed and -49 at 2 frames (4 frames: the same), the input's -63.
VARIATION_SMOOTH_FRAMES = 2.0


def vary(prior: LatentPrior, motion: Motion, count: int, sigma: float, seed: int = 0,
         options: InversionOptions = InversionOptions(), settle_prior=None) -> list[LatentTaskResult]:
    """``count`` variations: the motion's codes plus Gaussian offsets of ``sigma`` standard
    deviations along every principal direction of single codes (MoDi's crowds, sigma
    0.1-0.8), one offset per variation shared by all windows and codes.

    Each variation is the input plus what the offset changes in the generated motion,
    G(w + delta) - G(w), smoothed over ``VARIATION_SMOOTH_FRAMES``: the input's own detail,
    which the round trip G(I(x)) loses (1-3 cm of joint error), is kept, and sigma 0 gives
    the input back. Generated whole, held-out Bandai variations scored 26 nats per frame
    less likely than their input under the autoregressive prior (the round trip alone
    costs 8-46). With ``settle_prior`` (an autoregressive prior) each variation is then
    settled under it (``settled``): on the same clips from -49 (the input -63) to -134,
    3.5 cm from the variation on average, pairwise distance 5.8 -> 5.6 cm (bench/latent.py
    section 6)."""
    if count < 1:
        raise ValueError("--count must be at least 1")
    prep, inv = invert_input(prior, motion, options)
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        reproduced = generate_clip(prior, inv.wplus, inv, len(prep.x))
    out = []
    for i in range(count):
        eps = torch.randn(prior.config.w_dim, generator=g) * sigma
        delta = (eps * prior.w_scales) @ prior.w_components
        with torch.no_grad():
            change = generate_clip(prior, inv.wplus + delta, inv, len(prep.x)) - reproduced
            x = prep.x + gaussian_smooth(change[None], VARIATION_SMOOTH_FRAMES)[0]
        variation = result_of(prior, x, prep.start, motion, inv, {"variation": i, "sigma": sigma, "seed": seed},
                              n_frames=motion.num_frames)
        out.append(variation if settle_prior is None else settled(variation, settle_prior))
    return out
