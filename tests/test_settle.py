"""Settling a motion under the autoregressive prior (``problems.settle``) on real capture:
it makes a roughened walk likely again while staying within centimetres of it."""
from __future__ import annotations

import numpy as np
import pytest

from motionopt.noise import position_noise
from priors.checkpoint import CHECKPOINT_DIR, load_prior_cached
from priors.score import score_motion
from problems.settle import Settle

from clips import shared_excerpt


@pytest.fixture(scope="module")
def prior():
    return load_prior_cached(CHECKPOINT_DIR / "bandai-locomotion-ccnet.pt")


def test_settle_makes_a_roughened_walk_likely_within_centimetres(prior):
    walk = shared_excerpt("bandai2/dataset-2_walk_active_002.bvh", 0, 150)
    rough, _ = position_noise(walk, 0.02, seed=1)
    result = Settle(rough, prior).solve()
    out = result.motion
    assert out.num_frames == rough.num_frames and out.fps == rough.fps
    assert out.skeleton.names == rough.skeleton.names
    before, after = (score_motion(prior, m).nll_per_frame for m in (rough, out))
    assert after < before - 300  # 2 cm of noise costs the walk about 530 nats per frame; settled, about 50 are left
    assert result.metrics["settle_nll"] < result.metrics["settle_nll_start"]
    assert 0.3 < result.metrics["settle_change_cm"] < 5.0
    assert result.per_second and result.human_range is not None


def test_settle_rejects_bad_sigmas(prior):
    walk = shared_excerpt("bandai2/dataset-2_walk_active_002.bvh", 0, 30)
    with pytest.raises(ValueError, match="sigma_root must be positive"):
        Settle(walk, prior, sigma_root=0.0)


def test_settle_holds_the_held_frames_exactly_and_moves_the_others(prior):
    """Frames marked ``held`` (a completion's prefix) come out exactly as they went in,
    the solve moves the rest, and the change it reports is over the moved frames alone."""
    walk = shared_excerpt("bandai2/dataset-2_walk_active_002.bvh", 0, 90)
    rough, _ = position_noise(walk, 0.02, seed=2)
    held = np.arange(rough.num_frames) < 30
    result = Settle(rough, prior, held=held).solve()
    out = result.motion
    assert np.array_equal(out.rotations[held], rough.rotations[held])
    assert np.array_equal(out.root[held], rough.root[held])
    moved = np.linalg.norm(out.positions() - rough.positions(), axis=-1).mean(-1)
    assert moved[~held].mean() > 0.003
    assert result.metrics["settle_change_cm"] > 100 * moved[held].mean()   # held frames count no change
    assert result.metrics["settle_nll"] < result.metrics["settle_nll_start"]
    with pytest.raises(ValueError, match="held must have one entry per frame"):
        Settle(rough, prior, held=held[:-1])
