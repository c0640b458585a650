"""The editing task commands: path-follow, denoise, inbetween, complete, edit.

Each command is one entry of ``TASKS``: its help, its own arguments, and how the parsed
arguments become a task object of ``problems/`` (with ``--method latent``, the latent
prior's ``LatentTask``, or for denoising ``Denoise`` over ``priors.latent_density``).
Every command then runs the same steps, which the batch shares:
``start`` checks all inputs and outputs before solving, so that a mistake costs no time
and writes nothing, and builds the task; ``solve`` runs it with a progress bar over the
solver's windows; ``write_result`` writes the BVH with ``bvh.save`` (atomic), the optional
picture (``--plot``), interactive page (``--view``) and JSON report (``--report``); the
command prints the task's own summary (``task.summary(result)``).

Adding a task: its module in ``problems/`` (a class with ``options``, ``solve()`` and
``summary(result)``) and one entry in ``TASKS``.
"""
from __future__ import annotations

import argparse
import json
import logging
import shlex
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any, Callable, Protocol

from motionopt.atomic import write_text_atomic

from . import UserError, add_common

if TYPE_CHECKING:
    import numpy as np

    from motionopt.motion import Motion
    from motionopt.solver import InversionOptions, SolverOptions

log = logging.getLogger(__name__)

METHODS = ("ar", "latent")
#: Positional arguments of each command, first on the reproducing command line.
POSITIONAL = ("input",)


class Task(Protocol):
    """What the commands need of a task object: solver settings to adjust, its prior, a
    solve, and sentences about its result."""

    options: Any
    prior: Any

    def solve(self) -> Any: ...

    def summary(self, result: Any) -> list[str]: ...


#: One ``add_argument`` call as data: the flags and the keywords.
Arg = tuple[tuple[str, ...], dict]


def arg(*flags: str, **options: Any) -> Arg:
    """An argument of a task entry: what ``add_argument`` takes."""
    return flags, options


def _number(kind: type, ok: Callable[[float], bool], what: str) -> Callable[[str], float | int]:
    """An argparse type: a number of ``kind`` for which ``ok`` holds, refused as not ``what``."""
    def parse(text: str):
        value = kind(text)
        if not ok(value):
            raise argparse.ArgumentTypeError(f"must be {what}, got {text}")
        return value
    parse.__name__ = kind.__name__  # argparse names the type in its messages
    return parse


def positive(kind: type) -> Callable[[str], float | int]:
    """A number of ``kind`` above 0."""
    return _number(kind, lambda v: v > 0, "positive")


def non_negative(kind: type) -> Callable[[str], float | int]:
    """A number of ``kind`` of 0 or more (--iterations 0: the latent inversion's encoder
    alone; --sigma 0: a variation that is the input)."""
    return _number(kind, lambda v: v >= 0, "0 or more")


def _problems() -> ModuleType:
    """The ``problems`` package with its task modules, imported when a task runs rather than
    when the parser is built: they load the solver stack, which ``--help`` does not need."""
    import problems.denoise
    import problems.edit
    import problems.inbetween
    import problems.latent
    import problems.path_follow
    import problems.ranges

    return problems


# ---- pictures (--plot) -----------------------------------------------------------------------------

def filmstrip(rows: dict[str, Motion], out: Path) -> None:
    """A filmstrip of labelled motions, the inputs above the output (last), as the demo
    draws them: six moments spread over the longest."""
    import numpy as np

    from motionopt import plot

    n = max(rows.values(), key=lambda m: m.duration).num_frames
    frames = np.unique(np.linspace(0, n - 1, min(6, n)).round().astype(int)).tolist()
    *above, below = rows
    above = ", ".join(above)
    plot.plot_filmstrip(rows, out, frames=frames, force=True, title=f"{above[:1].upper()}{above[1:]} (top) and {below}")


def _filmstrip(task: Task, motion: Motion, result, out: Path) -> None:
    """A filmstrip of input over output."""
    filmstrip({"input": motion, "output": result.motion}, out)


def _path_picture(task: Task, seed: Motion, result, out: Path) -> None:
    """From above: the target path, the root, the feet (planted frames marked) and a few
    poses of the new frames; beside it the hip and lowest foot heights over time."""
    from motionopt import plot

    plot.plot_path_follow(result.motion, out, task.path, new_from=min(seed.num_frames, result.motion.num_frames) - 1,
                          title="Path following: the seed continued along the target path", force=True)


def _frames_around(first: int, last: int, n_frames: int, count: int = 6) -> list[int]:
    """``count`` frame numbers from the frame before ``first`` to the frame after ``last``
    (inside 0..n_frames-1): the frames a task changed, with one unchanged on each side."""
    import numpy as np

    a, b = max(0, first - 1), min(n_frames - 1, last + 1)
    return np.unique(np.linspace(a, b, min(count, b - a + 1)).round().astype(int)).tolist()


def _gap_filmstrip(task: Task, motion: Motion, result, out: Path) -> None:
    """Input over output at the frames of the longest gap between kept ranges (and the
    kept frame on each side of it), where the output is synthesised."""
    from motionopt import plot

    n = max(motion.num_frames, result.motion.num_frames)
    keep, _ = task.output_ranges()      # --after keep: the frames after the last range are not synthesised
    gaps = [(stop, start) for (_, stop), (start, _) in zip(keep, keep[1:])]
    if result.motion.num_frames > keep[-1][1]:
        gaps.append((keep[-1][1], result.motion.num_frames))
    if not gaps:
        return filmstrip({"input": motion, "output": result.motion}, out)
    a, b = max(gaps, key=lambda g: g[1] - g[0])
    rows = {"input (frames replaced)": motion, "output": result.motion}
    plot.plot_filmstrip(rows, out, frames=_frames_around(a, b - 1, n), force=True,
                        title=f"In-betweening: frames {a}-{b - 1} synthesised; input (top) and output")


def _edit_filmstrip(task: Task, motion: Motion, result, out: Path) -> None:
    """Input over output at the edited frames (the targets' frames, and one on each side)."""
    from motionopt import plot

    first = min(t.frames[0] for t in task.targets)
    last = max(t.frames[1] for t in task.targets)
    joints = ", ".join(sorted({t.joint for t in task.targets}))
    plot.plot_filmstrip({"input": motion, "output": result.motion}, out,
                        frames=_frames_around(first, last, min(motion.num_frames, result.motion.num_frames)),
                        force=True, title=f"Spatial edit of {joints} at frames {first}-{last}: input (top) and output")


def _foot_trajectory(task: Task, motion: Motion, result, out: Path) -> None:
    """A foot's trajectory before and after."""
    from motionopt import plot

    plot.plot_joint_trajectories({"input": motion, "denoised": result.motion}, task.prior.spec.contact_joints[0],
                                 out, force=True)


# ---- pages (--view) ------------------------------------------------------------------------------

def _no_marks(task: Task, motion: Motion) -> dict:
    """No target to draw on the page."""
    return {}


def _target_points(task: Task, motion: Motion) -> dict:
    """The spatial edit's targets as points on the page: each target's position at each
    of its frames (an offset target moves from where the input's joint is)."""
    import numpy as np

    pos = motion.positions()
    points = [np.asarray(t.position) if t.position is not None else pos[f, motion.skeleton.index(t.joint)] + t.offset
              for t in task.targets for f in range(t.frames[0], t.frames[1] + 1)]
    return {"points": np.unique(np.array(points), axis=0)}


def nll_curve(prior, motion: Motion, label: str):
    """The autoregressive prior's NLL of each frame of ``motion`` after its first, on the
    prior's joints and frame rate (``Codec``), as a page curve."""
    import numpy as np
    import torch

    from motionopt.codec import Codec
    from motionopt.view import Curve

    codec = Codec.of(prior)
    x = codec.features(codec.model_motion(motion))
    with torch.no_grad():
        nll = prior.nll(x[1:], x[:1]).numpy()
    return Curve("prior NLL per frame", label, np.arange(1, len(x)) / prior.spec.fps, nll)


def write_view_page(run: TaskRun, result, out: Path) -> None:
    """The --view page: input and output overlaid, the task's targets (``TaskEntry.marks``),
    and per-frame curves of hip height, foot skating, the distance to a target path and,
    with an autoregressive prior, the prior's NLL of each."""
    from motionopt.prior import MotionPrior
    from motionopt.view import write_view

    clips = {"input": run.motion, "output": result.motion}
    prior = run.task.prior
    curves = [nll_curve(prior, m, label) for label, m in clips.items()] if isinstance(prior, MotionPrior) else []
    write_view(out, clips, overlay=True, curves=curves, title=f"{run.args.command}: {run.args.input} -> {run.outs.bvh}",
               force=True, **run.entry.marks(run.task, run.motion))


# ---- the task entries ------------------------------------------------------------------------------

@dataclass(frozen=True)
class TaskEntry:
    """One task command: its help, its own ``arguments`` (the input first), and how the
    parsed arguments become its task object.

    ``build(args, inputs, motion, prior)`` makes the task object for the autoregressive
    prior, ``latent`` (same arguments) for ``--method latent``; ``latent_refused``: the
    command offers ``--method`` only to say why latent is not available; neither: no
    ``--method``. ``read(args, motion)`` checks the command's own inputs and reads its
    files once the input is loaded, before the prior is; what it returns is ``inputs``.
    ``draw(task, motion, result, path)`` draws the ``--plot`` picture; ``marks(task, motion)``
    gives what the ``--view`` page draws of the task (``path`` or ``points`` of
    ``motionopt.view.write_view``). ``new_frames``: the task synthesises frames (where the
    particle swarm works)."""

    help: str
    description: str
    arguments: tuple[Arg, ...]
    build: Callable[[argparse.Namespace, Any, Motion, Any], Task]
    latent: Callable[[argparse.Namespace, Any, Motion, Any], Task] | None = None
    latent_refused: str | None = None
    read: Callable[[argparse.Namespace, Motion], Any] = lambda args, motion: None
    draw: Callable[[Task, Motion, Any, Path], None] = _filmstrip
    marks: Callable[[Task, Motion], dict] = _no_marks
    new_frames: bool = True

    @property
    def offers_method(self) -> bool:
        """Whether the command has --method."""
        return self.latent is not None or self.latent_refused is not None


def _read_path(args: argparse.Namespace, seed: Motion) -> tuple[np.ndarray, np.ndarray | None]:
    """PATH.csv's points and times, refusing --speed where the file gives the timing."""
    points, times = _problems().path_follow.read_path_csv(args.path, args.path_unit)
    if times is not None and args.speed is not None:
        raise UserError(f"{args.path} sets the timing with its t column; drop --speed")
    return points, times


def _kept_ranges(args: argparse.Namespace, motion: Motion) -> list[tuple[int, int]]:
    """--keep's ranges, checked against the input's frames."""
    ranges = _problems().ranges
    return ranges.check_ranges(ranges.parse_ranges(args.keep), motion.num_frames)


def _latent_density(prior):
    """The latent prior as the MAP solver's prior term (``priors.latent_density``)."""
    from priors.latent_density import LatentDensity

    return LatentDensity(prior)


def _latent_inbetween(args: argparse.Namespace, keep: list[tuple[int, int]], motion: Motion, prior):
    """In-betweening with the latent prior, --after applied as the autoregressive task applies it."""
    _refuse_latent_seed(args)
    problems = _problems()
    ranges, length = problems.ranges.after_last_range(keep, motion.num_frames, args.after)
    return _latent_refined(args, problems.latent.LatentTask(motion[:length], prior, ranges,
                                                            problems.latent.gap_inversion_options(),
                                                            judge_prior=judging_prior(motion)))


def _refuse_latent_seed(args: argparse.Namespace) -> None:
    """--latent-seed belongs to the autoregressive solve, not to --method latent."""
    if args.latent_seed is not None:
        raise UserError("--latent-seed seeds the autoregressive solve: drop --latent-seed, or drop --method latent")


def _latent_refined(args: argparse.Namespace, task):
    """``task`` (a ``LatentTask``) without its MAP solve of the filled frames under --no-refine."""
    if args.refine is False:
        task.map_options = None
    return task


CLEAN_FEET = arg("--clean-feet", action=argparse.BooleanOptionalAction, default=None,
                 help="plant the feet the prior finds in contact by leg IK: less sliding in synthesised frames, not "
                 "none, for joints moved by up to tens of centimetres; on denoised capture it can add sliding (the "
                 "README gives figures; not with --method latent). On by default for complete, off otherwise")

LATENT_SEED = arg("--latent-seed", metavar="CKPT", default=None,
                  help="a latent prior (a file or a shipped checkpoint's name) whose masked encoder also seeds the "
                  "solve (in-betweening: of gaps of at least 0.3 s; completion: its continuation, settled under the "
                  "autoregressive prior): the solve starts from its fills and from the rollouts and keeps the lowest "
                  "objective of the results with the fewest seconds outside the range of human motion (held-out "
                  "clips: 18-32%% lower position error in 30-frame gaps, 6 times slower; the README gives figures). "
                  "Default: the shipped latent prior of the skeleton, if any; 'none': the rollouts alone")


def _latent_seed(args: argparse.Namespace, motion: Motion):
    """The latent prior whose fills seed in-betweening's or completion's solve (--latent-seed), or None."""
    from priors.checkpoint import CheckpointError, load_prior_of_kind

    if args.latent_seed == "none" or args.refine is False:
        return None
    try:
        prior, path = load_prior_of_kind(motion.skeleton, args.latent_seed, "LatentPrior",
                                         f"{args.command} --latent-seed")
    except CheckpointError:
        if args.latent_seed is not None:
            raise
        return None
    _say(args, f"latent seeds: {path}")
    return prior


def settle_args(what: str) -> tuple[Arg, Arg]:
    """--settle-prior and --no-settle: the autoregressive prior that settles ``what``."""
    return (arg("--settle-prior", default=None, metavar="CKPT",
                help=f"autoregressive prior that settles {what} (a MAP solve within a few centimetres that makes it "
                "natural; default: the shipped one for the skeleton)"),
            arg("--no-settle", action="store_true", help="write the generated motions as they are"))


def settle_prior(args: argparse.Namespace, motion: Motion):
    """The autoregressive prior that settles the outputs, or None with --no-settle."""
    from priors.checkpoint import load_prior_of_kind

    if args.no_settle:
        if args.settle_prior:
            raise UserError("--no-settle writes the generated motions as they are; drop --settle-prior or --no-settle")
        return None
    return load_prior_of_kind(motion.skeleton, args.settle_prior, "CCNetPrior", f"{args.command} --settle-prior",
                              "or pass --no-settle")[0]


def judging_prior(motion: Motion):
    """The shipped autoregressive prior of ``motion``'s skeleton, whose held-out range
    judges each second of a --method latent output; None when none models the skeleton."""
    from priors.checkpoint import CheckpointError, load_prior_of_kind

    try:
        return load_prior_of_kind(motion.skeleton, None, "CCNetPrior", "judging the output")[0]
    except CheckpointError:
        return None


def _latent_completion(args: argparse.Namespace, motion: Motion, prior):
    """``complete --method latent``: settled under the autoregressive prior (--settle-prior,
    --no-settle), and judged under it or, unsettled, under the skeleton's shipped one."""
    _refuse_latent_seed(args)
    settler = settle_prior(args, motion)
    return _latent_refined(args, _problems().latent.LatentTask.completion(
        motion, args.prefix, args.frames, prior, settle_prior=settler,
        judge_prior=settler if settler is not None else judging_prior(motion)))


def _autoregressive_completion(args: argparse.Namespace, motion: Motion, prior):
    """``complete`` under the autoregressive prior, which --settle-prior and --no-settle do not concern."""
    if args.settle_prior or args.no_settle:
        raise UserError("--settle-prior and --no-settle settle --method latent's completion; drop them or add "
                        "--method latent")
    return _problems().inbetween.complete(motion, args.prefix, args.frames, prior, refine=args.refine is not False,
                                          clean_feet=args.clean_feet is not False, latent=_latent_seed(args, motion))


#: The task commands by name, in the order ``motionopt --help`` lists them.
TASKS: dict[str, TaskEntry] = {
    "path-follow": TaskEntry(
        help="continue a motion so that its root walks along a path on the ground",
        description="Continue SEED.bvh along the ground path in PATH.csv (a header line 'x,z', optionally 't' in "
        "seconds after the seed's end, then one point per line; metres, or --path-unit, in the seed file's world "
        "coordinates). A pace faster than a person runs is refused before any synthesis. The prior rolls out "
        "a walk with its root on the path, then the MAP solver solves the new frames, root included, under the "
        "prior, the path (5 mm sigma), planted feet and feet gliding near the floor (--no-refine: the rollout "
        "alone). OUT.bvh holds the seed's frames followed by the new motion. --plot draws the root's path against the "
        "target path.",
        arguments=(
            arg("input", metavar="SEED.bvh", help="motion whose end the new motion continues"),
            arg("--path", required=True, metavar="PATH.csv", help="ground points to follow (x,z[,t])"),
            arg("--path-unit", choices=("m", "cm", "mm", "in"), default="m",
                help="length unit of PATH.csv's x and z (default m)"),
            arg("--seconds", type=positive(float), default=None, metavar="S",
                help="seconds of new motion (default: enough to reach the path's end)"),
            arg("--speed", type=positive(float), default=None, metavar="M_PER_S",
                help="walking speed along the path (default: the seed's recent speed, at least 1 m/s); not with a "
                "t column")),
        read=_read_path,
        build=lambda a, path, seed, prior: _problems().path_follow.PathFollow(
            seed, path[0], prior, times=path[1], speed=a.speed, seconds=a.seconds, refine=a.refine is not False,
            path_name=a.path),
        draw=_path_picture, marks=lambda task, motion: {"path": task.path}),
    "denoise": TaskEntry(
        help="clean captured motion: remove jitter, foot sliding and ground penetration",
        description="Estimate the capture noise in the clip, smooth each joint with the Butterworth or "
        "Savitzky-Golay filter of least estimated risk for it, then run the MAP solve from there: fidelity to the "
        "input's root and joint angles, the prior, contact terms and joint accelerations (--no-refine: the filter "
        "alone). Before that, glitches (one joint thrown off by tens of degrees for a fraction of a second, entering "
        "and leaving with the same turn) are found at the file's rate and turned back, and swirls (one joint thrown "
        "for a fraction of a second into poses it takes nowhere else in the clip, turning faster than 1200 degrees a "
        "second and than four times its usual fastest) are filled in from the frames around them; the summary names "
        "both. "
        "--clean-feet then plants the feet by leg IK. --plot draws a foot's trajectory before and after.",
        arguments=(arg("input", metavar="INPUT.bvh", help="motion to clean"), CLEAN_FEET,
                   arg("--keep-glitches", action="store_true",
                       help="do not look for glitches or swirls: bursts in which one joint is turned by an offset of 25 "
                       "degrees or more for 0.1-0.5 s, or swirls off its own poses, are then smoothed like the rest (a "
                       "filter smears them); use it for motion that really jumps tens of degrees a frame, like a "
                       "furious wave captured at 30 fps")),
        build=lambda a, _, motion, prior: _problems().denoise.Denoise(motion, prior, refine=a.refine is not False,
                                                                      clean_feet=bool(a.clean_feet),
                                                                      repair_glitches=not a.keep_glitches),
        latent=lambda a, _, motion, prior: _problems().denoise.Denoise(motion, _latent_density(prior),
                                                                       refine=a.refine is not False,
                                                                       repair_glitches=not a.keep_glitches,
                                                                       judge_prior=judging_prior(motion)),
        draw=_foot_trajectory, new_frames=False),
    "inbetween": TaskEntry(
        help="fill the frames between kept frame ranges",
        description="Keep the frames inside --keep exactly and synthesise the frames between them so that each "
        "gap meets the next kept frames without a jump, then solve them with the MAP solver (--no-refine: the "
        "steered rollout alone); the frames after the last kept range are kept as given unless --after says "
        "otherwise. --plot draws input over output at the frames of the longest "
        "gap.",
        arguments=(
            arg("input", metavar="INPUT.bvh", help="motion whose kept frames are used"),
            arg("--keep", required=True, metavar="RANGES",
                help="half-open frame ranges to keep, like Python slices, e.g. 0:30,60:90 (frames 0-29 and 60-89 of "
                "INPUT.bvh) or 0:30,60: (60 to the end); the first range must start at 0"),
            arg("--after", choices=("keep", "drop", "synthesise"), default="keep",
                help="the input's frames after the last kept range: keep them as given (default), drop them (the "
                "output ends with the last kept frame), or synthesise them (the prior continues freely)"),
            CLEAN_FEET, LATENT_SEED),
        read=_kept_ranges,
        build=lambda a, keep, motion, prior: _problems().inbetween.Inbetween(
            motion, keep, prior, refine=a.refine is not False, clean_feet=bool(a.clean_feet), after=a.after,
            latent=_latent_seed(a, motion)),
        draw=_gap_filmstrip,
        latent=lambda a, keep, motion, prior: _latent_inbetween(a, keep, motion, prior)),
    "complete": TaskEntry(
        help="continue the first frames of a motion (prefix completion)",
        description="Keep the first --prefix frames of INPUT.bvh and synthesise new motion after them, up to "
        "--frames frames in all (both in INPUT.bvh's frame rate): three rollouts of the prior and the latent prior's "
        "continuation (--latent-seed), each then solved with the MAP solver, the lowest objective of those that stay "
        "in the range of human motion kept (--no-refine: the first rollout alone). With --method latent: "
        "the masked encoder's continuation, solved under the latent prior, then settled under the autoregressive "
        "prior with the prefix held (--no-settle: not settled). --plot draws a filmstrip of output and input.",
        arguments=(
            arg("input", metavar="INPUT.bvh", help="motion whose first frames are kept"),
            arg("--prefix", required=True, type=positive(int), metavar="N", help="frames to keep"),
            arg("--frames", required=True, type=positive(int), metavar="N",
                help="frames of the output, prefix included"),
            CLEAN_FEET, LATENT_SEED,
            *settle_args("the frames --method latent makes after the prefix (the prefix is held)")),
        build=lambda a, _, motion, prior: _autoregressive_completion(a, motion, prior),
        latent=lambda a, _, motion, prior: _latent_completion(a, motion, prior)),
    "edit": TaskEntry(
        help="move chosen joints to targets at chosen frames (spatial edit)",
        description="Meet the joint targets in TARGETS.json, a list of {\"joint\": NAME, \"frame\": I or [I, J], "
        "\"position\": [x, y, z] (metres, world) or \"offset\": [dx, dy, dz]}, while the rest of the motion stays "
        "close to the input and natural. --plot draws input over output at the edited frames. (--method latent is not "
        "available for spatial edits yet.)",
        arguments=(arg("input", metavar="INPUT.bvh", help="motion to edit"),
                   arg("--targets", required=True, metavar="TARGETS.json", help="joint targets")),
        read=lambda a, motion: _problems().edit.load_targets(a.targets),
        build=lambda a, targets, motion, prior: _problems().edit.SpatialEdit(motion, targets, prior,
                                                                             refine=bool(a.refine)),
        latent_refused="spatial edits with the latent prior are not available (problems/latent.py has no spatial "
        "edit); use --method ar, the default",
        draw=_edit_filmstrip, marks=_target_points, new_frames=False),
}


def register(sub) -> None:
    for name, entry in TASKS.items():
        p = sub.add_parser(name, help=entry.help, description=entry.description)
        for flags, options in entry.arguments:
            p.add_argument(*flags, **options)
        _add_task_options(p, method=entry.offers_method, new_frames=entry.new_frames)
        p.set_defaults(func=cmd_task)


def _add_task_options(p: argparse.ArgumentParser, method: bool, new_frames: bool) -> None:
    """Options every task command shares; ``method``: it offers --method; ``new_frames``:
    it synthesises frames (where the particle swarm works)."""
    from motionopt.solver import OPTIMIZERS, PSOOptions, SolverOptions

    add_io_options(p, "BVH file to write, with the input's skeleton, channels, unit and frame rate",
                   report="write the solver's per-term values, the task's metrics, timings and the command")
    s = p.add_argument_group("prior and solver")
    if method:
        s.add_argument("--method", choices=METHODS, default="ar",
                       help="ar: MAP optimisation under the autoregressive prior (default); latent: the latent "
                       "(W+) prior (denoise: the same MAP solve with the latent prior as its prior term; inbetween "
                       "and complete: inversion of the latent prior)")
    add_prior_options(s)
    s.add_argument("--refine", action=argparse.BooleanOptionalAction, default=None,
                   help="run the MAP solver (prior, task and contact terms; windows of 34 frames, L-BFGS) on the "
                   "task's result: on by default for denoise, path-follow, inbetween and complete (--no-refine: the "
                   "filter or the rollout alone; with --method latent, the inversion alone), off by default for "
                   "edit, where with the shipped priors it does not improve the benchmark figures "
                   "(bench/results/tasks.txt)")
    s.add_argument("--iterations", type=non_negative(int), default=None, metavar="N",
                   help=f"local optimiser iterations per window (default {SolverOptions.max_iter})" + (
                       "; with --method latent, refinement iterations of the latent code (default 0: the "
                       "encoder alone; inbetween 200)" if method else ""))
    s.add_argument("--optimizer", default=None, metavar="NAME",
                   help=f"local optimiser: {', '.join(OPTIMIZERS)} (default {SolverOptions.optimizer}); scipy is "
                   "L-BFGS-B, nlopt LD_LBFGS, torch torch.optim.LBFGS, adam a first-order baseline")
    swarm = ("it steers the synthesised frames of --refine; off by default, --pso-particles turns it on"
             if new_frames else "it steers synthesised frames only, so with --method ar it changes nothing here")
    s.add_argument("--no-pso", action="store_true", help=f"no particle swarm before the local optimiser ({swarm})")
    s.add_argument("--pso-particles", type=positive(int), default=None, metavar="N",
                   help=f"particles of the swarm (default {PSOOptions.particles})")
    s.add_argument("--pso-iterations", type=positive(int), default=None, metavar="N",
                   help=f"particle swarm iterations (default {PSOOptions.iterations})" + (
                       "; with --method latent, swarm iterations over the latent code (default 0)"
                       if method else ""))


def add_io_options(p: argparse.ArgumentParser, out: str, report: str, out_dir: bool = False,
                   out_required: bool = True) -> argparse._ArgumentGroup:
    """The input and output options of every task command, the latent ones too: --out
    (``out``: what it holds; --out-dir for a command that writes several motions), --report
    (``report``: what it holds), --plot, --force, --fps, --unit and --max-frames; returns
    their group, for a command's own."""
    io = p.add_argument_group("input and output")
    if out_dir:
        io.add_argument("--out-dir", required=True, metavar="DIR", help=out)
    else:
        io.add_argument("--out", required=out_required, metavar="OUT.bvh", help=out)
    io.add_argument("--report", default=None, metavar="REPORT.json", help=report)
    io.add_argument("--plot", action="store_true",
                    help="also draw a picture next to each BVH file written (OUT.png next to OUT.bvh): a filmstrip "
                    "of input over output, or the task's own picture")
    io.add_argument("--view", default=None, metavar="VIEW.html",
                    help="also write an interactive 3-D page of input and output, with the task's targets and "
                    "per-frame curves of its measures (open it in a web browser; it works offline)")
    io.add_argument("--force", action="store_true", help="overwrite the outputs if they exist")
    io.add_argument("--fps", type=positive(float), default=None,
                    help="override the input file's frame rate (its header's Frame Time)")
    io.add_argument("--unit", choices=("auto", "cm", "m", "mm", "in"), default="auto",
                    help="length unit of the input file (default: guessed from the skeleton's size)")
    io.add_argument("--max-frames", type=positive(int), default=100_000, metavar="N",
                    help="refuse an input that declares more frames than this, before reading them (default "
                    "100000: 14 minutes at 120 fps)")
    add_common(p)
    return io


def add_prior_options(group: argparse._ArgumentGroup) -> None:
    """--prior, --seed and --threads, which every task command takes."""
    group.add_argument("--prior", default=None, metavar="CKPT",
                       help="prior checkpoint: a file, or a shipped checkpoint's name (`motionopt prior-info --list`); "
                       "default: the shipped one matching the input's skeleton")
    group.add_argument("--seed", type=int, default=0, help="seed of every random choice (default 0)")
    group.add_argument("--threads", type=positive(int), default=1, metavar="N",
                       help="CPU threads for torch (default 1: the priors' small convolutions run fastest on one, and "
                       "on a busy machine two ran a path-follow 8 to 35 times slower)")


def use_threads(args: argparse.Namespace) -> None:
    """Run torch on --threads threads."""
    import torch

    torch.set_num_threads(args.threads)


# ---- the steps every task command takes (and the batch with it) -----------------------------------

@dataclass
class Outputs:
    """Where a command writes: the BVH, and the optional report, picture and page."""

    bvh: Path
    report: Path | None
    picture: Path | None
    view: Path | None


@dataclass
class TaskRun:
    """A task command ready to solve: its arguments and entry, where it writes, the input,
    the prior's path, the task object, and when the command started."""

    args: argparse.Namespace
    entry: TaskEntry
    outs: Outputs
    motion: Motion
    prior_path: Path
    task: Task
    started: float


def start(args: argparse.Namespace, progress: Callable[[dict], object] | None = None) -> TaskRun:
    """The task of parsed command-line ``args``, every input and output checked first: the
    outputs, the options that do not go together, the input, the command's own inputs
    (``TaskEntry.read``), the prior (autoregressive, or latent with --method latent); then
    the task object, its solver settings the task's own with the command line's knobs
    applied (``progress``: the solver's callback)."""
    started = time.perf_counter()
    entry = TASKS[args.command]
    outs = check_outputs(args)
    use_threads(args)
    latent = _method(args) == "latent"
    if latent and entry.latent_refused:
        raise UserError(entry.latent_refused)
    if latent and getattr(args, "clean_feet", False):
        raise UserError("--clean-feet works with --method ar only")
    motion = load_input(args)
    inputs = entry.read(args, motion)
    prior, prior_path = load_prior(motion, args, "LatentPrior" if latent else "CCNetPrior")
    if latent:
        from motionopt.solver import InversionOptions

        task = entry.latent(args, inputs, motion, prior)
        task.options = (latent_options(args, task.options) if isinstance(task.options, InversionOptions)
                        else solver_options(args, task.options, progress))
    else:
        task = entry.build(args, inputs, motion, prior)
        task.options = solver_options(args, task.options, progress)
    return TaskRun(args, entry, outs, motion, prior_path, task, started)


def _method(args: argparse.Namespace) -> str:
    """--method, for a command that offers it; else ar."""
    return getattr(args, "method", "ar")


def view_output(args: argparse.Namespace) -> Path | None:
    """The --view page's path, checked to be an .html file (None without --view)."""
    view = Path(args.view) if args.view else None
    if view is not None and view.suffix.lower() != ".html":
        raise UserError(f"--view {view}: the page must be an .html file")
    return view


def check_outputs(args: argparse.Namespace) -> Outputs:
    """Every output path, checked before any work: suffix, folder, not the input, new or --force."""
    out = Path(args.out)
    if out.suffix.lower() != ".bvh":
        raise UserError(f"--out {out}: the output must be a .bvh file")
    report = report_output(args)
    view = view_output(args)
    picture = out.with_suffix(".png") if args.plot else None
    check_paths([out, report, picture, view], [args.input], args.force)
    return Outputs(out, report, picture, view)


def report_output(args: argparse.Namespace) -> Path | None:
    """--report's path, a .json file, or None."""
    report = Path(args.report) if args.report else None
    if report is not None and report.suffix.lower() != ".json":
        raise UserError(f"--report {report}: the report must be a .json file")
    return report


def check_paths(paths: list[Path | None], inputs: list[str], force: bool) -> None:
    """Output ``paths`` (None: not written), checked before any work: none is an input, each
    folder exists, each file is new unless ``force``."""
    for path in filter(None, paths):
        if any(Path(i).resolve() == path.resolve() for i in inputs):
            raise UserError(f"{path} is an input file; write the result to another file")
        if not path.parent.exists():
            raise UserError(f"folder {path.parent} does not exist; create it first")
        if path.exists() and not force:
            raise UserError(f"{path} exists; pass --force to overwrite it")


def load_input(args: argparse.Namespace, path: str | None = None) -> Motion:
    """The input file ``path`` (default: the command's INPUT) read with --unit, --fps and
    --max-frames; warns when its speeds say its header's frame rate is likely wrong
    (``info.frame_rate_doubt``), unless --fps gives the rate."""
    from motionopt import bvh
    from motionopt.info import frame_rate_doubt

    path = path or args.input
    motion = bvh.load(path, unit=args.unit, fps=args.fps, max_frames=args.max_frames)
    _say(args, f"read {path}: {motion.num_frames} frames at {motion.fps:g} fps, "
               f"{motion.skeleton.num_joints} joints, unit {motion.source_unit}")
    doubt = None if args.fps else frame_rate_doubt(motion, str(path))
    if doubt:
        log.warning(doubt)
    return motion


def load_prior(motion, args: argparse.Namespace, kind: str):
    """The prior of ``kind`` (a key of ``priors.checkpoint.KINDS``) for the motion: --prior
    (a file or a shipped checkpoint's name) or the shipped one of that kind whose skeleton
    matches; and its path. A checkpoint of the other kind is refused, saying which kind
    the command needs and, where a task takes either, the --method that takes the other."""
    from priors.checkpoint import KINDS, load_prior_of_kind

    latent = kind == "LatentPrior"
    either = args.command in TASKS and TASKS[args.command].latent is not None
    needed_by = f"{args.command} --method latent" if latent and either else args.command
    otherwise = f"{'drop' if latent else 'pass'} --method latent to use {args.prior}" if either else ""
    prior, path = load_prior_of_kind(motion.skeleton, args.prior, kind, needed_by, otherwise)
    _say(args, f"prior: {path} ({KINDS[kind].name}, {prior.spec.fps:g} fps, {len(prior.spec.joints)} joints)")
    return prior, path


def solver_options(args: argparse.Namespace, base: SolverOptions,
                   progress: Callable[[dict], object] | None = None) -> SolverOptions:
    """The task's solver settings ``base`` with the command line's knobs applied."""
    from motionopt.solver import OPTIMIZERS, PSOOptions

    if args.optimizer is not None and args.optimizer not in OPTIMIZERS:
        raise UserError(f"--optimizer {args.optimizer!r}: choose one of {', '.join(OPTIMIZERS)}")
    if args.no_pso and (args.pso_particles or args.pso_iterations):
        raise UserError("--no-pso turns the particle swarm off; drop --pso-particles/--pso-iterations or --no-pso")
    pso = base.pso
    if args.no_pso:
        pso = None
    elif args.pso_particles or args.pso_iterations:
        pso = replace(pso or PSOOptions(), **{k: v for k, v in (("particles", args.pso_particles),
                                                                 ("iterations", args.pso_iterations)) if v})
    if args.iterations == 0:
        raise UserError("--iterations 0 means the latent inversion's encoder alone (--method latent); the MAP "
                        "solver needs 1 or more, or pass --no-refine")
    return replace(base, optimizer=args.optimizer or base.optimizer, max_iter=args.iterations or base.max_iter,
                   pso=pso, seed=args.seed, callback=progress)


def latent_options(args: argparse.Namespace, base: InversionOptions) -> InversionOptions:
    """The latent task's inversion settings ``base`` with the command line's knobs applied (--method latent)."""
    for flag, value in (("--optimizer", args.optimizer), ("--pso-particles", args.pso_particles)):
        if value is not None:
            raise UserError(f"{flag} applies to --method ar only")
    if args.no_pso and args.pso_iterations:
        raise UserError("--no-pso turns the particle swarm off; drop --pso-iterations or --no-pso")
    return replace(base, refine_iters=base.refine_iters if args.iterations is None else args.iterations,
                   pso_iters=0 if args.no_pso else args.pso_iterations or base.pso_iters, seed=args.seed)


class WindowProgress:
    """A progress bar over the solver's windows, fed by ``SolverOptions.callback``; with
    --verbose also a line per window. Silent with --quiet. The bar appears with the
    solver's first iteration, so a task that fails its checks, or needs no solver, shows none."""

    def __init__(self, args: argparse.Namespace):
        self.args = args
        self.bar = None
        self.window = -1

    def __call__(self, info: dict) -> None:
        if info["window"] == self.window:
            return
        if self.bar is None:
            from tqdm import tqdm

            self.bar = tqdm(desc=f"{self.args.command}: solving window", bar_format="{desc} {n_fmt}{postfix} "
                            "[{elapsed}]", disable=self.args.quiet, leave=False, delay=0.5, file=sys.stderr)
        self.window = info["window"]
        a, b = info["frames"]
        self.bar.set_postfix_str(f"frames {a}-{b - 1} at the prior's rate", refresh=False)
        self.bar.update(1)
        _say(self.args, f"solving window {self.window + 1} (frames {a}-{b - 1} at the prior's rate)")

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _say(args: argparse.Namespace, text: str) -> None:
    """A detail line for --verbose."""
    if args.verbose:
        from tqdm import tqdm

        tqdm.write(text, file=sys.stdout)


def command_line(args: argparse.Namespace, prior_path: Path, positional: tuple[str, ...] = POSITIONAL) -> str:
    """The command with every option's value, defaults included, that reproduces this run
    (``positional``: the names of its positional arguments, in order)."""
    skip = {"func", "command", "quiet", "verbose", "force", *positional}
    words = ["motionopt", args.command, *(str(getattr(args, k)) for k in positional)]
    for key, value in vars(args).items():
        if key in skip or value is None or value is False:
            continue
        flag = "--" + key.replace("_", "-")
        words += [flag] if value is True else [flag, f"{value:g}" if isinstance(value, float) else str(value)]
    if args.prior is None:
        words += ["--prior", str(prior_path)]
    return " ".join(shlex.quote(w) for w in words)


def solve(run: TaskRun, progress: WindowProgress | None = None):
    """Solve the task (closing the progress bar after); log the solver's warnings, and with
    --verbose its windows and terms."""
    args = run.args
    if _method(args) == "latent":
        _say(args, f"{args.command}: inverting the latent prior")
    try:
        result = run.task.solve()
    finally:
        if progress is not None:
            progress.close()
    solver = getattr(result, "solver", None)
    if solver is not None:
        for w in solver.warnings:
            log.warning(w)
        if args.verbose:
            for i, w in enumerate(solver.windows):
                _say(args, f"window {i + 1}: frames {w['frames'][0]}-{w['frames'][1] - 1}, objective "
                           f"{w['fun_start']:.4g} -> {w['fun']:.4g} in {w['nit']} iterations ({w['message']})")
            for name, end in solver.terms.items():
                _say(args, f"term {name}: {solver.terms_start.get(name, float('nan')):.4g} -> {end:.4g}")
    return result


def write_result(run: TaskRun, result) -> dict:
    """Write the solved task's BVH, then its picture, page and report where asked for; return
    the report (also when it is not written). The one writer of a result, for the commands and
    the batch."""
    from motionopt import bvh

    args, outs = run.args, run.outs
    bvh.save(result.motion, outs.bvh, force=args.force)
    seconds = time.perf_counter() - run.started
    if outs.picture is not None:
        run.entry.draw(run.task, run.motion, result, outs.picture)
    if outs.view is not None:
        write_view_page(run, result, outs.view)
    report = {"command": command_line(args, run.prior_path), "task": args.command, "method": _method(args),
              "input": str(args.input), "output": str(outs.bvh),
              "picture": str(outs.picture) if outs.picture else None,
              "view": str(outs.view) if outs.view else None, "prior": str(run.prior_path),
              "input_frames": run.motion.num_frames, "input_fps": run.motion.fps, "seconds": seconds,
              **result.report()}
    if outs.report is not None:
        write_json(outs.report, report)
    return report


def json_text(data: object) -> str:
    """A report as JSON text (arrays as lists, other objects as text)."""
    return json.dumps(data, indent=2, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))


def write_json(path: Path, data: dict) -> None:
    """Write JSON through a temporary file, so that an interrupted run leaves no half file."""
    write_text_atomic(path, json_text(data) + "\n")


def cmd_task(args: argparse.Namespace) -> int:
    """A task command: check and build (``start``), solve, write, and say what came out:
    the task's summary of its metrics and, after --refine, the solver's objective."""
    progress = WindowProgress(args)
    run = start(args, progress)
    result = solve(run, progress)
    report = write_result(run, result)
    if args.quiet:
        return 0
    lines = run.task.summary(result)
    naturalness_line = result.naturalness_line() if hasattr(result, "naturalness_line") else None
    if naturalness_line is not None:
        lines.append(naturalness_line)
    solver = getattr(result, "solver", None)
    if solver is not None:
        lines.append(f"objective {solver.fun_start:.4g} -> {solver.fun:.4g} over {len(solver.windows)} windows, "
                     f"{solver.nit} iterations")
    print(f"wrote {run.outs.bvh}: {result.motion.num_frames} frames at {result.motion.fps:g} fps "
          f"(input {run.motion.num_frames}) in {report['seconds']:.1f} s")
    for line in lines:
        print(f"  {line}")
    for path in filter(None, (run.outs.picture, run.outs.view, run.outs.report)):
        print(f"wrote {path}")
    return 0
