"""What the task notebooks share: where the data and priors are, the FAST switch, a
scratch folder for pictures, and a metrics table shown as Markdown."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

from IPython.display import Image, Markdown

ROOT = Path(__file__).resolve().parent.parent
#: Short real clips shipped with the tests: the notebooks run without ../shared.
CLIPS = ROOT / "tests" / "data"
CHECKPOINTS = ROOT / "priors" / "checkpoints"
#: The full data set, when this checkout sits beside it (see ../shared/data/README.md).
SHARED = ROOT.parent / "shared" / "data"
#: MOTIONOPT_NOTEBOOK_FAST=1 (the test run) shrinks every iteration budget.
FAST = os.environ.get("MOTIONOPT_NOTEBOOK_FAST", "") not in ("", "0")

_FIGURES = Path(tempfile.mkdtemp(prefix="motionopt-notebook-"))


def figure(name: str) -> Path:
    """A fresh path for a picture; the pictures are shown inline, not kept."""
    return _FIGURES / name


def show(path: Path) -> Image:
    """A written PNG, embedded in the notebook."""
    return Image(filename=str(path))


def _cell(v) -> str:
    if isinstance(v, float):
        return f"{v:.3g}" if abs(v) < 1e4 else f"{v:.0f}"
    if isinstance(v, (list, tuple)):
        return ", ".join(_cell(x) for x in v) or "-"
    return str(v)


def table(header: list[str], rows: list[list]) -> Markdown:
    """A Markdown table; floats to three significant digits."""
    lines = ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    lines += ["| " + " | ".join(_cell(v) for v in row) + " |" for row in rows]
    return Markdown("\n".join(lines))


def metrics_table(metrics: dict) -> Markdown:
    """A task's metrics, one per row."""
    return table(["metric", "value"], [[k, v] for k, v in metrics.items()])


def terms_table(report: dict) -> Markdown:
    """Every objective term's value where the solver started and where it ended."""
    s = report.get("solver")
    if s is None:
        return Markdown("*No MAP solver ran in this task, so there are no objective terms to show.*")
    return table(["term", "start", "end"], [[k, s["terms_start"].get(k, float("nan")), v]
                                            for k, v in s["terms"].items()])
