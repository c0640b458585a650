"""Metrics of the latent prior's evaluation: reconstruction errors split as MoDi reports
them (table 5: global root position, root-relative joint positions) and the Fréchet
distance between two sets of feature vectors."""
from __future__ import annotations

import numpy as np
import torch
from torch import Tensor


def root_position_error_mm(pred: Tensor, target: Tensor) -> float:
    """Mean Euclidean distance (mm) of the root joint (index 0) between world positions
    ``(..., T, J, 3)`` in metres."""
    return float((pred[..., 0, :] - target[..., 0, :]).norm(dim=-1).mean() * 1000)


def local_position_error_mm(pred: Tensor, target: Tensor) -> float:
    """Mean Euclidean distance (mm) of the non-root joints after subtracting each frame's
    root position (root-relative, world axes)."""
    lp = pred[..., 1:, :] - pred[..., :1, :]
    lt = target[..., 1:, :] - target[..., :1, :]
    return float((lp - lt).norm(dim=-1).mean() * 1000)


def window_descriptors(x: Tensor) -> Tensor:
    """A fixed-size description of windows ``(N, T, D)``: per-dimension mean and standard
    deviation over time, and the mean absolute frame-to-frame change (N, 3D)."""
    return torch.cat((x.mean(1), x.std(1), (x[:, 1:] - x[:, :-1]).abs().mean(1)), dim=-1)


def frechet_distance(a: Tensor | np.ndarray, b: Tensor | np.ndarray) -> float:
    """Fréchet distance between Gaussians fitted to feature sets ``a (N, F)`` and ``b (M, F)``:
    |mu_a - mu_b|^2 + tr(C_a + C_b - 2 (C_a C_b)^(1/2)), as FID computes it."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1] or min(len(a), len(b)) < 2:
        raise ValueError(f"need two sets of at least two feature vectors of one size, got {a.shape} and {b.shape}")
    mu_a, mu_b = a.mean(0), b.mean(0)
    ca, cb = np.cov(a, rowvar=False), np.cov(b, rowvar=False)
    # tr (C_a C_b)^(1/2) = sum of square roots of the eigenvalues of C_a^(1/2) C_b C_a^(1/2) (symmetric, PSD)
    ev, vec = np.linalg.eigh(ca)
    sa = (vec * np.sqrt(np.clip(ev, 0, None))) @ vec.T
    tr_covmean = np.sqrt(np.clip(np.linalg.eigvalsh(sa @ cb @ sa), 0, None)).sum()
    return float(((mu_a - mu_b) ** 2).sum() + np.trace(ca) + np.trace(cb) - 2 * tr_covmean)
