"""What every editing task shares: preparing the input for a prior, the standard terms,
decoding the solution back onto the user's skeleton, and the result object."""
from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Sequence, TypeVar

import numpy as np
import torch

from motionopt import naturalness
from motionopt.codec import Codec
from motionopt.features import RootStart, contact_labels, estimate_ground, to_file_motion
from motionopt.info import MAX_HUMAN_SPEED  # noqa: F401 - the tasks' limit on a pace, with the engine's clip checks
from motionopt.motion import Motion
from motionopt.prior import ChannelClamp
from motionopt.objective import (ContactTerm, FloorTerm, MAPObjective, PoseFidelityTerm, SkatingTerm, SmoothnessTerm,
                                 SupportTerm, Term)
from motionopt.solver import MAPResult, Problem, SolverOptions, solve_from
from priors.checkpoint import check_compatible
from priors.train import ACCELERATION_KEY

log = logging.getLogger(__name__)

#: Largest user file (such as PATH.csv) read, checked before reading: far more than a real one needs.
MAX_FILE_BYTES = 50 * 2**20
#: Largest coordinate (metres) a user file may give: farther than 10 km is a unit mistake, not a motion.
MAX_COORDINATE = 1e4


def read_text(path: Path, what: str, limit: int = MAX_FILE_BYTES) -> str:
    """The text of a user file (``what`` it should hold, for messages): a regular file of at
    most ``limit`` bytes, checked before reading, in UTF-8 with or without a BOM. Errors
    are ``ValueError`` (``FileNotFoundError`` for a missing file) naming the file, and the
    line of a byte that is not UTF-8."""
    if not path.exists():
        raise FileNotFoundError(f"{path} does not exist")
    if not path.is_file():
        raise ValueError(f"{path} is not a file; expected {what}")
    try:
        size = path.stat().st_size
        if size <= limit:
            with path.open("rb") as f:
                data = f.read(limit + 1)  # bounded, should the file grow meanwhile
            size = max(size, len(data))
    except OSError as e:
        raise ValueError(f"{path} cannot be read ({e.strerror or e})") from None
    if size > limit:
        raise ValueError(f"{path} is {size / 2**20:.1f} MB; {what} of more than {limit / 2**20:g} MB is refused")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = data.count(b"\n", 0, e.start) + 1
        raise ValueError(f"{path}:{line}: byte 0x{data[e.start]:02x} is not UTF-8; save the file as UTF-8 "
                         "text") from None


def warned(texts: list[str]) -> list[str]:
    """``texts``, each logged as a warning (the command line prints them), for ``TaskResult.warnings``."""
    for text in texts:
        log.warning(text)
    return texts


@dataclass
class Prepared:
    """A user's motion as the prior sees it."""

    original: Motion
    model: Motion
    codec: Codec               # the prior's features, decoded onto the model skeleton
    raw: torch.Tensor          # (T, D) unnormalised features
    x: torch.Tensor            # (T, D) normalised features
    start: RootStart
    planted_height: np.ndarray  # (C,) height of each contact joint when planted (world y, metres)

    def to_file(self, model: Motion) -> Motion:
        """A model-skeleton result back on the user's skeleton, rate and units."""
        return to_file_motion(model, self.original)


def prepare(motion: Motion, prior) -> Prepared:
    """Check the skeleton against the prior, convert and encode."""
    check_compatible(prior.spec, motion.skeleton, kind=type(prior).__name__)
    model = Codec.of(prior).model_motion(motion)
    codec = Codec.of(prior, model.skeleton)
    raw, x, start = codec.encode(model)
    cidx = prior.spec.contact_indices()
    pos = model.positions()
    planted = np.percentile(pos[:, cidx, 1], 5.0, axis=0)
    return Prepared(motion, model, codec, raw, x, start, planted)


#: Sigma (m/s^2) of joint accelerations in the MAP objective of the tasks that run it by
#: default (denoising, in-betweening, completion). On held-out Bandai clips (denoising at
#: 3 cm noise) 10 gives 1.09 cm and a jerk 1.15 times the clean clips', 20 gives 1.10 cm
#: and 1.7 times (5 cm noise: 1.73 against 1.64 cm), 7 gives 1.15 cm; in-betweening
#: 5-frame gaps, L2P 0.071 m with it against 0.100 without.
ACCELERATION_SIGMA = 10.0
#: Floor and cap (m/s^2) of the per-joint acceleration sigmas of ``acceleration_sigmas``.
#: The cap keeps fast hands smooth: uncapped, CMU dance (hands at 21-32 m/s^2 RMS) came out
#: of denoising with 1.44 times the clean clips' jerk; capped at 14, 0.92-1.14 times.
ACCELERATION_FLOOR = 2.0
ACCELERATION_CAP = 14.0


#: Sigmas (root m, angle rad) of the fidelity to a kept frame where a synthesised gap meets it.
JOIN_SIGMA_ROOT = 0.01
JOIN_SIGMA_ANGLE = 0.02


#: Sigma (m/s) of the speed of a foot near the floor that is not planted, and the height
#: (m) above its planted height within which it counts as near (``SkatingTerm``). In path
#: following, 0.5 within 3 cm brought held-out walks' foot skating from 1.2-1.9 times the
#: mocap's per 5 s segment to 0.2-1.3 times (bench/paths.py; 0.2 within 1.5 cm: skating
#: over 1.2 times in 4 of 12 segments against 0).
SKATING_SIGMA = 0.5
SKATING_BAND = 0.03
#: Sigma (m) of the lowest foot's height above the floor (``SupportTerm``), for prefix
#: completion, whose root is free: with the skating term alone the body
#: rose so that no foot was near the floor to glide. Completing 5 s after the first second
#: of held-out Bandai clips (bench/tasks.py 4b), 5 mm kept 39 of 45 seconds in the data's
#: range, 1 cm 38, 2 cm 36, 5 cm 33. Path following needs it too (``PathFollow``): the path
#: holds the root's ground position, not its height.
SUPPORT_SIGMA = 0.005
#: Sigma (m) of a contact joint's depth below its planted height (``FloorTerm``).
FLOOR_SIGMA = 0.01
#: In-betweening's skating term: on held-out Bandai gaps of 5/15/30 frames (bench/tasks.py,
#: LAFAN1 protocol) feet skated 1.30/2.23/2.88 times the mocap's in the same gaps without
#: it (L2P 0.074/0.248/0.420 m), 0.67/0.68/1.09 with 0.2 within 1.5 cm (L2P
#: 0.080/0.227/0.425; CMU 0.61/0.71/0.81), 0.81/0.86/1.47 with 0.5 within 3 cm (L2P
#: 0.073/0.234/0.437). With the support term too, 0.2 within 2 cm gave Bandai
#: 0.56/0.56/1.14 at L2P 0.083/0.225/0.407 (37% below SLERP at 30 frames), but CMU dance
#: skated 1.55 times at 30 frames and its 5-frame L2P rose from 0.042 to 0.049 m: dancers
#: stand on their toes, off the planted height. So in-betweening holds a foot on the floor
#: only where the gap's start (its fill) has a planted one (``support_where`` "planted"):
#: Bandai 0.079/0.225/0.421 (34.7% below SLERP at 30 frames, against 34.0% without it),
#: skating 0.74/0.75/1.13; the CMU figures unchanged. Where the prior's contact head
#: expects one ("expected", as completion), 30-frame gaps reached 0.411 (36%) but skated
#: 1.60 times the mocap's (CMU 1.50).
INBETWEEN_SKATING_SIGMA = 0.2
INBETWEEN_SKATING_BAND = 0.015


#: Which frames ``SupportTerm`` holds (``TermSigmas.support_where``).
SUPPORT_WHERE = ("all", "planted", "expected")


@dataclass
class TermSigmas:
    """Sigmas of the standard terms, in user units."""

    contact_speed: float = 0.1      # m/s of a planted foot
    contact_height: float = 0.02    # m from the planted height
    #: m/s^2 of joint acceleration, one for all joints or one per model joint; None: no smoothness term
    smoothness: float | Sequence[float] | None = None
    #: m/s of a foot near the floor that is not planted (``SkatingTerm``); None: no skating term
    skating: float | None = None
    #: m above its planted height within which a foot counts as near the floor
    skating_band: float = SKATING_BAND
    #: m of the lowest foot above the floor (``SupportTerm``); None: no support term
    support: float | None = None
    #: the frames the support term holds (``SUPPORT_WHERE``): every one ("all"), those
    #: where the solve's start plants a foot ("planted") or those where the prior's contact
    #: head, run over the start, expects one ("expected", ``support_frames``)
    support_where: str = "all"
    #: the support term measures every contact joint from the floor, not from its own
    #: planted height (``SupportTerm.from_floor``)
    support_from_floor: bool = True
    #: m of a contact joint below its planted height (``FloorTerm``); None: no floor term
    floor: float | None = None

    def __post_init__(self) -> None:
        if self.support_where not in SUPPORT_WHERE:
            raise ValueError(f"support_where must be one of {', '.join(SUPPORT_WHERE)}; got {self.support_where!r}")


def gap_sigmas() -> TermSigmas:
    """The terms' sigmas of in-betweening's solve: accelerations, feet gliding in the gap,
    a foot on the floor where the fill plants one and none through it (held-out Bandai
    30-frame gaps: L2P 0.420 -> 0.418 m with the floor term, skating in the gaps 1.10 ->
    1.06 times mocap's; CMU 5-frame gaps 0.044 -> 0.043, 15 and 30 unchanged)."""
    return TermSigmas(smoothness=ACCELERATION_SIGMA, skating=INBETWEEN_SKATING_SIGMA, skating_band=INBETWEEN_SKATING_BAND,
                      support=SUPPORT_SIGMA, support_where="planted", floor=FLOOR_SIGMA)


def completion_sigmas() -> TermSigmas:
    """The terms' sigmas of prefix completion's solve: accelerations, feet gliding within
    ``SKATING_BAND``, the lowest foot on the floor (``SUPPORT_SIGMA``, each joint measured
    from its own planted height: ``SupportTerm.from_floor`` has the figures) and no foot
    through it (``FLOOR_SIGMA``)."""
    return TermSigmas(smoothness=ACCELERATION_SIGMA, skating=SKATING_SIGMA, support=SUPPORT_SIGMA,
                      support_where="expected", support_from_floor=False, floor=FLOOR_SIGMA)


def join_terms(root: np.ndarray, rotations: np.ndarray, join: np.ndarray, sigma_root: float = JOIN_SIGMA_ROOT,
               sigma_angle: float = JOIN_SIGMA_ANGLE) -> list[Term]:
    """Fidelity to the kept frames ``join`` (model frames where a synthesised gap meets a
    kept frame) of the target ``root`` and ``rotations``; none without such a frame."""
    if not join.any():
        return []
    return [PoseFidelityTerm(root, rotations, sigma_root, sigma_angle, mask=join, name="join")]


def acceleration_sigmas(prior, scale: float) -> float | list[float]:
    """Joint acceleration sigmas (m/s^2): ``scale`` times each joint's RMS acceleration
    over the prior's training clips (``priors.train.ACCELERATION_KEY`` in its metadata),
    within ``ACCELERATION_FLOOR`` and ``ACCELERATION_CAP``, or ``ACCELERATION_SIGMA`` for
    every joint of a checkpoint without them."""
    rms = prior.metadata.get(ACCELERATION_KEY)
    if rms is None:
        return ACCELERATION_SIGMA
    return [min(max(scale * float(r), ACCELERATION_FLOOR), ACCELERATION_CAP) for r in rms]


def support_frames(prior, start: torch.Tensor) -> np.ndarray:
    """(T,) the frames of features ``start (T, D)`` on which the prior's contact head
    expects some foot planted: where ``SupportTerm`` holds a foot on the floor. In a run
    it leaves the flight phases free; held to the floor there, completed runs slid their
    feet (held-out Bandai runs: 5 of their 10 completed seconds within the data's range,
    8 with this gate; gated instead by the start's own kinematics, where a floating
    rollout plants no foot, feet floated: 2)."""
    return contact_probabilities(prior, start).max(-1) > 0.5


def standard_terms(prep: Prepared, prior, sigmas: TermSigmas, start: torch.Tensor | None = None) -> list[Term]:
    """Contact (and optional smoothness, skating and support) terms every task adds to its
    own; ``start (T, D)``: the solve's start features, which ``sigmas.support_where``
    "expected" needs."""
    if sigmas.support and sigmas.support_where == "expected" and start is None:
        raise ValueError("a support term where the prior expects a planted foot needs the solve's start")
    cidx = prior.spec.contact_indices()
    terms: list[Term] = [ContactTerm(cidx, prep.planted_height, sigmas.contact_speed, sigmas.contact_height)]
    if sigmas.smoothness:
        terms.append(SmoothnessTerm(sigmas.smoothness))
    if sigmas.skating:
        terms.append(SkatingTerm(cidx, prep.planted_height, sigmas.skating, sigmas.skating_band,
                                 sigmas.skating_band / 6))
    if sigmas.support:
        mask = support_frames(prior, start) if sigmas.support_where == "expected" else None
        terms.append(SupportTerm(cidx, prep.planted_height, sigmas.support, mask=mask,
                                 planted_only=sigmas.support_where == "planted", from_floor=sigmas.support_from_floor))
    if sigmas.floor:
        terms.append(FloorTerm(cidx, prep.planted_height, sigmas.floor))
    return terms


#: A task result that ``judged`` fills in (``TaskResult``, ``problems.latent.LatentTaskResult``).
Judged = TypeVar("Judged")


@dataclass
class TaskResult:
    """An edited motion on the user's skeleton, with the solver's report and task metrics;
    ``warnings``: constraints the task could not meet (which, and by how much)."""

    motion: Motion
    model_motion: Motion
    solver: MAPResult | None
    metrics: dict = field(default_factory=dict)
    settings: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    #: Each second of ``model_motion`` measured (``naturalness.per_second``), the held-out
    #: data's range it is judged against (None: the prior carries none), and a warning for
    #: each measure that leaves it, naming the seconds.
    per_second: list[dict] = field(default_factory=list)
    human_range: naturalness.HumanRange | None = None
    naturalness_warnings: list[str] = field(default_factory=list)

    def naturalness_line(self) -> str:
        """How many seconds stay in the data's range, in one sentence."""
        return naturalness.summary_line(self.per_second, self.human_range)

    def report(self) -> dict:
        """JSON-ready: per-term values at start and end, metrics, timings, settings, the
        naturalness of each second against the data's range, and every warning of the run
        (the task's, the naturalness ones, then the solver's) under "warnings"."""
        r = {"metrics": self.metrics, "settings": self.settings,
             "frames": self.motion.num_frames, "fps": self.motion.fps,
             "per_second": self.per_second,
             "human_range": None if self.human_range is None else self.human_range.to_dict(),
             "warnings": self.warnings + self.naturalness_warnings +
                         (self.solver.warnings if self.solver is not None else [])}
        if self.solver is not None:
            s = self.solver
            r["solver"] = {"fun_start": s.fun_start, "fun": s.fun, "terms_start": s.terms_start, "terms": s.terms,
                           "nit": s.nit, "nfev": s.nfev, "success": s.success, "message": s.message,
                           "warnings": s.warnings, "timings": s.timings, "seam": s.seam,
                           "windows": len(s.windows)}
        return r


def judged(result: Judged, prior, ground: float, model: Motion | None = None) -> Judged:
    """``result`` (a ``TaskResult`` or ``problems.latent.LatentTaskResult``) with each second
    of ``model`` (its model motion by default; a motion on ``prior``'s joints and rate,
    floor at ``ground``) measured against the held-out data's range of human motion
    (``motionopt.naturalness``), and a warning (logged) for each measure that leaves it,
    naming the seconds."""
    seconds = naturalness.per_second(prior, result.model_motion if model is None else model, ground)
    known = naturalness.HumanRange.of_prior(prior)
    return replace(result, per_second=seconds, human_range=known,
                   naturalness_warnings=warned(naturalness.warnings_for(seconds, known)))


def judged_under(result: Judged, judge_prior, original: Motion) -> Judged:
    """``judged`` under ``judge_prior``, an autoregressive prior other than the one that
    made ``result`` (a latent prior's range of human motion is not measured): the output
    is put on its joints and rate, the floor is where it finds it in ``original`` (the input)."""
    codec = Codec.of(judge_prior)
    ground = estimate_ground(codec.model_motion(original).positions(), judge_prior.spec.contact_indices())
    return judged(result, judge_prior, ground, codec.model_motion(result.motion))


def run(prior, prep: Prepared, x0: torch.Tensor, free: np.ndarray, terms: list[Term], options: SolverOptions,
        prior_min_log_std: float | None = -2.5, other_starts: Sequence[torch.Tensor] = (),
        keep_human: bool = False) -> tuple[MAPResult, Motion]:
    """Solve and decode to a model-skeleton Motion (continuing the input's root).
    ``prior_min_log_std``: see ``MAPObjective`` (None: the prior as trained).
    ``other_starts``: more starting features like ``x0``; the lowest objective's result
    is kept (``solve_from``), with ``keep_human`` among those with the fewest seconds
    outside the range of human motion (``seconds_out_of_range``)."""
    objective = MAPObjective(prior, prep.model.skeleton, terms, prior_min_log_std=prior_min_log_std)
    faults = (lambda r: seconds_out_of_range(prior, prep, r.x)) if keep_human else None
    result = solve_from(objective, [Problem(x, free, prep.start) for x in (x0, *other_starts)], options, faults)
    # frame 0 keeps its zero deltas, so decoding from the input's start reproduces its root
    return result, prep.codec.motion(result.x.double(), prep.start, like=prep.original)


def seconds_out_of_range(prior, prep: Prepared, x: torch.Tensor) -> int:
    """How many seconds of the motion of features ``x`` leave the held-out data's range of
    human motion stored with ``prior`` in any measure (``naturalness.out_of_range``; 0 for
    a prior without a range)."""
    model = prep.codec.motion(x.double(), prep.start, like=prep.original)
    seconds = naturalness.per_second(prior, model, prep.start.ground)
    return len(naturalness.flagged_seconds(naturalness.out_of_range(seconds, naturalness.HumanRange.of_prior(prior))))


def model_frames_in(ranges: list[tuple[int, int]], original_fps: float, model_fps: float, n_model: int) -> np.ndarray:
    """Which prior-rate frames (n_model,) fall inside half-open ranges of original frames."""
    t = np.arange(n_model) / model_fps * original_fps  # position in original frame units
    inside = np.zeros(n_model, bool)
    for a, b in ranges:
        inside |= (t >= a - 1e-6) & (t <= b - 1 + 1e-6)
    return inside


def nearest_model_frame(frame: int, original_fps: float, model_fps: float) -> int:
    return int(round(frame / original_fps * model_fps))


def splice(synthesised: Motion, original: Motion, keep: np.ndarray) -> Motion:
    """``synthesised`` (on the original's skeleton and rate) with the frames where ``keep``
    is True taken exactly from ``original``."""
    n = synthesised.num_frames
    k = np.zeros(n, bool)
    k[:min(n, len(keep))] = keep[:n]
    rot = synthesised.rotations.copy()
    root = synthesised.root.copy()
    rot[k] = original.rotations[np.nonzero(k)[0]]
    root[k] = original.root[np.nonzero(k)[0]]
    tr = None
    if synthesised.translations is not None:
        tr = synthesised.translations.copy()
        tr[k] = original.local_translations()[np.nonzero(k)[0]]
    return synthesised.with_frames(rot, root, tr)


def clamped_rollout(prior, context: torch.Tensor, clamp_raw: torch.Tensor, channels: slice,
                    temperature: float, generator: torch.Generator | None = None) -> torch.Tensor:
    """Roll out ``len(clamp_raw)`` frames (..., N, D) after ``context (..., C, D)``
    (normalised; leading dims are independent rollouts), with the feature ``channels`` of
    every new frame set to ``clamp_raw (N, K)`` (unnormalised) before it becomes history:
    the prior synthesises the rest of each frame knowing the clamped channels of the
    frames before it (e.g. the pose for a given root path)."""
    norm = prior.normalizer
    clamp = (clamp_raw.float() - norm.mean[channels].float()) / norm.std[channels].float()
    return prior.sample(context.float(), len(clamp), generator=generator, temperature=temperature, plant=False,
                        steer=ChannelClamp(channels, clamp))


def contact_probabilities(prior, x: torch.Tensor) -> np.ndarray:
    """The prior's contact probability (T, C) for every frame of ``x (T, D)`` (frame 0
    takes frame 1's, having no history)."""
    with torch.no_grad():
        _, probs = prior.nll_and_contacts(x[1:].float(), x[:1].float())
    probs = probs.double().numpy()
    return np.concatenate((probs[:1], probs)) if len(probs) else np.zeros((len(x), prior.spec.num_contacts))


#: How far (m) ``plant_feet`` may lift a planted foot that the leg cannot reach
#: (``footik.clean_contacts``' ``max_rise``); beyond it the foot slides towards the hip.
PLANT_MAX_RISE = 0.02


def planted_contacts(probabilities: np.ndarray, positions: np.ndarray, cidx: list[int], planted_height: np.ndarray,
                     height: float, fps: float, slow: float) -> np.ndarray:
    """(T, C) contacts for the foot IK: the prior's contact ``probabilities`` where the
    joint is within ``height`` m of its planted height, and 1 where it is that near and
    moves slower than ``slow`` m/s (``contact_labels``). A foot the prior calls planted
    while it swings higher is left free: planted, the IK dragged it down or, out of
    reach, lifted the whole foot (path following's first second from a standing start,
    held-out Bandai walks)."""
    near_floor = positions[:, cidx, 1] - planted_height < height
    return np.maximum(probabilities * near_floor, contact_labels(positions, cidx, fps, 0.0, height, slow))


def plant_feet(model: Motion, prior, x: torch.Tensor, planted_height: np.ndarray,
               frames: slice | np.ndarray, slow: float = 1.0) -> Motion:
    """Foot-contact cleanup (``footik.clean_contacts``) on ``frames`` of a model motion,
    with the contacts the prior predicts for features ``x`` and where a foot is already
    near the ground moving slower than ``slow`` m/s; other frames (``frames``: a slice or a mask) stay as they are."""
    from motionopt.footik import clean_contacts

    contacts = planted_contacts(contact_probabilities(prior, x), model.positions(), prior.spec.contact_indices(),
                                planted_height, prior.spec.contact_height, model.fps, slow)
    keep = np.ones(model.num_frames, bool)
    keep[frames] = False
    contacts[keep] = 0.0
    cleaned = clean_contacts(model, list(prior.spec.contact_joints), contacts, planted_height, blend_frames=6,
                             max_rise=PLANT_MAX_RISE)
    rot = np.where(keep[:, None, None], model.rotations, cleaned.rotations)
    return model.with_frames(rot, model.root.copy(), model.translations)


def root_features(points: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Unnormalised root displacement and yaw-change features (K, 3) of frames whose root
    ground positions are ``points[1:]`` (x, z) and headings ``yaw[1:]`` (radians), after a
    frame at ``points[0]`` facing ``yaw[0]`` (the inverse of ``features.decode``'s root)."""
    d = np.diff(points, axis=0)
    c, s = np.cos(yaw[:-1]), np.sin(yaw[:-1])
    local = np.stack((c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1]), axis=-1)
    return np.concatenate((local, np.diff(yaw)[:, None]), axis=-1)
