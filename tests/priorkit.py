"""Tiny real priors for the prior tests, built from the CMU excerpts in tests/data.

The dataset and the briefly trained prior are cached per test process, so the three
prior test modules share one build (a few seconds on two cores).
"""
from __future__ import annotations

import functools
from pathlib import Path

import pytest
import torch

from motionopt import bvh
from motionopt.dataset import MotionDataset, build_dataset
from priors.ccnet import CCNetConfig, CCNetPrior
from clips import DATA

#: Small enough to train in a second, deep enough to have a receptive field of 8 frames.
TINY = CCNetConfig(channels=16, skip_channels=16, dilations=(1, 2, 4), input_dropout=0.0)


@functools.lru_cache(maxsize=None)
def cmu_clips() -> tuple[Path, ...]:
    """The CMU excerpts shipped for tests (43-joint skeleton rooted at ``hip``), by name."""
    clips = tuple(p for p in sorted(DATA.glob("*.bvh")) if bvh.read_channels(p)[0].names[0] == "hip")
    if len(clips) < 2:
        pytest.skip("needs at least two CMU excerpts in tests/data")
    return clips


def cmu_clip(fps: float) -> Path:
    """A shipped CMU excerpt whose header states ``fps`` frames per second."""
    for p in cmu_clips():
        if abs(1.0 / bvh.read_channels(p)[2] - fps) < 0.5:
            return p
    pytest.skip(f"no {fps:g} fps CMU excerpt in tests/data")


@functools.lru_cache(maxsize=None)
def tiny_dataset() -> MotionDataset:
    """All CMU excerpts at 30 fps; the last one held out for validation."""
    clips = cmu_clips()
    return build_dataset(DATA, include=[p.name for p in clips], val=[clips[-1].name])


def fresh_prior(seed: int = 0) -> CCNetPrior:
    """An untrained tiny prior on the test dataset."""
    ds = tiny_dataset()
    torch.manual_seed(seed)
    return CCNetPrior(ds.spec, ds.normalizer, ds.skeleton, TINY, {"licence": "test licence"})


@functools.lru_cache(maxsize=None)
def tiny_prior(steps: int = 30) -> CCNetPrior:
    """A tiny prior after ``steps`` Adam steps on the test dataset, in eval mode.

    Training moves the zero-initialised output layer, so every part of the network
    shapes the prediction (an untrained prior would predict "same as last frame").
    """
    prior = fresh_prior()
    windows = tiny_dataset().windows("train", 32, 8)
    opt = torch.optim.Adam(prior.parameters(), lr=3e-3)
    gen = torch.Generator().manual_seed(0)
    for _ in range(steps):
        batch = windows[torch.randint(len(windows), (8,), generator=gen)]
        loss, _ = prior.loss(batch)
        opt.zero_grad()
        loss.backward()
        opt.step()
    return prior.eval()


def features(path: Path, prior: CCNetPrior | None = None) -> torch.Tensor:
    """Normalised features (T, D) of a clip for a prior (default: the tiny prior)."""
    from priors.score import checked_features

    return checked_features(prior or tiny_prior(), bvh.load(path))

def assert_kept_the_best_sound_start(solver) -> None:
    """``solver`` (a ``MAPResult`` of several starts) kept the lowest objective among the
    starts with the fewest seconds outside the range of human motion."""
    faults = solver.starts_faults
    assert len(faults) == len(solver.starts_fun)
    assert solver.fun == min(f for f, n in zip(solver.starts_fun, faults) if n == min(faults))
