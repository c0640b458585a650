"""Commands about BVH files: ``convert`` (frame rate, unit, joints, frame range) and ``info``."""
from __future__ import annotations

import argparse
import fnmatch
import json
import os
from pathlib import Path

from . import UserError, add_common, frame_range

UNITS = ("cm", "m", "mm", "in")


def register(sub) -> None:
    p = sub.add_parser("convert", help="convert a BVH file: frame rate, length unit, joints, frame range",
                       description="Read IN.bvh and write OUT.bvh. With no options OUT reproduces IN: the same "
                       "hierarchy, joint names, channels, frame count, frame time and motion.")
    p.add_argument("input", metavar="IN.bvh", help="BVH file to read")
    p.add_argument("output", metavar="OUT.bvh", help="BVH file to write")
    p.add_argument("--fps", type=float, default=None,
                   help="resample to this frame rate (slerp for rotations, linear for positions)")
    p.add_argument("--unit", choices=UNITS, default=None, help="length unit of OUT (default: that of IN)")
    p.add_argument("--drop-joints", nargs="+", default=(), metavar="PATTERN",
                   help="remove joints whose names match these shell patterns (e.g. '*Thumb*' '*Eye*'); "
                   "the other joints keep their world positions")
    p.add_argument("--start", type=int, default=0, help="first frame to keep (IN's numbering, from 0)")
    p.add_argument("--stop", type=int, default=None, help="frame to stop before (default: the end of IN)")
    p.add_argument("--source-fps", type=float, default=None,
                   help="IN's true frame rate, when its Frame Time header is wrong")
    p.add_argument("--source-unit", choices=("auto",) + UNITS, default="auto",
                   help="length unit of IN (default: guessed from the skeleton's size)")
    p.add_argument("--force", action="store_true", help="overwrite OUT if it exists, even when it is IN")
    add_common(p)
    p.set_defaults(func=cmd_convert)

    p = sub.add_parser("info", help="print a BVH file's joints, frames, frame rate, duration, unit, path and size",
                       description="Print what a BVH file holds. Lengths are in metres; the root path is the "
                       "distance the root travels on the ground plane.")
    p.add_argument("input", metavar="FILE.bvh", help="BVH file")
    p.add_argument("--source-fps", "--fps", dest="source_fps", type=float, default=None,
                   help="the file's true frame rate, when its Frame Time header is wrong")
    p.add_argument("--unit", choices=("auto",) + UNITS, default="auto",
                   help="length unit of the file (default: guessed from the skeleton's size)")
    p.add_argument("--json", action="store_true", help="print JSON")
    add_common(p)
    p.set_defaults(func=cmd_info)


def _positive(value: float | None, option: str) -> None:
    if value is not None and not value > 0:
        raise UserError(f"{option} must be a positive number of frames per second, got {value:g}")


def cmd_convert(args: argparse.Namespace) -> int:
    from motionopt import bvh

    _positive(args.fps, "--fps")
    _positive(args.source_fps, "--source-fps")
    out = Path(args.output)
    if out.exists() and not args.force:
        same = os.path.samefile(out, args.input) if Path(args.input).exists() else False
        raise UserError(f"{out} is the input file; pass --force to overwrite it" if same
                        else f"{out} exists; pass --force to overwrite it")
    motion = bvh.load(args.input, unit=args.source_unit, fps=args.source_fps)
    motion = motion[frame_range(args.start, args.stop, motion.num_frames, args.input)]
    for pattern in args.drop_joints:
        if not any(fnmatch.fnmatchcase(name, pattern) for name in motion.skeleton.names):
            raise UserError(f"--drop-joints {pattern!r} matches no joint; joints are: "
                            f"{', '.join(motion.skeleton.names)}")
    if args.drop_joints:
        motion = motion.remove_joints(list(args.drop_joints))
    if args.fps is not None:
        motion = motion.resample(args.fps)
    bvh.save(motion, out, unit=args.unit, force=args.force)
    if not args.quiet:
        print(f"wrote {out}: {motion.skeleton.num_joints} joints, {motion.num_frames} frames at "
              f"{motion.fps:.6g} fps, in {args.unit or motion.source_unit}")
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    from motionopt import bvh
    from motionopt.info import describe

    _positive(args.source_fps, "--fps")
    info = describe(bvh.load(args.input, unit=args.unit, fps=args.source_fps))
    if args.json:
        print(json.dumps({"file": args.input, **info.to_dict(), "unit_guessed": args.unit == "auto"}, indent=2))
        return 0
    lo, hi = info.bbox_min, info.bbox_max
    lines = [
        f"file: {args.input}",
        f"joints: {len(info.joints)} ({', '.join(info.joints)})",
        f"frames: {info.frames}",
        f"frame rate: {info.fps:.6g} fps (frame time {1 / info.fps:.6g} s)",
        f"duration: {info.duration:.3f} s",
        f"unit: {info.unit}" + (" (guessed from the skeleton's size; set it with --unit)" if args.unit == "auto" else ""),
        f"root path length: {info.root_path_length:.3f} m on the ground plane ({info.root_joint})",
        "bounding box: " + ", ".join(f"{a} {lo[i]:.3f} to {hi[i]:.3f}" for i, a in enumerate("xyz")) + " m",
    ]
    print("\n".join(lines))
    return 0
