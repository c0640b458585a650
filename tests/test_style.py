"""The style classifier (priors.style) and the style directions it labels sampled motions for."""
from __future__ import annotations

from pathlib import Path

import pytest
import torch

from motionopt.dataset import build_dataset
from priors.checkpoint import CHECKPOINT_DIR, load_prior
from priors.semantic import directions_of, edit_codes
from priors.style import fit_style_classifier, style_classifier_of

BANDAI = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "bandai"


@pytest.mark.skipif(not BANDAI.is_dir(), reason="../shared/data/bandai is absent")
def test_classifier_tells_the_style_of_unseen_clips():
    """Fitted on the first take of every walk style, it names the style of the second
    take well above chance (1 in 15)."""
    ds = build_dataset(BANDAI, include=["dataset-1_walk_*"], val=["dataset-1_walk_*_002.bvh"])
    norm = {split: {k: ds.normalizer.normalize(v).float() for k, v in clips.items()}
            for split, clips in (("train", ds.train), ("val", ds.val))}
    clf = fit_style_classifier(norm["train"], norm["val"], window=64, min_windows=3)
    assert clf is not None and len(clf.styles) == 15
    assert clf.heldout_windows > 30
    assert clf.heldout_accuracy > 0.3


def test_shipped_style_edit_raises_the_style_probability():
    """On a fixed seed, samples edited along a style's direction get a higher probability
    of that style from the checkpoint's own classifier than samples edited against it."""
    prior = load_prior(CHECKPOINT_DIR / "bandai-latent.pt")
    clf = style_classifier_of(prior.metadata)
    assert clf is not None
    w = prior.sample_wplus(64, torch.Generator().manual_seed(11))
    dirs = directions_of(prior)
    for style in ("elderly", "exhausted", "sad"):
        low, high = (clf.score(prior.generate(edit_codes(w, dirs[f"style:{style}"], s)), style).mean()
                     for s in (-2.0, 2.0))
        assert high > low + 0.02, style


def test_a_style_edit_never_asks_a_window_against_its_sign():
    """The style goal's probability targets move by 0.4 per unit within 0.001-0.95, but a
    window already beyond that bound in the edit's direction is asked to stay where it is."""
    from problems.latent_edit import goal_of

    goal = goal_of(load_prior(CHECKPOINT_DIR / "bandai-latent.pt"), "style:elderly")
    p0 = torch.tensor([0.97, 0.5, 0.0005], dtype=torch.float64)
    up, down = (goal.target(p0.log(), k).exp() for k in (1.0, -1.0))
    assert torch.allclose(up, torch.tensor([0.97, 0.9, 0.4005], dtype=torch.float64))
    assert torch.allclose(down, torch.tensor([0.57, 0.1, 0.0005], dtype=torch.float64))


def test_classifier_rejects_an_unknown_style():
    clf = style_classifier_of(load_prior(CHECKPOINT_DIR / "bandai-latent.pt").metadata)
    with pytest.raises(ValueError, match="knows: active"):
        clf.score(torch.zeros(1, 64, len(clf.mean) // 3), "sleepy")
