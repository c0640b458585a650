"""Forward kinematics: one pure, differentiable torch function over a parents array."""
from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from .rotations import quat_apply, quat_multiply


def check_parents(parents: np.ndarray | list[int], num_joints: int) -> list[int]:
    """The parents array as ints, checked: one per joint, the root first (-1), and every
    parent before its children (topological order), which FK relies on."""
    parents = [int(p) for p in parents]
    if len(parents) != num_joints:
        raise ValueError(f"{len(parents)} parents for {num_joints} joints")
    if not parents or parents[0] != -1:
        raise ValueError("the first joint must be the root, with parent -1")
    bad = [j for j in range(1, len(parents)) if not 0 <= parents[j] < j]
    if bad:
        raise ValueError(f"joint {bad[0]} has parent {parents[bad[0]]}: parents must come before their children")
    return parents


def fk(
    parents: np.ndarray | list[int],
    rotations: Tensor,
    root: Tensor,
    offsets: Tensor,
    translations: Tensor | None = None,
    return_global_rotations: bool = False,
) -> Tensor | tuple[Tensor, Tensor]:
    """World joint positions from local rotations.

    Args:
        parents: (J,) parent index per joint, -1 for the root, parents before children.
        rotations: (..., J, 4) local unit quaternions, w first.
        root: (..., 3) world position of the root joint.
        offsets: (J, 3) or (..., J, 3) rest offsets from each parent.
        translations: optional (..., J, 3) per-frame local translations that replace
            ``offsets`` (BVH joints with position channels).
        return_global_rotations: also return the (..., J, 4) world rotations.

    Returns:
        positions (..., J, 3), and world rotations if asked.
    """
    parents = check_parents(parents, rotations.shape[-2])
    local_t = offsets if translations is None else translations
    local_t = local_t.to(rotations.dtype).expand(*rotations.shape[:-1], 3)
    g_rot: list[Tensor] = [rotations[..., 0, :]]
    g_pos: list[Tensor] = [root.to(rotations.dtype).expand(*rotations.shape[:-2], 3)]
    for j in range(1, len(parents)):
        p = parents[j]
        g_pos.append(g_pos[p] + quat_apply(g_rot[p], local_t[..., j, :]))
        g_rot.append(quat_multiply(g_rot[p], rotations[..., j, :]))
    positions = torch.stack(g_pos, dim=-2)
    if return_global_rotations:
        return positions, torch.stack(g_rot, dim=-2)
    return positions


def depth_levels(parents: np.ndarray | list[int]) -> list[tuple[list[int], list[int]]]:
    """Joints grouped by depth below the root, each level with its parents: FK can then
    process a whole level at once instead of one joint at a time."""
    parents = [int(p) for p in parents]
    depth = [0] * len(parents)
    for j in range(1, len(parents)):
        depth[j] = depth[parents[j]] + 1
    levels = []
    for d in range(1, max(depth, default=0) + 1):
        joints = [j for j in range(len(parents)) if depth[j] == d]
        levels.append((joints, [parents[j] for j in joints]))
    return levels


def fk_matrices(parents: np.ndarray | list[int], rotations: Tensor, root: Tensor, offsets: Tensor) -> Tensor:
    """World joint positions (..., J, 3) from local rotation matrices (..., J, 3, 3).

    The same numbers as ``fk`` with matrices, one level of the hierarchy at a time:
    the fast path for solvers, which decode features to matrices anyway.
    """
    n_j = rotations.shape[-3]
    lead = rotations.shape[:-3]
    offsets = offsets.to(rotations.dtype).expand(*lead, n_j, 3)
    g_rot = [None] * n_j
    g_pos = [None] * n_j
    g_rot[0] = rotations[..., 0, :, :]
    g_pos[0] = root
    for joints, pars in depth_levels(parents):
        prot = torch.stack([g_rot[p] for p in pars], dim=-3)
        ppos = torch.stack([g_pos[p] for p in pars], dim=-2)
        pos = ppos + (prot @ offsets[..., joints, :, None])[..., 0]
        rot = prot @ rotations[..., joints, :, :]
        for k, j in enumerate(joints):
            g_rot[j] = rot[..., k, :, :]
            g_pos[j] = pos[..., k, :]
    return torch.stack(g_pos, dim=-2)
