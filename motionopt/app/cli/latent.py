"""Commands of the latent (W+) prior: train-latent, fuse, latent-edit, vary, interpolate."""
from __future__ import annotations

import argparse
import shlex
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

from motionopt.features import missing_joints
from priors.latent import LatentConfig
from priors.train_latent import PHASES

from . import UserError
from .prior import add_training_data_args, add_training_run_args, training_dataset
from .tasks import (add_io_options, add_prior_options, check_paths, command_line, filmstrip, json_text, load_input,
                    load_prior, non_negative, report_output, settle_args, settle_prior, use_threads, view_output,
                    write_json)


def register(sub) -> None:
    p = sub.add_parser("train-latent", help="train a latent (W+) prior on a folder of BVH files",
                       description="Train the latent prior (autoencoder, then denoising encoder, then masked encoder) on every "
                       "BVH file under --data. Resumes from OUT.train-state.pt when it exists; logs to OUT.log.")
    add_training_data_args(p)
    p.add_argument("--autoencoder-epochs", type=int, default=60)
    p.add_argument("--denoising-epochs", type=int, default=20)
    p.add_argument("--masked-epochs", type=int, default=20)
    p.add_argument("--epoch-steps", type=int, default=200, help="optimiser steps per epoch (default 200)")
    p.add_argument("--stride", type=int, default=4, help="frames between the starts of training windows (default 4)")
    p.add_argument("--autoencoder-minutes", type=float, default=None,
                   help="stop the autoencoder phase after this much time")
    p.add_argument("--denoising-minutes", type=float, default=None)
    p.add_argument("--masked-minutes", type=float, default=None)
    p.add_argument("--max-minutes", type=float, default=None,
                   help="stop this run after this much time (run the same command again to resume)")
    p.add_argument("--tiny", action="store_true", help="a very small network (for tests and trials)")
    p.add_argument("--masked-context", type=int, default=LatentConfig.masked_context,
                   help="bidirectional GRU layers that let the masked encoder see the whole window "
                   f"(default {LatentConfig.masked_context}; 0: convolutions only, about 6 frames either side)")
    p.add_argument("--init", default=None, metavar="CKPT",
                   help="start from this latent checkpoint: its normaliser and every weight the architecture shares")
    p.add_argument("--phases", nargs="+", choices=PHASES, default=list(PHASES),
                   help="the phases to run, in order (default all; '--init CKPT --phases masked' retrains only "
                   "the masked encoder of CKPT, keeping its semantic directions)")
    add_training_run_args(p)
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("fuse", help="join two motions at a frame through the latent prior (MoDi fusion)",
                       description="Frames of A before --at, then frames of B from --at (B's root continues "
                       "from A's), passed through the latent prior's encoder and generator. --plot draws A, B "
                       "and the fused motion.")
    p.add_argument("a", metavar="A.bvh", help="BVH file whose start is kept")
    p.add_argument("b", metavar="B.bvh", help="BVH file whose end is kept")
    p.add_argument("--at", type=int, required=True,
                   help="frame of A where it hands over to B, which is taken from the same time into it")
    _task_options(p, "BVH file to write, on A's skeleton, unit and frame rate")
    p.set_defaults(func=cmd_fuse)

    p = sub.add_parser("latent-edit", help="strengthen or weaken an attribute by moving in the latent space",
                       description="Encode the motion into W+, step along the attribute's direction, then refine "
                       "the codes (L-BFGS under the latent prior) until the edit reaches its goal in user terms, "
                       "keeping the joints the attribute does not move and the feet planted. Strength units: crouch, "
                       "hips 3 cm lower (a negative strength never raises them above their highest in the clip); "
                       "gral (right-arm lift), the right arm 20 degrees higher; root_speed, speed times 1.2; "
                       "style:NAME (priors trained on Bandai clips), the style classifier's probability +0.4. "
                       "`--attribute list` prints the attributes of the prior. --plot draws input over output.")
    p.add_argument("input", metavar="INPUT.bvh", help="BVH file")
    p.add_argument("--attribute", required=True, help="attribute name, or 'list'")
    p.add_argument("--strength", type=float, default=1.0,
                   help="units of the attribute's edit (see above); negative weakens it (default 1)")
    _task_options(p, "BVH file to write (not needed with --attribute list)", out_required=False)
    p.set_defaults(func=cmd_edit)

    p = sub.add_parser("vary", help="variations of a motion: random offsets around its latent code",
                       description="Encode the motion into W+ and generate --count motions from random offsets "
                       "around its code (--seed draws them), each settled under the autoregressive prior (a MAP "
                       "solve within a few centimetres that makes it natural; --no-settle: as generated), written as "
                       "DIR/INPUT_var_00.bvh and on. --plot draws each against the input.")
    p.add_argument("input", metavar="INPUT.bvh", help="BVH file")
    p.add_argument("--count", type=int, default=8)
    p.add_argument("--sigma", type=non_negative(float), default=0.3,
                   help="offset size in standard deviations of the codes (0.1-0.8)")
    _task_options(p, "folder for the output BVH files (made if missing)", out_dir=True)
    _settle_options(p, "each variation")
    p.set_defaults(func=cmd_vary)

    p = sub.add_parser("interpolate", help="motions between two motions, by interpolating their latent codes",
                       description="Encode A and B into W+ and generate --steps motions between their codes, A "
                       "and B included, the steps between settled under the autoregressive prior (--no-settle: as "
                       "generated), written as DIR/A_to_B_00.bvh and on. --plot draws each against A and B.")
    p.add_argument("a", metavar="A.bvh", help="first BVH file")
    p.add_argument("b", metavar="B.bvh", help="second BVH file (same skeleton)")
    p.add_argument("--steps", type=int, default=5, help="number of motions, both ends included")
    _task_options(p, "folder for the output BVH files (made if missing)", out_dir=True)
    _settle_options(p, "each step between the ends")
    p.set_defaults(func=cmd_interpolate)


TINY = {"w_dim": 16, "channels": (16, 32), "sample_components": 64}


def cmd_train(args: argparse.Namespace) -> int:
    from priors.train_latent import LatentTrainConfig, train_latent

    model = LatentConfig(**TINY) if args.tiny else LatentConfig()
    if args.init:
        model = initial_config(args.init)
    model = replace(model, masked_context=args.masked_context)
    try:
        cfg = LatentTrainConfig(autoencoder_epochs=args.autoencoder_epochs, denoising_epochs=args.denoising_epochs,
                                masked_epochs=args.masked_epochs, denoising_minutes=args.denoising_minutes,
                                epoch_steps=args.epoch_steps, stride=args.stride,
                                autoencoder_minutes=args.autoencoder_minutes, masked_minutes=args.masked_minutes,
                                max_minutes=args.max_minutes, seed=args.seed, threads=args.threads, init=args.init,
                                phases=tuple(args.phases), model=model)
    except ValueError as e:
        raise UserError(str(e)) from e
    ds = training_dataset(args)
    meta = {"training_command": "motionopt " + " ".join(shlex.quote(a) for a in sys.argv[1:]),
            "data": str(Path(args.data)), "licence": args.licence}
    train_latent(ds, args.out, cfg, metadata=meta, progress=not args.quiet, force=args.force)
    if not args.quiet:
        print(f"wrote {args.out}")
    return 0


def initial_config(path: str) -> "LatentConfig":
    """The architecture of the latent checkpoint ``path`` (what --init starts from)."""
    from priors.checkpoint import load_prior, resolve_checkpoint
    from priors.latent import LatentPrior

    start = load_prior(resolve_checkpoint(path))
    if not isinstance(start, LatentPrior):
        raise UserError(f"--init {path} is a {type(start).__name__}; train-latent starts from a latent checkpoint")
    return start.config


def _task_options(p: argparse.ArgumentParser, out: str, out_dir: bool = False, out_required: bool = True) -> None:
    """The options every task command takes (``tasks.add_io_options``, and ``add_prior_options``:
    --prior, --seed, --threads), then the latent inversion's own; ``out``: what --out (or
    --out-dir) holds."""
    io = add_io_options(p, out, "write each output's inversion figures and timings, the prior and the command",
                        out_dir=out_dir, out_required=out_required)
    io.add_argument("--json", action="store_true", help="print the report as JSON")
    s = p.add_argument_group("prior and inversion")
    add_prior_options(s)
    s.add_argument("--refine", type=int, default=0, metavar="ITERS",
                   help="L-BFGS iterations refining the encoder's code toward the input (default 0: encoder only)")
    s.add_argument("--pso", type=int, default=0, metavar="ITERS", help="PSO iterations before refinement")
    s.add_argument("--reg", type=float, default=0.01,
                   help="weight keeping refined codes near the training codes' distribution")


def _settle_options(p: argparse.ArgumentParser, what: str) -> None:
    """--settle-prior and --no-settle in a group of their own."""
    g = p.add_argument_group("settling under the autoregressive prior")
    for flags, options in settle_args(what):
        g.add_argument(*flags, **options)


def _options(args: argparse.Namespace):
    from motionopt.solver import InversionOptions

    return InversionOptions(refine_iters=args.refine, pso_iters=args.pso, reg_weight=args.reg, seed=args.seed)


@dataclass
class LatentRun:
    """A latent command checked and loaded: the names of its input arguments, their
    motions, the prior and its path, where it writes (BVH files, their pictures with
    --plot, the report), and when it started."""

    args: argparse.Namespace
    names: tuple[str, ...]
    motions: list
    prior: object
    prior_path: Path
    bvhs: list[Path]
    pictures: list[Path]
    report: Path | None
    view: Path | None
    started: float


def _start(args: argparse.Namespace, names: tuple[str, ...], stems: list[str]) -> LatentRun:
    """Check every output before any work (``stems``: the names of the BVH files --out-dir
    gets; else --out), then read the inputs ``names`` (argument names) and load the
    latent prior, as the task commands do."""
    started = time.perf_counter()
    inputs = [getattr(args, n) for n in names]
    new_folder = False
    if hasattr(args, "out_dir"):
        folder = Path(args.out_dir)
        if not folder.parent.exists():
            raise UserError(f"folder {folder.parent} does not exist; create it first")
        new_folder = not folder.exists()  # made when the results are written
        bvhs = [folder / f"{stem}.bvh" for stem in stems]
    else:
        bvhs = [Path(args.out)] if args.out else []
        if bvhs and bvhs[0].suffix.lower() != ".bvh":
            raise UserError(f"--out {bvhs[0]}: the output must be a .bvh file")
    pictures = [b.with_suffix(".png") for b in bvhs] if args.plot else []
    report = report_output(args)
    view = view_output(args)
    check_paths([report, view] if new_folder else [*bvhs, *pictures, report, view], inputs, args.force)
    use_threads(args)
    motions = [load_input(args, path) for path in inputs]
    prior, prior_path = load_prior(motions[0], args, "LatentPrior")
    for path, motion in zip(inputs[1:], motions[1:]):
        missing = missing_joints(prior.spec, motion.skeleton)
        if missing:
            raise UserError(f"{path} is on another skeleton than {inputs[0]}: it lacks {', '.join(missing[:4])}"
                            f"{' ...' if len(missing) > 4 else ''}, which {prior_path.name} models for "
                            f"{inputs[0]}; {args.command} needs both motions on one skeleton")
    return LatentRun(args, names, motions, prior, prior_path, bvhs, pictures, report, view, started)


def _finish(run: LatentRun, results: list, label: str) -> int:
    """Write each result's BVH file and, with --plot, its filmstrip under the inputs (the
    result labelled ``label``); then the report (--report, --json) and what was written."""
    from motionopt import bvh

    args = run.args
    if run.bvhs:
        run.bvhs[0].parent.mkdir(exist_ok=True)
    for result, path in zip(results, run.bvhs):
        bvh.save(result.motion, path, force=args.force)
    rows = {n.upper() if len(run.names) > 1 else n: m for n, m in zip(run.names, run.motions)}
    for result, picture in zip(results, run.pictures):
        filmstrip({**rows, label: result.motion}, picture)
    if run.view is not None:
        from motionopt.view import write_view

        outs = {f"{label} {i}" if len(results) > 1 else label: r.motion for i, r in enumerate(results)}
        write_view(run.view, {**rows, **outs}, overlay=len(rows) == 1 and len(outs) == 1, force=True,
                   title=f"{args.command}: {', '.join(str(getattr(args, n)) for n in run.names)}")
    outputs = [{"output": str(p), "picture": str(run.pictures[i]) if run.pictures else None, **r.report()}
               for i, (r, p) in enumerate(zip(results, run.bvhs))]
    if run.report is not None:
        write_json(run.report, {"command": command_line(args, run.prior_path, run.names), "task": args.command,
                                "inputs": [str(getattr(args, n)) for n in run.names], "prior": str(run.prior_path),
                                "seconds": time.perf_counter() - run.started, "outputs": outputs})
    if args.json:
        print(json_text(outputs))
    elif not args.quiet:
        for out in outputs:
            extra = "" if out["objective"] is None else \
                f", objective {out['objective_start']:.4g} -> {out['objective']:.4g} in {out['nit']} iterations"
            print(f"wrote {out['output']} ({out['frames']} frames at {out['fps']:g} fps, {out['windows']} windows, "
                  f"{out['timings'].get('total', 0):.2f} s{extra})")
        for path in filter(None, (*run.pictures, run.view, run.report)):
            print(f"wrote {path}")
    return 0


def cmd_fuse(args: argparse.Namespace) -> int:
    from problems.latent import fuse

    run = _start(args, ("a", "b"), [])
    a, b = run.motions
    return _finish(run, [fuse(run.prior, a, b, args.at, _options(args))], "fused")


def cmd_edit(args: argparse.Namespace) -> int:
    from problems.latent import directions
    from problems.latent_edit import latent_edit

    if args.attribute != "list" and not args.out:
        raise UserError("--out is required (or use --attribute list)")
    run = _start(args, ("input",), [])
    if args.attribute == "list":
        for name, d in sorted(directions(run.prior).items()):
            print(f"{name:>24}: classifier accuracy {d.accuracy:.2f} ({d.source})")
        return 0
    result = latent_edit(run.prior, run.motions[0], args.attribute, args.strength, _options(args))
    code = _finish(run, [result], f"{args.attribute} {args.strength:+g}")
    if "goal_summary" in result.metrics and not (args.quiet or args.json):
        print(result.metrics["goal_summary"])
    return code


def cmd_vary(args: argparse.Namespace) -> int:
    from problems.latent import vary

    stem = Path(args.input).stem + "_var"
    run = _start(args, ("input",), [f"{stem}_{i:02d}" for i in range(args.count)])
    return _finish(run, vary(run.prior, run.motions[0], args.count, args.sigma, args.seed, _options(args),
                             settle_prior(args, run.motions[0])), "variation")


def cmd_interpolate(args: argparse.Namespace) -> int:
    from problems.latent import interpolate

    stem = f"{Path(args.a).stem}_to_{Path(args.b).stem}"
    run = _start(args, ("a", "b"), [f"{stem}_{i:02d}" for i in range(args.steps)])
    a, b = run.motions
    return _finish(run, interpolate(run.prior, a, b, args.steps, _options(args), settle_prior(args, a)),
                   "interpolated")
