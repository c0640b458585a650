"""Attribute scores of motion windows, for semantic editing in a latent space.

All functions are batched over leading dimensions and work on torch tensors:

- ``gradual_right_arm_lift``: MoDi appendix C.2 ("gral"). The shoulder and elbow angles
  are averaged over 8-frame windows with stride 4; a window scores 1 when its average
  exceeds the previous window's; the score is the mean over both joints. The paper does
  not say how a scalar angle comes from a rotation: here it is the angle between the
  upper arm (for the shoulder) or the forearm (for the elbow) and the downward vertical,
  so both grow as the arm lifts.
- ``root_speed``: mean horizontal root speed, m/s.
- ``crouch_depth``: how far the root is below its standing height, metres (mean over frames).
- ``style_of``: the style label of a Bandai file name ``dataset-1_{content}_{style}_{id}.bvh``.
"""
from __future__ import annotations

import re
from pathlib import Path

import torch
from torch import Tensor

from .kinematics import fk
from .skeleton import Skeleton

_RIGHT = re.compile(r"(^r[A-Z]|right|_R$|\.R$|^R_)", re.IGNORECASE)
_ELBOW = re.compile(r"(forearm|lowerarm|elbow)", re.IGNORECASE)
_BANDAI = re.compile(r"dataset-\d+_(?P<content>[a-z-]+)_(?P<style>[a-z-]+)_\d+\.bvh$")

ATTRIBUTES = ("gral", "root_speed", "crouch")


def right_arm(names: tuple[str, ...] | list[str], parents) -> tuple[int, int, int]:
    """Indices of the right shoulder (upper-arm joint), elbow and wrist, found by name: the
    elbow is the right forearm/lower-arm joint, the shoulder its parent, the wrist its child."""
    elbows = [j for j, n in enumerate(names) if _ELBOW.search(n) and _RIGHT.search(n)]
    if not elbows:
        raise ValueError("no right forearm joint (rForeArm, LowerArm_R, RightForeArm...) in the skeleton")
    e = elbows[0]
    children = [j for j, p in enumerate(parents) if p == e]
    if not children:
        raise ValueError(f"the right forearm joint {names[e]!r} has no child (wrist)")
    return int(parents[e]), e, children[0]


def angle_from_down(v: Tensor) -> Tensor:
    """Angle (radians) between vectors (..., 3) and the downward vertical."""
    down = -v[..., 1] / v.norm(dim=-1).clamp_min(1e-9)
    return torch.arccos(down.clamp(-1.0, 1.0))


def gradual_right_arm_lift(positions: Tensor, shoulder: int, elbow: int, wrist: int,
                           width: int = 8, stride: int = 4) -> Tensor:
    """Gral score in [0, 1] of world positions (..., T, J, 3)."""
    upper = angle_from_down(positions[..., elbow, :] - positions[..., shoulder, :])
    fore = angle_from_down(positions[..., wrist, :] - positions[..., elbow, :])
    a = torch.stack((upper, fore), dim=-2)  # (..., 2, T)
    avg = a.unfold(-1, width, stride).mean(-1)  # (..., 2, windows)
    return (avg[..., 1:] > avg[..., :-1]).to(positions.dtype).mean(dim=(-1, -2))


def root_speed(root: Tensor, fps: float) -> Tensor:
    """Mean horizontal speed (m/s) of root positions (..., T, 3)."""
    d = root[..., 1:, [0, 2]] - root[..., :-1, [0, 2]]
    return d.norm(dim=-1).mean(-1) * fps


def standing_height(skeleton: Skeleton, contact_idx: list[int]) -> float:
    """Height of the root above the lowest contact joint in the rest pose (metres)."""
    n = skeleton.num_joints
    rot = torch.zeros(n, 4, dtype=torch.float64)
    rot[:, 0] = 1.0
    pos = fk(skeleton.parents, rot, torch.zeros(3, dtype=torch.float64), torch.from_numpy(skeleton.offsets))
    return float(pos[0, 1] - pos[contact_idx, 1].min())


def crouch_depth(root_height: Tensor, standing: float) -> Tensor:
    """Mean of (standing height - root height above ground) over frames (..., T) -> (...)."""
    return (standing - root_height).mean(-1)


def style_of(path: str | Path) -> str | None:
    """Style label of a Bandai clip name, or None for other names."""
    m = _BANDAI.search(Path(path).name)
    return m.group("style") if m else None


def content_of(path: str | Path) -> str | None:
    """Content label (walk, run, bow, ...) of a Bandai clip name, or None."""
    m = _BANDAI.search(Path(path).name)
    return m.group("content") if m else None
