"""Commands about priors: train-prior, pool-priors, prior-info, score."""
from __future__ import annotations

import argparse
import json
import shlex
from pathlib import Path

from . import UserError, add_common

#: Defaults of the train-prior options that map onto ``TrainConfig`` and ``CCNetConfig``
#: (written out so that the parser does not import torch).
TRAIN_DEFAULTS = {"batch_size": 32, "noise_std": 0.03, "smooth_weight": 10.0, "channels": 64,
                  "input_dropout": 0.1, "log_std_min": -5.0, "std_floor": 0.0, "stride": 8,
                  "contrast_weight": 1.0, "contrast_margin": 0.1,
                  "rollout_frames": 0, "rollout_temperature": 0.5, "tail_dof": 0.0}


def register(sub) -> None:
    p = sub.add_parser("train-prior", help="train an autoregressive prior on a folder of BVH files",
                       description="Train the causal-convolution prior on every BVH file under --data. "
                       "Resumes from OUT.train-state.pt when it exists; logs to OUT.log.")
    add_training_data_args(p)
    p.add_argument("--epochs", type=int, default=40)
    p.add_argument("--window", type=int, default=96, help="frames per training window (default 96; "
                   "clips shorter than this, down to 8 frames, are padded)")
    p.add_argument("--max-minutes", type=float, default=None, help="stop after this much training time")
    p.add_argument("--passes", type=int, default=2,
                   help="passes per batch; passes after the first learn from the model's own predictions "
                   "(default 2; 1 is plain teacher forcing)")
    d = TRAIN_DEFAULTS
    p.add_argument("--batch-size", type=int, default=d["batch_size"], help=f"windows per step (default {d['batch_size']})")
    p.add_argument("--noise-std", type=float, default=d["noise_std"],
                   help=f"std of the noise added to the history in normalised units (default {d['noise_std']:g})")
    p.add_argument("--smooth-weight", type=float, default=d["smooth_weight"],
                   help=f"weight of the smoothness of the predicted means (default {d['smooth_weight']:g})")
    p.add_argument("--channels", type=int, default=d["channels"],
                   help=f"residual channels of the network; skip channels are twice this (default {d['channels']})")
    p.add_argument("--input-dropout", type=float, default=d["input_dropout"],
                   help=f"dropout on the input features (default {d['input_dropout']:g})")
    p.add_argument("--log-std-min", type=float, default=d["log_std_min"],
                   help=f"floor of the predicted log-std, normalised units (default {d['log_std_min']:g})")
    p.add_argument("--std-floor", type=float, default=d["std_floor"],
                   help="floor of the predicted std in the features' own units (6D rotation components, "
                   "metres), so that dimensions nearly still in training are not scored as certain "
                   f"(default {d['std_floor']:g}: none)")
    p.add_argument("--tail-dof", type=float, default=d["tail_dof"],
                   help="score each dimension by a Student-t with these degrees of freedom instead of a Gaussian "
                   "(heavier tails: a few dimensions far from the prediction cost less; default 0: Gaussian)")
    p.add_argument("--stride", type=int, default=d["stride"],
                   help=f"frames between the starts of training windows (default {d['stride']})")
    p.add_argument("--contrast-weight", type=float, default=d["contrast_weight"],
                   help="weight of the ranking loss that keeps degraded copies of each window (frozen, low-passed, "
                   "slowed, sped up, noisy) a margin above the real window's NLL "
                   f"(default {d['contrast_weight']:g}; 0: likelihood alone, which prefers still, smooth motion)")
    p.add_argument("--contrast-margin", type=float, default=d["contrast_margin"],
                   help=f"that margin in nats per frame and moving dimension (default {d['contrast_margin']:g})")
    p.add_argument("--absolute-pose", action="store_true",
                   help="predict the joint rotations directly, not as changes from the previous frame")
    p.add_argument("--absolute-joints", nargs="+", default=(), metavar="JOINT",
                   help="predict these joints' rotations directly (the root's: its tilt) and the rest as changes, "
                   "e.g. the legs, so that rollouts keep their feet under the predicted hip height")
    p.add_argument("--rollout-frames", type=int, default=d["rollout_frames"],
                   help="frames at the end of each window predicted, in an extra pass, from the model's own "
                   "free-running draws, so that it learns to steer back from the drift of long rollouts "
                   f"(default {d['rollout_frames']}: none)")
    p.add_argument("--rollout-temperature", type=float, default=d["rollout_temperature"],
                   help=f"temperature of those draws (default {d['rollout_temperature']:g})")
    p.add_argument("--init", default=None, help="start from this checkpoint's weights and normaliser (fine-tuning; "
                   "a file or a shipped checkpoint's name); its architecture wins over --channels and the like")
    p.add_argument("--device", default="cpu", help="torch device to train on: cpu (default) or cuda")
    add_training_run_args(p)
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("pool-priors", help="pool a change-predicting prior with an absolute-pose anchor",
                       description="Make one autoregressive prior of two trained on the same clips: PRIOR "
                       "(its changes of the pose are sharp one step ahead) and ANCHOR (trained with "
                       "train-prior --absolute-pose: it keeps long rollouts from drifting). Their next-frame "
                       "Gaussians are pooled geometrically with the anchor's weight; the sampling temperature "
                       "is calibrated again on PRIOR's training clips (needs its data folder).")
    p.add_argument("prior", help="change-predicting checkpoint (a file or a shipped checkpoint's name)")
    p.add_argument("anchor", help="absolute-pose checkpoint trained on the same clips")
    p.add_argument("--weight", type=float, default=0.5, help="the anchor's weight in the pool (default 0.5)")
    p.add_argument("--out", required=True, help="checkpoint file to write")
    p.add_argument("--seed", type=int, default=0, help="seed of the calibration rollouts")
    p.add_argument("--force", action="store_true", help="overwrite OUT")
    add_common(p)
    p.set_defaults(func=cmd_pool)

    p = sub.add_parser("prior-info", help="print a prior checkpoint's metadata, or list the shipped ones",
                       description="Print the metadata of a checkpoint (a file, or a shipped checkpoint by name, "
                       "such as cmu-ccnet.pt); --list lists the shipped checkpoints.")
    p.add_argument("checkpoint", nargs="?", help="checkpoint file (.pt) or a shipped checkpoint's name")
    p.add_argument("--list", action="store_true",
                   help="list the shipped checkpoints: name, kind, skeleton, frame rate, size")
    p.add_argument("--json", action="store_true", help="print JSON")
    add_common(p)
    p.set_defaults(func=cmd_info)

    p = sub.add_parser("score", help="how natural a clip is under a prior (per-frame NLL, worst stretches)")
    p.add_argument("input", help="BVH file")
    p.add_argument("--prior", default=None, help="autoregressive checkpoint, a file or a shipped checkpoint's name "
                   "(default: the shipped one matching the skeleton)")
    p.add_argument("--fps", type=float, default=None, help="override the file's frame rate")
    p.add_argument("--unit", default="auto", help="length unit of the file: cm, m, mm, in or auto")
    p.add_argument("--copies", action="store_true",
                   help="also score degraded copies of the clip (1 cm noise, low-passed at 2 and 1 Hz, frozen, "
                   "half and double speed) and say whether the prior ranks the clip above each")
    p.add_argument("--json", action="store_true", help="print JSON (key nll_per_frame)")
    add_common(p)
    p.set_defaults(func=cmd_score)


def add_training_data_args(p: argparse.ArgumentParser) -> None:
    """Options of every training command that say what to train on and where to write."""
    p.add_argument("--data", required=True, help="folder of BVH files (searched recursively)")
    p.add_argument("--out", required=True, help="checkpoint file to write")
    p.add_argument("--val", nargs="*", default=None,
                   help="clips to hold out (paths relative to --data, patterns allowed); "
                   "default: the last clip of each sub-folder, or every 10th clip")
    p.add_argument("--include", nargs="*", default=None, help="train only on clips matching these patterns")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate the prior models (default 30)")
    p.add_argument("--unit", default="auto", help="length unit of the files: cm, m, mm, in or auto")
    p.add_argument("--mirror", action="store_true",
                   help="also train on each training clip's left/right mirror image (twice the data; the skeleton "
                   "must be symmetric, as CMU's is)")


def add_training_run_args(p: argparse.ArgumentParser) -> None:
    """Options of every training command about the run: seed, threads, licence, overwrite."""
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=None, help="CPU threads for torch")
    p.add_argument("--licence", default="same as the training data", help="licence of the trained weights")
    p.add_argument("--force", action="store_true", help="overwrite OUT when there is no state to resume")
    add_common(p)


def training_dataset(args: argparse.Namespace):
    """The dataset the training options name, with a one-line summary unless --quiet."""
    from motionopt.dataset import build_dataset

    ds = build_dataset(args.data, fps=args.fps, val=args.val, unit=args.unit, include=args.include,
                       mirror=args.mirror)
    if not args.quiet:
        print(f"{len(ds.train)} training clips ({ds.num_train_frames} frames at {ds.spec.fps:g} fps), "
              f"{len(ds.val)} held out; prepared in {ds.seconds_to_build:.1f} s")
    return ds


def train_config(args: argparse.Namespace):
    """The ``TrainConfig`` that parsed train-prior options ask for."""
    from priors.ccnet import CCNetConfig
    from priors.train import TrainConfig

    model = CCNetConfig(channels=args.channels, skip_channels=2 * args.channels, input_dropout=args.input_dropout,
                        log_std_min=args.log_std_min, std_floor=args.std_floor, absolute_pose=args.absolute_pose,
                        absolute_joints=tuple(args.absolute_joints), tail_dof=args.tail_dof)
    return TrainConfig(epochs=args.epochs, window=args.window, seed=args.seed, max_minutes=args.max_minutes,
                       threads=args.threads, passes=args.passes, batch_size=args.batch_size,
                       noise_std=args.noise_std, smooth_weight=args.smooth_weight, device=args.device, model=model,
                       stride=args.stride, contrast_weight=args.contrast_weight, contrast_margin=args.contrast_margin,
                       rollout_frames=args.rollout_frames, rollout_temperature=args.rollout_temperature,
                       init=args.init)


def train_metadata(args: argparse.Namespace) -> dict:
    """What a checkpoint records of the train-prior command that made it."""
    return {"training_command": train_command(args), "data": str(Path(args.data)), "licence": args.licence}


def cmd_train(args: argparse.Namespace) -> int:
    from priors.train import train_prior

    ds = training_dataset(args)
    train_prior(ds, args.out, train_config(args), metadata=train_metadata(args), progress=not args.quiet,
                force=args.force)
    if not args.quiet:
        print(f"wrote {args.out}")
    return 0


def cmd_pool(args: argparse.Namespace) -> int:
    from priors.checkpoint import save_prior
    from priors.pool import calibrate_pooled, pool_priors

    out = Path(args.out)
    if out.exists() and not args.force:
        raise UserError(f"{out} exists; pass --force to overwrite it")
    try:
        pooled = pool_priors(args.prior, args.anchor, args.weight)
    except ValueError as e:
        raise UserError(str(e)) from None
    pooled.metadata["pool_command"] = " ".join(shlex.quote(w) for w in (
        "motionopt", "pool-priors", args.prior, args.anchor, "--weight", f"{args.weight:g}", "--out", args.out,
        "--seed", str(args.seed)))
    try:
        temperature = calibrate_pooled(pooled, args.seed)
    except (FileNotFoundError, KeyError) as e:
        raise UserError(f"{args.prior}: its training clips could not be read to calibrate the pool ({e})") from None
    save_prior(pooled, out)
    if not args.quiet:
        print(f"wrote {out} (anchor weight {args.weight:g}, sampling temperature {temperature:g})")
    return 0


def train_command(args: argparse.Namespace) -> str:
    """The full train-prior command line, defaults included, that reproduces a training."""
    words = ["motionopt", "train-prior", "--data", args.data, "--out", args.out, "--fps", f"{args.fps:g}",
             "--unit", args.unit, "--epochs", str(args.epochs), "--window", str(args.window),
             "--passes", str(args.passes), "--seed", str(args.seed),
             "--licence", args.licence]
    d = TRAIN_DEFAULTS
    for key in d:  # model and loss settings, where they differ from the defaults
        if getattr(args, key) != d[key]:
            words += ["--" + key.replace("_", "-"), f"{getattr(args, key):g}"]
    if args.device != "cpu":
        words += ["--device", args.device]
    for flag, values in (("--val", args.val), ("--include", args.include)):
        if values is not None:
            words += [flag, *values]
    for flag, value in (("--max-minutes", args.max_minutes), ("--threads", args.threads)):
        if value is not None:
            words += [flag, f"{value:g}"]
    return " ".join(shlex.quote(str(w)) for w in words)


def cmd_info(args: argparse.Namespace) -> int:
    from priors.checkpoint import read_checkpoint, resolve_checkpoint

    if args.list:
        if args.checkpoint:
            raise UserError(f"--list lists the shipped checkpoints; drop {args.checkpoint} or --list")
        return list_shipped(args)
    if not args.checkpoint:
        raise UserError("name a checkpoint (a file, or a shipped one such as cmu-ccnet.pt), or pass --list")
    data = read_checkpoint(resolve_checkpoint(args.checkpoint))
    meta = data["metadata"]
    hist = meta.get("history", [])
    info = {
        "kind": data["kind"],
        "licence": meta.get("licence"),
        "feature_version": data["spec"]["version"],
        "fps": data["spec"]["fps"],
        "joints": data["spec"]["joints"],
        "contact_joints": data["spec"]["contact_joints"],
        "feature_dim": len(data["normalizer"]["mean"]),
        "parameters": sum(v.numel() for v in data["state_dict"].values()),
        "architecture": data["config"],
        "data": meta.get("data"),
        "training_command": meta.get("training_command"),
        "anchor_training_command": meta.get("anchor", {}).get("training_command"),
        "anchor_weight": data["config"].get("anchor_weight") if data["config"].get("anchor") else None,
        "pool_command": meta.get("pool_command"),
        "train_clips": len(meta.get("train_clips", [])),
        "train_frames": meta.get("train_frames"),
        "validation_clips": meta.get("validation_clips"),
        "epochs": meta.get("epochs_done"),
        "training_minutes": meta.get("training_minutes"),
        "selected_epoch": meta.get("selected_epoch"),
        "val_nll_per_frame": next((r.get("val_nll_per_frame") for r in hist
                                   if r["epoch"] == meta.get("selected_epoch")), None),
        "val_nll_median": next((r.get("val_nll_median") for r in hist
                                if r["epoch"] == meta.get("selected_epoch")), None),
        "final_validation": {k: v for k, v in hist[-1].items() if k.startswith("val_")} if hist else None,
        "sample_temperature": meta.get("sample_temperature"),
        "semantic_attributes": sorted(meta.get("attribute_directions", {})) or None,
        "style_heldout_accuracy": meta.get("style_classifier", {}).get("heldout_accuracy"),
    }
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    for k, v in info.items():
        if isinstance(v, (list, tuple)):
            v = ", ".join(map(str, v))
        print(f"{k:>24}: {v}")
    return 0


def list_shipped(args: argparse.Namespace) -> int:
    """prior-info --list: each shipped checkpoint's name, kind, skeleton, frame rate and file size."""
    from motionopt.table import format_table
    from priors.checkpoint import CHECKPOINT_DIR, KINDS, SHIPPED, SHIPPED_LATENT, read_checkpoint, shipped_checkpoints

    rows = []
    for path in shipped_checkpoints(SHIPPED + SHIPPED_LATENT):
        data = read_checkpoint(path)
        joints = data["spec"]["joints"]
        rows.append({"name": path.name, "kind": KINDS[data["kind"]].name,
                     "skeleton": f"{len(joints)} joints from {joints[0]} ({', '.join(joints[1:4])}, ...)",
                     "fps": data["spec"]["fps"], "megabytes": path.stat().st_size / 2**20, "path": str(path)})
    if args.json:
        print(json.dumps(rows, indent=2))
    elif not args.quiet:
        table = [[r["name"], r["kind"], r["skeleton"], f"{r['fps']:g}", f"{r['megabytes']:.1f} MB"] for r in rows]
        print("\n".join(format_table(["name", "kind", "skeleton", "fps", "size"], table, indent=0)))
        print(f"in {CHECKPOINT_DIR}; pass a name to --prior or prior-info")
    return 0


def cmd_score(args: argparse.Namespace) -> int:
    from motionopt import bvh
    from priors.checkpoint import load_prior_of_kind
    from priors.score import copy_verdicts, score_motion

    motion = bvh.load(args.input, unit=args.unit, fps=args.fps)
    prior, path = load_prior_of_kind(motion.skeleton, args.prior, "CCNetPrior", "score",
                                     "a latent prior gives no per-frame likelihood to score with")
    report = score_motion(prior, motion)
    verdict = copy_verdicts(prior, motion, window_seconds=None)[0] if args.copies else None
    if args.json:
        copies = {"copies": verdict.copies, "copy_scored_nll_per_frame": verdict.real} if verdict else {}
        print(json.dumps({**report.to_dict(), **copies, "prior": str(path)}, indent=2))
    elif not args.quiet:
        print(f"{args.input}: {report.nll_per_frame:.2f} nats per frame under {path.name} "
              f"(lower is more natural; {report.frames} frames at {motion.fps:g} fps)")
        if report.worst:
            seconds = (report.worst[0][1] - report.worst[0][0]) / motion.fps
            print(f"least natural {seconds:.3g} s stretches (frames as half-open ranges of the file's):")
        for a, b, v in report.worst:
            print(f"  frames {a}:{b} ({a / motion.fps:.1f}-{b / motion.fps:.1f} s)  {v:.2f} nats per frame")
        if verdict:
            print(f"degraded copies (the clip scores {verdict.real:.2f} with heights from its own ground):")
            for name, v in verdict.copies.items():
                word = "less natural than the clip" if v > verdict.real else "MORE NATURAL than the clip"
                print(f"  {name:<14} {v:10.2f} nats per frame: {word}")
    return 0
