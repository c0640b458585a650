"""Motion metrics on a real clip and on exact transformations of it."""
from __future__ import annotations

import math

import pytest
import torch

from motionopt import bvh, metrics
from clips import DATA, CMU_120

CLIP = DATA / CMU_120
FEET = ["rFoot", "lFoot"]


@pytest.fixture(scope="module")
def clip():
    if not CLIP.exists():
        pytest.skip(f"{CLIP.name} not in tests/data")
    m = bvh.load(CLIP)
    pos = torch.from_numpy(m.positions())
    return pos, m.fps, [m.skeleton.index(n) for n in FEET]


def slide(pos: torch.Tensor, fps: float, velocity: tuple[float, float, float]) -> torch.Tensor:
    """The positions carried along at a constant world velocity (m/s)."""
    t = torch.arange(len(pos), dtype=pos.dtype)[:, None, None] / fps
    return pos + t * torch.tensor(velocity, dtype=pos.dtype)


def test_joint_speed_of_a_pose_carried_at_constant_velocity(clip):
    pos, fps, _ = clip
    still = pos[:1].expand(50, -1, -1)
    assert torch.equal(metrics.joint_speed(still, fps), torch.zeros(49, pos.shape[1], dtype=pos.dtype))
    speed = metrics.joint_speed(slide(still, fps, (0.6, 0.0, 0.8)), fps)
    assert torch.allclose(speed, torch.ones_like(speed))


def test_jerk_is_zero_for_constant_velocity_and_grows_with_noise(clip):
    pos, fps, _ = clip
    assert metrics.jerk(slide(pos[:1].expand(50, -1, -1), fps, (1.0, 0.0, 0.0)), fps) < 1e-6
    noisy = pos + 0.005 * torch.randn(pos.shape, generator=torch.Generator().manual_seed(0), dtype=pos.dtype)
    assert metrics.jerk(noisy, fps) > 5 * metrics.jerk(pos, fps)


def test_mpjpe_of_a_shift(clip):
    pos, _, _ = clip
    assert metrics.mpjpe(pos + torch.tensor([0.03, 0.04, 0.0], dtype=pos.dtype), pos) == pytest.approx(0.05)
    assert metrics.mpjpe(pos, pos) == 0


def test_foot_skating_sees_a_sliding_clip(clip):
    pos, fps, feet = clip
    clean = float(metrics.foot_skating(pos, fps, feet))
    assert 0 < clean < 0.3  # a stepping clip: planted feet barely move
    slid = float(metrics.foot_skating(slide(pos, fps, (1.0, 0.0, 0.0)), fps, feet))
    # the same frames stay planted; each planted speed changes by at most the clean one
    assert abs(slid - 1.0) <= clean + 1e-9


def test_planted_heights_follow_the_ground(clip):
    pos, fps, feet = clip
    lifted = pos + torch.tensor([0.0, 0.1, 0.0], dtype=pos.dtype)
    rest = metrics.rest_heights(pos, feet)
    assert torch.allclose(metrics.rest_heights(lifted, feet), rest + 0.1)
    assert torch.equal(metrics.planted(lifted, feet, ground=0.1), metrics.planted(pos, feet))
    mask = metrics.planted(pos, feet)
    assert 0 < mask.float().mean() < 1 and mask.shape == (len(pos) - 1, len(feet))
    # floating half a metre above where the feet rest: never planted, skating undefined
    assert math.isnan(metrics.foot_skating(pos + torch.tensor([0.0, 0.5, 0.0], dtype=pos.dtype), fps, feet,
                                           rest=rest))


def test_hip_sway_is_the_sideways_speed_of_a_walk_and_zero_on_a_straight_line():
    t = torch.arange(300, dtype=torch.float64) / 30
    amplitude, f = 0.03, 0.9
    line = torch.stack((torch.zeros_like(t), 1.2 * t), -1)
    swaying = line + torch.stack((amplitude * torch.sin(2 * math.pi * f * t), torch.zeros_like(t)), -1)
    # the sway's RMS speed, through the 0.1 s smoothing, less what of it the 0.4 s
    # direction of travel still follows
    response = [math.exp(-0.5 * (2 * math.pi * f * sigma) ** 2) for sigma in (0.1, 0.4)]
    expected = 2 * math.pi * f * amplitude / math.sqrt(2) * (response[0] - response[1])
    assert float(metrics.hip_sway(swaying, 30.0)) == pytest.approx(expected, rel=0.05)
    assert float(metrics.hip_sway(line, 30.0)) < 1e-9
    assert math.isnan(float(metrics.hip_sway(torch.zeros(30, 2, dtype=torch.float64), 30.0)))    # standing
