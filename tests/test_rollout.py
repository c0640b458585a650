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


def test_chosen_rollout_keeps_the_clamped_root_across_its_seconds():
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
    new = chosen_rollout(prior, x, state, model.positions()[19, cidx], prior.skeleton,
                         np.percentile(model.positions()[:, cidx, 1], 5, axis=0), n, 3, 0.5,
                         torch.Generator().manual_seed(0), clamp)
    assert new.shape == (n, x.shape[1])
    back = prior.normalizer.denormalize(new.double())
    assert torch.allclose(back[:, :3], clamp, atol=1e-5)
    _, root = decode(back, prior.spec, state)
    assert np.allclose(root[:, [0, 2]].numpy(), pts[1:], atol=1e-4)
