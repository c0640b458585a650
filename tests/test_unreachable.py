"""Constraints no person can meet (too far, out of a limb's reach) still give the best
compromise, with warnings that name the constraint and by how much: in the task result,
in the --report JSON under "warnings", and in the log; a path-following pace no person
runs is refused before synthesis. Short shipped clips,
no solver, so each case takes a second or two."""
from __future__ import annotations

import json
import logging

import numpy as np
import pytest

from motionopt import bvh
from motionopt.app.cli import main
from priors.checkpoint import CHECKPOINT_DIR, load_prior
from problems.edit import JointTarget, SpatialEdit
from problems.inbetween import Inbetween
from problems.path_follow import PathFollow
from clips import DATA, CMU_120, BANDAI_30


TINY = ("--iterations", "3", "--pso-particles", "4", "--pso-iterations", "1")


def prior(name: str):
    if not (CHECKPOINT_DIR / name).exists():
        pytest.skip(f"needs the shipped checkpoint priors/checkpoints/{name}")
    return load_prior(CHECKPOINT_DIR / name)


@pytest.fixture(scope="module")
def walk():
    """One second of the Bandai walk (30 fps), its prior, and the line it walks along:
    its hips' last ground position and heading."""
    motion = bvh.load(DATA / BANDAI_30)[:30]
    ground = motion.positions()[:, motion.skeleton.index("Hips"), [0, 2]]
    heading = (ground[-1] - ground[-10]) / np.linalg.norm(ground[-1] - ground[-10])
    return motion, prior("bandai-locomotion-ccnet.pt"), ground[-1], heading


def distance_to_segment(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    t = np.clip((points - a) @ (b - a) / ((b - a) @ (b - a)), 0, 1)
    return np.linalg.norm(a + t[:, None] * (b - a) - points, axis=1)


def only(warnings: list[str], words: str) -> str:
    found = [w for w in warnings if words in w]
    assert len(found) == 1, warnings
    return found[0]


# ---- path following ---------------------------------------------------------------------------------

def test_path_follow_too_fast_is_refused_before_synthesis(capsys, walk, tmp_path):
    motion, _, end, heading = walk
    clip, path = tmp_path / "walk.bvh", tmp_path / "path.csv"
    bvh.save(motion, clip)
    far = end + 10 * heading
    path.write_text(f"x,z\n{end[0]},{end[1]}\n{far[0]},{far[1]}\n")
    out = tmp_path / "out.bvh"
    rc = main([str(a) for a in ("path-follow", clip, "--path", path, "--speed", 20, "--seconds", 0.5,
                                "--out", out, *TINY)])
    assert rc == 1 and not out.exists()
    assert capsys.readouterr().err.strip() == (
        f"motionopt path-follow: error: path-follow: {path} is refused before synthesis: the requested speed is "
        "20.0 m/s, faster than a person runs (about 8 m/s at most)")


def test_path_follow_times_faster_than_a_person_name_the_stretch(walk):
    motion, walk_prior, end, heading = walk
    path = np.stack([end, end + 1.0 * heading, end + 11.0 * heading])
    with pytest.raises(ValueError, match=r"its times ask for 20\.0 m/s from t = 0\.5 s to 1 s \(10\.00 m in "
                                         r"0\.5 s\), faster than a person runs \(about 8 m/s at most\); the path is read in metres"):
        PathFollow(motion, path, walk_prior, times=np.array([0.0, 0.5, 1.0]), candidates=2).solve()


def test_path_follow_far_from_the_seed_refuses_the_join_and_warns_of_the_distance(walk):
    motion, walk_prior, end, heading = walk
    side = np.array([-heading[1], heading[0]])
    with pytest.raises(ValueError, match=r"the seed ends at x, z = .*, 5\.0\d m from where the path takes it, and "
                                         r"joining it in 0\.5 s asks for 10\.\d m/s"):
        PathFollow(motion, np.stack([end + 5 * side, end + 5 * side + 10 * heading]), walk_prior, seconds=0.3,
                   candidates=2).solve()
    a, b = end + 2 * side, end + 2 * side + 10 * heading  # a join at 4 m/s: made, and the root stays off the path
    result = PathFollow(motion, np.stack([a, b]), walk_prior, seconds=0.3, candidates=2).solve()
    n_seed = 30  # the seed's frames at the prior's rate (both 30 fps)
    dist = distance_to_segment(result.model_motion.root[n_seed:, [0, 2]], a, b)
    assert dist.mean() == pytest.approx(result.metrics["path_distance_cm_mean"] / 100)
    only(result.warnings, f"the root keeps {dist.mean():.2f} m from the path on average ({dist.max():.2f} m at "
                          "most), beyond the tolerance of 0.1 m")
    only(result.warnings, f"the motion ends {dist[-1]:.2f} m from the path, beyond the tolerance of 0.1 m")
    assert dist[-1] > 0.1 and len(result.warnings) == 2


def test_path_follow_within_reach_has_no_warnings(walk):
    motion, walk_prior, end, heading = walk
    result = PathFollow(motion, np.stack([end, end + 2 * heading]), walk_prior, speed=1.2, candidates=2).solve()
    assert result.warnings == [] and result.report()["warnings"] == result.naturalness_warnings


# ---- spatial edits ----------------------------------------------------------------------------------

def test_edit_out_of_reach_names_the_target_the_miss_and_the_limb(walk):
    motion, walk_prior, _, _ = walk
    result = SpatialEdit(motion, [JointTarget("Hand_L", (10, 12), offset=(0.0, 3.0, 0.0))], walk_prior).solve()
    model = result.model_motion
    sk, pos = model.skeleton, model.positions()
    hand, shoulder = sk.index("Hand_L"), sk.index("Shoulder_L")
    goal = motion.positions()[10:13, motion.skeleton.index("Hand_L")] + [0.0, 3.0, 0.0]
    miss = np.linalg.norm(pos[10:13, hand] - goal, axis=1)
    worst = int(miss.argmax())
    arm = sum(np.linalg.norm(sk.offsets[sk.index(n)]) for n in ("Hand_L", "LowerArm_L", "UpperArm_L"))
    reach = np.linalg.norm(goal[worst] - pos[10 + worst, shoulder])
    assert miss.max() * 100 == pytest.approx(result.metrics["target_error_cm_max"], abs=0.01)
    only(result.warnings, f"edit: target 0 (Hand_L) is missed by more than 1 cm at 3 of its 3 frames, by up to "
                          f"{miss.max() * 100:.1f} cm at frame {10 + worst}; the target is {reach:.2f} m from "
                          f"Shoulder_L, out of reach of the {arm:.2f} m limb")


def test_warnings_go_to_the_report_and_the_log(capsys, caplog, walk, tmp_path):
    motion, _, _, _ = walk
    clip, targets, report = tmp_path / "walk.bvh", tmp_path / "targets.json", tmp_path / "report.json"
    bvh.save(motion, clip)
    targets.write_text(json.dumps([{"joint": "Hand_L", "frame": [10, 12], "offset": [0.0, 3.0, 0.0]}]))
    with caplog.at_level(logging.WARNING, logger="problems"):
        rc = main([str(a) for a in ("edit", clip, "--targets", targets, "--out", tmp_path / "out.bvh", "--report",
                                    report, *TINY)])
    assert rc == 0, capsys.readouterr().err
    warnings = json.loads(report.read_text())["warnings"]
    assert len([w for w in warnings if "out of reach" in w]) == 1 and "out of reach" in warnings[0]
    assert all("out of reach" in w or "leaves the held-out data's" in w for w in warnings)  # or naturalness
    assert [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING] == warnings


def test_edit_with_clashing_targets_names_the_one_missed(walk):
    motion, walk_prior, _, _ = walk
    targets = [JointTarget("Hand_L", (10, 10), offset=(0.0, 0.1, 0.0)),
               JointTarget("Hand_L", (10, 10), offset=(0.0, 0.05, 0.0))]
    result = SpatialEdit(motion, targets, walk_prior).solve()
    text = only(result.warnings, "is missed by")
    assert text == ("edit: target 0 (Hand_L) is missed by more than 1 cm at 1 of its 1 frames, by up to "
                    f"{result.metrics['target_error_cm_max']:.1f} cm at frame 10")
    assert result.metrics["target_error_cm_max"] == pytest.approx(5.0, abs=0.1)  # they are 5 cm apart


def test_edit_within_reach_has_no_warnings(walk):
    motion, walk_prior, _, _ = walk
    result = SpatialEdit(motion, [JointTarget("Hand_L", (10, 12), offset=(0.0, 0.1, 0.0))], walk_prior).solve()
    assert result.warnings == [] and result.metrics["target_error_cm_max"] < 1.0


# ---- in-betweening ----------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def martial():
    """One second of the CMU martial-arts clip (120 fps) and its prior."""
    return bvh.load(DATA / CMU_120)[:121], prior("cmu-ccnet.pt")


def test_inbetween_gap_too_far_to_cover_names_the_gap_and_the_speed(martial):
    motion, cmu_prior = martial
    root = motion.root.copy()
    root[90:, 0] += 30.0  # the frames after the gap, 30 m away
    far = motion.with_frames(motion.rotations, root, motion.translations)
    result = Inbetween(far, [(0, 30), (90, 121)], cmu_prior).solve()
    hips = far.positions()[:, 0, [0, 2]]
    distance, seconds = np.linalg.norm(hips[90] - hips[29]), 61 / 120
    assert distance == pytest.approx(30.0, abs=0.5)
    text = only(result.warnings, "the gap 30:90")
    assert text == (f"inbetween: the gap 30:90 asks the root to cover {distance:.2f} m from kept frame 29 to kept "
                    f"frame 90 in {seconds:.2f} s, {distance / seconds:.1f} m/s, faster than a person runs (about "
                    "8 m/s at most); the synthesised frames are the best compromise and cannot look natural")
    assert result.motion.num_frames == 121  # still a result
    unchanged = Inbetween(motion, [(0, 30), (90, 121)], cmu_prior).solve()
    assert unchanged.warnings == []
