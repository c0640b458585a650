"""Time alignment of two motions and the play times of their blends."""
import numpy as np
import pytest

from motionopt.timewarp import align, blend_times


def gait(frames: int, period: float, phase: float) -> np.ndarray:
    """Two channels of a periodic 'gait' (left and right legs half a cycle apart)."""
    t = (np.arange(frames) + phase) * 2 * np.pi / period
    return np.stack([np.sin(t), np.sin(t + np.pi)], axis=1)


def test_alignment_finds_the_phase_shift_between_two_gaits():
    a, b = gait(120, 30, 0), gait(120, 30, 8)   # B is 8 frames ahead
    al = align(a, b)
    inner = (al.a > 20) & (al.a < 90)
    assert np.median(al.a[inner] - al.b[inner]) == pytest.approx(8, abs=1.5)
    assert al.a[0] == al.b[0] == 0 and al.a[-1] == 119 and al.b[-1] == pytest.approx(119)
    assert np.all(np.diff(al.a) > 0) and np.all(np.diff(al.b) > 0)


def test_alignment_of_different_cadences_and_lengths_matches_cycles():
    a, b = gait(90, 30, 0), gait(60, 20, 0)   # three cycles each, B faster and shorter
    al = align(a, b)
    assert np.abs(al.b - al.a * 59 / 89).max() < 2.0


def test_blend_ends_play_the_inputs_as_given():
    al = align(gait(120, 30, 0), gait(100, 25, 5))
    at_a, _ = blend_times(al, 0.0, 120)
    _, at_b = blend_times(al, 1.0, 100)
    assert np.allclose(at_a, np.arange(120)) and np.allclose(at_b, np.arange(100))
    mid_a, mid_b = blend_times(al, 0.5, 110)
    assert np.all(np.diff(mid_a) >= 0) and np.all(np.diff(mid_b) >= 0)
    assert mid_a[-1] == pytest.approx(119) and mid_b[-1] == pytest.approx(99)


def test_alignment_needs_two_frames():
    with pytest.raises(ValueError, match="two frames"):
        align(np.zeros((1, 2)), np.zeros((5, 2)))


def test_long_clips_are_aligned_at_a_coarser_rate():
    from motionopt.timewarp import MAX_ALIGN_FRAMES

    frames = 2 * MAX_ALIGN_FRAMES
    al = align(gait(frames, 60, 0), gait(frames, 60, 16))
    assert al.a[-1] == pytest.approx(frames - 1) and len(al.a) <= 2 * MAX_ALIGN_FRAMES
    inner = (al.a > 0.2 * frames) & (al.a < 0.8 * frames)
    assert np.median(al.a[inner] - al.b[inner]) == pytest.approx(16, abs=3)
