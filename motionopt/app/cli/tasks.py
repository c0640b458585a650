"""The editing task commands: path-follow, denoise, inbetween, complete, edit.

Every command checks all of its inputs and outputs before solving, so that a mistake
costs no time and writes nothing; then it runs the task class from ``problems/`` (or
the latent prior's inversion with ``--method latent``), shows a progress bar over the
solver's windows, writes the BVH with ``bvh.save`` (atomic), and optionally a JSON
report (``--report``) and a picture next to the output (``--plot``).
"""
from __future__ import annotations

import argparse
import json
import logging
import shlex
import sys
import time
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Callable

from motionopt.atomic import write_text_atomic

from . import UserError, add_common

log = logging.getLogger(__name__)

METHODS = ("ar", "latent")
#: Positional arguments of each command, first on the reproducing command line.
POSITIONAL = ("input",)


def register(sub) -> None:
    p = sub.add_parser(
        "path-follow", help="continue a motion so that its root walks along a path on the ground",
        description="Continue SEED.bvh along the ground path in PATH.csv (a header line 'x,z', optionally "
        "'t' in seconds after the seed's end, then one point per line; metres in the seed file's world "
        "coordinates). OUT.bvh holds the seed's frames followed by the new motion. --plot draws the root's "
        "path against the target path.")
    p.add_argument("input", metavar="SEED.bvh", help="motion whose end the new motion continues")
    p.add_argument("--path", required=True, metavar="PATH.csv", help="ground points to follow (x,z[,t])")
    p.add_argument("--seconds", type=_positive(float), default=None, metavar="S",
                   help="seconds of new motion (default: enough to reach the path's end)")
    p.add_argument("--speed", type=_positive(float), default=None, metavar="M_PER_S",
                   help="walking speed along the path (default: the seed's recent speed, at least 1 m/s); "
                   "not with a t column")
    _add_task_options(p, latent=False, new_frames=True)
    p.set_defaults(func=cmd_path_follow)

    p = sub.add_parser(
        "denoise", help="clean captured motion: remove jitter, foot sliding and ground penetration",
        description="Estimate the capture noise in the clip and smooth each joint with the Butterworth or "
        "Savitzky-Golay filter of least estimated risk for it. --clean-feet then plants the feet by leg IK. "
        "--refine then adds the MAP solve: fidelity to the input's root and joint "
        "angles, the prior and contact terms. --plot draws a foot's trajectory before and after.")
    p.add_argument("input", metavar="INPUT.bvh", help="motion to clean")
    _add_task_options(p, latent=True, new_frames=False)
    _add_clean_feet(p)
    p.set_defaults(func=cmd_denoise)

    p = sub.add_parser(
        "inbetween", help="fill the frames between kept frame ranges",
        description="Keep the frames inside --keep exactly and synthesise the frames between them so that "
        "each gap meets the next kept frames without a jump. --plot draws a filmstrip of output and input.")
    p.add_argument("input", metavar="INPUT.bvh", help="motion whose kept frames are used")
    p.add_argument("--keep", required=True, metavar="RANGES",
                   help="half-open frame ranges to keep, like Python slices, e.g. 0:30,60:90 (frames 0-29 and "
                   "60-89 of INPUT.bvh); the first range must start at 0")
    _add_task_options(p, latent=True, new_frames=True)
    _add_clean_feet(p)
    p.set_defaults(func=cmd_inbetween)

    p = sub.add_parser(
        "complete", help="continue the first frames of a motion (prefix completion)",
        description="Keep the first --prefix frames of INPUT.bvh and synthesise new motion after them, up to "
        "--frames frames in all (both in INPUT.bvh's frame rate). --plot draws a filmstrip of output and "
        "input.")
    p.add_argument("input", metavar="INPUT.bvh", help="motion whose first frames are kept")
    p.add_argument("--prefix", required=True, type=_positive(int), metavar="N", help="frames to keep")
    p.add_argument("--frames", required=True, type=_positive(int), metavar="N",
                   help="frames of the output, prefix included")
    _add_task_options(p, latent=True, new_frames=True)
    _add_clean_feet(p)
    p.set_defaults(func=cmd_complete)

    p = sub.add_parser(
        "edit", help="move chosen joints to targets at chosen frames (spatial edit)",
        description="Meet the joint targets in TARGETS.json, a list of {\"joint\": NAME, \"frame\": I or "
        "[I, J], \"position\": [x, y, z] (metres, world) or \"offset\": [dx, dy, dz]}, while the rest of "
        "the motion stays close to the input and natural. --plot draws a filmstrip of output and input. "
        "(--method latent is not available for spatial edits yet.)")
    p.add_argument("input", metavar="INPUT.bvh", help="motion to edit")
    p.add_argument("--targets", required=True, metavar="TARGETS.json", help="joint targets")
    _add_task_options(p, latent=True, new_frames=False)
    p.set_defaults(func=cmd_edit)


def _positive(kind: type) -> Callable[[str], float | int]:
    def parse(text: str):
        value = kind(text)
        if not value > 0:
            raise argparse.ArgumentTypeError(f"must be positive, got {text}")
        return value
    parse.__name__ = kind.__name__  # argparse names the type in its messages
    return parse


def _add_clean_feet(p: argparse.ArgumentParser) -> None:
    p.add_argument("--clean-feet", action="store_true",
                   help="plant the feet the prior finds in contact by leg IK: no sliding, at a cost of "
                   "centimetres in fidelity (not with --method latent)")


def _no_clean_feet_with_latent(args: argparse.Namespace) -> None:
    if args.method == "latent" and args.clean_feet:
        raise UserError("--clean-feet works with --method ar only")


def _add_task_options(p: argparse.ArgumentParser, latent: bool, new_frames: bool) -> None:
    """Options every task command shares; ``latent``: it offers --method latent; ``new_frames``:
    it synthesises frames (where the particle swarm works)."""
    from motionopt.solver import BACKENDS as OPTIMIZERS, PSOOptions, SolverOptions

    io = p.add_argument_group("input and output")
    io.add_argument("--out", required=True, metavar="OUT.bvh",
                    help="BVH file to write, with the input's skeleton, channels, unit and frame rate")
    io.add_argument("--report", default=None, metavar="REPORT.json",
                    help="write the solver's per-term values, the task's metrics, timings and the command")
    io.add_argument("--plot", action="store_true", help="also draw a picture: OUT.png next to OUT.bvh")
    io.add_argument("--force", action="store_true", help="overwrite OUT, REPORT and the picture if they exist")
    io.add_argument("--fps", type=_positive(float), default=None, help="override the input file's frame rate")
    io.add_argument("--unit", choices=("auto", "cm", "m", "mm", "in"), default="auto",
                    help="length unit of the input file (default: guessed from the skeleton's size)")
    io.add_argument("--max-frames", type=_positive(int), default=100_000, metavar="N",
                    help="refuse an input that declares more frames than this, before reading them (default "
                    "100000: 14 minutes at 120 fps)")
    s = p.add_argument_group("prior and solver")
    if latent:
        s.add_argument("--method", choices=METHODS, default="ar",
                       help="ar: MAP optimisation under the autoregressive prior (default); latent: inversion "
                       "of the latent (W+) prior")
    s.add_argument("--prior", default=None, metavar="CKPT",
                   help="prior checkpoint (default: the shipped one matching the input's skeleton)")
    s.add_argument("--seed", type=int, default=0, help="seed of every random choice (default 0)")
    s.add_argument("--refine", action="store_true",
                   help="polish the result with the MAP solver (prior, task and contact terms; windows of "
                   "34 frames, L-BFGS); off by default because with the shipped priors it does not improve "
                   "the benchmark figures (bench/results/tasks.txt)")
    s.add_argument("--iterations", type=_positive(int), default=None, metavar="N",
                   help=f"local optimiser iterations per window (default {SolverOptions.max_iter})" + (
                       "; with --method latent, refinement iterations of the latent code (default 0: the "
                       "encoder alone)" if latent else ""))
    s.add_argument("--optimizer", default=None, metavar="NAME",
                   help=f"local optimiser: {', '.join(OPTIMIZERS)} (default {SolverOptions.method}); scipy is "
                   "L-BFGS-B, nlopt LD_LBFGS, torch torch.optim.LBFGS, adam a first-order baseline")
    swarm = ("it steers the synthesised frames of --refine; off by default, --pso-particles turns it on"
             if new_frames else "it steers synthesised frames only, so with --method ar it changes nothing here")
    s.add_argument("--no-pso", action="store_true", help=f"no particle swarm before the local optimiser ({swarm})")
    s.add_argument("--pso-particles", type=_positive(int), default=None, metavar="N",
                   help=f"particles of the swarm (default {PSOOptions.particles})")
    s.add_argument("--pso-iterations", type=_positive(int), default=None, metavar="N",
                   help=f"particle swarm iterations (default {PSOOptions.iterations})" + (
                       "; with --method latent, swarm iterations over the latent code (default 0)"
                       if latent else ""))
    add_common(p)


# ---- shared steps ---------------------------------------------------------------------------------

@dataclass
class Outputs:
    """Where a command writes: the BVH, and the optional report and picture."""

    bvh: Path
    report: Path | None
    picture: Path | None


def check_outputs(args: argparse.Namespace) -> Outputs:
    """Every output path, checked before any work: suffix, folder, not the input, new or --force."""
    out = Path(args.out)
    if out.suffix.lower() != ".bvh":
        raise UserError(f"--out {out}: the output must be a .bvh file")
    report = Path(args.report) if args.report else None
    if report is not None and report.suffix.lower() != ".json":
        raise UserError(f"--report {report}: the report must be a .json file")
    picture = out.with_suffix(".png") if args.plot else None
    for path in filter(None, (out, report, picture)):
        if Path(args.input).resolve() == path.resolve():
            raise UserError(f"{path} is the input file; write the result to another file")
        if not path.parent.exists():
            raise UserError(f"folder {path.parent} does not exist; create it first")
        if path.exists() and not args.force:
            raise UserError(f"{path} exists; pass --force to overwrite it")
    return Outputs(out, report, picture)


def load_input(args: argparse.Namespace):
    from motionopt import bvh

    motion = bvh.load(args.input, unit=args.unit, fps=args.fps, max_frames=args.max_frames)
    _say(args, f"read {args.input}: {motion.num_frames} frames at {motion.fps:g} fps, "
               f"{motion.skeleton.num_joints} joints, unit {motion.source_unit}")
    return motion


def load_ar_prior(motion, args: argparse.Namespace):
    """The autoregressive prior for the motion (named or shipped), refusing a latent one; and its path."""
    from priors.latent import LatentPrior

    from .prior import load_prior_for

    prior, path = load_prior_for(motion, args.prior)
    if isinstance(prior, LatentPrior):
        raise UserError(f"{path} is a latent prior; pass --method latent, or an autoregressive checkpoint")
    _say(args, f"prior: {path} ({prior.spec.fps:g} fps, {len(prior.spec.joints)} joints)")
    return prior, path


def load_latent_prior(motion, args: argparse.Namespace):
    """The latent prior for the motion (named or shipped); and its path."""
    from priors.checkpoint import SHIPPED_LATENT, find_prior_for
    from problems.latent import load_latent_for

    path = Path(args.prior) if args.prior else find_prior_for(motion.skeleton, SHIPPED_LATENT, "train-latent")
    prior = load_latent_for(motion, str(path))
    _say(args, f"latent prior: {path} ({prior.spec.fps:g} fps, {len(prior.spec.joints)} joints)")
    return prior, path


def solver_options(args: argparse.Namespace, task: type, progress: "WindowProgress"):
    """The task's default solver options with the command line's knobs applied."""
    from motionopt.solver import BACKENDS as OPTIMIZERS, PSOOptions

    if args.optimizer is not None and args.optimizer not in OPTIMIZERS:
        raise UserError(f"--optimizer {args.optimizer!r}: choose one of {', '.join(OPTIMIZERS)}")
    if args.no_pso and (args.pso_particles or args.pso_iterations):
        raise UserError("--no-pso turns the particle swarm off; drop --pso-particles/--pso-iterations or --no-pso")
    base = next(f for f in fields(task) if f.name == "options").default_factory()
    pso = base.pso
    if args.no_pso:
        pso = None
    elif args.pso_particles or args.pso_iterations:
        pso = replace(pso or PSOOptions(), **{k: v for k, v in (("particles", args.pso_particles),
                                                                 ("iterations", args.pso_iterations)) if v})
    return replace(base, method=args.optimizer or base.method, max_iter=args.iterations or base.max_iter,
                   pso=pso, seed=args.seed, callback=progress)


def latent_options(args: argparse.Namespace):
    """Inversion settings from the command line (--method latent)."""
    from motionopt.solver import InversionOptions

    for flag, value in (("--optimizer", args.optimizer), ("--pso-particles", args.pso_particles)):
        if value is not None:
            raise UserError(f"{flag} applies to --method ar only")
    if args.no_pso and args.pso_iterations:
        raise UserError("--no-pso turns the particle swarm off; drop --pso-iterations or --no-pso")
    return InversionOptions(refine_iters=args.iterations or 0,
                            pso_iters=0 if args.no_pso else args.pso_iterations or 0, seed=args.seed)


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


def command_line(args: argparse.Namespace, prior_path: Path) -> str:
    """The command with every option's value, defaults included, that reproduces this run."""
    skip = {"func", "command", "quiet", "verbose", "force", *POSITIONAL}
    words = ["motionopt", args.command, *(str(getattr(args, k)) for k in POSITIONAL)]
    for key, value in vars(args).items():
        if key in skip or value is None or value is False:
            continue
        flag = "--" + key.replace("_", "-")
        words += [flag] if value is True else [flag, f"{value:g}" if isinstance(value, float) else str(value)]
    if args.prior is None:
        words += ["--prior", str(prior_path)]
    return " ".join(shlex.quote(w) for w in words)


def solve(args: argparse.Namespace, run: Callable[[], object], progress: WindowProgress | None = None):
    """Run the task's solve with the progress bar; log the solver's warnings."""
    if progress is None:
        _say(args, f"{args.command}: inverting the latent prior")
    try:
        result = run()
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


def finish(args: argparse.Namespace, outs: Outputs, motion, result, prior_path: Path, started: float,
           draw: Callable[[Path], object]) -> int:
    """Write the BVH, the report and the picture; print the summary."""
    from motionopt import bvh

    bvh.save(result.motion, outs.bvh, force=args.force)
    seconds = time.perf_counter() - started
    if outs.picture is not None:
        draw(outs.picture)
    if outs.report is not None:
        report = {"command": command_line(args, prior_path), "task": args.command,
                  "method": getattr(args, "method", "ar"),
                  "input": str(args.input), "output": str(outs.bvh),
                  "picture": str(outs.picture) if outs.picture else None, "prior": str(prior_path),
                  "input_frames": motion.num_frames, "input_fps": motion.fps, "seconds": seconds, **result.report()}
        _write_json(outs.report, report)
    if not args.quiet:
        print(f"wrote {outs.bvh}: {result.motion.num_frames} frames at {result.motion.fps:g} fps "
              f"(input {motion.num_frames}) in {seconds:.1f} s")
        for line in summary_lines(result):
            print(f"  {line}")
        for path in filter(None, (outs.picture, outs.report)):
            print(f"wrote {path}")
    return 0


def _write_json(path: Path, data: dict) -> None:
    """Write JSON through a temporary file, so that an interrupted run leaves no half file."""
    text = json.dumps(data, indent=2, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))
    write_text_atomic(path, text + "\n")


#: How to say a task's metrics: (keys that must all be present, sentence from their values).
SUMMARY: list[tuple[tuple[str, ...], Callable[..., str]]] = [
    (("path_distance_cm_mean", "path_distance_cm_max"),
     lambda m, x: f"root distance to the path: {m:.1f} cm on average, {x:.1f} cm at most"),
    (("end_distance_to_path_end_m",), lambda d: f"the motion ends {d:.2f} m from the path's end"),
    (("new_frames", "speed_m_per_s"), lambda n, v: f"{n} new frames at the prior's rate, at {v:.2f} m/s"),
    (("foot_skating_cm_per_s",), lambda s: f"foot skating: {s:.1f} cm/s (mocap: a few cm/s)"),
    (("jerk_input_m_per_s3", "jerk_output_m_per_s3"),
     lambda a, b: f"jitter (mean jerk): {a:.0f} -> {b:.0f} m/s^3, input -> output"),
    (("foot_skating_input_cm_per_s", "foot_skating_output_cm_per_s"),
     lambda a, b: f"foot skating: {a:.1f} -> {b:.1f} cm/s, input -> output"),
    (("mean_change_cm",), lambda c: f"joints moved {c:.2f} cm on average"),
    (("synthesised_frames",), lambda n: f"{n} frames synthesised"),
    (("join_root_error_cm",), lambda e: "gaps meet the kept frames within "
     + (", ".join(f"{v:.1f}" for v in e) + " cm (root)" if e else "- (no gap before a kept frame)")),
    (("target_error_cm_mean", "target_error_cm_max"),
     lambda m, x: f"targets met within {x:.2f} cm ({m:.2f} cm on average)"),
    (("untouched_change_cm_mean",), lambda c: f"frames away from the targets moved {c:.2f} cm on average"),
    (("prior_nll_per_frame",), lambda v: f"naturalness: {v:.1f} nats per frame under the prior (lower is "
     "more natural)"),
    (("frames_per_second",), lambda f: f"speed: {f:.0f} frames per second"),
]


def summary_lines(result) -> list[str]:
    """Short sentences about the result's metrics (unknown metrics as name: value)."""
    metrics = dict(result.metrics)
    lines = []
    for keys, say in SUMMARY:
        if all(k in metrics for k in keys):
            lines.append(say(*(metrics.pop(k) for k in keys)))
    lines += [f"{k}: {v:.4g}" if isinstance(v, float) else f"{k}: {v}" for k, v in metrics.items()]
    solver = getattr(result, "solver", None)
    inversion = getattr(result, "inversion", None)
    if solver is not None:
        lines.append(f"objective {solver.fun_start:.4g} -> {solver.fun:.4g} over {len(solver.windows)} windows, "
                     f"{solver.nit} iterations")
    elif inversion is not None:
        how = f"refined in {inversion.nit} iterations" if inversion.nit else "from the encoder alone"
        fit = "" if inversion.objective is None else \
            f"; fidelity objective {inversion.objective_start:.4g} -> {inversion.objective:.4g}"
        lines.append(f"latent codes of {len(inversion.starts)} windows {how}{fit}")
    return lines


def filmstrip(motion, result) -> Callable[[Path], object]:
    """A filmstrip of output over input, six moments spread over the output."""
    import numpy as np

    from motionopt import plot

    n = result.motion.num_frames
    frames = np.unique(np.linspace(0, n - 1, min(6, n)).round().astype(int)).tolist()
    return lambda out: plot.plot_filmstrip({"output": result.motion, "input": motion}, out, frames=frames,
                                           title="Output (top) and input", force=True)


# ---- the commands ----------------------------------------------------------------------------------

def cmd_path_follow(args: argparse.Namespace) -> int:
    from motionopt import plot
    from problems.path_follow import PathFollow, read_path_csv

    started = time.perf_counter()
    outs = check_outputs(args)
    points, times = read_path_csv(args.path)
    if times is not None and args.speed is not None:
        raise UserError(f"{args.path} sets the timing with its t column; drop --speed")
    seed = load_input(args)
    prior, prior_path = load_ar_prior(seed, args)
    progress = WindowProgress(args)
    task = PathFollow(seed, points, prior, times=times, speed=args.speed, seconds=args.seconds,
                      options=solver_options(args, PathFollow, progress), refine=args.refine)
    result = solve(args, task.solve, progress)
    return finish(args, outs, seed, result, prior_path, started, lambda out: plot.plot_root_paths(
        {"output": result.motion, "seed": seed}, out, target=points, title="Root path and target path",
        force=True))


def cmd_denoise(args: argparse.Namespace) -> int:
    from motionopt import plot

    started = time.perf_counter()
    outs = check_outputs(args)
    _no_clean_feet_with_latent(args)
    motion = load_input(args)
    if args.method == "latent":
        from problems.latent import reconstruct

        prior, prior_path = load_latent_prior(motion, args)
        options = latent_options(args)
        result = solve(args, lambda: reconstruct(prior, motion, options))
    else:
        from problems.denoise import Denoise

        prior, prior_path = load_ar_prior(motion, args)
        progress = WindowProgress(args)
        task = Denoise(motion, prior, options=solver_options(args, Denoise, progress), refine=args.refine,
                       clean_feet=args.clean_feet)
        result = solve(args, task.solve, progress)
    foot = prior.spec.contact_joints[0]
    return finish(args, outs, motion, result, prior_path, started, lambda out: plot.plot_joint_trajectories(
        {"input": motion, "denoised": result.motion}, foot, out, force=True))


def cmd_inbetween(args: argparse.Namespace) -> int:
    from problems.inbetween import check_ranges, parse_ranges

    started = time.perf_counter()
    outs = check_outputs(args)
    _no_clean_feet_with_latent(args)
    motion = load_input(args)
    keep = check_ranges(parse_ranges(args.keep), motion.num_frames)
    if args.method == "latent":
        import numpy as np

        from problems.latent import infill

        prior, prior_path = load_latent_prior(motion, args)
        options = latent_options(args)
        seen = np.zeros(motion.num_frames, bool)
        for a, b in keep:
            seen[a:b] = True
        result = solve(args, lambda: infill(prior, motion, seen, options))
    else:
        from problems.inbetween import Inbetween

        prior, prior_path = load_ar_prior(motion, args)
        progress = WindowProgress(args)
        task = Inbetween(motion, keep, prior, options=solver_options(args, Inbetween, progress), refine=args.refine,
                         clean_feet=args.clean_feet)
        result = solve(args, task.solve, progress)
    return finish(args, outs, motion, result, prior_path, started, filmstrip(motion, result))


def cmd_complete(args: argparse.Namespace) -> int:
    started = time.perf_counter()
    outs = check_outputs(args)
    _no_clean_feet_with_latent(args)
    motion = load_input(args)
    if args.method == "latent":
        from problems.latent import complete

        prior, prior_path = load_latent_prior(motion, args)
        options = latent_options(args)
        result = solve(args, lambda: complete(prior, motion, args.prefix, args.frames, options))
    else:
        from problems.inbetween import Inbetween, complete

        prior, prior_path = load_ar_prior(motion, args)
        progress = WindowProgress(args)
        task = complete(motion, args.prefix, args.frames, prior,
                        options=solver_options(args, Inbetween, progress), refine=args.refine,
                        clean_feet=args.clean_feet)
        result = solve(args, task.solve, progress)
    return finish(args, outs, motion, result, prior_path, started, filmstrip(motion, result))


def cmd_edit(args: argparse.Namespace) -> int:
    from problems.edit import SpatialEdit, load_targets

    started = time.perf_counter()
    outs = check_outputs(args)
    if args.method == "latent":
        raise UserError("spatial edits with the latent prior are not available (problems/latent.py has no "
                        "spatial edit); use --method ar, the default")
    targets = load_targets(args.targets)
    motion = load_input(args)
    prior, prior_path = load_ar_prior(motion, args)
    progress = WindowProgress(args)
    task = SpatialEdit(motion, targets, prior, options=solver_options(args, SpatialEdit, progress),
                       refine=args.refine)
    result = solve(args, task.solve, progress)
    return finish(args, outs, motion, result, prior_path, started, filmstrip(motion, result))
