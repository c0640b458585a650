"""Inertialization: a continuation carried on from the real frames before it."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from clips import DATA, CMU_60
from motionopt import bvh
from motionopt import rotations as R
from motionopt.inertialization import carry_on, held_drift, spring_decay


@pytest.fixture(scope="module")
def real():
    return bvh.load(DATA / CMU_60)


def shifted(motion, angle: float, offset: np.ndarray):
    """``motion`` with every joint turned by ``angle`` about x and the root moved by
    ``offset``: a continuation that starts away from the real motion."""
    turn = R.axis_angle_to_quat(torch.tensor([angle, 0.0, 0.0], dtype=torch.float64))
    q = R.quat_multiply(turn.expand(*motion.rotations.shape[:-1], 4), torch.from_numpy(motion.rotations))
    return motion.with_frames(q.numpy(), motion.root + offset, motion.translations)


def test_spring_starts_at_offset_and_velocity_and_fades():
    t = np.arange(0, 4.0, 1e-3)
    x = spring_decay(np.array([1.0]), np.array([2.0]), t, halflife=0.3)
    assert x[0, 0] == pytest.approx(1.0)
    assert (x[1, 0] - x[0, 0]) / 1e-3 == pytest.approx(2.0, rel=1e-2)
    assert abs(x[-1, 0]) < 1e-3
    held = held_drift(np.array([1.0]), np.array([2.0]), t, halflife=0.3)
    assert held[0, 0] == pytest.approx(1.0)
    assert held[-1, 0] == pytest.approx(1.0 + 2.0 * 0.3 / (2 * np.log(2)), rel=1e-3)


def test_carry_on_continues_the_real_frames_and_turns_into_the_generated(real):
    seam = 60
    generated = shifted(real, 0.3, np.array([0.2, 0.05, -0.1]))
    out = carry_on(generated, real, seam, halflife=0.2)
    assert np.array_equal(out.rotations[:seam], real.rotations[:seam])
    # the first carried frame is where the real motion was going, not where the generated one jumped
    jump = float(R.quat_angle(torch.from_numpy(out.rotations[seam]), torch.from_numpy(real.rotations[seam])).max())
    assert jump < 0.02
    assert np.abs(out.root[seam] - real.root[seam]).max() < 0.01
    # two seconds on, the pose is the generated one; the root keeps the real path's placement
    late = seam + 2 * int(real.fps)
    assert float(R.quat_angle(torch.from_numpy(out.rotations[late]),
                              torch.from_numpy(generated.rotations[late])).max()) < 1e-3
    assert out.root[late, 1] == pytest.approx(generated.root[late, 1], abs=1e-3)
    assert out.root[late, [0, 2]] == pytest.approx(real.root[late, [0, 2]], abs=1e-3)


def test_carry_on_needs_real_frames_before_and_generated_after(real):
    with pytest.raises(ValueError, match="seam"):
        carry_on(real, real, 1, halflife=0.2)
    with pytest.raises(ValueError, match="seam"):
        carry_on(real, real, real.num_frames, halflife=0.2)
