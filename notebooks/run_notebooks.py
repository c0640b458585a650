"""Execute the task notebooks headless, with this interpreter as the kernel, and save them
with their outputs and pictures (the committed notebooks are saved this way, with full
budgets):

    python notebooks/run_notebooks.py                 # every notebook, full budgets, saved
    python notebooks/run_notebooks.py --fast 02-denoising.ipynb   # small budgets, not saved

The kernel is started from a kernel spec written to a temporary folder that names
``sys.executable``, so neither a missing nor another Python's ``python3`` kernel spec can
change which interpreter runs the notebooks (a fresh virtual environment needs only
``ipykernel``, ``nbclient`` and ``nbformat`` installed).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import nbclient
import nbformat
from jupyter_client import KernelManager
from jupyter_client.kernelspec import KernelSpecManager

NOTEBOOKS = Path(__file__).resolve().parent
KERNEL = "motionopt-notebooks"


def kernel_manager(folder: Path) -> KernelManager:
    """A kernel manager whose kernel is ``sys.executable -m ipykernel_launcher``; its spec
    is written under ``folder``."""
    spec = folder / KERNEL
    spec.mkdir(parents=True, exist_ok=True)
    (spec / "kernel.json").write_text(json.dumps({
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "motionopt", "language": "python"}))
    specs = KernelSpecManager(kernel_dirs=[str(folder)], ensure_native_kernel=False)
    return KernelManager(kernel_name=KERNEL, kernel_spec_manager=specs)


def execute(path: Path, fast: bool, timeout: int = 900, env: dict[str, str] | None = None) -> nbformat.NotebookNode:
    """Run every cell of the notebook at ``path`` in its own folder and return it with its
    outputs; raises ``nbclient.exceptions.CellExecutionError`` (naming the cell) on the first
    error. ``fast`` sets MOTIONOPT_NOTEBOOK_FAST=1 for the kernel; ``env`` adds variables."""
    book = nbformat.read(path, as_version=4)
    kernel_env = {**os.environ, **(env or {}), "MOTIONOPT_NOTEBOOK_FAST": "1" if fast else "0"}
    with tempfile.TemporaryDirectory() as tmp:
        client = nbclient.NotebookClient(book, km=kernel_manager(Path(tmp)), timeout=timeout, startup_timeout=120,
                                         resources={"metadata": {"path": str(path.parent)}})
        client.execute(env=kernel_env)
    return book


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Execute the task notebooks and save them with their outputs.")
    parser.add_argument("names", nargs="*", help="notebook file names (default: every *.ipynb here)")
    parser.add_argument("--fast", action="store_true", help="small iteration budgets; the notebooks are not saved")
    args = parser.parse_args(argv)
    paths = [NOTEBOOKS / n for n in args.names] or sorted(NOTEBOOKS.glob("*.ipynb"))
    for path in paths:
        start = time.perf_counter()
        book = execute(path, args.fast)
        if not args.fast:
            nbformat.write(book, path)
        print(f"{path.name}: {time.perf_counter() - start:.0f} s" + ("" if args.fast else ", saved"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
