"""Degraded feature windows for training (priors.degrade) and the ranking part of the
prior's loss, on the tiny test prior's data."""
from __future__ import annotations

import torch

from priors.degrade import KINDS, degraded_batch, frozen, lowpass, retimed

from priorkit import fresh_prior, tiny_dataset


def raw_windows(n: int = 6, length: int = 32) -> torch.Tensor:
    ds = tiny_dataset()
    return ds.normalizer.denormalize(ds.windows("train", length, 1)[:n]).double()


def test_frozen_repeats_the_first_pose_without_root_motion():
    x = raw_windows()
    spec = tiny_dataset().spec
    f = frozen(x, spec)
    s = spec.slices()
    assert torch.equal(f[:, 5, 3:], x[:, 0, 3:])
    assert f[..., s["root_delta"]].abs().max() == 0 and f[..., s["yaw_delta"]].abs().max() == 0


def test_lowpass_keeps_constants_and_lowers_frame_to_frame_change():
    x = raw_windows()
    spec = tiny_dataset().spec
    p = spec.pose_dim
    const = x[:, :1].expand_as(x).clone()
    assert torch.allclose(lowpass(const, spec, torch.full((len(x),), 1.0)), const)
    smooth = lowpass(x, spec, torch.full((len(x),), 1.0))
    assert smooth[:, 1:, :p].diff(dim=1).abs().mean() < x[:, 1:, :p].diff(dim=1).abs().mean()
    assert torch.equal(smooth[..., p:], x[..., p:])  # contact labels untouched


def test_retimed_scales_root_steps_and_masks_frames_past_the_end():
    x = raw_windows()
    spec = tiny_dataset().spec
    fast, valid = retimed(x, spec, torch.full((len(x),), 2.0))
    assert valid[:, :16].all() and not valid[:, 16:].any()
    assert torch.allclose(fast[:, 3, :3], 2 * x[:, 6, :3])
    assert torch.allclose(fast[:, 3, 3:spec.pose_dim], x[:, 6, 3:spec.pose_dim])
    slow, valid = retimed(x, spec, torch.full((len(x),), 0.5))
    assert valid.all() and torch.allclose(slow[:, 4, 3:spec.pose_dim], x[:, 2, 3:spec.pose_dim])


def test_degraded_batch_draws_every_kind_and_changes_each_window():
    x = raw_windows(n=40)
    out, valid, kinds = degraded_batch(x, tiny_dataset().spec, torch.Generator().manual_seed(0))
    assert out.shape == x.shape and valid.shape == x.shape[:2] and set(kinds) == set(KINDS)
    p = tiny_dataset().spec.pose_dim
    assert ((out[:, 1:, :p] - x[:, 1:, :p]).abs().amax(dim=(1, 2)) > 0).all()


def test_ranking_loss_raises_degraded_copies_above_real_windows():
    """A few steps with the ranking part leave the copies of training windows a smaller
    shortfall behind the margin (the hinge) than the same steps on likelihood alone; on
    this tiny data likelihood alone already ranks most copies behind, so the shortfall,
    not the share, tells the two apart (bench/prior.py measures the share on real data)."""
    windows = tiny_dataset().windows("train", 32, 1)

    def shortfall_after(weight: float) -> float:
        prior = fresh_prior(seed=1)
        opt = torch.optim.Adam(prior.parameters(), lr=3e-3)
        gen = torch.Generator().manual_seed(0)
        for _ in range(60):
            batch = windows[torch.randint(len(windows), (8,), generator=gen)]
            loss, _ = prior.loss(batch, contrast_weight=weight, generator=gen)
            opt.zero_grad()
            loss.backward()
            opt.step()
        return sum(prior.loss(windows, contrast_weight=1.0, generator=torch.Generator().manual_seed(s))[1]["contrast"]
                   for s in range(5)) / 5

    assert shortfall_after(1.0) < 0.75 * shortfall_after(0.0)

