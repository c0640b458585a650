"""The prior's networks evaluated as stacked matrix products (``priors.stacked``): the
numbers of the CCNet modules, for one network and for a pool of two of any widths."""
from __future__ import annotations

from dataclasses import replace

import torch
import torch.nn.functional as Fn

from priors.ccnet import CCNetPrior

from priorkit import TINY, cmu_clips, features, fresh_prior, tiny_prior


def module_pass(net: CCNetPrior, history: torch.Tensor) -> torch.Tensor:
    """Decoder output (B, T, out) of one network over ``history (B, T, D)``, written as the
    CCNet paper's layers with torch's own convolutions: causal (left-padded) dilated
    convolution, tanh * sigmoid gate, residual and summed skip outputs."""
    h = net.encoder(history.transpose(1, 2))
    skip = 0
    for block in net.blocks:
        a, b = Fn.conv1d(Fn.pad(h, (block.conv.dilation[0] * (block.conv.kernel_size[0] - 1), 0)),
                         block.conv.weight, block.conv.bias, dilation=block.conv.dilation).chunk(2, dim=1)
        g = torch.tanh(a) * torch.sigmoid(b)
        h, skip = h + block.res(g), skip + block.skip(g)
    return net.decoder(skip).transpose(1, 2)


def randomised(net: CCNetPrior, seed: int) -> CCNetPrior:
    """``net`` with every parameter drawn at random (the output layer starts at zero)."""
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in net.parameters():
            p.copy_(0.3 * torch.randn(p.shape, generator=gen))
    return net.eval()


def x() -> torch.Tensor:
    return features(cmu_clips()[0])[:40]


def test_the_stacked_pass_is_the_module_pass():
    prior = tiny_prior()
    history = torch.stack((x()[:-1], x()[1:]))
    with torch.no_grad():
        mean, log_std, logits = prior._predict(history)
        want = prior._head(history, module_pass(prior, history))
    for got, ref in zip((mean, log_std, logits), want):
        assert torch.allclose(got, ref, atol=1e-5)


def test_a_pool_of_two_widths_is_the_pool_of_each_network_alone():
    base = fresh_prior()
    config = replace(TINY, anchor=replace(TINY, channels=8, absolute_pose=True), anchor_weight=0.3)
    pooled = randomised(CCNetPrior(base.spec, base.normalizer, base.skeleton, config), seed=1)
    history = x()[None, :-1]
    with torch.no_grad():
        mean, log_std, _ = pooled._predict(history)
        own = pooled._head(history, module_pass(pooled, history))
        theirs = pooled.anchor._head(history, module_pass(pooled.anchor, history))
        want_mean, want_log_std = pooled.pool(own[0], own[1], theirs[0], theirs[1])
    assert torch.allclose(mean, want_mean, atol=1e-5)
    assert torch.allclose(log_std, want_log_std, atol=1e-5)


def test_training_reaches_every_parameter_and_an_update_reaches_evaluation():
    prior = randomised(fresh_prior(), seed=2).train()
    loss, _ = prior.loss(x()[None])
    loss.backward()
    # the last block's residual output feeds nothing (only its skip output is read)
    last_res = {id(p) for p in prior.blocks[-1].res.parameters()}
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in prior.parameters() if id(p) not in last_res)
    prior.eval()
    history = x()[None, :-1]
    with torch.no_grad():
        before = prior._predict(history)[0]
        prior.decoder[-1].bias += 0.5       # an in-place update, as an optimiser step makes
        after = prior._predict(history)[0]
        want = prior._head(history, module_pass(prior, history))[0]
    assert not torch.allclose(before, after)
    assert torch.allclose(after, want, atol=1e-5)
