"""Rollouts chosen a second at a time (``problems.rollout``): the cost that chooses them,
and a chosen rollout on a real clip that keeps its clamped root."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from motionopt import bvh
from motionopt.features import advance, decode, encode, to_model_motion
from problems.common import root_features
from problems.rollout import AIRBORNE_COST, FLOOR_BAND, LIFT_COST, chosen_rollout, glide_cost, lift_limit

from priorkit import tiny_prior
from clips import DATA


def feet(heights: list[float], speed: float, frames: int = 31) -> torch.Tensor:
    """Contact joints (frames, C, 3) at fixed heights moving along x at ``speed`` m/s (30 fps)."""
    p = torch.zeros(frames, len(heights), 3, dtype=torch.float64)
    p[..., 1] = torch.tensor(heights, dtype=torch.float64)
    p[..., 0] = (torch.arange(frames, dtype=torch.float64) * speed / 30)[:, None]
    return p


def test_glide_cost_counts_speed_near_the_floor_and_frames_with_no_foot_there():
    planted = np.zeros(2)
    assert float(glide_cost(feet([0.0, 0.2], 0.0), planted, 30)) == 0.0            # standing on one foot
    assert float(glide_cost(feet([0.0, 0.2], 1.5), planted, 30)) == pytest.approx(1.5)   # one foot gliding
    assert float(glide_cost(feet([0.0, 0.0], 1.5), planted, 30)) == pytest.approx(3.0)   # both
    up = FLOOR_BAND + 0.01
    assert float(glide_cost(feet([up, up], 1.5), planted, 30)) == pytest.approx(AIRBORNE_COST)   # floating
    batch = torch.stack((feet([0.0, 0.2], 1.5), feet([up, up], 0.0)))
    assert glide_cost(batch, planted, 30).shape == (2,)
    # a foot kicked above the limit costs LIFT_COST per metre too high, averaged over frames
    assert float(glide_cost(feet([0.0, 0.2], 0.0), planted, 30, max_lift=0.3)) == 0.0
    assert float(glide_cost(feet([0.0, 0.8], 0.0), planted, 30, max_lift=0.3)) == pytest.approx(LIFT_COST * 0.5)


def test_lift_limit_follows_the_contexts_own_lift():
    context = np.zeros((10, 2, 3))
    context[4, 1, 1] = 0.2                     # one step lifts a foot 20 cm above its planted height
    assert lift_limit(context, np.zeros(2)) == pytest.approx(1.5 * 0.2 + 0.05)
    assert lift_limit(np.zeros((1, 2, 3)), np.zeros(2)) == pytest.approx(0.05)   # standing still


@pytest.fixture(scope="module")
def walk_on_a_path():
    """The tiny prior, a clip's first 20 frames (normalised), the root state at frame 19,
    its contact joints there and when planted, and 45 frames of root features along a
    gently turning path from where the clip's root is at frame 19 (its points (46, 2))."""
    prior = tiny_prior()
    model = to_model_motion(bvh.load(sorted(DATA.glob("cmu-*.bvh"))[0]), prior.spec)
    raw, start = encode(model, prior.spec)
    x = prior.normalizer.normalize(raw).float()[:20]
    n = 45    # a second and a half: two chosen pieces
    pts = model.root[19, [0, 2]] + np.cumsum(np.full((n + 1, 2), 0.02), axis=0) - 0.02
    state = advance(start, raw[:20], prior.spec)     # the root at frame 19, which pts[0] is
    yaw = state.yaw + np.linspace(0.0, 0.4, n + 1)
    clamp = torch.from_numpy(root_features(pts, yaw))
    cidx = prior.spec.contact_indices()
    return (prior, x, state, model.positions()[19, cidx], np.percentile(model.positions()[:, cidx, 1], 5, axis=0),
            clamp, pts)


def test_chosen_rollout_keeps_the_clamped_root_across_its_seconds(walk_on_a_path):
    prior, x, state, last_feet, planted, clamp, pts = walk_on_a_path
    n = len(clamp)
    new = chosen_rollout(prior, x, state, last_feet, prior.skeleton, planted, n, 3, 0.5,
                         torch.Generator().manual_seed(0), clamp)
    assert new.shape == (n, x.shape[1])
    back = prior.normalizer.denormalize(new.double())
    assert torch.allclose(back[:, :3], clamp, atol=1e-5)
    _, root = decode(back, prior.spec, state)
    assert np.allclose(root[:, [0, 2]].numpy(), pts[1:], atol=1e-4)


def test_a_swaying_rollout_turns_and_advances_with_the_path_and_sways_about_it(walk_on_a_path):
    """With ``sway`` the yaw changes are the path's, the root moves sideways as the legs
    take it (not on the path exactly) and stays within a few centimetres of it."""
    prior, x, state, last_feet, planted, clamp, pts = walk_on_a_path
    new = chosen_rollout(prior, x, state, last_feet, prior.skeleton, planted, len(clamp), 3, 0.5,
                         torch.Generator().manual_seed(0), clamp, sway=True)
    back = prior.normalizer.denormalize(new.double())
    assert torch.allclose(back[:, 2], clamp[:, 2], atol=1e-5)
    _, root = decode(back, prior.spec, state)
    off = np.linalg.norm(root[:, [0, 2]].numpy() - pts[1:], axis=1)
    assert 0.002 < off.mean() and off.max() < 0.1
