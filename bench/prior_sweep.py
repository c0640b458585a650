"""Sweep of train-prior settings: train several priors side by side, compare them.

Each setting is a list of ``motionopt train-prior`` options; the sweep parses them with
the command's own parser and trains with the same code, so the winner's checkpoint
records the command that reproduces it. Training data is prepared once (``prepare``,
where the BVH files are) into one file that travels to a machine without them (the
lent GPU machine), where ``run`` trains every setting in its own process and scores
each checkpoint:

- validation NLL per frame, mean and median, from the training log;
- rollouts: ``--seconds`` from 1 s of each held-out clip's context, at temperatures 0.3
  and 1, with and without foot planting: joint speed over the held-out data's, and
  foot skating over the data's (as ``bench/prior.py``, which gives the full figures).

    python bench/prior_sweep.py prepare --like priors/checkpoints/cmu-ccnet.pt --out sweep/data.pt
    python bench/prior_sweep.py run --prepared sweep/data.pt --out sweep --device cuda
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import shlex
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
import prior as bench_prior  # noqa: E402  (bench/prior.py)

from motionopt.app.cli import build_parser  # noqa: E402
from motionopt.app.cli.prior import train_config, train_metadata  # noqa: E402
from priors.heldout import held_out_clips  # noqa: E402
from priors.temperature import window_speed_ratios  # noqa: E402

#: Settings tried: name -> train-prior options beyond those of the checkpoint it is like.
SETTINGS: dict[str, list[str]] = {
    "base": [],
    "passes4": ["--passes", "4"],
    "regular": ["--noise-std", "0.1", "--input-dropout", "0.3"],
    "small": ["--channels", "32"],
    "floor-3": ["--log-std-min", "-3"],
    "smooth50": ["--smooth-weight", "50"],
    "passes4-regular": ["--passes", "4", "--noise-std", "0.1", "--input-dropout", "0.3"],
    "small-floor-3": ["--channels", "32", "--log-std-min", "-3"],
    "passes3-floor-4": ["--passes", "3", "--noise-std", "0.1", "--input-dropout", "0.2", "--log-std-min", "-4"],
}


def base_options(like: dict, out: Path) -> list[str]:
    """train-prior options of the checkpoint metadata ``like``, writing to ``out``; options
    given after these win (argparse keeps the last), so settings are simply appended."""
    return [*shlex.split(like["training_command"])[2:], "--out", str(out)]


def prepare(like: Path, out: Path) -> None:
    """Build the dataset and held-out clips of checkpoint ``like`` once, into ``out``."""
    from priors.checkpoint import read_checkpoint

    meta = read_checkpoint(like)["metadata"]
    args = build_parser().parse_args(["train-prior", *base_options(meta, out), "-q"])
    from motionopt.dataset import build_dataset
    from priors.checkpoint import load_prior

    ds = build_dataset(args.data, fps=args.fps, val=args.val, unit=args.unit, include=args.include)
    for split in (ds.train, ds.val):  # half the size to travel; windows are float32 anyway
        split.update({k: v.float() for k, v in split.items()})
    clips = held_out_clips(load_prior(like), Path(args.data))
    out.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"dataset": ds, "clips": clips, "meta": meta}, out)
    print(f"wrote {out}: {len(ds.train)} training clips ({ds.num_train_frames} frames), {len(clips)} held out")


def rollout_scores(prior, clips, seconds: float) -> dict[str, float]:
    """Per temperature and with or without planting: mean joint speed over the data's, the
    share of 5 s windows inside 0.3-3 times it, and skating over the data's."""
    fps = prior.spec.fps
    data_speed, data_skate = bench_prior.data_reference(prior, clips)
    out = {}
    for plant in (False, True):
        for temperature in (0.3, 1.0):
            runs = bench_prior.rollouts(prior, clips, seconds, 1, temperature, plant=plant)
            ratios = [r for _, pos in runs for r in window_speed_ratios(pos, fps, data_speed)]
            key = f"T{temperature:g}{'-plant' if plant else ''}"
            out[f"{key} speed"] = statistics.mean(ratios)
            out[f"{key} inside"] = sum(0.3 <= r <= 3 for r in ratios) / len(ratios)
            out[f"{key} skate"] = statistics.mean(bench_prior.skating(prior, pos, c) for c, pos in runs) / data_skate
    return out


def train_and_score(name: str, argv: list[str], prepared: Path, seconds: float) -> None:
    """One setting: train, then score on the CPU; writes NAME.json beside the checkpoint."""
    from priors.train import train_prior

    torch.set_num_threads(1)
    data = torch.load(prepared, weights_only=False)  # our own file, written by ``prepare``
    args = build_parser().parse_args(["train-prior", *argv, "-q"])
    t0 = time.perf_counter()
    train_prior(data["dataset"], args.out, train_config(args), metadata=train_metadata(args), progress=False,
                force=True)
    minutes = (time.perf_counter() - t0) / 60
    from priors.checkpoint import load_prior

    prior = load_prior(args.out)  # the selected epoch, as shipped
    hist = prior.metadata["history"]
    best = next(r for r in hist if r["epoch"] == prior.metadata["selected_epoch"])
    result = {"name": name, "options": argv, "minutes": minutes, "epochs": len(hist),
              "selected_epoch": best["epoch"], "val_mean": best["val_nll_per_frame"],
              "val_median": best["val_nll_median"], **rollout_scores(prior, data["clips"], seconds)}
    Path(args.out).with_suffix(".json").write_text(json.dumps(result, indent=1))
    print(f"{name}: done in {minutes:.1f} min of training", flush=True)


def run(prepared: Path, out: Path, device: str, names: list[str], seconds: float, max_minutes: float,
        epochs: int | None) -> None:
    """Every setting in its own process at once; then a table of their scores."""
    meta = torch.load(prepared, weights_only=False)["meta"]
    out.mkdir(parents=True, exist_ok=True)
    ctx = mp.get_context("spawn")
    procs = []
    for name in names:
        argv = base_options(meta, out / f"{name}.pt") + SETTINGS[name] + ["--device", device,
                                                                          "--max-minutes", f"{max_minutes:g}"]
        if epochs:
            argv += ["--epochs", str(epochs)]
        p = ctx.Process(target=train_and_score, args=(name, argv, prepared, seconds))
        p.start()
        procs.append(p)
    for p in procs:
        p.join()
    results = [json.loads((out / f"{n}.json").read_text()) for n in names if (out / f"{n}.json").exists()]
    if not results:
        raise SystemExit("no setting finished")
    keys = [k for k in results[0] if k not in ("name", "options")]
    rows = [["setting", *keys]] + [[r["name"], *(f"{r[k]:.3g}" for k in keys)] for r in results]
    text = bench_prior.table(rows)
    print(text)
    (out / "summary.txt").write_text(text + "\n" + "\n".join(f"{r['name']}: {' '.join(r['options'])}"
                                                             for r in results) + "\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("prepare", help="build the training data of a checkpoint's command into one file")
    p.add_argument("--like", type=Path, required=True, help="checkpoint whose data, split and settings to use")
    p.add_argument("--out", type=Path, required=True)
    p = sub.add_parser("run", help="train and score every setting")
    p.add_argument("--prepared", type=Path, required=True)
    p.add_argument("--out", type=Path, required=True, help="folder for checkpoints, logs and scores")
    p.add_argument("--device", default="cpu")
    p.add_argument("--settings", nargs="*", default=list(SETTINGS), choices=list(SETTINGS))
    p.add_argument("--seconds", type=float, default=20.0, help="rollout length (default 20)")
    p.add_argument("--max-minutes", type=float, default=6.0, help="training time limit per setting (default 6)")
    p.add_argument("--epochs", type=int, default=None, help="override the checkpoint's epochs")
    args = ap.parse_args()
    if args.cmd == "prepare":
        prepare(args.like, args.out)
    else:
        run(args.prepared, args.out, args.device, args.settings, args.seconds, args.max_minutes, args.epochs)


if __name__ == "__main__":
    main()
