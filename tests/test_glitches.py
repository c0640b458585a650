"""Capture glitches (``motionopt.glitches``): found where one joint is thrown off by an
offset for a fraction of a second, not found in real motion, turned back, and repaired
by ``denoise``; swirls found in the one real capture known to hold one (CMU salsa/15's
right shin) and filled in, none in ordinary motion."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from motionopt import rotations as R
from motionopt.glitches import fill_swirls, find_glitches, find_swirls, pose_distance, turn_back
from motionopt.noise import glitch, position_noise
from problems.denoise import estimate_noise

from clips import shared_excerpt

#: Real capture the priors never saw: fast dance at 120 fps and a Bandai run at 30 fps.
CLIPS = [("cmu/indian/14.bvh", 0, 1200), ("bandai/dataset-1_run_feminine_001.bvh", 0, 120)]


@pytest.mark.parametrize("relative,start,stop", CLIPS)
def test_real_capture_with_noise_has_no_glitch(relative, start, stop):
    """Ordinary motion, clean or noisy, is left alone: fast limbs do not count as glitches."""
    clean = shared_excerpt(relative, start, stop)
    for level in (0.0, 0.01, 0.03):
        m = clean if level == 0 else position_noise(clean, level, seed=1)[0]
        assert find_glitches(m, estimate_noise(m)[0]) == []
        assert find_swirls(m, estimate_noise(m)[0]) == []


@pytest.mark.parametrize("relative,start,stop", CLIPS)
def test_a_knee_turned_thirty_degrees_for_a_quarter_second_is_found_and_turned_back(relative, start, stop):
    clean = shared_excerpt(relative, start, stop)
    noisy, _ = position_noise(clean, 0.01, seed=2)
    knee = next(i for i, n in enumerate(clean.skeleton.names) if n in ("lShin", "LowerLeg_L"))
    first, count = int(clean.fps), int(round(0.25 * clean.fps))
    seen = glitch(noisy, knee, first, count, 30.0)
    found = find_glitches(seen, estimate_noise(seen)[0])
    assert [(g.joint, g.first, g.stop) for g in found] == [(knee, first, first + count)]
    assert 25 < found[0].degrees < 35
    repaired = turn_back(seen, found)
    foot = list(clean.skeleton.parents).index(knee)
    err = np.linalg.norm(repaired.positions() - clean.positions(), axis=-1)[first:first + count, foot]
    before = np.linalg.norm(seen.positions() - clean.positions(), axis=-1)[first:first + count, foot]
    assert err.mean() < 0.15 * before.mean()


def test_denoise_turns_a_glitch_back_where_a_filter_smears_it():
    """The issue's case: 1 cm of noise and a 0.25 s burst of +30 degrees on a knee. The
    foot below it comes out within 3 cm of the clean clip over the burst (the best
    Butterworth leaves about 15), and the report names the glitch."""
    from priors.checkpoint import CHECKPOINT_DIR, load_prior_cached
    from problems.denoise import Denoise

    prior = load_prior_cached(CHECKPOINT_DIR / "bandai-locomotion-ccnet.pt")   # a clip it never saw
    clean = shared_excerpt("bandai/dataset-1_walk-left_feminine_001.bvh", 0, 90)
    noisy, _ = position_noise(clean, 0.01, seed=0)
    names = clean.skeleton.names
    knee, foot = names.index("LowerLeg_L"), names.index("Foot_L")
    seen = glitch(noisy, knee, 45, 8, 30.0)
    task = Denoise(seen, prior)
    result = task.solve()
    assert result.settings["glitches"] == [{"joint": "LowerLeg_L", "frames": [45, 52],
                                            "degrees": result.settings["glitches"][0]["degrees"]}]
    assert any("LowerLeg_L frames 45-52" in line for line in task.summary(result))

    def foot_error(m) -> float:
        return float(np.linalg.norm(m.positions()[45:53, foot] - clean.positions()[45:53, foot], axis=-1).mean())

    assert foot_error(result.motion) < 0.03 < 0.2 * foot_error(seen)
    kept = Denoise(seen, prior, repair_glitches=False, refine=False).solve()
    assert kept.settings["glitches"] == [] and foot_error(kept.motion) > 0.1


def test_the_real_shin_swirl_of_salsa_15_is_found_and_filled_in():
    """CMU salsa/15 (60 fps), frames 1500-2099: the right shin and foot twist 3000
    degrees a second into poses taken nowhere else (frames 1794-1812); the left leg,
    which does the same dance, is left alone. Filled in, the shin turns no faster than
    twice its usual fastest and stays within its own poses."""
    m = shared_excerpt("cmu/salsa/15.bvh", 1500, 2100)
    names = m.skeleton.names
    found = find_swirls(m, estimate_noise(m)[0])
    assert sorted(names[w.joint] for w in found) == ["rFoot", "rShin"]
    for w in found:
        assert w.first <= 1794 - 1500 and w.stop >= 1812 - 1500 and w.stop - w.first < 0.5 * m.fps
        assert w.degrees_per_second > 2500
    shin = names.index("rShin")
    burst = slice(1790 - 1500, 1820 - 1500)
    assert pose_distance(m)[burst, shin].max() > 50
    repaired = fill_swirls(m, found)
    q = torch.from_numpy(repaired.rotations[:, shin])
    turn = np.degrees(R.quat_angle(q[:-1], q[1:]).numpy()) * m.fps
    assert turn[burst].max() < 2 * np.percentile(turn, 99)
    assert pose_distance(repaired)[burst, shin].max() < 5
    untouched = [j for j in range(len(names)) if j not in {w.joint for w in found}]
    assert np.array_equal(repaired.rotations[:, untouched], m.rotations[:, untouched])
