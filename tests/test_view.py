"""The interactive page (``motionopt.view``) and the ``view`` command without a browser: the
page is self-contained, animates every frame with a slider, draws what it is given, and
stays small. tests/test_view_browser.py opens the pages in Chromium."""
from __future__ import annotations

import re
from dataclasses import replace
import numpy as np
import pytest
from plotly.offline import get_plotlyjs

from motionopt import bvh
from motionopt import view as V
from motionopt.app.cli import main
from motionopt.plot import body_root, stick_figure
from clips import BANDAI_30, CMU_120, DATA


@pytest.fixture(scope="module")
def walk():
    return bvh.load(DATA / BANDAI_30)  # 2 s at 30 fps, joint_Root above the hips


@pytest.fixture(scope="module")
def martial():
    return bvh.load(DATA / CMU_120)  # 2 s at 120 fps, fingers and eyes


def _moving(fig, label: str) -> list:
    """The figure's traces of one clip at frame 0: left, right and midline bones, feet, head."""
    return [t for t in fig.data if t.legendgroup == label and t.type == "scatter3d"]


def test_page_animates_every_frame_at_most_30_fps(walk, martial):
    fig = V.view_figure({"walk": walk, "martial": martial})
    n = int(np.floor(martial.duration * V.MAX_FPS + 1e-6)) + 1  # 120 fps shown at 30 fps
    assert len(fig.frames) == n and [f.name for f in fig.frames] == [str(k) for k in range(n)]
    steps = fig.layout.sliders[0].steps
    assert len(steps) == n and list(steps[-1].args[0]) == [str(n - 1)]
    assert [b.label for b in fig.layout.updatemenus[0].buttons] == ["play", "pause"]
    assert fig.layout.scene.camera.up.y == 1  # y up
    # side by side: the second clip starts right of the first, over the whole clip
    left = max(np.nanmax(t.x) for f in fig.frames for t in f.data[:5] if len(t.x))
    right = min(np.nanmin(t.x) for f in fig.frames for t in f.data[5:10] if len(t.x))
    assert right > left
    # every bone is drawn: the polylines of a clip hold each bone as two neighbouring points
    sf = stick_figure(walk)
    drawn = {pair for order in (V._chains([b for b in sf.bones if sf.sides[b[1]] == s]) for s in (1, -1, 0))
             for pair in zip(order, order[1:]) if -1 not in pair}
    assert set(sf.bones) <= drawn


def test_overlay_keeps_clips_where_they_are(walk):
    fig = V.view_figure({"a": walk, "b": walk}, overlay=True)
    a, b = _moving(fig, "a"), _moving(fig, "b")
    for ta, tb in zip(a, b):
        np.testing.assert_array_equal(ta.x, tb.x)


def test_measures_of_a_clip(walk):
    sf = stick_figure(walk)
    hips = walk.positions()[:, body_root(walk.skeleton)]
    m = V.measures(sf, path=hips[:, [0, 2]])
    np.testing.assert_allclose(m["hip height (m)"], hips[:, 1] - sf.ground)
    np.testing.assert_allclose(m["distance to the path (cm)"], 0.0, atol=1e-6)  # the path it walks
    skating = m["foot skating (cm/s)"]
    planted = sf.contacts.any(axis=1)
    assert planted.any() and np.isfinite(skating[planted]).all() and np.isnan(skating[~planted]).all()
    assert (skating[planted] >= 0).all() and skating[planted].max() < 60  # planted feet move under 0.5 m/s


def test_targets_and_curves_are_drawn(walk):
    path = np.array([[0.0, 0.0], [1.0, 0.5], [2.0, 0.0]])
    nll = V.Curve("prior NLL per frame", "walk", np.arange(1, 60) / 30, np.linspace(-50, 20, 59))
    fig = V.view_figure({"walk": walk}, path=path, points=[[0.2, 1.0, 0.3]], curves=[nll])
    names = [t.name for t in fig.data]
    assert "target path" in names and "targets" in names
    rows = [fig.layout[f"yaxis{r + 1 if r else ''}"].title.text for r in range(4)]
    assert "yaxis5" not in fig.layout
    assert rows == ["hip height (m)", "foot skating (cm/s)", "distance to the path (cm)", "prior NLL per frame"]
    # each row has a cursor that the frames move with the slider
    last = fig.frames[-1].data
    cursors = [d for d in last if d.type == "scatter"]
    assert len(cursors) == len(rows) and all(c.x == (59 / 30, 59 / 30) for c in cursors)


def test_page_is_self_contained_and_small(walk, martial, tmp_path):
    out = V.write_view(tmp_path / "v.html", {"walk": walk, "martial": martial})
    html = out.read_text()
    assert "<html" in html[:200]
    plotly_js = get_plotlyjs()
    assert plotly_js in html  # plotly.js is inside the page
    page = html.replace(plotly_js, "")
    assert not re.search(r"<script[^>]+src=", page) and not re.search(r"https?:", page)  # nothing is fetched
    assert "Plotly.newPlot" in page and "addFrames" in page and "showHashFrame" in page
    # plotly.js is about 4.8 MB; two 2-second clips add well under half a megabyte
    assert len(page) < 400_000


def test_bad_input_is_refused(walk, tmp_path):
    with pytest.raises(ValueError, match="at least one"):
        V.view_figure({})
    with pytest.raises(ValueError, match=r"\(N, 2\)"):
        V.view_figure({"walk": walk}, path=np.zeros((1, 2)))
    slow = replace(walk, fps=(walk.num_frames - 1) / (V.MAX_SECONDS + 1))  # lasts over MAX_SECONDS
    with pytest.raises(ValueError, match="--start/--stop"):
        V.view_figure({"slow": slow})
    out = tmp_path / "v.html"
    out.write_text("mine")
    with pytest.raises(FileExistsError, match="force"):
        V.write_view(out, {"walk": walk})
    assert out.read_text() == "mine"
    with pytest.raises(ValueError, match=".html"):
        V.write_view(tmp_path / "v.png", {"walk": walk})


def test_view_command(tmp_path, capsys):
    out = tmp_path / "two.html"
    argv = ["view", str(DATA / BANDAI_30), str(DATA / CMU_120), "--out", str(out), "--start", "0", "--stop", "40"]
    assert main(argv) == 0
    said = capsys.readouterr().out
    assert f"wrote {out} (2 clips" in said and "MB" in said
    assert "Plotly.newPlot" in out.read_text()
    assert main(argv) == 1  # exists
    assert "--force" in capsys.readouterr().err
    assert main([*argv, "--force", "--overlay", "--labels", "a,b", "-q"]) == 0
    assert capsys.readouterr().out == ""
    assert main([*argv, "--force", "--labels", "a"]) == 1
    assert "--labels gives 1 names for 2 inputs" in capsys.readouterr().err
    assert main(["view", str(DATA / BANDAI_30), str(DATA / BANDAI_30), "--out", str(tmp_path / "x.html")]) == 1
    assert "--labels" in capsys.readouterr().err
    assert not (tmp_path / "x.html").exists()


def test_batch_refuses_one_page_for_many_files(tmp_path, capsys):
    argv = ["batch", "denoise", "--in", str(tmp_path), "--out", str(tmp_path / "out"), "--view", "v.html"]
    assert main(argv) == 1
    assert "motionopt view" in capsys.readouterr().err
