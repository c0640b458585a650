"""No tracked file holds frames of a clip under ``../shared/data``: the clips stay there.

A frame is recognised by its channel values, not its file: the first twelve values of a
BVH frame row (root position and the first rotations) and the rotation values after the
root position (which a change of length unit leaves alone), rounded to a tenth. An
excerpt, a copy with joints dropped from the end of the hierarchy or in other units, or
rows pasted into a notebook or a CSV are all found.
"""
from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest

from motionopt import bvh

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared" / "data"
KEY_VALUES = 12
#: Rows with fewer large values than this are too plain to tell apart (rest poses, zeros).
MIN_LARGE = 6


def row_keys(rows: np.ndarray) -> set[bytes]:
    """Keys of the distinctive rows of a (frames, values) array."""
    keys: set[bytes] = set()
    if rows.ndim != 2 or rows.shape[1] < KEY_VALUES + 3:
        return keys
    for part in (rows[:, :KEY_VALUES], rows[:, 3:KEY_VALUES + 3]):
        rounded = np.round(part, 1) + 0.0  # + 0.0: -0.0 becomes 0.0
        plain = (np.abs(rounded) > 0.5).sum(axis=1) < MIN_LARGE
        keys.update(r.tobytes() for r in rounded[~plain])
    return keys


def bvh_rows(path: Path) -> np.ndarray:
    """The frame rows of a BVH file, without parsing its hierarchy."""
    text = path.read_text(errors="replace")
    _, _, motion = text.partition("Frame Time:")
    lines = [line for line in motion.splitlines()[1:] if line.strip()]
    width = len(lines[0].split()) if lines else 0
    values = np.fromstring(" ".join(lines), sep=" ") if lines else np.zeros(0)
    return values.reshape(-1, width) if width and values.size % width == 0 else np.zeros((0, 0))


def text_rows(path: Path) -> list[np.ndarray]:
    """Runs of numbers in any text file, one array per line that holds many of them."""
    out = []
    for line in path.read_text(errors="replace").splitlines():
        tokens = line.replace(",", " ").replace('"', " ").replace("\\n", " ").split()
        numbers = []
        for t in tokens:
            try:
                numbers.append(float(t))
            except ValueError:
                continue
        if len(numbers) >= KEY_VALUES + 3:
            out.append(np.array(numbers)[None])
    return out


def file_keys(path: Path) -> set[bytes]:
    if path.suffix.lower() == ".bvh":
        return row_keys(bvh_rows(path))
    keys: set[bytes] = set()
    for rows in text_rows(path):
        keys |= row_keys(rows)
    return keys


def tracked_files() -> list[Path]:
    """Every file git tracks (or, outside a git checkout, every file but caches and venvs)."""
    try:
        names = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
        paths = [ROOT / n for n in names.decode().split("\0") if n]
    except (OSError, subprocess.CalledProcessError):
        skip = {".git", ".venv", "venv", "__pycache__", "node_modules"}
        paths = [p for p in ROOT.rglob("*") if p.is_file() and not skip & set(p.relative_to(ROOT).parts)]
    return [p for p in paths if p.is_file() and p.suffix.lower() not in (".pt", ".png", ".gif", ".npz")]


def shared_keys() -> dict[bytes, Path]:
    keys: dict[bytes, Path] = {}
    for path in sorted(SHARED.rglob("*.bvh")):
        for k in row_keys(bvh_rows(path)):
            keys.setdefault(k, path)
    return keys


needs_shared = pytest.mark.skipif(not SHARED.is_dir(), reason="../shared/data is absent: nothing to compare with")


@pytest.fixture(scope="module")
def shared() -> dict[bytes, Path]:
    return shared_keys()


@needs_shared
def test_no_tracked_file_holds_frames_of_a_shared_clip(shared):
    found = []
    for path in tracked_files():
        hits = file_keys(path) & shared.keys()
        if hits:
            found.append(f"{path.relative_to(ROOT)}: {len(hits)} frame rows of {shared[next(iter(hits))]}")
    assert not found, "tracked files hold frames of ../shared/data clips:\n" + "\n".join(found)


@needs_shared
def test_the_check_finds_excerpts_converted_and_cut_down_copies(shared, tmp_path):
    src = SHARED / "cmu" / "martial" / "03.bvh"
    if not src.exists():
        pytest.skip("needs ../shared/data/cmu/martial/03.bvh")
    clip = bvh.load(src)[300:330]
    copies = {"excerpt": bvh.save(clip, tmp_path / "excerpt.bvh"),
              "metres": bvh.save(clip, tmp_path / "metres.bvh", unit="m"),
              "no fingers": bvh.save(clip.remove_joints(["*Thumb*", "*Index*", "*Mid[0-9]*", "*Ring*", "*Pinky*"]),
                                     tmp_path / "cut.bvh")}
    rows = bvh_rows(copies["excerpt"])[:2]
    pasted = tmp_path / "notebook.ipynb"
    pasted.write_text("\n".join('    "' + " ".join(f"{v:.6f}" for v in r) + '\\n",' for r in rows))
    copies["pasted rows"] = pasted
    for name, path in copies.items():
        assert file_keys(path) & shared.keys(), f"the {name} copy was not recognised"


def test_generated_clips_are_not_recognised_as_each_other():
    from clips import DATA

    keys = [file_keys(p) for p in sorted(DATA.glob("*.bvh"))]
    assert all(keys) and not keys[0] & keys[1] and not keys[1] & keys[2]
