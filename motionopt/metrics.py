"""Motion quality metrics the field uses, on world joint positions.

Positions are torch tensors ``(..., T, J, 3)`` in metres with y up; frame rates in
frames per second. Each function says what it measures and in which unit, so that
benchmarks and reports can quote the numbers as they are.
"""
from __future__ import annotations

import torch
from torch import Tensor

from .smoothing import gaussian_smooth


def joint_speed(positions: Tensor, fps: float) -> Tensor:
    """Speed (m/s) of every joint between consecutive frames, shape ``(..., T-1, J)``."""
    return (positions[..., 1:, :, :] - positions[..., :-1, :, :]).norm(dim=-1) * fps


def acceleration(positions: Tensor, fps: float) -> Tensor:
    """Every joint's acceleration (m/s^2) by second differences, shape ``(..., T-2, J, 3)``."""
    p = positions
    return (p[..., 2:, :, :] - 2 * p[..., 1:-1, :, :] + p[..., :-2, :, :]) * fps ** 2


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


#: What ``foot_skating`` measures and what clean capture scores on it, for the sentences that report it
#: (held-out clips of the shipped priors, at 30 fps: 10 Bandai locomotion clips, 4 CMU dance and martial arts clips).
FOOT_SKATING_MEANS = ("speed over the ground of feet within 3 cm of their resting height; clean mocap: "
                      "17-57 cm/s for Bandai walks and runs, 8-25 for CMU dance")


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


def hip_sway(root_xz: Tensor, fps: float, min_speed: float = 0.3) -> Tensor:
    """RMS speed (m/s) of the root (T, 2 ground coordinates) across its direction of
    travel: the side-to-side sway of a walk (held-out Bandai walks: 0.05-0.14). The
    velocity is smoothed over 0.1 s (capture jitter), the direction of travel over 0.4 s
    (a stride); frames travelling slower than ``min_speed`` m/s do not count (NaN if none).
    A root that takes a corner dead square scores far above any walk (0.6-0.8)."""
    v = torch.gradient(root_xz, dim=0)[0] * fps
    travel = gaussian_smooth(v[None], 0.4 * fps)[0]
    speed = travel.norm(dim=-1)
    side = torch.stack((travel[:, 1], -travel[:, 0]), -1) / speed.clamp_min(1e-9)[:, None]
    across = (gaussian_smooth(v[None], 0.1 * fps)[0] * side).sum(-1)
    moving = speed > min_speed
    return across[moving].pow(2).mean().sqrt() if moving.any() else torch.tensor(float("nan"))


def l2p(pred: Tensor, target: Tensor) -> Tensor:
    """Global position error of in-betweening (LAFAN1's L2P, here in metres, without its
    normalisation by training statistics): per frame, the Euclidean norm of all joints'
    position errors stacked, ``(..., T, J, 3)`` -> mean over frames ``(...)``."""
    return (pred - target).flatten(-2).norm(dim=-1).mean(-1)


def l2q(pred: Tensor, target: Tensor) -> Tensor:
    """Global rotation error of in-betweening (LAFAN1's L2Q): per frame, the Euclidean
    norm of all joints' world quaternion differences ``(..., T, J, 4)`` stacked, each
    predicted quaternion taken in the target's hemisphere (q and -q are one rotation);
    mean over frames ``(...)``."""
    sign = torch.where((pred * target).sum(-1, keepdim=True) < 0, -1.0, 1.0).to(pred)
    return (pred * sign - target).flatten(-2).norm(dim=-1).mean(-1)


def npss(pred: Tensor, target: Tensor) -> Tensor:
    """Normalised power spectrum similarity (Gopalakrishnan et al. 2019), lower is better:
    per feature, the earth mover's distance between the normalised power spectra over
    time of prediction and target, averaged with the target's power as weights.
    ``(B, T, F)`` sequences (e.g. world quaternions flattened) -> scalar."""
    p_pred = torch.fft.rfft(pred, dim=-2).abs().pow(2)
    p_true = torch.fft.rfft(target, dim=-2).abs().pow(2)
    power = p_true.sum(-2)
    n_pred = p_pred / p_pred.sum(-2, keepdim=True).clamp_min(1e-12)
    n_true = p_true / power[..., None, :].clamp_min(1e-12)
    emd = (n_pred.cumsum(-2) - n_true.cumsum(-2)).abs().sum(-2)
    return (emd * power).sum() / power.sum().clamp_min(1e-12)
