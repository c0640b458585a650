"""Batch throughput on the CMU folder and memory growth of each task with clip length.

    python bench/robustness.py [--workers 1 2] [--lengths 100 1000 10000]

1. ``motionopt batch denoise`` over every clip of ``../shared/data/cmu`` with 1 and 2
   workers (the same ``run_batch`` the command calls): files, frames, time, throughput.
2. Peak resident memory of one task command (a fresh process each) on clips of 100,
   1 000 and 10 000 frames, cut from a CMU clip played back and forth so that the motion
   stays continuous: the slope in KB per frame between lengths shows whether memory
   grows linearly (equal slopes) or worse.
Tables are printed and saved to ``bench/results/robustness.txt``.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from motionopt import bvh  # noqa: E402
from motionopt.app.batch import BatchPlan, find_inputs, run_batch  # noqa: E402
from motionopt.motion import Motion  # noqa: E402

CMU = ROOT.parent / "shared" / "data" / "cmu"
SOURCE = CMU / "martial" / "06.bvh"
RESULTS = ROOT / "bench" / "results" / "robustness.txt"

#: Peak RSS (KB) of a child process, printed by a wrapper so each run is measured alone.
MEASURE = ("import resource, subprocess, sys; r = subprocess.run(sys.argv[1:]); "
           "print(r.returncode, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)")


def back_and_forth(motion: Motion, n: int) -> Motion:
    """``n`` frames of the clip played forward, backward, forward...: long and continuous."""
    period = np.concatenate([np.arange(motion.num_frames), np.arange(motion.num_frames - 2, 0, -1)])
    idx = period[np.arange(n) % len(period)]
    tr = None if motion.translations is None else motion.translations[idx]
    return Motion(motion.skeleton, motion.rotations[idx], motion.root[idx], motion.fps, tr, motion.source_unit)


def task_argv(task: str, clip: Path, n: int, folder: Path) -> list[str]:
    """The command line of one memory run; synthesised frames grow with the clip."""
    out = ["--out", str(folder / f"{task.replace(' ', '-')}-{n}.bvh"), "--quiet", "--force"]
    if task == "denoise":
        return ["denoise", str(clip), *out]
    if task == "denoise --refine":
        return ["denoise", str(clip), "--refine", *out]
    if task == "inbetween":  # keep 80 of every 100 frames: a 20-frame gap per 100
        keep = ",".join(f"{a}:{min(a + 80, n)}" for a in range(0, n, 100))
        return ["inbetween", str(clip), "--keep", keep, *out]
    if task == "edit":
        targets = folder / "targets.json"
        targets.write_text(json.dumps([{"joint": "lHand", "frame": [n // 2 - 10, n // 2 + 10],
                                        "offset": [0.0, 0.1, 0.0]}]))
        return ["edit", str(clip), "--targets", str(targets), *out]
    raise ValueError(task)


def peak_memory(argv: list[str]) -> tuple[float, float]:
    """(peak RSS in MB, seconds) of ``motionopt ARGV`` in a fresh process."""
    started = time.perf_counter()
    cmd = [sys.executable, "-c", MEASURE, sys.executable, "-m", "motionopt", *argv]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout.split()
    if out[0] != "0":
        raise RuntimeError(f"{' '.join(argv)} failed")
    return int(out[1]) / 1024, time.perf_counter() - started


def memory_table(lengths: list[int], tasks: list[str]) -> list[str]:
    source = bvh.load(SOURCE)
    lines = [f"Peak resident memory of one command, clip cut from {SOURCE.relative_to(CMU.parent)} "
             f"({source.fps:g} fps) played back and forth",
             f"{'task':<18}" + "".join(f"{f'{n} frames':>16}" for n in lengths)
             + "".join(f"{f'KB/frame {a}-{b}':>20}" for a, b in zip(lengths, lengths[1:]))]
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        clips = {}
        for n in lengths:
            clips[n] = folder / f"clip-{n}.bvh"
            bvh.save(back_and_forth(source, n), clips[n])
        for task in tasks:
            runs = [peak_memory(task_argv(task, clips[n], n, folder)) for n in lengths]
            slopes = [(runs[i + 1][0] - runs[i][0]) * 1024 / (b - a)
                      for i, (a, b) in enumerate(zip(lengths, lengths[1:]))]
            lines.append(f"{task:<18}" + "".join(f"{f'{m:.0f} MB {s:.0f} s':>16}" for m, s in runs)
                         + "".join(f"{s:>20.1f}" for s in slopes))
            print(lines[-1], flush=True)
    return lines


def throughput_table(workers: list[int]) -> list[str]:
    files = find_inputs(CMU, Path(tempfile.gettempdir()) / "none")
    frames = sum(bvh.read_channels(f)[1].shape[0] for f in files)
    lines = [f"motionopt batch denoise over {CMU.relative_to(CMU.parent.parent)}: {len(files)} clips, "
             f"{frames} frames",
             f"{'workers':>8}{'ok':>5}{'failed':>8}{'seconds':>10}{'files/s':>10}{'frames/s':>10}{'speed-up':>10}"]
    base = None
    for w in workers:
        with tempfile.TemporaryDirectory() as tmp:
            summary = run_batch(BatchPlan("denoise", CMU, Path(tmp) / "out"), workers=w)
        base = base or summary.seconds
        lines.append(f"{w:>8}{summary.count('ok'):>5}{summary.count('failed'):>8}{summary.seconds:>10.1f}"
                     f"{len(files) / summary.seconds:>10.2f}{frames / summary.seconds:>10.0f}"
                     f"{base / summary.seconds:>10.2f}")
        print(lines[-1], flush=True)
    return lines


def main() -> None:
    import torch

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--lengths", type=int, nargs="+", default=[100, 1000, 10000])
    parser.add_argument("--tasks", nargs="+", default=["denoise", "denoise --refine", "inbetween", "edit"])
    args = parser.parse_args()
    if not CMU.exists():
        sys.exit(f"needs the CMU clips in {CMU}")
    torch.set_num_threads(1)
    lines = throughput_table(args.workers) + [""] + memory_table(args.lengths, args.tasks)
    text = "\n".join(lines) + "\n"
    print("\n" + text)
    RESULTS.write_text(text)


if __name__ == "__main__":
    main()
