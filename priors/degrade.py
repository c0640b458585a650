"""Degraded copies of feature windows, for training a prior to rank real motion first.

A Gaussian autoregressive prior trained by likelihood alone rewards predictability: a
pose held still, a low-passed copy or a slowed-down copy of a walk is easier to predict
than the walk, and scores better (issue 21 measured it on both shipped priors). The
contrastive part of ``CCNetPrior.loss`` shows the network such copies of its training
windows and asks their NLL to stay a margin above the real window's.

Every degradation works on a batch of raw (unnormalised) feature windows (B, T, D) and
returns the degraded batch and a mask of the frames that exist. Cutoffs and speed
factors are drawn from ranges, not fixed at the values a benchmark tests, so that the
prior learns what real motion is rather than one test's copies.
"""
from __future__ import annotations

import math

import torch
from torch import Tensor

from motionopt.features import FeatureSpec
from motionopt.smoothing import gaussian_smooth

#: The kinds of copy, and how often each is drawn. Low-passes get the most: a copy
#: smoothed at 2 Hz keeps most of a walk and is the hardest to tell from it (a prior
#: trained with equal shares ranked it first on 3 of 13 held-out windows, every other
#: kind on 11 to 13).
KINDS = ("frozen", "lowpass", "slow", "fast", "noise")
SHARES = (0.15, 0.35, 0.2, 0.15, 0.15)


def frozen(raw: Tensor, spec: FeatureSpec) -> Tensor:
    """Every frame a copy of the first, with no root motion."""
    out = raw[:, :1].expand_as(raw).clone()
    s = spec.slices()
    out[..., s["root_delta"]] = 0
    out[..., s["yaw_delta"]] = 0
    return out


def lowpass(raw: Tensor, spec: FeatureSpec, cutoff_hz: Tensor) -> Tensor:
    """Each window smoothed by a Gaussian whose half-power frequency is ``cutoff_hz`` (B,);
    contact labels are kept."""
    sigma = spec.fps * math.sqrt(math.log(2)) / (2 * math.pi * cutoff_hz)  # frames
    p = spec.pose_dim
    return torch.cat((gaussian_smooth(raw[..., :p], sigma.to(raw)), raw[..., p:]), dim=-1)


def retimed(raw: Tensor, spec: FeatureSpec, factor: Tensor) -> tuple[Tensor, Tensor]:
    """Each window played ``factor`` (B,) times as fast at the same frame rate (linear
    interpolation of poses, root steps scaled by the factor). A fast copy covers fewer
    frames: the mask (B, T) is False after its end, where its last frame is held."""
    B, T, _ = raw.shape
    src = torch.arange(T, dtype=raw.dtype, device=raw.device)[None] * factor[:, None].to(raw)  # (B, T)
    valid = src <= T - 1
    src = src.clamp(max=T - 1)
    lo = src.floor().long().clamp(max=T - 2)
    w = (src - lo)[..., None]
    take = lambda i: torch.gather(raw, 1, i[..., None].expand(-1, -1, raw.shape[-1]))  # noqa: E731
    out = take(lo) * (1 - w) + take(lo + 1) * w
    s = spec.slices()
    rates = torch.cat((torch.arange(s["root_delta"].start, s["root_delta"].stop),
                       torch.arange(s["yaw_delta"].start, s["yaw_delta"].stop)))
    out[..., rates] = out[..., rates] * factor[:, None, None].to(raw)
    c = s["contacts"]
    out[..., c] = (out[..., c] > 0.5).to(raw)
    return out, valid


def noisy(raw: Tensor, spec: FeatureSpec, std: Tensor, generator: torch.Generator | None = None) -> Tensor:
    """Root tilt and joint rotations (6D) with Gaussian noise of ``std`` (B,) per component."""
    s = spec.slices()
    out = raw.clone()
    rot = slice(s["root_tilt"].start, s["joint_rotations"].stop)
    eps = torch.randn(out[..., rot].shape, generator=generator, dtype=raw.dtype).to(raw.device)
    out[..., rot] = out[..., rot] + eps * std[:, None, None].to(raw)
    return out


def degraded_batch(raw: Tensor, spec: FeatureSpec, generator: torch.Generator | None = None
                   ) -> tuple[Tensor, Tensor, list[str]]:
    """One degraded copy of each window of ``raw (B, T, D)``, of a kind drawn from
    ``KINDS`` in their ``SHARES``: frozen; low-passed at 0.8-4 Hz; slowed to 0.3-0.75 or
    sped up to 1.4-2.5 times; rotation noise of 0.01-0.05 per 6D component (about 0.5-3
    degrees). Returns the copies, their frame mask (B, T) and the kind of each."""
    B = raw.shape[0]
    pick = torch.multinomial(torch.tensor(SHARES), B, replacement=True, generator=generator)
    u = torch.rand(B, generator=generator, dtype=raw.dtype)
    out = raw.clone()
    valid = torch.ones(raw.shape[:2], dtype=torch.bool, device=raw.device)
    kinds = [KINDS[int(i)] for i in pick]
    for k, kind in enumerate(KINDS):
        m = (pick == k).to(raw.device)
        if not m.any():
            continue
        x, r = raw[m], u[m.cpu()]
        if kind == "frozen":
            out[m] = frozen(x, spec)
        elif kind == "lowpass":
            out[m] = lowpass(x, spec, 0.8 + 3.2 * r)
        elif kind == "noise":
            out[m] = noisy(x, spec, 0.01 + 0.04 * r, generator)
        else:
            factor = 0.3 + 0.45 * r if kind == "slow" else 1.4 + 1.1 * r
            out[m], valid[m] = retimed(x, spec, factor)
    return out, valid, kinds
