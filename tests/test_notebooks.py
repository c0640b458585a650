"""The task notebooks run from top to bottom, headless, on the shipped clips and priors,
with the small iteration budgets of MOTIONOPT_NOTEBOOK_FAST=1; and the committed copies
carry their outputs and pictures. The kernel is this interpreter (see
``notebooks/run_notebooks.py``), so a fresh virtual environment with the test extras is
enough: no kernel spec needs installing."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")

NOTEBOOKS = Path(__file__).resolve().parent.parent / "notebooks"
sys.path.insert(0, str(NOTEBOOKS))
from run_notebooks import execute  # noqa: E402

TASKS = ("01-path-following.ipynb", "02-denoising.ipynb", "03-inbetweening-and-completion.ipynb",
         "04-spatial-edit.ipynb", "05-latent-editing.ipynb")
LATENT_CHECKPOINT = NOTEBOOKS.parent / "priors" / "checkpoints" / "cmu-latent.pt"
MAX_BYTES = 1_500_000


def pictures(book) -> int:
    """How many PNG outputs the notebook's cells show."""
    return sum("image/png" in out.get("data", {}) for cell in book.cells if cell.cell_type == "code"
               for out in cell.get("outputs", []))


def expects_pictures(name: str) -> bool:
    """Every notebook shows pictures, except latent editing when its checkpoint is absent."""
    return name != "05-latent-editing.ipynb" or LATENT_CHECKPOINT.exists()


def test_one_notebook_per_task():
    assert sorted(p.name for p in NOTEBOOKS.glob("*.ipynb")) == sorted(TASKS)


@pytest.mark.parametrize("name", TASKS)
def test_notebook_runs(name):
    # small models on a shared two-core machine: more torch threads only contend
    book = execute(NOTEBOOKS / name, fast=True, timeout=300, env={"OMP_NUM_THREADS": "1"})
    first = next(c for c in book.cells if c.cell_type == "code")
    assert "FAST" in "".join(out.get("text", "") for out in first.outputs)  # the switch reached the kernel
    if expects_pictures(name):
        assert pictures(book) >= 2


@pytest.mark.parametrize("name", TASKS)
def test_committed_notebook_shows_its_outputs(name):
    path = NOTEBOOKS / name
    assert path.stat().st_size < MAX_BYTES, f"{name} is {path.stat().st_size} bytes: keep pictures small"
    book = nbformat.read(path, as_version=4)
    nbformat.validate(book)
    code = [c for c in book.cells if c.cell_type == "code"]
    assert all(c.execution_count for c in code), \
        f"{name} is saved unexecuted: run `python notebooks/run_notebooks.py {name}`"
    if expects_pictures(name):
        assert pictures(book) >= 2
