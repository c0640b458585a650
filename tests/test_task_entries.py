"""The CLI's task entries (``motionopt.app.cli.tasks.TASKS``) against the task classes of
problems/: every entry runs as a command, which prints the task's own summary and
reports a command line that parses again, and through the batch, which builds the same
task object and writes a report of the same shape."""
from __future__ import annotations

import json
import shlex
from pathlib import Path

import numpy as np
import pytest

from motionopt import bvh
from motionopt.app.batch import BatchPlan, run_batch
from motionopt.app.cli import build_parser, main
from motionopt.app.cli.tasks import TASKS
from priors.checkpoint import CHECKPOINT_DIR
from clips import DATA, BANDAI_30

#: Options of each task command for a one-second walk; a task added to the CLI needs its line here.
CASES = {
    "path-follow": ("--path", "{path}", "--seconds", "0.3"),
    "denoise": (),
    "inbetween": ("--keep", "0:10,20:30"),
    "complete": ("--prefix", "10", "--frames", "40"),
    "edit": ("--targets", "{targets}"),
}
#: The commands that run with --method latent too.
LATENT = ("denoise", "inbetween", "complete")


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    """IN/walk.bvh (a second of the Bandai walk), a path on from its end, and a target for a hand."""
    for name in ("bandai-locomotion-ccnet.pt", "bandai-latent.pt"):
        if not (CHECKPOINT_DIR / name).exists():
            pytest.skip(f"needs the shipped checkpoint priors/checkpoints/{name}")
    folder = tmp_path_factory.mktemp("entries")
    (folder / "in").mkdir()
    walk = bvh.save(bvh.load(DATA / BANDAI_30)[:30], folder / "in" / "walk.bvh")
    motion = bvh.load(walk)
    ground = motion.positions()[:, motion.skeleton.index("Hips"), [0, 2]]
    end = ground[-1] + (ground[-1] - ground[-10]) / np.linalg.norm(ground[-1] - ground[-10])
    (folder / "path.csv").write_text(f"x,z\n{ground[-1][0]},{ground[-1][1]}\n{end[0]},{end[1]}\n")
    (folder / "targets.json").write_text(json.dumps([{"joint": "Hand_L", "frame": 12, "offset": [0, 0.05, 0]}]))
    return {"in": folder / "in", "walk": walk, "path": folder / "path.csv", "targets": folder / "targets.json"}


def test_every_task_entry_has_a_case_here():
    assert set(CASES) == set(TASKS)
    assert {name for name, entry in TASKS.items() if entry.latent} == set(LATENT)


@pytest.mark.parametrize("task,method", [(t, "ar") for t in CASES] + [(t, "latent") for t in LATENT])
def test_each_task_runs_as_a_command_and_in_a_batch_alike(files, tmp_path, capsys, task, method):
    options = [o.format(**{k: str(v) for k, v in files.items()}) for o in CASES[task]]
    options += ["--method", method] if method == "latent" else []
    report, page = tmp_path / "one.json", tmp_path / "one.html"
    rc = main([task, str(files["walk"]), *options, "--out", str(tmp_path / "one.bvh"), "--report", str(report),
               "--view", str(page), "--plot"])
    out, err = capsys.readouterr()
    assert rc == 0, err
    assert (tmp_path / "one.png").stat().st_size > 0   # the task's picture
    html = page.read_text()  # the page of every task: input and output, the task's targets, its measures
    assert '"name":"input"' in html and '"name":"output"' in html and "foot skating" in html
    assert ("prior NLL per frame" in html) == (method == "ar" or task == "denoise")  # latent denoising is a MAP solve
    assert ('"name":"target path"' in html) == (task == "path-follow")
    assert ('"name":"targets"' in html) == (task == "edit")
    said = [line.strip() for line in out.splitlines() if line.startswith("  ")]
    one = json.loads(report.read_text())
    assert one["view"] == str(page)
    assert said and not any(key in out for key in one["metrics"])  # sentences, not metric names
    # only a gap before a kept frame has a join to tell of (prefix completion has none)
    joins = any(line.startswith("gaps meet the kept frames") for line in said)
    assert joins == ((task, method) == ("inbetween", "ar"))
    build_parser().parse_args(shlex.split(one["command"])[1:])  # the reproducing command is one

    summary = run_batch(BatchPlan(task, files["in"], tmp_path / "batch", tuple(options)))
    assert [r.status for r in summary.results] == ["ok"], summary.results[0].error
    batch = json.loads((tmp_path / "batch" / "walk.json").read_text())
    assert batch.keys() == one.keys() and batch["metrics"].keys() == one["metrics"].keys()
    assert (batch["task"], batch["method"]) == (task, method)
