"""``motionopt demo``: the main job on built-in data, offline."""
from __future__ import annotations

import argparse

from . import add_common

EXPLAIN = {
    "path_distance_cm_mean": "mean distance of the root from the drawn path (cm per frame)",
    "foot_skating_cm_per_s": "horizontal speed of planted feet (cm/s; mocap is a few cm/s)",
    "new_frames": "frames synthesised after the seed",
    "frames_per_second": "output frames per second of solving",
    "mpjpe_noisy_cm": "mean joint position error of the noisy input against the clean clip (cm)",
    "mpjpe_denoised_cm": "the same error after denoising (cm; lower is better)",
    "jerk_input": "jitter of the input (mean jerk, m/s^3)",
    "jerk_output": "jitter of the output (m/s^3; lower is smoother)",
    "join_root_error_cm": "root distance where the synthesised gap meets the kept frames (cm)",
    "synthesised_frames": "frames filled in",
}


def register(sub) -> None:
    p = sub.add_parser("demo", help="run path following, denoising and in-betweening on built-in clips",
                       description="Runs three tasks on clips shipped with motionopt, with the shipped priors, "
                       "offline; writes BVH files, pictures and JSON reports into --out-dir.")
    p.add_argument("--out-dir", default="motionopt-demo", help="folder for the results (default ./motionopt-demo)")
    p.add_argument("--force", action="store_true", help="overwrite results of an earlier demo run")
    p.add_argument("--fast", action="store_true", help="a shorter walk (a quick smoke test)")
    add_common(p)
    p.set_defaults(func=cmd_demo)


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.2f}"
    if isinstance(v, list):
        return ", ".join(_fmt(x) for x in v)
    return str(v)


def cmd_demo(args: argparse.Namespace) -> int:
    from motionopt.demo import run_demo

    say = (lambda s: None) if args.quiet else (lambda s: print(f"... {s}", flush=True))
    summary = run_demo(args.out_dir, force=args.force, fast=args.fast, progress=say)
    if args.quiet:
        return 0
    print(f"\nmotionopt demo finished in {summary.seconds:.0f} s; results in {summary.out_dir.resolve()}")
    for step in summary.steps:
        print(f"\n{step.name}: {step.description} ({step.seconds:.0f} s)")
        for f in step.files:
            print(f"  wrote {f}")
        for k, v in step.metrics.items():
            print(f"  {_fmt(v):>10}  {EXPLAIN.get(k, k)}")
    print("\nOpen the .png files to see the results; the .bvh files open in Blender or any BVH viewer; "
          "`motionopt render FILE.bvh --out FILE.gif` animates one. The path-following prior is trained on "
          "Bandai-Namco-Research-Motiondataset (CC BY-NC 4.0, non-commercial).")
    return 0
