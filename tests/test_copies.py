"""Degraded copies of a motion (motionopt.copies), on motion the tests make."""
from __future__ import annotations

import numpy as np
import pytest

from motionopt import bvh
from motionopt.copies import COPIES, frozen, low_passed, retimed, window_copies

from clips import BANDAI_30, DATA


@pytest.fixture(scope="module")
def walk():
    return bvh.load(DATA / BANDAI_30)


def roughness(m) -> float:
    """Mean squared second difference of joint positions: what a low-pass removes."""
    p = m.positions()
    return float(np.square(p[2:] - 2 * p[1:-1] + p[:-2]).mean())


def test_low_pass_keeps_length_and_unit_quaternions_and_removes_detail(walk):
    two, one = low_passed(walk, 2.0), low_passed(walk, 1.0)
    assert two.num_frames == walk.num_frames and two.fps == walk.fps
    assert np.allclose(np.linalg.norm(two.rotations, axis=-1), 1.0)
    assert roughness(one) < roughness(two) < roughness(walk)
    # a low-pass follows the motion: positions stay near the source's
    assert np.abs(two.positions() - walk.positions()).mean() < 0.05


def test_frozen_holds_the_first_frame(walk):
    f = frozen(walk[10:40])
    assert f.num_frames == 30
    assert np.allclose(f.rotations, walk.rotations[10]) and np.allclose(f.root, walk.root[10])


def test_retimed_copies_cover_the_time_they_should(walk):
    half, double = retimed(walk, 0.5), retimed(walk, 2.0)
    assert half.fps == double.fps == walk.fps
    assert half.num_frames == 2 * (walk.num_frames - 1) + 1
    assert double.num_frames == (walk.num_frames - 1) // 2 + 1
    assert np.allclose(double.rotations[3], walk.rotations[6])
    assert np.allclose(half.root[4], walk.root[2])


def test_window_copies_cut_each_kind_at_the_window(walk):
    n = 20
    windows = window_copies(walk, [0, 10], n)
    assert [list(w) for w in windows] == [list(COPIES)] * 2
    w = windows[1]
    assert all(m.num_frames == n for k, m in w.items() if k != "double speed")
    assert np.allclose(w["frozen"].root, walk.root[10])
    assert np.allclose(w["half speed"].root[0], walk.root[10])
    assert np.allclose(w["double speed"].root[0], walk.root[10]) and w["double speed"].num_frames == n
    assert np.allclose(w["low-pass 2 Hz"].root, low_passed(walk, 2.0).root[10:30])
