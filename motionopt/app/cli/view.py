"""Commands that draw motions: ``render`` (animated stick figure), ``plot`` (pictures) and
``view`` (an interactive 3-D page)."""
from __future__ import annotations

import argparse
import re
from pathlib import Path

from . import UserError, add_common, frame_range

KINDS = ("filmstrip", "path", "trajectory")


def register(sub) -> None:
    p = sub.add_parser("render", help="animate a BVH clip as a stick figure (GIF)",
                       description="Write an animated GIF of a stick figure moving on a floor grid, with "
                       "its shadow and planted feet highlighted; the camera follows the body from the side.")
    p.add_argument("input", help="BVH file")
    p.add_argument("--out", required=True, help="GIF file to write")
    p.add_argument("--fps", type=float, default=None,
                   help="frames per second of the animation (default: the clip's, at most 25); "
                   "the clip is resampled so that it plays at real speed")
    _add_frame_range(p)
    p.add_argument("--size", default="640x480", help="picture size in pixels, WIDTHxHEIGHT (default 640x480)")
    p.add_argument("--elevation", type=float, default=15.0,
                   help="degrees the camera looks down (default 15; 0 is a plain side view)")
    p.add_argument("--title", default=None, help="text in the top right corner (default: the file name)")
    _add_input_options(p)
    add_common(p)
    p.set_defaults(func=cmd_render)

    p = sub.add_parser("plot", help="draw pictures of BVH clips (filmstrip, root path, joint trajectory)",
                       description="Draw one PNG of one or more BVH clips: 'filmstrip' shows stick figures at "
                       "moments spread over the clip, one row per file; 'path' shows the root's path on the "
                       "ground seen from above; 'trajectory' shows one joint's x, y, z over time, one line per file.")
    p.add_argument("inputs", nargs="+", metavar="INPUT", help="BVH files (several are compared in one picture)")
    p.add_argument("--out", required=True, help="PNG file to write")
    p.add_argument("--kind", choices=KINDS, default="filmstrip", help="which picture (default filmstrip)")
    p.add_argument("--joint", default=None, help="joint for --kind trajectory (default: the first foot joint)")
    p.add_argument("--frames", type=int, default=6, help="stick figures per row for --kind filmstrip (default 6, at most 30: "
                   "motionopt view plays every frame)")
    p.add_argument("--elevation", type=float, default=0.0,
                   help="degrees the filmstrip camera looks down (default 0: side view)")
    _add_labelled_inputs_options(p, "picture title")
    p.set_defaults(func=cmd_plot)

    p = sub.add_parser("view", help="write an interactive 3-D page of BVH clips (HTML that works offline)",
                       description="Write one self-contained HTML page (open it in a browser; no network needed) "
                       "that plays the clips as 3-D skeletons on the floor, side by side or overlaid, with play "
                       "and pause, a frame slider, orbit and zoom, planted feet marked, and under them per-frame "
                       "curves of hip height and foot skating. Clips are shown at most at 30 frames per second; "
                       "open the page at #frame=N to start at its frame N.")
    p.add_argument("inputs", nargs="+", metavar="INPUT", help="BVH files (several are shown together)")
    p.add_argument("--out", required=True, help="HTML file to write")
    p.add_argument("--overlay", action="store_true",
                   help="draw the clips where they are, over each other (default: side by side along x)")
    _add_labelled_inputs_options(p, "page title (default: the labels)")
    p.set_defaults(func=cmd_view)


def _add_frame_range(p: argparse.ArgumentParser) -> None:
    p.add_argument("--start", type=int, default=0, help="first frame to use (the file's numbering, from 0)")
    p.add_argument("--stop", type=int, default=None, help="frame to stop before (default: the end of the clip)")


def _add_labelled_inputs_options(p: argparse.ArgumentParser, title: str) -> None:
    """The options of a command that draws several labelled inputs (``_labelled``):
    --labels, --title (``title``: its help), the frame range, the input options and the
    common ones."""
    p.add_argument("--labels", default=None, help="comma-separated names for the inputs (default: file names)")
    p.add_argument("--title", default=None, help=title)
    _add_frame_range(p)
    _add_input_options(p)
    add_common(p)


def _add_input_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--source-fps", type=float, default=None, help="override the frame rate written in the file")
    p.add_argument("--unit", choices=("auto", "cm", "m", "mm", "in"), default="auto",
                   help="length unit of the file (default: guessed from the skeleton's size)")
    p.add_argument("--force", action="store_true", help="overwrite OUT if it exists")


def _load(path: str, args: argparse.Namespace):
    """The file's motion cut to --start/--stop."""
    from motionopt import bvh

    motion = bvh.load(path, unit=args.unit, fps=args.source_fps)
    return motion[frame_range(args.start, args.stop, motion.num_frames, path, min_frames=2)]


def cmd_render(args: argparse.Namespace) -> int:
    from motionopt.plot import GIF_FPS, check_output, render_gif

    out = check_output(args.out, (".gif",), args.force)
    size = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", args.size)
    if not size:
        raise UserError(f"--size {args.size!r}: write the size as WIDTHxHEIGHT in pixels, e.g. 640x480")
    motion = _load(args.input, args)
    render_gif(motion, out, fps=args.fps, size=(int(size[1]), int(size[2])), elevation=args.elevation,
               first_frame=args.start, title=args.title if args.title is not None else Path(args.input).name,
               progress=not args.quiet, force=args.force)
    if not args.quiet:
        rate = args.fps or min(motion.fps, GIF_FPS)
        print(f"wrote {out} ({motion.duration:.2f} s at {rate:g} frames per second)")
    return 0


def cmd_plot(args: argparse.Namespace) -> int:
    from motionopt import plot
    from motionopt.features import default_spec

    out = plot.check_output(args.out, (".png",), args.force)
    motions = _labelled(args)
    if args.kind == "filmstrip":
        plot.plot_filmstrip(motions, out, frames=args.frames, elevation=args.elevation, first_frame=args.start,
                            title=args.title, force=args.force)
    elif args.kind == "path":
        plot.plot_root_paths(motions, out, **({"title": args.title} if args.title else {}), force=args.force)
    else:
        first = next(iter(motions.values()))
        joint = args.joint
        if joint is None:
            try:
                joint = default_spec(first.skeleton).contact_joints[0]
            except ValueError:
                joint = first.skeleton.names[plot.body_root(first.skeleton)]
        for label, m in motions.items():
            if joint not in m.skeleton.names:
                raise UserError(f"joint {joint!r} is not in {label}; its joints are: {', '.join(m.skeleton.names)}")
        plot.plot_joint_trajectories(motions, joint, out, title=args.title, first_frame=args.start, force=args.force)
    if not args.quiet:
        print(f"wrote {out}")
    return 0


def cmd_view(args: argparse.Namespace) -> int:
    from motionopt.plot import check_output
    from motionopt.view import write_view

    out = check_output(args.out, (".html",), args.force)
    motions = _labelled(args)
    write_view(out, motions, overlay=args.overlay, title=args.title, force=args.force)
    if not args.quiet:
        seconds = max(m.duration for m in motions.values())
        print(f"wrote {out} ({len(motions)} clip{'s' * (len(motions) > 1)}, {seconds:.2f} s, "
              f"{out.stat().st_size / 1e6:.1f} MB): open it in a web browser")
    return 0


def _labelled(args: argparse.Namespace) -> dict:
    """The inputs' motions (cut to --start/--stop) by their --labels or file names."""
    labels = [x.strip() for x in args.labels.split(",")] if args.labels else _names(args.inputs)
    if len(labels) != len(args.inputs):
        raise UserError(f"--labels gives {len(labels)} names for {len(args.inputs)} inputs")
    twice = next((label for i, label in enumerate(labels) if label in labels[:i]), None)
    if twice is not None:
        raise UserError(f"two inputs are named {twice!r}; give each its own name with --labels")
    return {label: _load(path, args) for label, path in zip(labels, args.inputs)}


def _names(paths: list[str]) -> list[str]:
    """File names without .bvh as labels; whole paths where two files share a name."""
    names = [Path(p).stem for p in paths]
    return names if len(set(names)) == len(names) else list(paths)
