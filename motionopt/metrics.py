"""Motion quality metrics the field uses, on world joint positions.

Positions are torch tensors ``(..., T, J, 3)`` in metres with y up; frame rates in
frames per second. Each function says what it measures and in which unit, so that
benchmarks and reports can quote the numbers as they are.
"""
from __future__ import annotations

import torch
from torch import Tensor


def joint_speed(positions: Tensor, fps: float) -> Tensor:
    """Speed (m/s) of every joint between consecutive frames, shape ``(..., T-1, J)``."""
    return (positions[..., 1:, :, :] - positions[..., :-1, :, :]).norm(dim=-1) * fps


def jerk(positions: Tensor, fps: float) -> Tensor:
    """Mean magnitude (m/s^3) of the third time derivative of joint positions, by finite
    differences over four frames, averaged over frames and joints; shape ``(...)``.
    Low jerk means smooth motion; capture noise and pops raise it."""
    p = positions
    d3 = p[..., 3:, :, :] - 3 * p[..., 2:-1, :, :] + 3 * p[..., 1:-2, :, :] - p[..., :-3, :, :]
    return d3.norm(dim=-1).mean(dim=(-1, -2)) * fps ** 3


def mpjpe(pred: Tensor, target: Tensor) -> Tensor:
    """Mean per-joint position error (metres): Euclidean distance between corresponding
    joints, averaged over joints and frames; shape ``(...)``. No alignment is applied."""
    return (pred - target).norm(dim=-1).mean(dim=(-1, -2))


def rest_heights(positions: Tensor, contact_idx: list[int], ground: float = 0.0,
                 percentile: float = 5.0) -> Tensor:
    """Height (m) above ``ground`` of each contact joint when planted: a low percentile
    of its height over the clip, shape ``(C,)``. An ankle rests several centimetres
    above the floor; skating is measured relative to this height."""
    h = positions[..., contact_idx, 1].reshape(-1, len(contact_idx)) - ground
    return torch.quantile(h, percentile / 100.0, dim=0)


def planted(positions: Tensor, contact_idx: list[int], ground: float = 0.0, rest: Tensor | None = None,
            threshold: float = 0.03) -> Tensor:
    """Whether each contact joint is planted over each frame step, shape ``(..., T-1, C)``:
    its height above its rest height is under ``threshold`` metres at both ends of the
    step. ``rest`` defaults to ``rest_heights`` of the same clip."""
    if rest is None:
        rest = rest_heights(positions, contact_idx, ground)
    low = positions[..., contact_idx, 1] - ground - rest.to(positions) < threshold
    return low[..., 1:, :] & low[..., :-1, :]


def foot_skating(positions: Tensor, fps: float, contact_idx: list[int], ground: float = 0.0,
                 rest: Tensor | None = None, threshold: float = 0.03) -> Tensor:
    """Foot skating (m/s): mean horizontal speed of the contact joints over the frame
    steps on which they are planted (see ``planted``); a scalar over the whole input.
    NaN when no joint is ever planted (a motion that never touches the ground)."""
    mask = planted(positions, contact_idx, ground, rest, threshold)
    p = positions[..., contact_idx, :]
    step = p[..., 1:, :, :] - p[..., :-1, :, :]
    speed = step[..., [0, 2]].norm(dim=-1) * fps
    return speed[mask].mean() if mask.any() else torch.tensor(float("nan"), dtype=positions.dtype)
