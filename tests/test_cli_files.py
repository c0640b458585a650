"""``motionopt convert`` and ``motionopt info`` through ``motionopt.app.cli.main``."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from motionopt import bvh
from motionopt.app.cli import main
from clips import DATA, CMU_120, CMU_60, BANDAI_30

MARTIAL = DATA / CMU_120
SALSA = DATA / CMU_60
BANDAI = DATA / BANDAI_30


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("src", [MARTIAL, BANDAI], ids=["cmu", "bandai"])
def test_convert_without_options_reproduces_the_input(src, tmp_path, capsys):
    out = tmp_path / "out.bvh"
    code, stdout, err = run(capsys, "convert", src, out)
    assert code == 0 and err == "" and f"wrote {out}" in stdout
    a, b = bvh.load(src), bvh.load(out)
    assert b.skeleton.names == a.skeleton.names and np.array_equal(b.skeleton.parents, a.skeleton.parents)
    assert b.skeleton.channels == a.skeleton.channels
    assert b.num_frames == a.num_frames and bvh.read_channels(out)[2] == bvh.read_channels(src)[2]
    assert np.abs(b.positions() - a.positions()).max() < 1e-4  # 0.1 mm
    np.testing.assert_allclose(bvh.read_channels(out)[1], bvh.read_channels(src)[1], rtol=1e-9, atol=1e-9)


def test_convert_fps_unit_joints_and_frame_range(tmp_path, capsys):
    out = tmp_path / "out.bvh"
    code, _, err = run(capsys, "convert", MARTIAL, out, "--fps", "30", "--unit", "m", "--drop-joints", "*Thumb*",
                       "*Eye", "--start", "40", "--stop", "200", "-q")
    assert code == 0 and err == ""
    src, got = bvh.load(MARTIAL), bvh.load(out)
    assert got.fps == 30.0 and got.num_frames == 40 and got.source_unit == "m"
    assert not any("Thumb" in n or "Eye" in n for n in got.skeleton.names)
    assert got.skeleton.num_joints == src.skeleton.num_joints - 6
    idx = [src.skeleton.index(n) for n in got.skeleton.names]
    np.testing.assert_allclose(got.positions(), src.positions()[40:200:4][:, idx], atol=1e-6)


def test_convert_source_fps_overrides_a_wrong_header(tmp_path, capsys):
    out = tmp_path / "out.bvh"
    # the clip is 60 fps (240 frames); read as if its header said 120 it would play twice as fast
    assert run(capsys, "convert", SALSA, out, "--source-fps", "120", "--fps", "30")[0] == 0
    assert bvh.load(out).num_frames == 60


def test_convert_never_overwrites_without_force(tmp_path, capsys):
    out = tmp_path / "out.bvh"
    out.write_text("precious")
    code, stdout, err = run(capsys, "convert", MARTIAL, out)
    assert code == 1 and stdout == "" and out.read_text() == "precious"
    assert err.count("\n") == 1 and "exists; pass --force" in err
    src = tmp_path / "in.bvh"
    shutil.copy(SALSA, src)
    before = src.read_bytes()
    code, _, err = run(capsys, "convert", src, src, "--fps", "30")
    assert code == 1 and "is the input file; pass --force" in err and src.read_bytes() == before
    assert run(capsys, "convert", src, src, "--fps", "30", "--force", "-q")[0] == 0
    assert bvh.load(src).fps == 30.0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.bvh", "out.bvh"]  # no temporary files left


def test_info_prints_the_facts(capsys):
    code, out, err = run(capsys, "info", SALSA)
    assert code == 0 and err == ""
    assert "joints: 43 (hip, abdomen" in out and "frames: 240" in out
    assert "frame rate: 60 fps" in out and "duration: 3.983 s" in out
    assert "unit: cm (guessed" in out and "root path length:" in out and "bounding box: x" in out


def test_info_json_matches_the_clip(capsys):
    code, out, _ = run(capsys, "info", BANDAI, "--json")
    info = json.loads(out)
    motion = bvh.load(BANDAI)
    pos = motion.positions()
    assert code == 0 and info["frames"] == 60 and info["fps"] == 30.0 and info["unit"] == "cm"
    assert info["joints"][:2] == ["joint_Root", "Hips"] and info["unit_guessed"] is True
    np.testing.assert_allclose(info["bbox_min"], pos.reshape(-1, 3).min(0))
    np.testing.assert_allclose(info["bbox_max"], pos.reshape(-1, 3).max(0))
    hips = pos[:, motion.skeleton.index("Hips"), :]
    assert info["root_joint"] == "Hips"  # the static joint_Root above it is not the body's root
    steps = np.linalg.norm(np.diff(hips[:, [0, 2]], axis=0), axis=1)
    assert info["root_path_length"] == pytest.approx(steps.sum())
    assert 0.2 < info["root_path_length"] < 4.0  # two seconds of walking
    code, out, _ = run(capsys, "info", BANDAI, "--json", "--fps", "60", "--unit", "m")
    info = json.loads(out)
    assert info["fps"] == 60.0 and info["unit"] == "m" and info["unit_guessed"] is False


@pytest.mark.parametrize("argv,words", [
    (["info", "{bad}"], "{bad}:4: expected a number for OFFSET of Hips, found 'x'"),
    (["info", "{missing}"], "No such file"),
    (["convert", "{good}", "{out}", "--drop-joints", "*Thmb*"], "--drop-joints '*Thmb*' matches no joint"),
    (["convert", "{good}", "{out}", "--start", "300"], "--start 300 is outside"),
    (["convert", "{good}", "{out}", "--fps", "0"], "--fps must be a positive"),
    (["convert", "{good}", "{out}", "--drop-joints", "hip"], "cannot remove the root joint"),
    (["convert", "{bad}", "{out}"], "{bad}:4:"),
], ids=["malformed", "missing", "unknown joint pattern", "frame range", "fps", "root", "malformed input"])
def test_errors_are_one_line_with_non_zero_exit(argv, words, tmp_path, capsys):
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 x 0\n")
    paths = {"bad": bad, "missing": tmp_path / "missing.bvh", "good": MARTIAL, "out": tmp_path / "out.bvh"}
    code, out, err = run(capsys, *[a.format(**paths) for a in argv])
    assert code == 1 and out == ""
    assert err.startswith(f"motionopt {argv[0]}: error: ") and err.count("\n") == 1
    assert words.format(**paths) in err
    assert not (tmp_path / "out.bvh").exists()
