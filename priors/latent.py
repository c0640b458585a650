"""Latent motion prior after MoDi (Raab et al. 2023, sections 3.3-3.4): a StyleGAN2-like
generator over fixed windows of feature frames, with encoders into its W+ space.

- ``mapping``: an MLP z -> w (equalised learning rate, as StyleGAN).
- ``synthesis``: from a learned constant of ``window / 2**(levels-1)`` frames, each level
  doubles the frames (linear upsampling) and applies modulated/demodulated temporal
  convolutions; every convolution reads its own style code, so W+ holds ``num_ws`` codes.
  Output layers per level add into a skip output (StyleGAN2's "toRGB" skips).
  This is a plain temporal convolution over the feature vector, not MoDi's skeleton-aware
  convolution, and it has no noise inputs: a W+ code fixes the motion.
- ``encoder``/``masked_encoder``: convolutional networks that map a window (the second
  also takes a mask of seen frames; unseen frames are zeroed) to W+, as offsets from
  the mean w.
- ``Discriminator`` is used in training only and is not part of the shipped checkpoint.

Features are the normalised vectors of ``motionopt.features``; the generator outputs
contact logits in the contact dimensions, which ``generate`` turns into probabilities.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as Fn
from torch import Tensor, nn

from motionopt.dataset import Normalizer
from motionopt.features import FeatureSpec
from motionopt.skeleton import Skeleton

_SQRT2 = math.sqrt(2.0)


@dataclass(frozen=True)
class LatentConfig:
    """Architecture. ``channels`` has one width per synthesis level (coarse to fine);
    ``encoder_channels`` one width per downsampling block of encoders and discriminator."""

    window: int = 64
    z_dim: int = 128
    w_dim: int = 128
    mapping_layers: int = 4
    mapping_lr_mul: float = 0.01
    channels: tuple[int, ...] = (192, 192, 128, 96, 64)
    kernel_size: int = 3
    encoder_channels: tuple[int, ...] = (64, 96, 128, 128)
    encoder_hidden: int = 256

    @property
    def levels(self) -> int:
        return len(self.channels)

    @property
    def base_frames(self) -> int:
        return self.window // 2 ** (self.levels - 1)

    @property
    def num_ws(self) -> int:
        """Style codes in W+: one per convolution plus one for the last output layer."""
        return 2 * self.levels

    def __post_init__(self) -> None:
        if self.window % 2 ** (self.levels - 1) or self.base_frames < 2:
            raise ValueError(f"window {self.window} must be a multiple of {2 ** (self.levels - 1)} "
                             f"(at least 2 frames at the coarsest of {self.levels} levels)")
        if self.window % 2 ** len(self.encoder_channels):
            raise ValueError(f"window {self.window} must be divisible by 2**{len(self.encoder_channels)}")

    @classmethod
    def from_dict(cls, d: dict) -> "LatentConfig":
        d = dict(d)
        for k in ("channels", "encoder_channels"):
            d[k] = tuple(d[k])
        return cls(**d)

    def to_dict(self) -> dict:
        return asdict(self)


class EqualLinear(nn.Module):
    """Linear layer with equalised learning rate (weights scaled at run time)."""

    def __init__(self, cin: int, cout: int, bias_init: float = 0.0, lr_mul: float = 1.0, activate: bool = False):
        super().__init__()
        self.weight = nn.Parameter(torch.randn(cout, cin) / lr_mul)
        self.bias = nn.Parameter(torch.full((cout,), float(bias_init) / lr_mul))
        self.scale, self.lr_mul, self.activate = lr_mul / math.sqrt(cin), lr_mul, activate

    def forward(self, x: Tensor) -> Tensor:
        out = Fn.linear(x, self.weight * self.scale, self.bias * self.lr_mul)
        return Fn.leaky_relu(out, 0.2) * _SQRT2 if self.activate else out


class ModulatedConv(nn.Module):
    """Temporal convolution whose input channels are scaled by a style from w, then
    demodulated so every output channel has unit expected variance (StyleGAN2 Eq. 1-3).

    Implemented as scale-input, shared convolution, scale-output, which equals the
    per-sample modulated kernel."""

    def __init__(self, cin: int, cout: int, kernel: int, w_dim: int, demodulate: bool = True,
                 upsample: bool = False, activate: bool = True):
        super().__init__()
        self.weight = nn.Parameter(torch.randn(cout, cin, kernel))
        self.bias = nn.Parameter(torch.zeros(cout))
        self.affine = EqualLinear(w_dim, cin, bias_init=1.0)
        self.scale = 1.0 / math.sqrt(cin * kernel)
        self.demodulate, self.upsample, self.activate = demodulate, upsample, activate

    def forward(self, x: Tensor, w: Tensor) -> Tensor:
        s = self.affine(w)  # (B, cin)
        weight = self.weight * self.scale
        if self.upsample:
            x = Fn.interpolate(x, scale_factor=2, mode="linear", align_corners=False)
        out = Fn.conv1d(x * s[:, :, None], weight, padding=weight.shape[-1] // 2)
        if self.demodulate:
            d = torch.rsqrt((s * s) @ weight.pow(2).sum(-1).t() + 1e-8)  # (B, cout)
            out = out * d[:, :, None]
        out = out + self.bias[None, :, None]
        return Fn.leaky_relu(out, 0.2) * _SQRT2 if self.activate else out


class Synthesis(nn.Module):
    """Constant -> levels of modulated convolutions -> features (B, D, window)."""

    def __init__(self, config: LatentConfig, out_dim: int):
        super().__init__()
        c, k, wd = config.channels, config.kernel_size, config.w_dim
        self.const = nn.Parameter(torch.randn(c[0], config.base_frames))
        self.convs = nn.ModuleList([ModulatedConv(c[0], c[0], k, wd)])
        self.outs = nn.ModuleList([ModulatedConv(c[0], out_dim, 1, wd, demodulate=False, activate=False)])
        for i in range(1, config.levels):
            self.convs.append(ModulatedConv(c[i - 1], c[i], k, wd, upsample=True))
            self.convs.append(ModulatedConv(c[i], c[i], k, wd))
            self.outs.append(ModulatedConv(c[i], out_dim, 1, wd, demodulate=False, activate=False))

    def forward(self, ws: Tensor) -> Tensor:
        """``ws (B, num_ws, w_dim)`` -> (B, D, window). Convolution i reads ws[:, i]; the
        output layer of level l reads the code after its last convolution."""
        x = self.convs[0](self.const[None].expand(len(ws), -1, -1), ws[:, 0])
        skip = self.outs[0](x, ws[:, 1])
        for lvl in range(1, len(self.outs)):
            x = self.convs[2 * lvl - 1](x, ws[:, 2 * lvl - 1])
            x = self.convs[2 * lvl](x, ws[:, 2 * lvl])
            skip = Fn.interpolate(skip, scale_factor=2, mode="linear", align_corners=False) + \
                self.outs[lvl](x, ws[:, 2 * lvl + 1])
        return skip


class ConvTrunk(nn.Module):
    """Residual blocks that halve the frames each time: the shared shape of the
    discriminator and the encoders. (B, cin, T) -> (B, C_last, T / 2**blocks)."""

    def __init__(self, cin: int, channels: tuple[int, ...], kernel: int = 3):
        super().__init__()
        self.inp = nn.Conv1d(cin, channels[0], 1)
        self.blocks = nn.ModuleList()
        prev = channels[0]
        for c in channels:
            self.blocks.append(nn.ModuleDict({
                "conv1": nn.Conv1d(prev, prev, kernel, padding=kernel // 2),
                "conv2": nn.Conv1d(prev, c, kernel, padding=kernel // 2),
                "skip": nn.Conv1d(prev, c, 1, bias=False),
            }))
            prev = c

    def forward(self, x: Tensor) -> Tensor:
        h = Fn.leaky_relu(self.inp(x), 0.2)
        for b in self.blocks:
            y = Fn.leaky_relu(b["conv1"](h), 0.2)
            y = Fn.avg_pool1d(Fn.leaky_relu(b["conv2"](y), 0.2), 2)
            h = (y + Fn.avg_pool1d(b["skip"](h), 2)) / _SQRT2
        return h


class Discriminator(nn.Module):
    """Real/fake score of a window (B, T, D): residual trunk, minibatch std, linear head."""

    def __init__(self, config: LatentConfig, in_dim: int):
        super().__init__()
        self.trunk = ConvTrunk(in_dim, config.encoder_channels, config.kernel_size)
        c = config.encoder_channels[-1]
        frames = config.window // 2 ** len(config.encoder_channels)
        self.final = nn.Conv1d(c + 1, c, 3, padding=1)
        self.head = nn.Sequential(nn.Linear(c * frames, config.encoder_hidden), nn.LeakyReLU(0.2),
                                  nn.Linear(config.encoder_hidden, 1))

    def forward(self, x: Tensor) -> Tensor:
        h = self.trunk(x.transpose(1, 2))
        group = min(4, len(h))
        if len(h) % group:
            group = 1
        y = h.reshape(group, -1, *h.shape[1:])
        std = torch.sqrt(y.var(0, unbiased=False) + 1e-8).mean(dim=(1, 2))  # (B/group,)
        std = std.repeat(group)[:, None, None].expand(-1, 1, h.shape[-1])
        h = Fn.leaky_relu(self.final(torch.cat((h, std), 1)), 0.2)
        return self.head(h.flatten(1)).squeeze(-1)


class Encoder(nn.Module):
    """Window (B, T, D) [and mask (B, T)] -> W+ offsets (B, num_ws, w_dim)."""

    def __init__(self, config: LatentConfig, in_dim: int, masked: bool = False):
        super().__init__()
        self.masked = masked
        self.trunk = ConvTrunk(in_dim + int(masked), config.encoder_channels, config.kernel_size)
        frames = config.window // 2 ** len(config.encoder_channels)
        self.head = nn.Sequential(nn.Linear(config.encoder_channels[-1] * frames, config.encoder_hidden),
                                  nn.LeakyReLU(0.2), nn.Linear(config.encoder_hidden, config.num_ws * config.w_dim))
        nn.init.zeros_(self.head[-1].weight)
        nn.init.zeros_(self.head[-1].bias)
        self.shape = (config.num_ws, config.w_dim)

    def forward(self, x: Tensor, mask: Tensor | None = None) -> Tensor:
        if self.masked:
            if mask is None:
                raise ValueError("the masked encoder needs a mask of seen frames")
            m = mask.to(x)[..., None]
            x = torch.cat((x * m, m), dim=-1)
        return self.head(self.trunk(x.transpose(1, 2)).flatten(1)).reshape(len(x), *self.shape)


class LatentPrior(nn.Module):
    """The latent prior; implements ``motionopt.prior.LatentMotionPrior``.

    Buffers ``w_mean``, ``w_components`` (rows: principal directions of W, largest first)
    and ``w_scales`` (their standard deviations) describe the mapping network's output
    distribution; training fills them from samples.
    """

    def __init__(self, spec: FeatureSpec, normalizer: Normalizer, skeleton: Skeleton,
                 config: LatentConfig = LatentConfig(), metadata: dict | None = None):
        super().__init__()
        self.spec, self.normalizer, self.skeleton = spec, normalizer, skeleton
        self.config = config
        self.metadata = dict(metadata or {})
        layers = [EqualLinear(config.z_dim if i == 0 else config.w_dim, config.w_dim,
                              lr_mul=config.mapping_lr_mul, activate=True) for i in range(config.mapping_layers)]
        self.mapping_net = nn.Sequential(*layers)
        self.synthesis = Synthesis(config, spec.dim)
        self.encoder = Encoder(config, spec.dim)
        self.masked_encoder = Encoder(config, spec.dim, masked=True)
        wd = config.w_dim
        self.register_buffer("w_mean", torch.zeros(wd))
        self.register_buffer("w_components", torch.eye(wd))
        self.register_buffer("w_scales", torch.ones(wd))

    # ---- protocol ----------------------------------------------------------------------
    @property
    def window(self) -> int:
        return self.config.window

    @property
    def num_ws(self) -> int:
        return self.config.num_ws

    @property
    def mean_w(self) -> Tensor:
        return self.w_mean

    def mapping(self, z: Tensor) -> Tensor:
        """w (B, w_dim) of latent noise z (B, z_dim); z is normalised to unit RMS first."""
        z = z * torch.rsqrt(z.pow(2).mean(-1, keepdim=True) + 1e-8)
        return self.mapping_net(z)

    def synthesize(self, wplus: Tensor) -> Tensor:
        """Normalised features (B, window, D) with contact *logits* in the contact dimensions."""
        return self.synthesis(self._check_wplus(wplus)).transpose(1, 2)

    def generate(self, wplus: Tensor) -> Tensor:
        """Normalised features (B, window, D) of W+ codes (B, num_ws, w_dim); contact
        dimensions hold probabilities."""
        return self.contacts_to_probabilities(self.synthesize(wplus))

    def encode(self, x: Tensor) -> Tensor:
        """W+ codes (B, num_ws, w_dim) of normalised windows (B, window, D)."""
        return self.w_mean + self.encoder(self._check_window(x))

    def encode_masked(self, x: Tensor, mask: Tensor) -> Tensor:
        """W+ codes of windows of which only frames with ``mask (B, window)`` true are seen;
        the other frames do not influence the result."""
        return self.w_mean + self.masked_encoder(self._check_window(x), mask)

    # ---- helpers -----------------------------------------------------------------------
    def contacts_to_probabilities(self, raw: Tensor) -> Tensor:
        c = self.spec.slices()["contacts"]
        return torch.cat((raw[..., :c.start], torch.sigmoid(raw[..., c])), dim=-1)

    def broadcast(self, w: Tensor) -> Tensor:
        """W+ code (B, num_ws, w_dim) that repeats one w (B, w_dim) for every layer."""
        return w[:, None, :].expand(-1, self.num_ws, -1)

    def sample_w(self, n: int, generator: torch.Generator | None = None, truncation: float = 1.0) -> Tensor:
        """n codes w from the mapping network, pulled toward the mean by ``truncation`` < 1."""
        p = next(self.parameters())
        z = torch.randn(n, self.config.z_dim, generator=generator, dtype=p.dtype)
        w = self.mapping(z)
        return self.w_mean + truncation * (w - self.w_mean)

    @torch.no_grad()
    def fit_w_statistics(self, n: int = 8192, generator: torch.Generator | None = None) -> None:
        """Set ``w_mean``, ``w_components`` and ``w_scales`` from ``n`` mapped samples."""
        w = self.sample_w(n, generator).double()
        mean = w.mean(0)
        cov = torch.cov((w - mean).t())
        evals, evecs = torch.linalg.eigh(cov)
        order = torch.argsort(evals, descending=True)
        self.w_mean.copy_(mean)
        self.w_components.copy_(evecs[:, order].t())
        self.w_scales.copy_(evals[order].clamp_min(1e-12).sqrt())

    def whiten(self, w: Tensor) -> Tensor:
        """Coordinates of w (..., w_dim) along the principal directions, in standard deviations."""
        return ((w - self.w_mean) @ self.w_components.t()) / self.w_scales

    def _check_window(self, x: Tensor) -> Tensor:
        if x.dim() != 3 or x.shape[1] != self.window or x.shape[2] != self.spec.dim:
            raise ValueError(f"expected windows (B, {self.window}, {self.spec.dim}), got {tuple(x.shape)}")
        return x

    def _check_wplus(self, wplus: Tensor) -> Tensor:
        if wplus.dim() != 3 or wplus.shape[1:] != (self.num_ws, self.config.w_dim):
            raise ValueError(f"expected W+ codes (B, {self.num_ws}, {self.config.w_dim}), got {tuple(wplus.shape)}")
        return wplus
