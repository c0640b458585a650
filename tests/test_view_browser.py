"""The interactive pages in a real browser: headless Chromium (Debian's ``chromium``) opens
a ``motionopt view`` page of two clips and a task's ``--view`` page from file:// URLs with
every host name unresolvable (so nothing can come from the network), and screenshots
them. The 3-D figure must be drawn (the clips' colours, many colours in all), and the
page opened at another frame (``#frame=N``, which moves the slider) must show another
pose. Skips when no Chromium is installed (.ci/run installs it)."""
from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from motionopt import bvh
from motionopt.app.cli import main
from motionopt.view import CLIP_COLORS, SCENE_PX
from clips import BANDAI_30, CMU_120, DATA

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
BROWSER = next((b for b in map(shutil.which, BROWSERS) if b), None)
WINDOW = (900, 1000)
#: The rows of a screenshot that hold the 3-D scene (under the title, above the slider).
SCENE_ROWS = slice(60, 50 + SCENE_PX - 20)

pytestmark = pytest.mark.skipif(BROWSER is None, reason="no Chromium found (install Debian's package: "
                                "apt-get install chromium) to test the pages in a browser")


def screenshot(page: Path, frame: int, out: Path) -> np.ndarray:
    """RGB pixels of ``page`` opened at ``#frame=frame`` in headless Chromium, offline."""
    cmd = [BROWSER, "--headless", "--disable-gpu", "--no-sandbox", "--enable-unsafe-swiftshader",
           "--host-resolver-rules=MAP * ~NOTFOUND", f"--user-data-dir={out.parent / 'chromium-profile'}",
           f"--screenshot={out}", f"--window-size={WINDOW[0]},{WINDOW[1]}", "--virtual-time-budget=2000",
           f"{page.resolve().as_uri()}#frame={frame}"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and out.exists(), done.stderr[-2000:]
    with Image.open(out) as im:
        return np.asarray(im.convert("RGB")).astype(int)


def near(img: np.ndarray, hex_colour: str, tolerance: int = 40) -> int:
    """Pixels within ``tolerance`` (summed over R, G, B) of a colour."""
    rgb = np.array([int(hex_colour[i:i + 2], 16) for i in (1, 3, 5)])
    return int((np.abs(img - rgb).sum(axis=-1) < tolerance).sum())


def assert_drawn_and_moving(page: Path, frame: int, clips: int, tmp_path: Path) -> None:
    """The page's scene at frame 0 shows each clip's skeleton (its midline colour) over a
    drawn floor and axes, and at ``frame`` shows another pose."""
    first = screenshot(page, 0, tmp_path / "first.png")[SCENE_ROWS]
    later = screenshot(page, frame, tmp_path / "later.png")[SCENE_ROWS]
    for colour in CLIP_COLORS[:clips]:
        assert near(first, colour) > 30, f"no {colour} pixels: the skeleton is not drawn"
    colours = len(np.unique(first.reshape(-1, 3), axis=0))
    assert colours > 200, f"only {colours} colours: the 3-D scene is blank"
    assert (first.sum(axis=-1) < 3 * 250).mean() > 0.05  # not a white page
    changed = (np.abs(first - later).sum(axis=-1) > 30).sum()
    assert changed > 300, f"only {changed} pixels changed between frames 0 and {frame}: the pose did not move"


def test_view_page_of_two_clips(tmp_path, capsys):
    page = tmp_path / "two.html"
    assert main(["view", str(DATA / BANDAI_30), str(DATA / CMU_120), "--out", str(page), "-q"]) == 0
    assert_drawn_and_moving(page, 45, clips=2, tmp_path=tmp_path)


def test_task_view_page(tmp_path, capsys):
    walk = bvh.save(bvh.load(DATA / BANDAI_30)[:30], tmp_path / "walk.bvh")
    targets = tmp_path / "targets.json"
    targets.write_text(json.dumps([{"joint": "Hand_L", "frame": [8, 12], "offset": [0.0, 0.2, 0.1]}]))
    page = tmp_path / "edit.html"
    rc = main(["edit", str(walk), "--targets", str(targets), "--out", str(tmp_path / "out.bvh"), "--view", str(page),
               "-q"])
    assert rc == 0, capsys.readouterr().err
    assert_drawn_and_moving(page, 25, clips=1, tmp_path=tmp_path)  # the output covers the input
