"""The offline demo end to end (small budgets), and its BVH files read by an independent parser."""
from pathlib import Path

import bvhio
import pytest

from motionopt import bvh
from motionopt.cli import main
from motionopt.demo import run_demo


@pytest.fixture(scope="module")
def demo_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("demo")
    summary = run_demo(out, fast=True)
    assert [s.name for s in summary.steps] == ["path following", "denoising", "in-betweening"]
    return out


def test_demo_writes_every_file(demo_dir: Path) -> None:
    for name in ("path-follow.bvh", "path.csv", "path-follow.png", "noisy.bvh", "denoised.bvh",
                 "denoise-trajectory.png", "inbetween.bvh", "inbetween.png", "summary.json"):
        assert (demo_dir / name).stat().st_size > 0, name


@pytest.mark.parametrize("name", ["path-follow.bvh", "noisy.bvh", "denoised.bvh", "inbetween.bvh"])
def test_bvh_outputs_open_in_bvhio(demo_dir: Path, name: str) -> None:
    ours = bvh.load(demo_dir / name)
    other = bvhio.readAsBvh(str(demo_dir / name))
    assert other.FrameCount == ours.num_frames
    assert other.FrameTime == pytest.approx(1.0 / ours.fps, rel=1e-5)
    assert len(other.Root.layout()) == ours.skeleton.num_joints


def test_demo_refuses_to_overwrite(demo_dir: Path, capsys) -> None:
    assert main(["demo", "--out-dir", str(demo_dir), "--fast", "-q"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--force" in err[0]
