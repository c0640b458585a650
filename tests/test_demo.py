"""The offline demo end to end (small budgets) on motion it generates itself, and its BVH
files read by an independent parser."""
import re
from pathlib import Path

import bvhio
import pytest

from motionopt import bvh
from motionopt.app.cli import main
from motionopt.app.cli.demo import EXPLAIN, figure
from motionopt.app.demo import FILES, demo_inputs, run_demo
from priors.sampling import root_speed


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    summary = run_demo(out, fast=True)
    assert [s.name for s in summary.steps] == ["inputs", "path following", "denoising", "in-betweening",
                                               "completion", "spatial edit", "latent edit"]
    return summary


@pytest.fixture(scope="module")
def demo_dir(demo_run) -> Path:
    return demo_run.out_dir


def test_the_readme_shows_what_the_demo_prints(demo_run) -> None:
    """The README's sample summary: every line explained as the demo explains it, and its
    figures those of a run (but the path and the speeds, which --fast and the machine change),
    within 5%: the round-off of another CPU moves an L-BFGS solve a little (the denoised
    jitter: 131.70 on one machine, 128.94 on another, with the same packages)."""
    readme = (Path(__file__).resolve().parent.parent / "README.md").read_text()
    block = readme.split("The printed summary explains every number")[1].split("```")[1]
    shown: dict[str, list[tuple[str, str]]] = {}
    for line in block.splitlines():
        if head := re.match(r"(\w[\w -]*): .* \(\d+ s\)$", line):
            shown[head[1]] = []
        elif row := re.match(r"\s+(\S+)  (.+)$", line):
            shown[list(shown)[-1]].append((row[1], row[2]))
    assert set(shown) == {s.name for s in demo_run.steps}
    for step in demo_run.steps:
        assert [text for _, text in shown[step.name]] == [EXPLAIN[k] for k in step.metrics], step.name
        if step.name != "path following":
            assert [float(v) for v, _ in shown[step.name]] == pytest.approx(
                [float(figure(step.metrics[k])) for k in step.metrics], rel=0.05), step.name


def test_the_package_ships_no_motion_files() -> None:
    package = Path(bvh.__file__).parent
    assert not [p for p in package.rglob("*") if p.suffix.lower() in (".bvh", ".csv")]


def test_demo_writes_every_file(demo_dir: Path) -> None:
    for name in FILES:
        assert (demo_dir / name).stat().st_size > 0, name


@pytest.mark.parametrize("name", [n for n in FILES if n.endswith(".bvh")])
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


def test_the_generated_inputs_are_repeatable_and_move() -> None:
    (walk, moves), (walk2, _) = demo_inputs(), demo_inputs()
    assert walk.rotations.tobytes() == walk2.rotations.tobytes()
    assert root_speed(walk) > 0.3  # a walk, not a figure standing still
    feet = moves.positions()[:, [moves.skeleton.index("lFoot"), moves.skeleton.index("rFoot")], 1]
    assert abs(feet.min()) < 0.05  # on the floor
