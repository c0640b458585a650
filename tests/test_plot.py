"""Pictures and the render/plot commands, on clips generated in the CMU and Bandai layouts."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from motionopt import bvh
from motionopt import plot as P
from motionopt.app.cli import main
from clips import BANDAI_30, CMU_120, DATA, slide


@pytest.fixture(scope="module")
def walk_path() -> Path:
    return DATA / BANDAI_30  # 22 joints with joint_Root above the hips, 30 fps


@pytest.fixture(scope="module")
def walk(walk_path):
    return bvh.load(walk_path)


@pytest.fixture(scope="module")
def martial_path() -> Path:
    return DATA / CMU_120  # 43 joints with fingers and eyes, 120 fps, centimetres


@pytest.fixture(scope="module")
def martial(martial_path):
    return bvh.load(martial_path)


def _rgb(path: Path) -> np.ndarray:
    with Image.open(path) as im:
        assert im.format == "PNG"
        return np.asarray(im.convert("RGB")).astype(int)


def _has_colour(img: np.ndarray, hex_colour: str, min_pixels: int = 20) -> bool:
    rgb = np.array([int(hex_colour[i:i + 2], 16) for i in (1, 3, 5)])
    return int((np.abs(img - rgb).sum(axis=-1) < 30).sum()) >= min_pixels


# ---- what is drawn ------------------------------------------------------------------------

def test_stick_figure_of_a_walk(walk):
    sf = P.stick_figure(walk)
    sk = walk.skeleton
    hips = P.body_root(sk)
    assert sk.names[hips] == "Hips"  # joint_Root is a helper, not drawn
    np.testing.assert_allclose(sf.points[:, sf.root], walk.positions()[:, hips], atol=1e-9)
    assert sf.points.shape[:2] == (walk.num_frames, sk.num_joints - 1 + len(sk.end_sites))
    assert all(0 <= p < len(sf.sides) and 0 <= c < len(sf.sides) for p, c in sf.bones)
    assert sf.head is not None and sf.neck is not None
    # the lowest points stand on the floor that was found
    assert abs(np.percentile(sf.points[..., 1].min(axis=1), 50) - sf.ground) < 0.05
    # walking: each foot is planted some of the time, lifted some of the time; only feet are planted
    planted = sf.contacts.any(axis=0)
    assert 0 < sf.contacts.mean() < 0.5
    assert planted.any() and not planted[sf.root] and not planted[sf.head]
    assert {int(s) for s in sf.sides[planted]} == {-1, 1}
    assert (sf.sides == 1).sum() == (sf.sides == -1).sum()


def test_stick_figure_leaves_fingers_and_eyes_out(martial):
    sf = P.stick_figure(martial)
    kept = [n for n in martial.skeleton.names if not any(k in n for k in ("Thumb", "Index", "Mid", "Ring",
                                                                          "Pinky", "Eye"))]
    feet_ends = [j for j in martial.skeleton.end_sites if "Foot" in martial.skeleton.names[j]]
    assert sf.points.shape[1] == len(kept) + len(feet_ends)


def test_camera_sees_a_walk_from_the_side(walk):
    # carried along x at 1 m/s, so that the walk goes one way (the generated walk is slow)
    sf = P.stick_figure(slide(walk, [1.0, 0.0, 0.0]))
    cam = P.Camera.beside(sf)
    travel = sf.points[-1, 0] - sf.points[0, 0]
    assert travel @ cam.forward > 0.95 * np.linalg.norm(travel[[0, 2]])  # walks to the right
    assert abs(cam.forward @ cam.left) < 1e-12 and abs(cam.left[1]) < 1e-12
    up = cam.project(np.array([0.0, 1.0, 0.0]))
    np.testing.assert_allclose(up, [0.0, 1.0], atol=1e-12)
    tilted = P.Camera.beside(sf, 30.0)
    assert tilted.project(np.array([0.0, 1.0, 0.0]))[1] == pytest.approx(np.cos(np.deg2rad(30)))
    assert tilted.depth(tilted.left) > tilted.depth(-tilted.left)  # +left is away from the camera


# ---- PNG pictures -------------------------------------------------------------------------

def test_filmstrip(walk, tmp_path):
    out = P.plot_filmstrip({"input": walk, "output": walk[10:]}, tmp_path / "film.png", frames=6)
    img = _rgb(out)
    assert img.shape[1] > img.shape[0] > 200  # a strip: wider than tall
    panels = img[: int(0.85 * img.shape[0])]  # without the legend below them
    for colour in (P.LEFT_COLOR, P.RIGHT_COLOR, P.CONTACT_COLOR):
        assert _has_colour(panels, colour, min_pixels=100)


def test_filmstrip_of_given_frames_with_a_tilted_camera(martial, tmp_path):
    out = P.plot_filmstrip({"martial": martial}, tmp_path / "film.png", frames=[0, 100, 239], elevation=20)
    assert _has_colour(_rgb(out), P.RIGHT_COLOR)
    with pytest.raises(ValueError, match="0..239"):
        P.plot_filmstrip({"martial": martial}, tmp_path / "bad.png", frames=[0, 240])
    with pytest.raises(ValueError, match="at least one frame"):
        P.plot_filmstrip({"martial": martial}, tmp_path / "bad.png", frames=0)
    with pytest.raises(ValueError, match="at most 30 figures per row, got 400"):
        P.plot_filmstrip({"martial": martial}, tmp_path / "bad.png", frames=400)
    assert not (tmp_path / "bad.png").exists()


def test_plot_help_gives_the_filmstrip_limit(capsys):
    with pytest.raises(SystemExit):
        main(["plot", "--help"])
    assert f"at most {P.MAX_FILMSTRIP_FRAMES}" in " ".join(capsys.readouterr().out.split())


def test_root_paths_against_a_target(walk, tmp_path):
    hips = walk.positions()[:, P.body_root(walk.skeleton)]
    target = hips[::10][:, [0, 2]] + [0.3, 0.0]
    out = P.plot_root_paths({"walk": walk, "array": hips + [0.6, 0, 0]}, tmp_path / "path.png", target=target)
    img = _rgb(out)
    assert _has_colour(img, "#1f77b4") and _has_colour(img, "#ff7f0e")  # the two paths, C0 and C1
    with pytest.raises(ValueError, match=r"\(N, 2\)"):
        P.plot_root_paths({"walk": walk}, tmp_path / "bad.png", target=np.zeros((1, 2)))
    with pytest.raises(ValueError, match="shape"):
        P.plot_root_paths({"walk": np.zeros((5, 4))}, tmp_path / "bad.png")


def test_path_follow_picture_shows_path_feet_poses_and_heights(walk, tmp_path):
    hips = walk.positions()[:, P.body_root(walk.skeleton)]
    target = hips[20::5][:, [0, 2]]
    out = P.plot_path_follow(walk, tmp_path / "pf.png", target, new_from=20)
    img = _rgb(out)
    for colour in (P.LEFT_COLOR, P.RIGHT_COLOR, P.CONTACT_COLOR, "#ff7f0e"):  # poses, planted feet, foot tracks
        assert _has_colour(img, colour)
    with pytest.raises(ValueError, match=r"\(N, 2\)"):
        P.plot_path_follow(walk, tmp_path / "bad.png", np.zeros((1, 2)))
    assert not (tmp_path / "bad.png").exists()


def test_joint_trajectories_noisy_against_clean(walk, tmp_path):
    rng = np.random.default_rng(0)
    j = walk.skeleton.index("Hand_L")
    clean = walk.positions()
    noisy = clean + rng.normal(0.0, 0.02, clean.shape)
    out = P.plot_joint_trajectories({"noisy": noisy, "clean": walk}, j, tmp_path / "traj.png", fps=walk.fps)
    img = _rgb(out)
    assert _has_colour(img, "#1f77b4") and _has_colour(img, "#ff7f0e")
    with pytest.raises(ValueError, match="fps"):
        P.plot_joint_trajectories({"noisy": noisy}, j, tmp_path / "bad.png")
    with pytest.raises(KeyError, match="Nope"):
        P.plot_joint_trajectories({"clean": walk}, "Nope", tmp_path / "bad.png")


@pytest.fixture
def drawn(monkeypatch) -> list:
    """The matplotlib figures the picture functions save, as they saved them."""
    figures = []
    save = P._save

    def keep(fig, out):
        figures.append(fig)
        return save(fig, out)

    monkeypatch.setattr(P, "_save", keep)
    return figures


def test_filmstrip_title_clears_the_time_labels_however_many_rows(walk, tmp_path, drawn):
    for rows in (1, 6):
        P.plot_filmstrip({f"take {i}": walk for i in range(rows)}, tmp_path / f"{rows}.png", title="Takes")
        fig = drawn[-1]
        renderer = fig.canvas.get_renderer()
        title = fig._suptitle.get_window_extent(renderer)
        labels = [ax.title.get_window_extent(renderer) for ax in fig.axes if ax.get_title()]
        assert labels and all(title.y0 >= label.y1 for label in labels), rows


def test_path_pictures_see_the_ground_from_above(tmp_path, drawn):
    # a walker heading +x turns to its left: towards -z (left = up x forward, y up, right-handed)
    a = np.linspace(0.0, np.pi / 2, 30)
    turn = np.stack([np.sin(a), np.cos(a) - 1.0], axis=-1)
    P.plot_root_paths({"left turn": turn}, tmp_path / "turn.png")
    ax = drawn[-1].axes[0]
    start, end = ax.transData.transform(turn[[0, -1]])
    assert end[0] > start[0] and end[1] > start[1]  # seen from above, heading right, it turns up the page
    assert "seen from above" in ax.get_title() and "down the page" in ax.get_ylabel()


def test_trajectory_times_count_from_the_first_frame_drawn(walk_path, tmp_path, capsys, drawn):
    assert main(["plot", str(walk_path), "--kind", "trajectory", "--start", "15", "--out",
                 str(tmp_path / "t.png")]) == 0
    t = drawn[-1].axes[0].lines[0].get_xdata()
    assert t[0] == pytest.approx(15 / 30) and drawn[-1].axes[0].get_xlim()[0] >= 0.4


def _limbs_height(path: Path) -> list[int]:
    """Pixel rows each frame of a GIF spans with limb colours, outside the legend (bottom right)."""
    heights = []
    with Image.open(path) as im:
        for f in range(im.n_frames):
            im.seek(f)
            img = np.asarray(im.convert("RGB")).astype(int)
            mask = np.zeros(img.shape[:2], bool)
            for colour in (P.LEFT_COLOR, P.RIGHT_COLOR):
                rgb = np.array([int(colour[i:i + 2], 16) for i in (1, 3, 5)])
                mask |= np.abs(img - rgb).sum(axis=-1) < 40
            mask[-70:, -170:] = False  # the legend
            rows = np.nonzero(mask.any(axis=1))[0]
            heights.append(int(rows.max() - rows.min()) if len(rows) else 0)
    return heights


def test_gif_from_above_keeps_the_figure_large_along_a_curve(walk, tmp_path):
    # the walk carried along a quarter circle of 5 m, so that it moves away from the camera as it goes
    a = np.linspace(0.0, np.pi / 2, walk.num_frames)[:, None]
    curve = walk.with_frames(walk.rotations, walk.root + 5.0 * np.hstack([np.sin(a), 0 * a, 1 - np.cos(a)]),
                             walk.translations)
    side = _limbs_height(P.render_gif(curve, tmp_path / "side.gif", elevation=0))
    above = _limbs_height(P.render_gif(curve, tmp_path / "above.gif", elevation=40))
    assert min(side) > 0 and min(above) > 0  # in view in every frame
    assert np.mean(above) > 0.6 * np.mean(side)  # tilting the camera does not shrink the figure


def test_pictures_are_not_overwritten_without_force(walk, tmp_path):
    out = tmp_path / "path.png"
    out.write_bytes(b"mine")
    with pytest.raises(FileExistsError, match="force"):
        P.plot_root_paths({"walk": walk}, out)
    assert out.read_bytes() == b"mine"
    P.plot_root_paths({"walk": walk}, out, force=True)
    assert _rgb(out).size > 0
    with pytest.raises(ValueError, match=".png"):
        P.plot_root_paths({"walk": walk}, tmp_path / "path.jpg")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        P.plot_root_paths({"walk": walk}, tmp_path / "missing" / "path.png")


# ---- animation ----------------------------------------------------------------------------

def _gif_frames(path: Path) -> tuple[int, list[int], tuple[int, int]]:
    with Image.open(path) as im:
        assert im.format == "GIF"
        durations = []
        for k in range(im.n_frames):
            im.seek(k)
            durations.append(im.info["duration"])
        return im.n_frames, durations, im.size


def test_gif_plays_at_real_speed(martial, tmp_path):
    clip = martial[:120]  # 1 s at 120 fps
    out = P.render_gif(clip, tmp_path / "m.gif", fps=20, size=(160, 120))
    n, durations, size = _gif_frames(out)
    assert size == (160, 120)
    assert n == 20  # frames at 0, 1/20, ..., 19/20 s (the clip ends at 119/120 s)
    assert all(d == 50 for d in durations)
    with pytest.raises(FileExistsError):
        P.render_gif(clip, out, fps=20, size=(160, 120))


def test_gif_default_rate_and_moving_figure(walk, tmp_path):
    out = P.render_gif(walk[:30], tmp_path / "w.gif", size=(160, 120), elevation=0)
    n, durations, _ = _gif_frames(out)
    assert n == int(np.floor((29 / walk.fps) * P.GIF_FPS + 1e-6)) + 1
    assert set(durations) == {40}
    with Image.open(out) as im:
        first = np.asarray(im.convert("RGB")).astype(int)
        im.seek(n - 1)
        last = np.asarray(im.convert("RGB")).astype(int)
    assert np.abs(first - last).sum(axis=-1).astype(bool).sum() > 200  # the figure moved


def test_gif_rejects_bad_settings(walk, tmp_path):
    with pytest.raises(ValueError, match="positive"):
        P.render_gif(walk, tmp_path / "a.gif", fps=0)
    with pytest.raises(ValueError, match="too small"):
        P.render_gif(walk, tmp_path / "a.gif", size=(20, 20))
    with pytest.raises(ValueError, match=".gif"):
        P.render_gif(walk, tmp_path / "a.mp4")
    assert not list(tmp_path.iterdir())


# ---- commands -----------------------------------------------------------------------------

def _one_line_error(capsys, command: str) -> str:
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"motionopt {command}: error: ") and "\n" not in err, err
    return err


def test_render_command(walk_path, tmp_path, capsys):
    out = tmp_path / "walk.gif"
    args = ["render", str(walk_path), "--out", str(out), "--fps", "10", "--start", "5", "--stop", "35",
            "--size", "200x150"]
    assert main(args + ["-q"]) == 0
    assert capsys.readouterr().out == ""
    n, durations, size = _gif_frames(out)
    assert (n, size) == (10, (200, 150)) and set(durations) == {100}  # 30 frames at 30 fps, shown at 10 fps
    assert main(args) == 1
    assert "--force" in _one_line_error(capsys, "render")
    assert main(args + ["--force"]) == 0
    assert f"wrote {out}" in capsys.readouterr().out


def test_plot_command_kinds(walk_path, martial_path, tmp_path, capsys):
    for kind in ("filmstrip", "path", "trajectory"):
        out = tmp_path / f"{kind}.png"
        assert main(["plot", str(walk_path), str(walk_path), "--labels", "a,b", "--kind", kind, "--frames", "3",
                     "--out", str(out), "-q"]) == 0
        assert _rgb(out).shape[0] > 100
    out = tmp_path / "hand.png"
    assert main(["plot", str(martial_path), "--kind", "trajectory", "--joint", "lHand", "--start", "20",
                 "--out", str(out)]) == 0
    assert f"wrote {out}" in capsys.readouterr().out


@pytest.mark.parametrize("command, extra, message", [
    ("render", ["--size", "big"], "WIDTHxHEIGHT"),
    ("render", ["--start", "500"], "--start 500"),
    ("render", ["--start", "10", "--stop", "5"], "--stop 5"),
    ("render", ["--fps", "-3"], "positive"),
    ("plot", ["--kind", "trajectory", "--joint", "Nope"], "joint 'Nope' is not in"),
    ("plot", ["--labels", "one,two"], "2 names for 1 inputs"),
    ("plot", ["--stop", "1"], "fewer than 2 frames"),
])
def test_command_errors(walk_path, tmp_path, capsys, command, extra, message):
    out = tmp_path / ("x.gif" if command == "render" else "x.png")
    assert main([command, str(walk_path), "--out", str(out)] + extra) == 1
    assert message in _one_line_error(capsys, command)
    assert not out.exists()


def test_plot_command_file_errors(walk_path, tmp_path, capsys):
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT hip\n{\n  OFFSET 0 0\n")
    assert main(["plot", str(bad), "--out", str(tmp_path / "x.png")]) == 1
    assert "bad.bvh" in _one_line_error(capsys, "plot")
    assert main(["plot", str(walk_path), "--out", str(tmp_path / "x.jpg")]) == 1
    assert ".png" in _one_line_error(capsys, "plot")
    existing = tmp_path / "keep.png"
    existing.write_bytes(b"mine")
    assert main(["plot", str(walk_path), "--out", str(existing)]) == 1
    assert "--force" in _one_line_error(capsys, "plot")
    assert existing.read_bytes() == b"mine"
