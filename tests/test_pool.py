"""A prior pooled with an absolute-pose anchor (``priors.pool``, ``CCNetConfig.anchor``)."""
from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from priors.checkpoint import load_prior, save_prior
from priors.pool import pool_priors

from priorkit import cmu_clips, features, fresh_prior, tiny_dataset, tiny_prior


def trained_anchor(steps: int = 30):
    """A tiny absolute-pose prior trained like ``tiny_prior`` on the same clips."""
    fresh = fresh_prior(seed=1)
    anchor = type(fresh)(fresh.spec, fresh.normalizer, fresh.skeleton, replace(fresh.config, absolute_pose=True),
                         {"licence": "test licence"})
    windows = tiny_dataset().windows("train", 32, 8)
    opt = torch.optim.Adam(anchor.parameters(), lr=3e-3)
    gen = torch.Generator().manual_seed(1)
    for _ in range(steps):
        loss, _ = anchor.loss(windows[torch.randint(len(windows), (8,), generator=gen)])
        opt.zero_grad()
        loss.backward()
        opt.step()
    return anchor.eval()


@pytest.fixture(scope="module")
def parts(tmp_path_factory):
    """Paths of the tiny prior, a tiny anchor, and the pool of the two at weight 0.3."""
    folder = tmp_path_factory.mktemp("pool")
    save_prior(tiny_prior(), folder / "prior.pt")
    save_prior(trained_anchor(), folder / "anchor.pt")
    save_prior(pool_priors(folder / "prior.pt", folder / "anchor.pt", 0.3), folder / "pooled.pt")
    return folder / "prior.pt", folder / "anchor.pt", folder / "pooled.pt"


@pytest.fixture(scope="module")
def x():
    return features(cmu_clips()[0])[:40]


def test_the_pool_is_the_weighted_geometric_mean_of_the_two_gaussians(parts, x):
    prior, anchor, pooled = (load_prior(p) for p in parts)
    m1, l1, c1 = prior.gaussian(x[1:], context=x[:1])
    m2, l2, _ = anchor.gaussian(x[1:], context=x[:1])
    m, log_std, contacts = pooled.gaussian(x[1:], context=x[:1])
    precision = 0.7 * torch.exp(-2 * l1) + 0.3 * torch.exp(-2 * l2)
    assert torch.allclose(log_std, -0.5 * torch.log(precision), atol=1e-5)
    assert torch.allclose(m, (0.7 * torch.exp(-2 * l1) * m1 + 0.3 * torch.exp(-2 * l2) * m2) / precision, atol=1e-4)
    assert torch.equal(contacts, c1)   # contacts come from the change-predicting prior
    between = torch.minimum(m1, m2) - 1e-4 <= m
    assert bool((between & (m <= torch.maximum(m1, m2) + 1e-4)).all())
    assert not torch.allclose(m1, m2, atol=1e-3)   # the test means something: the two differ


def test_a_pooled_rollout_continues_the_teacher_forced_pass(parts, x):
    """Step by step (each network's state carried), a rollout's means are those of one
    teacher-forced pass over the frames it drew."""
    pooled = load_prior(parts[2])
    context = x[:12]
    drawn = pooled.sample(context, 6, generator=torch.Generator().manual_seed(0), temperature=0.0, plant=False)
    mean, _, _ = pooled.gaussian(drawn, context=pooled.cache_context(context))
    p = pooled.spec.pose_dim
    assert torch.allclose(drawn[:, :p], pooled.project(torch.cat((mean, drawn[:, p:]), -1))[:, :p], atol=1e-4)


def test_the_pool_survives_a_checkpoint_and_names_its_anchor(parts):
    pooled = load_prior(parts[2])
    assert pooled.anchor is not None and pooled.config.anchor_weight == 0.3
    assert pooled.config.anchor.absolute_pose and not pooled.config.absolute_pose
    assert "sample_temperature" not in pooled.metadata


def test_pooling_refuses_what_it_cannot_pool(parts, tmp_path):
    prior, anchor, pooled = parts
    with pytest.raises(ValueError, match="absolute-pose"):
        pool_priors(anchor, prior, 0.5)
    with pytest.raises(ValueError, match="between 0 and 1"):
        pool_priors(prior, anchor, 1.0)
    with pytest.raises(ValueError, match="already pooled"):
        pool_priors(pooled, anchor, 0.5)
    other = load_prior(anchor)
    other.normalizer = replace(other.normalizer, std=other.normalizer.std * 2)
    save_prior(other, tmp_path / "other.pt")
    with pytest.raises(ValueError, match="normalise"):
        pool_priors(prior, tmp_path / "other.pt", 0.5)
    heavy = load_prior(anchor)
    heavy.config = replace(heavy.config, tail_dof=5.0)
    save_prior(heavy, tmp_path / "heavy.pt")
    with pytest.raises(ValueError, match="Student-t"):
        pool_priors(prior, tmp_path / "heavy.pt", 0.5)


def test_unpooled_is_the_change_model_alone_and_leaves_the_pool_whole(parts, x):
    prior, _, pooled_path = parts
    change, pooled = load_prior(prior), load_prior(pooled_path)
    alone = pooled.unpooled()
    for a, b in zip(alone.gaussian(x[1:], context=x[:1]), change.gaussian(x[1:], context=x[:1])):
        assert torch.equal(a, b)
    assert pooled.anchor is not None and alone.anchor is None
    assert not torch.equal(pooled.gaussian(x[1:], context=x[:1])[0], alone.gaussian(x[1:], context=x[:1])[0])
    assert change.unpooled() is change
