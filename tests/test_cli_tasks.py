"""The task commands (path-follow, denoise, inbetween, complete, edit) run as a user runs
them, on short shipped clips with the shipped priors and tiny iteration budgets: outputs
round-trip, constraints hold loosely, and every invalid input fails in one line, writing
nothing."""
from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest
import torch

from motionopt import bvh
from motionopt.rotations import axis_angle_to_quat, quat_multiply
from motionopt.app.cli import main
from motionopt.metrics import foot_skating, jerk
from motionopt.motion import Motion
from motionopt.plot import body_root
from priors.checkpoint import CHECKPOINT_DIR
from problems.path_follow import read_path_csv
from problems.ranges import check_ranges, parse_ranges
from clips import DATA, CMU_120, CMU_60, BANDAI_30


WALK = DATA / BANDAI_30    # 30 fps, 60 frames, Bandai skeleton
MARTIAL = DATA / CMU_120    # 120 fps, 240 frames, CMU skeleton
SALSA = DATA / CMU_60       # 60 fps, 150 frames, CMU skeleton
TINY = ("--iterations", "3", "--pso-particles", "4", "--pso-iterations", "1")
COMMANDS = ("path-follow", "denoise", "inbetween", "complete", "edit")


def needs(*names: str) -> None:
    for name in names:
        if not (CHECKPOINT_DIR / name).exists():
            pytest.skip(f"needs the shipped checkpoint priors/checkpoints/{name}")


def run(capsys, *argv) -> tuple[int, str, str]:
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.fixture(scope="module")
def clips(tmp_path_factory) -> dict[str, Path]:
    """Short cuts of the shipped excerpts (a second or so), saved as the user's files."""
    folder = tmp_path_factory.mktemp("clips")
    cuts = {"walk": (WALK, 0, 30), "martial": (MARTIAL, 0, 121), "martial-odd": (MARTIAL, 0, 120),
            "salsa": (SALSA, 0, 60)}
    out = {}
    for name, (src, a, b) in cuts.items():
        out[name] = bvh.save(bvh.load(src)[a:b], folder / f"{name}.bvh")
    out["martial-noisy"] = bvh.save(noisy(bvh.load(out["martial"]), 0.03, seed=1), folder / "martial-noisy.bvh")
    return out


def noisy(motion: Motion, sigma: float, seed: int) -> Motion:
    """Capture-like noise: ``sigma`` radians on every joint rotation, ``sigma / 10`` metres on the root."""
    rng = np.random.default_rng(seed)
    kick = axis_angle_to_quat(torch.from_numpy(rng.normal(0.0, sigma, motion.rotations.shape[:-1] + (3,))))
    rot = quat_multiply(torch.from_numpy(motion.rotations), kick).numpy()
    return motion.with_frames(rot, motion.root + rng.normal(0.0, sigma / 10, motion.root.shape), motion.translations)


def assert_round_trips(out: Path, source: Path, frames: int) -> None:
    """OUT reads back with the source's joints, channels and frame time, and ``frames`` frames."""
    sk_o, values, ft_o = bvh.read_channels(out)
    sk_i, _, ft_i = bvh.read_channels(source)
    assert sk_o.names == sk_i.names and sk_o.channels == sk_i.channels
    assert ft_o == pytest.approx(ft_i, rel=1e-6)
    assert len(values) == frames
    a, b = bvh.load(out), bvh.load(source)
    assert a.source_unit == b.source_unit
    np.testing.assert_allclose(a.skeleton.offsets, b.skeleton.offsets, atol=1e-9)


def kept_values(path: Path, frames: slice) -> np.ndarray:
    return bvh.read_channels(path)[1][frames]


# ---- each command end to end ----------------------------------------------------------------------

def test_path_follow_continues_the_seed_along_the_path(capsys, clips, tmp_path):
    needs("bandai-locomotion-ccnet.pt")
    seed = bvh.load(clips["walk"])
    hips = body_root(seed.skeleton)  # the Bandai files' ROOT stays on the floor; the hips move
    root = seed.positions()[:, hips, [0, 2]]
    heading = (root[-1] - root[-10]) / np.linalg.norm(root[-1] - root[-10])
    end = root[-1] + 1.5 * heading
    path = tmp_path / "path.csv"
    path.write_text(f"x,z\n{root[-1][0]},{root[-1][1]}\n{end[0]},{end[1]}\n")
    out, report = tmp_path / "out.bvh", tmp_path / "report.json"
    rc, stdout, err = run(capsys, "path-follow", clips["walk"], "--path", path, "--out", out, "--seconds", 0.5,
                          "--report", report, "--plot", *TINY)
    assert rc == 0, err
    assert_round_trips(out, clips["walk"], 30 + 15)
    motion = bvh.load(out)
    new = motion.positions()[30:, hips, [0, 2]]
    np.testing.assert_allclose(motion.positions()[:30], seed.positions(), atol=0.01)  # the seed stays
    along = (new - root[-1]) @ heading
    across = np.abs((new - root[-1]) @ np.array([-heading[1], heading[0]]))
    assert along[-1] > 0.25 and across.mean() < 0.3  # walked forwards, near the line
    rep = json.loads(report.read_text())
    assert rep["input"] == str(clips["walk"]) and rep["output"] == str(out) and rep["task"] == "path-follow"
    assert rep["command"].startswith("motionopt path-follow ") and "--seconds 0.5" in rep["command"]
    assert rep["prior"].endswith("bandai-locomotion-ccnet.pt")
    assert rep["metrics"]["path_distance_cm_mean"] >= 0 and rep["frames"] == 45
    assert out.with_suffix(".png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "root distance to the path" in stdout and f"wrote {out}" in stdout
    assert "cm/s (speed over the ground of feet within 3 cm of their resting height; clean mocap: " in stdout


def test_path_follow_refuses_a_path_in_centimetres_before_synthesis(capsys, clips, tmp_path):
    needs("bandai-locomotion-ccnet.pt")
    seed = bvh.load(clips["walk"])
    root = seed.positions()[:, body_root(seed.skeleton), [0, 2]]
    heading = (root[-1] - root[-10]) / np.linalg.norm(root[-1] - root[-10])
    points = np.stack([root[-1], root[-1] + 1.5 * heading]) * 100  # the same path, in centimetres
    path, out = tmp_path / "path.csv", tmp_path / "out.bvh"
    path.write_text("x,z\n" + "".join(f"{x},{z}\n" for x, z in points))
    rc, stdout, err = run(capsys, "path-follow", clips["walk"], "--path", path, "--out", out, "--seconds", 0.3, *TINY)
    assert rc == 1 and stdout == "" and not out.exists()
    line, = err.strip().splitlines()
    assert f"{path} is refused before synthesis" in line and "m/s" in line and "pass --path-unit cm" in line
    rc, stdout, err = run(capsys, "path-follow", clips["walk"], "--path", path, "--path-unit", "cm", "--out", out,
                          "--seconds", 0.3, "--report", tmp_path / "r.json", *TINY)
    assert rc == 0, err
    assert json.loads((tmp_path / "r.json").read_text())["metrics"]["path_distance_cm_mean"] < 20


def test_a_task_warns_once_when_the_speeds_say_the_header_rate_is_wrong(caplog, tmp_path):
    needs("cmu-ccnet.pt")
    from dataclasses import replace

    from motionopt.app.cli import build_parser
    from motionopt.app.cli.tasks import start
    from motionopt.info import frame_rate_doubt

    for name in (CMU_120, CMU_60, BANDAI_30):  # generated clips at their true rates
        assert frame_rate_doubt(bvh.load(DATA / name), name) is None
    # a brisk 30 fps clip (the 4 s CMU clip played three times as fast), its header saying 120 fps
    brisk = bvh.load(SALSA).resample(10.0)
    assert frame_rate_doubt(replace(brisk, fps=30.0), "brisk.bvh") is None
    clip = bvh.save(replace(brisk, fps=120.0), tmp_path / "brisk.bvh")
    said = {}
    for extra in ((), ("--fps", "30")):
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="motionopt"):
            start(build_parser().parse_args(["denoise", str(clip), "--out", str(tmp_path / "out.bvh"), *extra]))
        said[extra] = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    text, = said[()]
    assert text.startswith(f"{clip}: at the 120 fps its header gives, its limbs move at ")
    assert "faster than a person" in text and text.endswith("pass the true one with --fps (e.g. --fps 30)")
    assert said[("--fps", "30")] == [] and not (tmp_path / "out.bvh").exists()


def test_tasks_run_torch_on_one_thread_unless_told(clips, tmp_path):
    needs("bandai-locomotion-ccnet.pt")
    from motionopt.app.cli import build_parser
    from motionopt.app.cli.tasks import start

    argv = ["denoise", str(clips["walk"]), "--out", str(tmp_path / "out.bvh")]
    try:
        start(build_parser().parse_args([*argv, "--threads", "2"]))
        assert torch.get_num_threads() == 2
        start(build_parser().parse_args(argv))
        assert torch.get_num_threads() == 1  # a busy machine ran path-follow 8-35 times slower on two
    finally:
        torch.set_num_threads(1)


def test_denoise_reduces_jitter_and_tells_what_it_does(capsys, clips, tmp_path):
    needs("cmu-ccnet.pt")
    out = tmp_path / "clean.bvh"
    rc, stdout, err = run(capsys, "denoise", clips["martial-noisy"], "--out", out, "--plot", "--verbose", "--refine",
                          *TINY)
    assert rc == 0, err
    assert_round_trips(out, clips["martial-noisy"], 121)
    before, after = bvh.load(clips["martial-noisy"]), bvh.load(out)
    assert jerk(torch.from_numpy(after.positions()), after.fps) < jerk(torch.from_numpy(before.positions()), before.fps)
    assert "window 1: frames 0-" in stdout and "term prior:" in stdout and "jitter" in stdout
    assert out.with_suffix(".png").exists()


def test_denoise_keeps_the_frame_count_of_any_clip(capsys, clips, tmp_path):
    needs("cmu-ccnet.pt")
    out = tmp_path / "out.bvh"
    rc, _, err = run(capsys, "denoise", clips["martial-odd"], "--out", out, "--iterations", 1, "--quiet")
    assert rc == 0, err
    assert bvh.load(out).num_frames == 120


def test_inbetween_keeps_the_kept_frames_exactly(capsys, clips, tmp_path):
    needs("cmu-ccnet.pt")
    out = tmp_path / "out.bvh"
    rc, stdout, err = run(capsys, "inbetween", clips["martial"], "--keep", "0:30,90:121", "--out", out, "--plot",
                          *TINY)
    assert rc == 0, err
    assert_round_trips(out, clips["martial"], 121)
    for kept in (slice(0, 30), slice(90, 121)):
        np.testing.assert_allclose(kept_values(out, kept), kept_values(clips["martial"], kept), atol=1e-6)
    assert np.abs(kept_values(out, slice(30, 90)) - kept_values(clips["martial"], slice(30, 90))).max() > 1e-3
    assert "frames synthesised" in stdout


@pytest.mark.parametrize("after, frames", [("keep", 121), ("drop", 60), ("synthesise", 121)])
def test_inbetween_keeps_drops_or_synthesises_the_frames_after_the_last_range_as_told(capsys, clips, tmp_path,
                                                                                     after, frames):
    needs("cmu-ccnet.pt")
    out, report = tmp_path / "out.bvh", tmp_path / "r.json"
    argv = ["--keep", "0:30,45:60", "--out", out, "--report", report, "--quiet", *TINY]
    rc, _, err = run(capsys, "inbetween", clips["martial"], *argv, *(() if after == "keep" else ("--after", after)))
    assert rc == 0, err
    assert_round_trips(out, clips["martial"], frames)
    tail = slice(60, 121)
    if after != "drop":
        same = np.abs(kept_values(out, tail) - kept_values(clips["martial"], tail)).max() < 1e-6
        assert same == (after == "keep")
    r = json.loads(report.read_text())
    assert r["settings"]["after"] == after
    assert len(r["per_second"]) >= 1 and r["human_range"] is not None   # naturalness of each second
    assert r["metrics"]["synthesised_frames"] == 15 + (61 if after == "synthesise" else 0)


def test_complete_keeps_the_prefix_and_is_silent_with_quiet(capsys, clips, tmp_path):
    needs("cmu-ccnet.pt")
    out, report = tmp_path / "out.bvh", tmp_path / "r.json"
    rc, stdout, err = run(capsys, "complete", clips["salsa"], "--prefix", 30, "--frames", 90, "--out", out,
                          "--report", report, "--quiet", *TINY)
    assert rc == 0 and stdout == "" and err == ""
    assert_round_trips(out, clips["salsa"], 90)
    # the same poses; the channels may take the other Euler triple of a rotation, as the output
    # (longer than the input) carries no angle-wrapping hint from it
    np.testing.assert_allclose(bvh.load(out).positions()[:30], bvh.load(clips["salsa"]).positions()[:30], atol=1e-6)
    assert json.loads(report.read_text())["settings"]["frames"] == 90


def test_complete_with_clean_feet_slides_less(capsys, clips, tmp_path):
    """On the rollout alone (--no-refine): the solve's own skating and support terms already
    leave this short completion's feet nearly still, with little for the IK to remove.
    The IK is completion's default."""
    needs("bandai-locomotion-ccnet.pt")
    skating = {}
    for flag in (["--no-clean-feet"], []):
        out, report = tmp_path / f"out{len(flag)}.bvh", tmp_path / f"r{len(flag)}.json"
        rc, _, err = run(capsys, "complete", clips["walk"], "--prefix", 10, "--frames", 30, "--out", out,
                         "--report", report, "--quiet", "--no-refine", *flag)
        assert rc == 0, err
        after = bvh.load(out)
        cidx = [after.skeleton.names.index(n) for n in ("Foot_L", "Foot_R")]
        skating[not flag] = float(foot_skating(torch.from_numpy(after.positions()[10:]), after.fps, cidx))
    assert skating[True] < skating[False]
    rc, _, err = run(capsys, "complete", clips["walk"], "--prefix", 10, "--frames", 30, "--out", tmp_path / "l.bvh",
                     "--method", "latent", "--clean-feet")
    assert rc != 0 and "--clean-feet works with --method ar only" in err


def test_edit_moves_the_joint_toward_its_target(capsys, clips, tmp_path):
    needs("bandai-locomotion-ccnet.pt")
    targets = tmp_path / "targets.json"
    targets.write_text(json.dumps([{"joint": "Hand_L", "frame": [10, 12], "offset": [0.0, 0.1, 0.0]}]))
    out = tmp_path / "out.bvh"
    rc, stdout, err = run(capsys, "edit", clips["walk"], "--targets", targets, "--out", out, "--iterations", 8)
    assert rc == 0, err
    assert_round_trips(out, clips["walk"], 30)
    before, after = bvh.load(clips["walk"]), bvh.load(out)
    j = before.skeleton.names.index("Hand_L")
    want = before.positions()[10:13, j] + [0.0, 0.1, 0.0]
    error = np.linalg.norm(after.positions()[10:13, j] - want, axis=-1)
    assert error.max() < 0.07  # from 10 cm, in a few iterations
    assert "targets met within" in stdout


def test_latent_method_denoises_and_completes(capsys, clips, tmp_path):
    needs("bandai-latent.pt")
    out = tmp_path / "denoised.bvh"
    rc, stdout, err = run(capsys, "denoise", clips["walk"], "--method", "latent", "--out", out)
    assert rc == 0, err
    assert_round_trips(out, clips["walk"], 30)
    assert "within the held-out data's range" in stdout  # judged under the shipped autoregressive prior's range
    out = tmp_path / "completed.bvh"
    rc, stdout, err = run(capsys, "complete", clips["walk"], "--method", "latent", "--prefix", 10, "--frames", 45,
                          "--out", out, "--iterations", 1)
    assert rc == 0, err
    assert_round_trips(out, clips["walk"], 45)
    assert "latent codes of" in stdout and "refined in" in stdout
    assert "MAP solve" in stdout
    rc, stdout, err = run(capsys, "complete", clips["walk"], "--method", "latent", "--prefix", 10, "--frames", 45,
                          "--out", out, "--force", "--no-refine", "--no-settle")
    assert rc == 0, err
    assert "latent codes of" in stdout and "MAP solve" not in stdout   # --no-refine: the inversion alone
    rc, stdout, err = run(capsys, "inbetween", clips["walk"], "--method", "latent", "--keep", "0:5,20:30",
                          "--iterations", 0, "--out", out, "--force", "--no-refine")
    assert rc == 0, err
    assert "from the encoder alone" in stdout   # --iterations 0: no refinement of the codes
    assert "naturalness per second:" in stdout  # judged under the skeleton's shipped autoregressive prior


def test_force_overwrites_and_without_it_nothing_changes(capsys, clips, tmp_path):
    needs("bandai-latent.pt")
    out = tmp_path / "out.bvh"
    out.write_text("mine")
    argv = ("denoise", clips["walk"], "--method", "latent", "--out", out, "--quiet")
    rc, _, err = run(capsys, *argv)
    assert rc == 1 and err.strip() == f"motionopt denoise: error: {out} exists; pass --force to overwrite it"
    assert out.read_text() == "mine"
    rc, _, err = run(capsys, *argv, "--force")
    assert rc == 0, err
    assert bvh.load(out).num_frames == 30


# ---- invalid input: one line on stderr, non-zero exit, nothing written -----------------------------

def _files(tmp: Path) -> dict[str, Path]:
    (tmp / "one.csv").write_text("x,z\n0,0\n")
    (tmp / "bad.csv").write_text("x,z\n0,0\n1,north\n")
    (tmp / "header.csv").write_text("x,y\n0,0\n1,1\n")
    (tmp / "timed.csv").write_text("t,x,z\n0.5,0,0\n1.5,1,1\n")
    (tmp / "nose.json").write_text(json.dumps([{"joint": "Nose", "frame": 3, "offset": [0, 0.1, 0]}]))
    (tmp / "hand.json").write_text(json.dumps([{"joint": "Hand_L", "frame": 3, "offset": [0, 0.1, 0]}]))
    return {p.stem: p for p in tmp.iterdir()}


INVALID = [
    # (case, argv after the command and clip, words the error must hold)
    ("path with one point", ("path-follow", "walk", "--path", "{one}"), "at least 2 points"),
    ("path with a bad number", ("path-follow", "walk", "--path", "{bad}"), "bad.csv:3"),
    ("path without x,z header", ("path-follow", "walk", "--path", "{header}"), "header.csv:1"),
    ("timed path with --speed", ("path-follow", "walk", "--path", "{timed}", "--speed", "1"), "drop --speed"),
    ("keep range outside the clip", ("inbetween", "martial", "--keep", "0:30,100:200"), "100:200"),
    ("overlapping keep ranges", ("inbetween", "martial", "--keep", "0:30,20:60"), "overlap"),
    ("keep range not like a slice", ("inbetween", "martial", "--keep", "0-30"), "START:STOP"),
    ("keep range with a negative frame", ("inbetween", "martial", "--keep=-5:30"), "frames count from 0"),
    ("keep ranges that leave no gap", ("inbetween", "martial", "--keep", ":"), "nothing to fill"),
    ("latent keep ranges that leave no gap", ("inbetween", "martial", "--keep", "0:30,30:", "--method", "latent"),
     "nothing to fill"),
    ("prefix longer than the clip", ("complete", "salsa", "--prefix", "61", "--frames", "90"), "--prefix 61"),
    ("frames not after the prefix", ("complete", "salsa", "--prefix", "30", "--frames", "20"), "--frames 20"),
    ("target joint not in the skeleton", ("edit", "walk", "--targets", "{nose}"), "'Nose'"),
    ("skeleton the named prior cannot model", ("denoise", "walk", "--prior", "{cmu}"), "lacks"),
    ("skeleton no shipped prior models", ("denoise", "handless"), "no shipped prior"),
    ("latent checkpoint where an ar one is wanted", ("denoise", "walk", "--prior", "{latent}"), "--method latent"),
    ("latent spatial edit", ("edit", "walk", "--targets", "{hand}", "--method", "latent"), "--method ar"),
    ("unknown optimiser", ("denoise", "walk", "--optimizer", "bfgs"), "scipy, nlopt, torch, adam"),
    ("latent seed with the latent method", ("inbetween", "martial", "--keep", "0:30,60:90", "--method", "latent",
                                            "--latent-seed", "none"), "--latent-seed"),
    ("latent seed with latent completion", ("complete", "salsa", "--prefix", "30", "--frames", "60", "--method",
                                            "latent", "--latent-seed", "none"), "--latent-seed"),
    ("latent seed of the wrong kind", ("inbetween", "martial", "--keep", "0:30,60:90", "--latent-seed", "{cmu}"),
     "latent"),
    ("swarm off and on", ("inbetween", "martial", "--keep", "0:30,60:", "--no-pso", "--pso-particles", "4"), "--no-pso"),
    ("optimiser with latent", ("complete", "walk", "--prefix", "10", "--frames", "40", "--method", "latent",
                               "--optimizer", "nlopt"), "--method ar"),
    ("no iterations for the MAP solver", ("complete", "walk", "--prefix", "10", "--frames", "40", "--iterations", "0"),
     "--no-refine"),
    ("output not BVH", ("denoise", "walk", "--out", "{tmp}/out.txt"), ".bvh"),
    ("output folder missing", ("denoise", "walk", "--out", "{tmp}/nowhere/out.bvh"), "does not exist"),
    ("existing report", ("denoise", "walk", "--report", "{nose}"), "exists"),
    ("report not JSON", ("denoise", "walk", "--report", "{tmp}/report.txt"), ".json"),
]


@pytest.mark.parametrize("case,argv,words", INVALID, ids=[c[0] for c in INVALID])
def test_invalid_input_fails_in_one_line_and_writes_nothing(capsys, clips, tmp_path, case, argv, words):
    needs("cmu-ccnet.pt", "bandai-locomotion-ccnet.pt", "bandai-latent.pt")
    files = _files(tmp_path)
    handless = tmp_path / "handless.bvh"
    bvh.save(bvh.load(clips["walk"]).remove_joints("*Hand*"), handless)
    names = {**{k: str(v) for k, v in files.items()}, "tmp": str(tmp_path),
             "cmu": str(CHECKPOINT_DIR / "cmu-ccnet.pt"), "latent": str(CHECKPOINT_DIR / "bandai-latent.pt")}
    command, clip, *rest = argv
    rest = [a.format(**names) for a in rest]
    for flag, default in (("--out", tmp_path / "out.bvh"), ("--report", tmp_path / "report.json")):
        if flag not in rest:
            rest += [flag, str(default)]
    before = set(tmp_path.rglob("*"))
    rc, stdout, err = run(capsys, command, handless if clip == "handless" else clips[clip], *rest, "--plot")
    assert rc != 0
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"motionopt {command}: error: "), err
    assert words in lines[0]
    assert stdout == ""
    assert set(tmp_path.rglob("*")) == before  # no BVH, report or picture


# ---- the path reader and the help -------------------------------------------------------------------

def test_keep_ranges_read_like_python_slices():
    assert parse_ranges("0:30, 60:90") == [(0, 30), (60, 90)]
    assert check_ranges(parse_ranges(":30,60:"), 120) == [(0, 30), (60, 120)]
    assert check_ranges(parse_ranges("60:,0:30"), 120) == [(0, 30), (60, 120)]
    with pytest.raises(ValueError, match="'60:x' must hold whole frame numbers"):
        parse_ranges("0:30,60:x")
    with pytest.raises(ValueError, match="30:20 is outside"):
        check_ranges(parse_ranges("0:10,30:20"), 120)
    with pytest.raises(ValueError, match="0:70 and 60: overlap"):   # quoted as written, the stop left open
        check_ranges(parse_ranges("60:,0:70"), 120)
    with pytest.raises(ValueError, match="keep range 130: is outside"):
        check_ranges(parse_ranges("0:30,130:"), 120)


def test_read_path_csv_columns_times_and_line_numbers(tmp_path):
    p = tmp_path / "p.csv"
    p.write_text("\ufeffz, x ,T\n\n1,0,0.5\n2,0.5,1.0\n")
    points, times = read_path_csv(p)
    np.testing.assert_array_equal(points, [[0, 1], [0.5, 2]])
    np.testing.assert_array_equal(times, [0.5, 1.0])
    p.write_text("x,z\n0,0\n1,1\n")
    assert read_path_csv(p)[1] is None
    for text, where in (("x,z\n0,0\n1\n", ":3:"), ("x,z\n0,0\n1,inf\n", ":3:"), ("t,x,z\n1,0,0\n1,1,1\n", ":3:"),
                        ("t,x,z\n-1,0,0\n1,1,1\n", ":2:"), ("", "empty"), ("x,z,x\n0,0,0\n1,1,1\n", ":1:")):
        p.write_text(text)
        with pytest.raises(ValueError, match=where):
            read_path_csv(p)


#: The options the README says every task takes.
COMMON = ("--prior", "--seed", "--report", "--plot", "--view", "--force", "--fps", "--unit", "--quiet", "--verbose")


def test_vary_refuses_a_negative_sigma_before_reading_anything(capsys, tmp_path):
    with pytest.raises(SystemExit) as e:
        main(["vary", str(tmp_path / "missing.bvh"), "--sigma", "-1", "--out-dir", str(tmp_path / "v")])
    assert e.value.code == 2 and "--sigma: must be 0 or more, got -1" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", ("fuse", "latent-edit", "vary", "interpolate"))
def test_the_latent_commands_take_the_common_options(capsys, command):
    with pytest.raises(SystemExit) as e:
        main([command, "--help"])
    assert e.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert [option for option in COMMON if option not in text] == []


@pytest.mark.parametrize("command", COMMANDS)
def test_help_names_every_common_option(capsys, command):
    with pytest.raises(SystemExit) as e:
        main([command, "--help"])
    assert e.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    for option in ("--out", *COMMON, "--iterations", "--no-pso", "--pso-particles", "--pso-iterations", "--optimizer"):
        assert option in text
    assert ("--method {ar,latent}" in text) == (command != "path-follow")
