"""``motionopt batch``: one task over every BVH file of a folder tree (``motionopt.app.batch``)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from . import UserError, add_common, build_parser
from .tasks import TASKS


def register(sub) -> None:
    p = sub.add_parser(
        "batch", help="run a task over every BVH file of a folder tree (resumable, on Dask)", allow_abbrev=False,
        usage="motionopt batch TASK --in DIR --out DIR [--workers N | --scheduler ADDRESS] [--max-frames N] "
        "[--force] [TASK OPTIONS]",
        description="Run TASK (the command of the same name) on every .bvh file under --in, mirroring the "
        "folders under --out: IN/a/take.bvh gives OUT/a/take.bvh and its report OUT/a/take.json. Any other "
        "option is passed to every run of the task (see motionopt TASK --help), e.g. "
        "`motionopt batch denoise --in takes --out clean --no-refine`. A file that fails is recorded with its "
        "error and the batch goes on. OUT/batch-summary.csv and .json list every file's status, error, "
        "metrics and time. OUT/batch-manifest.jsonl records each finished file as it finishes: rerunning the "
        "same command skips the files that are complete and unchanged and redoes the others (interrupted or "
        "failed). Inputs are never modified; every output is written to a temporary file and renamed.")
    p.add_argument("task", choices=TASKS, metavar="TASK", help=f"the task: {', '.join(TASKS)}")
    p.add_argument("--in", dest="in_dir", required=True, metavar="DIR", help="folder of BVH files (searched "
                   "recursively; a folder --out inside it is skipped)")
    p.add_argument("--out", dest="out_dir", required=True, metavar="DIR", help="folder for outputs, reports, "
                   "summary and manifest (created if missing)")
    p.add_argument("--workers", type=int, default=1, metavar="N", help="files at a time: 1 (default) runs in "
                   "this process; above 1 starts a local Dask cluster of N processes, one torch thread each")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS", help="run on an existing Dask cluster "
                   "(e.g. tcp://10.0.0.5:8786); its workers need motionopt installed and these folders at the "
                   "same paths")
    p.add_argument("--max-frames", type=int, default=100_000, metavar="N", help="fail a file that declares more "
                   "frames than this, before reading its frames (default 100000: 14 minutes at 120 fps)")
    p.add_argument("--force", action="store_true", help="start over: ignore the manifest of an earlier run and "
                   "write into a non-empty --out")
    add_common(p)
    p.set_defaults(func=cmd_batch, takes_task_options=True)


def check_task_options(task: str, options: list[str]) -> None:
    """Refuse the options a batch sets itself, and let the task's own parser check the rest
    now, so that a typo fails before the first file rather than on every file."""
    from motionopt.app.batch import RESERVED

    for word in options:
        if word.split("=")[0] in RESERVED:
            raise UserError(f"{word} is set by the batch for each file; leave it out of the task options")
        if word.split("=")[0] == "--view":
            raise UserError("--view writes one page, and a batch runs many files: leave it out, and view an output "
                            "afterwards with `motionopt view INPUT.bvh OUTPUT.bvh --out VIEW.html --overlay`")
    try:
        build_parser().parse_args([task, "INPUT.bvh", "--out", "OUT.bvh", *options])
    except SystemExit as e:
        if e.code:
            raise UserError(f"the options {' '.join(options)!r} are not valid for `motionopt {task}` "
                            "(see the message above)") from None
        raise


def cmd_batch(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from motionopt.app.batch import BatchError, BatchPlan, prepare, run_batch

    if args.workers < 1:
        raise UserError(f"--workers must be at least 1, got {args.workers}")
    if args.max_frames < 1:
        raise UserError(f"--max-frames must be at least 1, got {args.max_frames}")
    check_task_options(args.task, args.task_options)
    plan = BatchPlan(args.task, Path(args.in_dir), Path(args.out_dir), tuple(args.task_options), args.max_frames)
    try:
        jobs, _ = prepare(plan, args.force)
    except BatchError as e:
        raise UserError(str(e)) from None
    bar = tqdm(total=len(jobs), desc=f"batch {args.task}", unit="file", disable=args.quiet, file=sys.stderr)

    def show(result) -> None:
        bar.update(1)
        if result.status == "failed":
            bar.write(f"failed: {result.file}: {result.error}", file=sys.stderr)
        elif args.verbose:
            bar.write(f"{result.status}: {result.file} ({result.seconds:.1f} s)")

    try:
        summary = run_batch(plan, workers=args.workers, scheduler=args.scheduler, force=args.force, on_result=show)
    except BatchError as e:
        raise UserError(str(e)) from None
    finally:
        bar.close()
    if not args.quiet:
        ran = [r for r in summary.results if r.status != "skipped"]
        busy = sum(r.seconds for r in ran)
        print(f"{len(summary.results)} files: {summary.count('ok')} done, {summary.count('skipped')} already done "
              f"(skipped), {summary.count('failed')} failed, in {summary.seconds:.1f} s "
              f"({busy:.1f} s of task time)")
        print(f"wrote {summary.csv_path} and {summary.json_path}")
    return 1 if summary.count("failed") else 0
