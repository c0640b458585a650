"""Commands of the latent (W+) prior: train-latent, fuse, latent-edit, vary, interpolate."""
from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from . import UserError, add_common


def register(sub) -> None:
    p = sub.add_parser("train-latent", help="train a latent (W+) prior on a folder of BVH files",
                       description="Train the latent prior (GAN, then encoder, then masked encoder) on every "
                       "BVH file under --data. Resumes from OUT.train-state.pt when it exists; logs to OUT.log.")
    p.add_argument("--data", required=True, help="folder of BVH files (searched recursively)")
    p.add_argument("--out", required=True, help="checkpoint file to write")
    p.add_argument("--val", nargs="*", default=None,
                   help="clips to hold out (paths relative to --data, patterns allowed); "
                   "default: the last clip of each sub-folder, or every 10th clip")
    p.add_argument("--include", nargs="*", default=None, help="train only on clips matching these patterns")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate the prior models (default 30)")
    p.add_argument("--unit", default="auto", help="length unit of the files: cm, m, mm, in or auto")
    p.add_argument("--gan-epochs", type=int, default=60)
    p.add_argument("--encoder-epochs", type=int, default=20)
    p.add_argument("--masked-epochs", type=int, default=20)
    p.add_argument("--epoch-steps", type=int, default=200, help="optimiser steps per epoch (default 200)")
    p.add_argument("--gan-minutes", type=float, default=None, help="stop the GAN phase after this much time")
    p.add_argument("--encoder-minutes", type=float, default=None)
    p.add_argument("--masked-minutes", type=float, default=None)
    p.add_argument("--tiny", action="store_true", help="a very small network (for tests and trials)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=None, help="CPU threads for torch")
    p.add_argument("--licence", default="same as the training data", help="licence of the trained weights")
    p.add_argument("--force", action="store_true", help="overwrite OUT when there is no state to resume")
    add_common(p)
    p.set_defaults(func=cmd_train)


TINY = {"z_dim": 16, "w_dim": 16, "mapping_layers": 2, "channels": (32, 32, 24, 16, 16),
        "encoder_channels": (16, 16, 24, 24), "encoder_hidden": 32}


def cmd_train(args: argparse.Namespace) -> int:
    from motionopt.dataset import build_dataset
    from priors.latent import LatentConfig
    from priors.train_latent import LatentTrainConfig, train_latent

    ds = build_dataset(args.data, fps=args.fps, val=args.val, unit=args.unit, include=args.include)
    if not args.quiet:
        print(f"{len(ds.train)} training clips ({ds.num_train_frames} frames at {ds.spec.fps:g} fps), "
              f"{len(ds.val)} held out; prepared in {ds.seconds_to_build:.1f} s")
    cfg = LatentTrainConfig(gan_epochs=args.gan_epochs, encoder_epochs=args.encoder_epochs,
                            masked_epochs=args.masked_epochs, epoch_steps=args.epoch_steps,
                            gan_minutes=args.gan_minutes, encoder_minutes=args.encoder_minutes,
                            masked_minutes=args.masked_minutes, seed=args.seed, threads=args.threads,
                            model=LatentConfig(**TINY) if args.tiny else LatentConfig())
    meta = {"training_command": "motionopt " + " ".join(shlex.quote(a) for a in sys.argv[1:]),
            "data": str(Path(args.data)), "licence": args.licence}
    train_latent(ds, args.out, cfg, metadata=meta, progress=not args.quiet, force=args.force)
    if not args.quiet:
        print(f"wrote {args.out}")
    return 0
