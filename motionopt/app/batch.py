"""Run one task over every BVH file of a folder tree: resumable, fault tolerant, on Dask.

A batch mirrors the input tree in the output folder: ``IN/a/take.bvh`` becomes
``OUT/a/take.bvh`` with its report ``OUT/a/take.json``. Each file is what the
single-file command (``motionopt TASK take.bvh --out ... --report ...``) gives: the
command's own parser reads its options, its entry (``cli.tasks.TASKS``) builds the task
object, and the command's writer writes the outputs and report, so a batch result is
exactly what that command gives.

Why the pieces are as they are:

- **Faults stay per file.** A file that fails (bad BVH, skeleton no prior models,
  a solver error, a worker killed under it) is recorded with its error and the
  batch goes on.
- **Nothing is lost.** The manifest ``OUT/batch-manifest.jsonl`` gets one line per
  finished file, appended and synced by the driver as results arrive, so a batch
  stopped after three hours keeps its finished files. Rerunning the same command
  skips the files whose output and report exist with the recorded checksum and whose
  input is unchanged, and redoes the rest (interrupted or failed). Every output is
  written to a temporary file and renamed; inputs are only read.
- **Scale-out.** With ``workers > 1`` (a ``dask.distributed.LocalCluster`` of
  processes, one torch thread each) or a ``scheduler`` address, files are Dask tasks.
  Each worker process loads a prior once (the command layer caches loaded
  checkpoints) and a killed worker's files are rescheduled by Dask.
"""
from __future__ import annotations

import csv
import hashlib
import io
import json
import logging
import os
import time
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Iterator

from ..atomic import write_text_atomic
from .cli import USER_ERRORS, build_parser, error_message
from .cli.tasks import TASKS, solve, start, write_result

MANIFEST = "batch-manifest.jsonl"
SUMMARY = "batch-summary"
MANIFEST_VERSION = 1
#: Options that the batch sets per file; a user may not pass them as task options.
RESERVED = ("--out", "--report", "--force", "--max-frames", "--quiet", "-q", "--verbose", "-v")


class BatchError(ValueError):
    """A batch that cannot start (bad folders, options that do not match the manifest)."""


@dataclass(frozen=True)
class BatchPlan:
    """What a batch does: ``task`` with ``options`` on the BVH files under ``in_dir``,
    outputs mirrored under ``out_dir``; files declaring more than ``max_frames`` fail."""

    task: str
    in_dir: Path
    out_dir: Path
    options: tuple[str, ...] = ()
    max_frames: int = 100_000

    def signature(self) -> dict:
        """What must match for a rerun to resume this batch."""
        return {"kind": "motionopt-batch", "version": MANIFEST_VERSION, "task": self.task,
                "options": list(self.options), "max_frames": self.max_frames,
                "input": str(self.in_dir.resolve())}


@dataclass(frozen=True)
class FileJob:
    """One file of a batch, with every path absolute so that any worker can run it."""

    task: str
    rel: str
    input: Path
    output: Path
    report: Path
    options: tuple[str, ...]
    max_frames: int


@dataclass
class FileResult:
    """How one file went: ``status`` is ok, failed or skipped (done by an earlier run)."""

    file: str
    status: str
    error: str | None = None
    seconds: float = 0.0
    metrics: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    output: str | None = None
    report: str | None = None
    output_sha256: str | None = None
    input_sha256: str | None = None
    worker: str | None = None


@dataclass
class BatchSummary:
    """Every file's result in input order, where they are written, and the batch's time."""

    results: list[FileResult]
    seconds: float
    csv_path: Path
    json_path: Path

    def count(self, status: str) -> int:
        return sum(r.status == status for r in self.results)


def find_inputs(in_dir: Path, out_dir: Path) -> list[Path]:
    """The BVH files under ``in_dir`` (any case of .bvh), sorted, without those under ``out_dir``."""
    out = out_dir.resolve()
    found = []
    for path in in_dir.rglob("*"):
        if path.suffix.lower() != ".bvh" or not path.is_file():
            continue
        if out == path.resolve().parent or out in path.resolve().parents:
            continue
        found.append(path)
    return sorted(found)


def plan_jobs(plan: BatchPlan, inputs: Iterable[Path]) -> list[FileJob]:
    """One job per input, refusing two inputs whose reports would collide (a.bvh, a.BVH)."""
    jobs, seen = [], {}
    for path in inputs:
        rel = path.relative_to(plan.in_dir)
        out = plan.out_dir / rel
        report = out.with_suffix(".json")
        key = str(report).lower()
        if key in seen:
            raise BatchError(f"{path} and {seen[key]} would write the same report {report}; rename one")
        seen[key] = path
        jobs.append(FileJob(plan.task, rel.as_posix(), path.resolve(), out.resolve(), report.resolve(),
                            plan.options, plan.max_frames))
    return jobs


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


# ---- one file (runs on a worker) -----------------------------------------------------------------

def run_file(job: FileJob, threads: int | None = None) -> FileResult:
    """Run the task on one file and return its result; never raises for a failure of the
    file (the error is recorded), so one file cannot stop a batch."""
    if threads is not None:
        import torch

        torch.set_num_threads(threads)
    started = time.perf_counter()
    result = FileResult(job.rel, "failed", worker=_worker_name())
    try:
        result.input_sha256 = sha256(job.input)
        job.output.parent.mkdir(parents=True, exist_ok=True)
        try:
            report = run_task(job)
        except USER_ERRORS as e:
            result.error = error_message(e)
        else:
            result.status, result.metrics = "ok", _scalars(report["metrics"])
            result.warnings = [str(w) for w in report.get("warnings", [])]
            result.output, result.report = str(job.output), str(job.report)
            result.output_sha256 = sha256(job.output)
    except Exception as e:  # noqa: BLE001 - a batch records any failure of a file and goes on
        result.error = f"{type(e).__name__}: {e} (at {_where(e)})"
    result.seconds = time.perf_counter() - started
    return result


def run_task(job: FileJob) -> dict:
    """Solve the job's task as ``motionopt TASK INPUT --out OUTPUT --report REPORT --force
    --quiet --max-frames N OPTIONS`` would, through the command's entry and writer, and
    return the report it wrote. Errors of the file are the command's user errors."""
    argv = [job.task, str(job.input), "--out", str(job.output), "--report", str(job.report), "--force", "--quiet",
            "--max-frames", str(job.max_frames), *job.options]
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as e:
        raise BatchError(f"invalid arguments {argv[1:]} (exit status {e.code})") from None
    run = start(args)
    return write_result(run, solve(run))


def _where(e: BaseException) -> str:
    frame = traceback.extract_tb(e.__traceback__)[-1]
    return f"{Path(frame.filename).name}:{frame.lineno}"


def _worker_name() -> str | None:
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return None


def _scalars(metrics: dict) -> dict:
    """The metrics that fit a table cell: numbers, strings and booleans."""
    return {k: v for k, v in metrics.items() if isinstance(v, (int, float, str, bool)) or v is None}


# ---- manifest --------------------------------------------------------------------------------------

def read_manifest(path: Path, plan: BatchPlan) -> dict[str, FileResult]:
    """The finished files of an earlier run of the same batch, by relative path.

    Raises BatchError when the manifest belongs to another batch. A line cut short by a
    stop is ignored (its file is redone); any other malformed line is an error.
    """
    if not path.exists():
        return {}
    lines = path.read_text(encoding="utf-8").splitlines()
    try:
        head = json.loads(lines[0]) if lines else None
    except json.JSONDecodeError:
        head = None
    if not isinstance(head, dict) or head.get("kind") != "motionopt-batch":
        raise BatchError(f"{path} is not a motionopt batch manifest; choose another --out or pass --force")
    if head != plan.signature():
        diff = ", ".join(f"{k}: {head.get(k)!r} there, {v!r} now" for k, v in plan.signature().items()
                         if head.get(k) != v)
        raise BatchError(f"{path.parent} holds another batch ({diff}); rerun with the same task and options "
                         "to resume it, choose another --out, or pass --force to start over")
    done: dict[str, FileResult] = {}
    names = {f.name for f in FileResult.__dataclass_fields__.values()}
    for i, line in enumerate(lines[1:], start=2):
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            if i == len(lines):
                continue  # the last line of a run stopped while writing it
            raise BatchError(f"{path}, line {i}: not JSON; delete the line (its file is then redone)") from None
        if not isinstance(record, dict) or set(record) - names or not isinstance(record.get("file"), str):
            raise BatchError(f"{path}, line {i}: not a file record; delete the line (its file is then redone)")
        done[record["file"]] = FileResult(**record)
    return done


def is_complete(job: FileJob, record: FileResult | None) -> bool:
    """Whether an earlier run finished this file and its output is intact: recorded as
    ok, output and report present, output checksum as recorded, input unchanged."""
    if record is None or record.status != "ok" or not record.output_sha256:
        return False
    if not (job.output.is_file() and job.report.is_file()):
        return False
    return sha256(job.output) == record.output_sha256 and sha256(job.input) == record.input_sha256


class Manifest:
    """The append-only record of finished files (one JSON line each, synced)."""

    def __init__(self, path: Path, plan: BatchPlan, fresh: bool):
        self.path = path
        if fresh or not path.exists():
            write_text_atomic(path, json.dumps(plan.signature()) + "\n")
        else:
            _drop_partial_last_line(path)
        self.file = open(path, "a", encoding="utf-8")

    def append(self, result: FileResult) -> None:
        self.file.write(json.dumps(asdict(result)) + "\n")
        self.file.flush()
        os.fsync(self.file.fileno())

    def close(self) -> None:
        self.file.close()


def _drop_partial_last_line(path: Path) -> None:
    """Cut a last line that a stop left without its newline, so appends start on a new line."""
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        with open(path, "r+b") as f:
            f.truncate(data.rfind(b"\n") + 1)


# ---- summary ---------------------------------------------------------------------------------------

def write_summary(out_dir: Path, results: list[FileResult]) -> tuple[Path, Path]:
    """``batch-summary.csv`` (file, status, error, warnings, seconds, then one column per
    metric) and ``batch-summary.json`` (the full records)."""
    keys = sorted({k for r in results for k in r.metrics})
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(["file", "status", "error", "warnings", "seconds", *keys])
    for r in results:
        writer.writerow([r.file, r.status, r.error or "", " | ".join(r.warnings), f"{r.seconds:.3f}",
                         *(_cell(r.metrics.get(k)) for k in keys)])
    csv_path, json_path = out_dir / f"{SUMMARY}.csv", out_dir / f"{SUMMARY}.json"
    write_text_atomic(csv_path, buf.getvalue())
    write_text_atomic(json_path, json.dumps([asdict(r) for r in results], indent=2) + "\n")
    return csv_path, json_path


def _cell(value: object) -> str:
    if value is None:
        return ""
    return f"{value:.6g}" if isinstance(value, float) else str(value)


def remove_stale_temporaries(out_dir: Path) -> int:
    """Delete the temporary files (``.NAME.*.tmp``) a killed worker left behind."""
    stale = [p for p in out_dir.rglob(".*.tmp") if p.is_file()]
    for p in stale:
        p.unlink(missing_ok=True)
    return len(stale)


# ---- the batch -------------------------------------------------------------------------------------

def prepare(plan: BatchPlan, force: bool = False) -> tuple[list[FileJob], dict[str, FileResult]]:
    """Check the folders, list the jobs and read what an earlier run finished."""
    if plan.task not in TASKS:
        raise BatchError(f"unknown task {plan.task!r}; choose one of {', '.join(TASKS)}")
    if not plan.in_dir.is_dir():
        raise BatchError(f"--in {plan.in_dir} is not a folder")
    if plan.out_dir.exists() and not plan.out_dir.is_dir():
        raise BatchError(f"--out {plan.out_dir} exists and is not a folder")
    if plan.in_dir.resolve() == plan.out_dir.resolve():
        raise BatchError("--out must differ from --in: inputs are never modified")
    manifest = plan.out_dir / MANIFEST
    if plan.out_dir.exists() and not manifest.exists() and any(plan.out_dir.iterdir()) and not force:
        raise BatchError(f"--out {plan.out_dir} is not empty and holds no batch manifest; choose an empty or new "
                         "folder, or pass --force to write into it")
    jobs = plan_jobs(plan, find_inputs(plan.in_dir, plan.out_dir))
    if not jobs:
        raise BatchError(f"no .bvh files under {plan.in_dir}")
    plan.out_dir.mkdir(parents=True, exist_ok=True)
    done = {} if force else read_manifest(manifest, plan)
    return jobs, done


def run_batch(plan: BatchPlan, workers: int = 1, scheduler: str | None = None, force: bool = False,
              on_result: Callable[[FileResult], None] | None = None) -> BatchSummary:
    """Run the batch: skip complete files, run the rest in this process (``workers=1``),
    on a local Dask cluster (``workers > 1``) or on the cluster at ``scheduler``; record
    each result in the manifest as it arrives and write the summary tables at the end
    (also when stopped). ``on_result`` sees every result, skipped ones included."""
    started = time.perf_counter()
    jobs, done = prepare(plan, force)
    manifest = Manifest(plan.out_dir / MANIFEST, plan, fresh=force)
    results: dict[str, FileResult] = {}
    todo = []
    for job in jobs:
        if is_complete(job, done.get(job.rel)):
            results[job.rel] = FileResult(**{**asdict(done[job.rel]), "status": "skipped"})
            if on_result:
                on_result(results[job.rel])
        else:
            todo.append(job)
    try:
        runner = _run_local(todo) if workers <= 1 and scheduler is None else _run_dask(todo, workers, scheduler)
        for result in runner:
            manifest.append(result)
            results[result.file] = result
            if on_result:
                on_result(result)
    finally:
        manifest.close()
        remove_stale_temporaries(plan.out_dir)
        ordered = [results[j.rel] for j in jobs if j.rel in results]
        csv_path, json_path = write_summary(plan.out_dir, ordered)
    return BatchSummary(ordered, time.perf_counter() - started, csv_path, json_path)


def _run_local(jobs: list[FileJob]) -> Iterator[FileResult]:
    for job in jobs:
        yield run_file(job)


def _run_dask(jobs: list[FileJob], workers: int, scheduler: str | None) -> Iterator[FileResult]:
    """Files as Dask tasks; a file whose task Dask gives up on (its worker died each
    time it ran, e.g. out of memory) is a failed file, not a failed batch."""
    try:
        from distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise BatchError("--workers above 1 and --scheduler need Dask: pip install 'motionopt[cluster]'") from None
    # Dask's own start-up and shutdown chatter (INFO) only with --verbose, as ours
    verbose = logging.getLogger("motionopt").isEnabledFor(logging.DEBUG)
    logging.getLogger("distributed").setLevel(logging.INFO if verbose else logging.WARNING)
    cluster = None
    if scheduler is None:
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
    client = Client(scheduler or cluster)
    try:
        futures = {client.submit(run_file, job, 1, key=f"motionopt-batch-{job.rel}-{os.urandom(4).hex()}",
                                 pure=False): job for job in jobs}
        for future in as_completed(futures):
            job = futures[future]
            try:
                yield future.result()
            except Exception as e:  # noqa: BLE001 - e.g. KilledWorker: the file failed, the batch goes on
                yield FileResult(job.rel, "failed", error=f"{type(e).__name__}: the worker running this file died "
                                 f"or the task failed ({e}); a file too large for memory? see --max-frames")
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
