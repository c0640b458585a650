"""One or more causal-convolution networks of one architecture evaluated together.

A pooled prior runs two networks (the change model and its anchor) over the same
history. Run one after the other, each as ``Conv1d`` modules, a window of 56 frames
costs hundreds of small tensor operations, and on the CPU their fixed cost, not their
arithmetic, is the time: a gated block took 0.37 ms for 0.9 MFLOP. Here the networks'
weights are stacked along a leading axis, so that one batched matrix product does each
layer of every network; the residual blocks' skip outputs are gathered and projected
by one product after the last block (a sum of per-block products is one product over
the blocks' outputs stacked); and the last block's residual output, which nothing
reads, is not computed. The numbers are those of the modules, to float rounding.

Shapes: ``N`` networks, ``C`` channels, ``B`` sequences, ``T`` frames, in that order, so
that every layer is one batched product with ``B * T`` columns.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as Fn
from torch import Tensor, nn


@dataclass
class StackedWeights:
    """The weights of ``N`` networks, each of shape (N, out, in) with biases (N, out, 1)."""

    encoder: list[tuple[Tensor, Tensor]]
    conv: list[tuple[Tensor, Tensor]]        # per block: taps stacked along the input channels
    res: list[tuple[Tensor, Tensor]]         # per block but the last
    skip: tuple[Tensor, Tensor]              # over every block's gated output, stacked
    decoder: list[tuple[Tensor, Tensor]]
    dilations: tuple[int, ...]
    kernel: int
    channels: int


def architecture(net: nn.Module) -> tuple:
    """What must agree for networks to be stacked: input size, widths, dilations, kernel."""
    c = net.config
    return net.spec.dim, c.channels, c.skip_channels, tuple(c.dilations), c.kernel_size


def _conv(layers: list[nn.Conv1d]) -> tuple[Tensor, Tensor]:
    """Kernel-1 convolutions of N networks as (N, out, in) weights and (N, out, 1) biases."""
    return torch.stack([m.weight[..., 0] for m in layers]), torch.stack([m.bias[:, None] for m in layers])


def stack_weights(nets: list[nn.Module]) -> StackedWeights:
    """The weights of ``nets`` (``CCNetPrior``s of one ``architecture``), stacked.
    Differentiable: in training, gradients reach each network's parameters."""
    blocks = list(zip(*(n.blocks for n in nets)))
    conv = []
    for layer in blocks:
        w = torch.stack([b.conv.weight for b in layer])                  # (N, 2C, C, K)
        conv.append((w.transpose(2, 3).reshape(w.shape[0], w.shape[1], -1),
                     torch.stack([b.conv.bias[:, None] for b in layer])))
    skips = [_conv([b.skip for b in layer]) for layer in blocks]
    skip_w, skip_b = torch.cat([w for w, _ in skips], dim=-1), sum(b for _, b in skips)
    first = nets[0]
    return StackedWeights(
        encoder=[_conv([n.encoder[i] for n in nets]) for i in (0, 2)],
        conv=conv, res=[_conv([b.res for b in layer]) for layer in blocks[:-1]], skip=(skip_w, skip_b),
        decoder=[_conv([n.decoder[i] for n in nets]) for i in (1, 3)],
        dilations=tuple(first.config.dilations), kernel=first.config.kernel_size, channels=first.config.channels)


def _linear(layer: tuple[Tensor, Tensor], h: Tensor) -> Tensor:
    """(N, out, B, T) of a kernel-1 convolution of ``h (N, in, B, T)``: one batched
    product over every sequence and frame (``B * T`` columns), which a rollout's one frame
    per step needs to stay a matrix product rather than ``B`` matrix-vector ones."""
    w, b = layer
    n, _, bt, t = h.shape
    return torch.baddbmm(b, w, h.reshape(n, -1, bt * t)).view(n, -1, bt, t)


def encode(w: StackedWeights, history: Tensor) -> Tensor:
    """(N, C, B, T) first block's input for frames ``history (B, T, D)`` (shared by the
    networks: their first layers are one product)."""
    (w0, b0), (n, c, _) = w.encoder[0], w.encoder[0][0].shape
    b, t, d = history.shape
    h = torch.addmm(b0.reshape(n * c, 1), w0.reshape(n * c, d), history.permute(2, 0, 1).reshape(d, b * t))
    return _linear(w.encoder[1], torch.relu(h).view(n, c, b, t))


def blocks(w: StackedWeights, h: Tensor, past: list[Tensor] | None = None) -> tuple[Tensor, list[Tensor]]:
    """Decoder output (N, out, B, T) after the gated blocks over ``h (N, C, B, T)``
    (``encode``), and each block's input over its receptive span: ``past[i]
    (N, C, B or 1, pad_i)`` (the block's input before ``h``; None: zeros, the sequence's
    start) followed by its input over ``h``."""
    n, c, b, t = h.shape
    gated, spans = [], []
    for i, d in enumerate(w.dilations):
        pad = (w.kernel - 1) * d
        x = Fn.pad(h, (pad, 0)) if past is None else torch.cat((past[i].to(h).expand(n, c, b, -1), h), dim=-1)
        spans.append(x)
        taps = torch.cat([x[..., k * d:k * d + t] for k in range(w.kernel)], dim=1)
        a = _linear(w.conv[i], taps)
        g = torch.tanh(a[:, :c]) * torch.sigmoid(a[:, c:])
        gated.append(g)
        if i < len(w.res):
            h = h + _linear(w.res[i], g)
    skip = _linear(w.skip, torch.cat(gated, dim=1))
    out = _linear(w.decoder[1], torch.relu(_linear(w.decoder[0], torch.relu(skip))))
    return out, spans
