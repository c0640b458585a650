"""One model of capture noise, for benchmarks, notebooks and the demo.

Noise is made in the motion's own degrees of freedom, as a capture system's solver
leaves it: every local rotation (the root's included) turned by an axis-angle drawn from
N(0, s^2 I), the root moved by N(0, r^2) per axis, and optionally rare pops (a joint
turned by a large angle for one frame), or a glitch (one joint turned by tens of degrees
for a fraction of a second, ``glitch``). Bones keep their lengths. The same seed gives
the same draws, so that a benchmark's noisy clips are the same in every run.
"""
from __future__ import annotations

import numpy as np
import torch

from . import rotations as R
from .motion import Motion


def capture_noise(motion: Motion, angle_sigma: float, root_sigma: float = 0.0, seed: int = 0,
                  pop_rate: float = 0.0, pop_angle: float = 0.3) -> Motion:
    """``motion`` with rotation noise of std ``angle_sigma`` (radians per axis), root noise
    of std ``root_sigma`` (metres per axis) and, with ``pop_rate`` > 0, that fraction of
    joint-frames turned by about ``pop_angle`` radians instead."""
    g = torch.Generator().manual_seed(seed)
    q = torch.from_numpy(motion.rotations)
    aa = torch.randn(*q.shape[:-1], 3, generator=g, dtype=torch.float64) * angle_sigma
    jitter = torch.randn(motion.root.shape, generator=g, dtype=torch.float64).numpy() * root_sigma
    if pop_rate > 0:
        pop = torch.rand(q.shape[:-1], generator=g, dtype=torch.float64) < pop_rate
        aa[pop] *= pop_angle / max(angle_sigma, 1e-12)
    turned = R.quat_multiply(q, R.axis_angle_to_quat(aa))
    return motion.with_frames(turned.numpy(), motion.root + jitter, motion.translations)


def position_noise(motion: Motion, rms: float, seed: int = 0) -> tuple[Motion, float]:
    """Rotation noise (root path left alone) whose std is chosen so that joint positions
    move ``rms`` metres RMS (3D distance over all joints and frames); returns the noisy
    motion and that std (radians)."""
    clean = torch.from_numpy(motion.positions())
    scale = 0.01
    for _ in range(3):  # displacement is nearly linear in the scale: a few secant steps
        moved = torch.from_numpy(capture_noise(motion, scale, seed=seed).positions())
        scale *= rms / (moved - clean).norm(dim=-1).pow(2).mean().sqrt().item()
    return capture_noise(motion, scale, seed=seed), scale


def main_axis(motion: Motion, joint: int) -> tuple[float, float, float]:
    """The local axis joint ``joint`` turns about most in ``motion`` (a knee's flexion
    axis): the leading principal direction of its rotation vectors."""
    aa = R.quat_to_axis_angle(torch.from_numpy(motion.rotations[:, joint])).numpy()
    _, _, vt = np.linalg.svd(aa - aa.mean(0), full_matrices=False)
    return tuple(float(v) for v in vt[0])


def glitch(motion: Motion, joint: int, first: int, count: int, degrees: float = 30.0,
           axis: tuple[float, float, float] | None = None) -> Motion:
    """``motion`` with joint ``joint``'s local rotation turned by ``degrees`` about its own
    ``axis`` (default: the axis it turns about most, ``main_axis``) at frames ``first`` to
    ``first + count - 1``: a capture glitch, like a marker swap that bends a knee the
    wrong way for a quarter of a second."""
    if not 0 <= first < first + count <= motion.num_frames:
        raise ValueError(f"glitch frames {first}-{first + count - 1} are outside the clip's {motion.num_frames}")
    q = motion.rotations.copy()
    aa = torch.tensor(main_axis(motion, joint) if axis is None else axis, dtype=torch.float64)
    turn = R.axis_angle_to_quat(aa / aa.norm() * torch.pi * degrees / 180.0)
    q[first:first + count, joint] = R.quat_multiply(torch.from_numpy(q[first:first + count, joint]), turn).numpy()
    return motion.with_frames(q, motion.root, motion.translations)
