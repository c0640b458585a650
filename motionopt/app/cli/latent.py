"""Commands of the latent (W+) prior: train-latent, fuse, latent-edit, vary, interpolate."""
from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

from . import UserError, add_common
from .prior import add_training_data_args, add_training_run_args, training_dataset


def register(sub) -> None:
    p = sub.add_parser("train-latent", help="train a latent (W+) prior on a folder of BVH files",
                       description="Train the latent prior (GAN, then encoder, then masked encoder) on every "
                       "BVH file under --data. Resumes from OUT.train-state.pt when it exists; logs to OUT.log.")
    add_training_data_args(p)
    p.add_argument("--gan-epochs", type=int, default=60)
    p.add_argument("--encoder-epochs", type=int, default=20)
    p.add_argument("--masked-epochs", type=int, default=20)
    p.add_argument("--epoch-steps", type=int, default=200, help="optimiser steps per epoch (default 200)")
    p.add_argument("--gan-minutes", type=float, default=None, help="stop the GAN phase after this much time")
    p.add_argument("--encoder-minutes", type=float, default=None)
    p.add_argument("--masked-minutes", type=float, default=None)
    p.add_argument("--max-minutes", type=float, default=None,
                   help="stop this run after this much time (run the same command again to resume)")
    p.add_argument("--tiny", action="store_true", help="a very small network (for tests and trials)")
    add_training_run_args(p)
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("fuse", help="join two motions at a frame through the latent prior (MoDi fusion)",
                       description="Frames of A before --at, then frames of B from --at (B's root continues "
                       "from A's), passed through the latent prior's encoder and generator.")
    p.add_argument("a", help="BVH file whose start is kept")
    p.add_argument("b", help="BVH file whose end is kept")
    p.add_argument("--at", type=int, required=True, help="frame (of the files) where A hands over to B")
    _inversion_args(p)
    p.set_defaults(func=cmd_fuse)

    p = sub.add_parser("latent-edit", help="strengthen or weaken an attribute by moving in the latent space",
                       description="Encode the motion into W+, move along the attribute's direction in W "
                       "(strength in standard deviations of W), generate. Attributes: gral (gradual right-arm "
                       "lift), root_speed, crouch, and style:NAME for priors trained on Bandai clips; "
                       "`--attribute list` prints those of the prior.")
    p.add_argument("input", help="BVH file")
    p.add_argument("--attribute", required=True, help="attribute name, or 'list'")
    p.add_argument("--strength", type=float, default=1.0, help="standard deviations of W along the direction")
    _inversion_args(p, out_required=False)
    p.set_defaults(func=cmd_edit)

    p = sub.add_parser("vary", help="variations of a motion: random offsets around its latent code")
    p.add_argument("input", help="BVH file")
    p.add_argument("--count", type=int, default=8)
    p.add_argument("--sigma", type=float, default=0.3, help="offset size in standard deviations of W (0.1-0.8)")
    p.add_argument("--seed", type=int, default=0)
    _inversion_args(p, out_dir=True)
    p.set_defaults(func=cmd_vary)

    p = sub.add_parser("interpolate", help="motions between two motions, by interpolating their latent codes")
    p.add_argument("a", help="first BVH file")
    p.add_argument("b", help="second BVH file (same skeleton)")
    p.add_argument("--steps", type=int, default=5, help="number of motions, both ends included")
    _inversion_args(p, out_dir=True)
    p.set_defaults(func=cmd_interpolate)



TINY = {"z_dim": 16, "w_dim": 16, "mapping_layers": 2, "channels": (32, 32, 24, 16, 16),
        "encoder_channels": (16, 16, 24, 24), "encoder_hidden": 32}


def cmd_train(args: argparse.Namespace) -> int:
    from priors.latent import LatentConfig
    from priors.train_latent import LatentTrainConfig, train_latent

    ds = training_dataset(args)
    cfg = LatentTrainConfig(gan_epochs=args.gan_epochs, encoder_epochs=args.encoder_epochs,
                            masked_epochs=args.masked_epochs, epoch_steps=args.epoch_steps,
                            gan_minutes=args.gan_minutes, encoder_minutes=args.encoder_minutes,
                            masked_minutes=args.masked_minutes, max_minutes=args.max_minutes, seed=args.seed, threads=args.threads,
                            model=LatentConfig(**TINY) if args.tiny else LatentConfig())
    meta = {"training_command": "motionopt " + " ".join(shlex.quote(a) for a in sys.argv[1:]),
            "data": str(Path(args.data)), "licence": args.licence}
    train_latent(ds, args.out, cfg, metadata=meta, progress=not args.quiet, force=args.force)
    if not args.quiet:
        print(f"wrote {args.out}")
    return 0


def _inversion_args(p: argparse.ArgumentParser, out_dir: bool = False, out_required: bool = True) -> None:
    if out_dir:
        p.add_argument("--out-dir", required=True, help="folder for the output BVH files")
    else:
        p.add_argument("--out", required=out_required, help="output BVH file")
    p.add_argument("--prior", default=None, help="latent checkpoint (default: the shipped one matching the skeleton)")
    p.add_argument("--refine", type=int, default=0, metavar="ITERS",
                   help="L-BFGS iterations refining the encoder's code toward the input (default 0: encoder only)")
    p.add_argument("--pso", type=int, default=0, metavar="ITERS", help="PSO iterations before refinement")
    p.add_argument("--reg", type=float, default=0.05, help="weight keeping refined codes near the mapping's distribution")
    p.add_argument("--fps", type=float, default=None, help="override the files' frame rate")
    p.add_argument("--unit", default="auto", help="length unit of the files: cm, m, mm, in or auto")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    add_common(p)


def _options(args: argparse.Namespace):
    from motionopt.solver import InversionOptions

    return InversionOptions(refine_iters=args.refine, pso_iters=args.pso, reg_weight=args.reg)


def _load(path: str, args: argparse.Namespace):
    from motionopt import bvh

    return bvh.load(path, unit=args.unit, fps=args.fps)


def _report(args: argparse.Namespace, results: list, paths: list[Path]) -> None:
    if args.json:
        print(json.dumps([{"output": str(p), **r.report()} for r, p in zip(results, paths)], indent=2))
        return
    if args.quiet:
        return
    for r, p in zip(results, paths):
        rep = r.report()
        extra = "" if rep["objective"] is None else \
            f", objective {rep['objective_start']:.4g} -> {rep['objective']:.4g} in {rep['nit']} iterations"
        print(f"wrote {p} ({rep['frames']} frames at {rep['fps']:g} fps, {rep['windows']} windows, "
              f"{rep['timings'].get('total', 0):.2f} s{extra})")


def _save_all(args: argparse.Namespace, results: list, stem: str) -> list[Path]:
    from motionopt import bvh

    folder = Path(args.out_dir)
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / f"{stem}_{i:02d}.bvh" for i in range(len(results))]
    existing = [p for p in paths if p.exists()]
    if existing and not args.force:
        raise FileExistsError(f"{existing[0]} exists; pass --force to overwrite")
    for r, p in zip(results, paths):
        bvh.save(r.motion, p, force=args.force)
    return paths


def cmd_fuse(args: argparse.Namespace) -> int:
    from motionopt import bvh
    from problems.latent import fuse, load_latent_for

    a, b = _load(args.a, args), _load(args.b, args)
    prior = load_latent_for(a, args.prior)
    result = fuse(prior, a, b, args.at, _options(args))
    bvh.save(result.motion, args.out, force=args.force)
    _report(args, [result], [Path(args.out)])
    return 0


def cmd_edit(args: argparse.Namespace) -> int:
    from motionopt import bvh
    from problems.latent import directions, latent_edit, load_latent_for

    motion = _load(args.input, args)
    prior = load_latent_for(motion, args.prior)
    if args.attribute == "list":
        for name, d in sorted(directions(prior).items()):
            print(f"{name:>24}: classifier accuracy {d.accuracy:.2f} ({d.source})")
        return 0
    if not args.out:
        raise UserError("--out is required (or use --attribute list)")
    result = latent_edit(prior, motion, args.attribute, args.strength, _options(args))
    bvh.save(result.motion, args.out, force=args.force)
    _report(args, [result], [Path(args.out)])
    return 0


def cmd_vary(args: argparse.Namespace) -> int:
    from problems.latent import load_latent_for, vary

    motion = _load(args.input, args)
    prior = load_latent_for(motion, args.prior)
    results = vary(prior, motion, args.count, args.sigma, args.seed, _options(args))
    _report(args, results, _save_all(args, results, Path(args.input).stem + "_var"))
    return 0


def cmd_interpolate(args: argparse.Namespace) -> int:
    from problems.latent import interpolate, load_latent_for

    a, b = _load(args.a, args), _load(args.b, args)
    prior = load_latent_for(a, args.prior)
    results = interpolate(prior, a, b, args.steps, _options(args))
    _report(args, results, _save_all(args, results, f"{Path(args.a).stem}_to_{Path(args.b).stem}"))
    return 0
