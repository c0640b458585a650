"""``motionopt batch``: a folder tree of real clips (and a broken file) cleaned in one run,
resumed after faults, and scaled out on a Dask LocalCluster whose worker is killed."""
from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from motionopt import bvh
from motionopt.app.batch import MANIFEST, BatchError, BatchPlan, run_batch, sha256
from motionopt.app.cli import main
from clips import DATA, CMU_120, CMU_60, BANDAI_30


CLIPS = (BANDAI_30, CMU_120, CMU_60)


@pytest.fixture
def tree(tmp_path: Path) -> Path:
    """IN/walk.bvh, IN/cmu/martial.bvh, IN/cmu/dance/salsa.bvh and IN/cmu/broken.bvh (cut short)."""
    root = tmp_path / "in"
    (root / "cmu" / "dance").mkdir(parents=True)
    shutil.copy(DATA / CLIPS[0], root / "walk.bvh")
    shutil.copy(DATA / CLIPS[1], root / "cmu" / "martial.bvh")
    shutil.copy(DATA / CLIPS[2], root / "cmu" / "dance" / "salsa.bvh")
    text = (DATA / CLIPS[1]).read_text()
    (root / "cmu" / "broken.bvh").write_text(text[: len(text) // 3])
    return root


def hashes(root: Path) -> dict[str, str]:
    return {p.relative_to(root).as_posix(): sha256(p) for p in sorted(root.rglob("*")) if p.is_file()}


def manifest_records(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / MANIFEST).read_text().splitlines()[1:]]


def test_batch_mirrors_the_tree_and_records_a_failure_without_stopping(tree, tmp_path, capsys):
    before = hashes(tree)
    out = tmp_path / "out"
    rc = main(["batch", "denoise", "--in", str(tree), "--out", str(out), "--quiet"])
    assert rc == 1  # one file failed
    assert hashes(tree) == before  # inputs untouched
    for rel in ("walk", "cmu/martial", "cmu/dance/salsa"):
        clean = bvh.load(out / f"{rel}.bvh")
        assert clean.num_frames == bvh.load(tree / f"{rel}.bvh").num_frames
        assert json.loads((out / f"{rel}.json").read_text())["task"] == "denoise"
    assert not (out / "cmu" / "broken.bvh").exists()
    rows = {r["file"]: r for r in csv.DictReader((out / "batch-summary.csv").open())}
    assert list(rows) == ["cmu/broken.bvh", "cmu/dance/salsa.bvh", "cmu/martial.bvh", "walk.bvh"]
    assert [rows[f]["status"] for f in rows] == ["failed", "ok", "ok", "ok"]
    assert "broken.bvh" in rows["cmu/broken.bvh"]["error"] and "line" in rows["cmu/broken.bvh"]["error"]
    assert float(rows["walk.bvh"]["jerk_output_m_per_s3"]) < float(rows["walk.bvh"]["jerk_input_m_per_s3"])
    records = json.loads((out / "batch-summary.json").read_text())
    assert {r["file"] for r in records} == set(rows) and all(r["seconds"] > 0 for r in records)
    assert not list(out.rglob("*.tmp"))


def test_rerun_skips_complete_files_and_redoes_interrupted_or_damaged_ones(tree, tmp_path):
    out = tmp_path / "out"
    plan = BatchPlan("denoise", tree, out)
    run_batch(plan)
    # Simulate a stop while writing salsa (no manifest line) and a damaged martial output.
    lines = (out / MANIFEST).read_text().splitlines()
    (out / MANIFEST).write_text("\n".join(l for l in lines if "salsa" not in l) + "\n" + '{"file": "cmu/da')
    (out / "cmu" / "martial.bvh").write_text("HIERARCHY\n")
    seen = []
    summary = run_batch(plan, on_result=seen.append)
    status = {r.file: r.status for r in seen}
    assert status == {"walk.bvh": "skipped", "cmu/martial.bvh": "ok", "cmu/dance/salsa.bvh": "ok",
                      "cmu/broken.bvh": "failed"}
    assert bvh.load(out / "cmu" / "martial.bvh").num_frames == bvh.load(tree / "cmu" / "martial.bvh").num_frames
    assert summary.count("skipped") == 1 and summary.count("ok") == 2
    # A third run has nothing left to do but the broken file.
    again = run_batch(plan)
    assert again.count("skipped") == 3 and again.count("failed") == 1


def test_a_changed_input_is_redone(tree, tmp_path):
    out = tmp_path / "out"
    plan = BatchPlan("denoise", tree, out)
    run_batch(plan)
    shutil.copy(DATA / CLIPS[2], tree / "walk.bvh")  # the user replaced a take
    seen = []
    run_batch(plan, on_result=seen.append)
    assert {r.file: r.status for r in seen}["walk.bvh"] == "ok"


def test_other_options_or_a_foreign_folder_are_refused(tree, tmp_path, capsys):
    out = tmp_path / "out"
    run_batch(BatchPlan("denoise", tree, out))
    with pytest.raises(BatchError, match="holds another batch.*options"):
        run_batch(BatchPlan("denoise", tree, out, options=("--refine",)))
    assert main(["batch", "denoise", "--in", str(tree), "--out", str(out), "--refine", "--iterations", "2",
                 "--force", "--quiet"]) == 1  # --force starts over with the new options
    assert json.loads((out / "walk.json").read_text())["command"].count("--refine") == 1
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    rc = main(["batch", "denoise", "--in", str(tree), "--out", str(foreign)])
    assert rc == 1 and "not empty" in capsys.readouterr().err
    assert (foreign / "notes.txt").read_text() == "mine"


@pytest.mark.parametrize("options, message", [
    (["--report", "r.json"], "set by the batch"),
    (["--report=r.json"], "set by the batch"),
    (["--iterations", "zero"], "not valid for `motionopt denoise`"),
    (["--no-such-option"], "not valid for `motionopt denoise`"),
])
def test_bad_task_options_fail_before_any_file(tree, tmp_path, capsys, options, message):
    out = tmp_path / "out"
    rc = main(["batch", "denoise", "--in", str(tree), "--out", str(out), *options])
    assert rc == 1 and message in capsys.readouterr().err
    assert not out.exists()


def test_max_frames_fails_long_files_before_reading_them(tree, tmp_path):
    summary = run_batch(BatchPlan("denoise", tree, tmp_path / "out", max_frames=100))
    failed = {r.file: r.error for r in summary.results if r.status == "failed"}
    assert set(failed) == {"cmu/martial.bvh", "cmu/dance/salsa.bvh", "cmu/broken.bvh"}
    assert "100" in failed["cmu/martial.bvh"] and "--max-frames" in failed["cmu/martial.bvh"]
    assert summary.count("ok") == 1  # walk.bvh has 60 frames


@pytest.fixture
def cluster():
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as c, distributed.Client(c) as client:
        yield c, client


def test_batch_on_a_local_cluster_matches_the_local_run(tree, tmp_path, cluster):
    c, client = cluster
    local = run_batch(BatchPlan("denoise", tree, tmp_path / "local"))
    spread = run_batch(BatchPlan("denoise", tree, tmp_path / "dask"), scheduler=c.scheduler_address)
    assert [(r.file, r.status, r.output_sha256) for r in spread.results] == \
        [(r.file, r.status, r.output_sha256) for r in local.results]
    assert {r.worker for r in spread.results if r.status == "ok"} <= set(client.run(os.getpid))


def test_workers_on_the_command_line_keep_dask_chatter_out_of_the_terminal(tree, tmp_path):
    """In a real process (pytest's own log capture would hide the chatter): only our lines."""
    pytest.importorskip("distributed")
    run = subprocess.run([sys.executable, "-m", "motionopt", "batch", "denoise", "--in", str(tree), "--out",
                          str(tmp_path / "out"), "--workers", "2"], capture_output=True, text=True, timeout=300)
    assert run.returncode == 1 and "failed: cmu/broken.bvh" in run.stderr  # the tree holds one bad file
    assert "INFO" not in run.stderr and "Scheduler at" not in run.stderr


def test_killing_a_worker_mid_batch_loses_and_duplicates_nothing(tree, tmp_path, cluster):
    c, client = cluster
    for i in range(6):  # more files than workers, so that the killed worker has work queued
        shutil.copy(DATA / CLIPS[i % 2], tree / f"take{i}.bvh")
    pids = client.run(os.getpid)
    killed = []

    def kill_once(result) -> None:
        if not killed:
            victim = next(a for a in pids if a != result.worker)
            os.kill(pids[victim], signal.SIGKILL)
            killed.append(victim)

    out = tmp_path / "out"
    summary = run_batch(BatchPlan("denoise", tree, out), scheduler=c.scheduler_address, on_result=kill_once)
    assert killed
    files = sorted(p.relative_to(tree).as_posix() for p in tree.rglob("*.bvh"))
    assert [r.file for r in summary.results] == files
    assert {r.file for r in summary.results if r.status == "failed"} == {"cmu/broken.bvh"}
    records = manifest_records(out)
    assert sorted(r["file"] for r in records) == files  # each file recorded once
    for r in records:
        if r["status"] == "ok":
            assert sha256(out / r["file"]) == r["output_sha256"]
    assert not list(out.rglob("*.tmp"))
