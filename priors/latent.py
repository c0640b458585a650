"""Latent motion prior: a temporal convolutional autoencoder whose latent codes, one per
``2**levels`` frames of a window, form the W+ code that tasks invert, edit and sample.

MoDi (Raab et al. 2023, sections 3.3-3.4) generates windows from a learned constant
whose only input is one style code per layer, and finds codes for a motion with an
encoder trained afterwards against the frozen generator. Trained on this CPU that
design reproduced held-out motion to 11-13 cm (joint positions relative to the root),
and trained as an autoencoder it still stalled at 12 cm: a motion's timing had to pass
through per-channel scales of a fixed constant. Here the code itself is a sequence:

- ``encoder``: residual convolutions that halve the frames ``levels`` times, then a 1x1
  convolution to ``w_dim`` channels: a window (B, window, D) -> codes (B, num_ws, w_dim),
  one per ``2**levels`` frames (4 frames, 0.13 s at 30 fps, by default).
- ``generator``: the mirror image, doubling the frames ``levels`` times (linear
  upsampling and residual convolutions) back to (B, window, D); contact dimensions hold
  logits, which ``generate`` turns into probabilities.
- ``masked_encoder``: the encoder with a mask channel (unseen frames zeroed), trained
  against the frozen generator for completion and in-betweening.

Trained with noise on the codes and a penalty on their size (``priors.train_latent``),
the codes fill a smooth region that a Gaussian describes: ``fit_code_statistics``
stores its mean and principal directions over whole codes (``sample_wplus`` draws from
it) and over single codes (``whiten``, the inversion's regulariser, its particle swarm
and ``vary`` use those).
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
    """Architecture. ``channels`` has one width per level, finest first (the encoder's
    order; the generator runs them in reverse); ``sample_components`` is how many
    principal directions of whole codes the sampling Gaussian keeps."""

    window: int = 64
    w_dim: int = 64
    channels: tuple[int, ...] = (128, 256)
    kernel_size: int = 3
    sample_components: int = 256
    #: Bidirectional GRU layers over the masked encoder's codes (0: none, the design of
    #: checkpoints trained before 2026-12-05). Its convolutions see about 6 frames either
    #: side of a code, so without them a completed second is decoded from nothing.
    masked_context: int = 1

    @property
    def levels(self) -> int:
        return len(self.channels)

    @property
    def num_ws(self) -> int:
        """Codes per window: one per ``2**levels`` frames."""
        return self.window // 2 ** self.levels

    def __post_init__(self) -> None:
        if self.window % 2 ** self.levels or self.num_ws < 2:
            raise ValueError(f"window {self.window} must be a multiple of {2 ** self.levels} "
                             f"(at least 2 codes after {self.levels} levels that halve the frames)")

    @classmethod
    def from_dict(cls, d: dict) -> "LatentConfig":
        d = dict(d)
        d["channels"] = tuple(d["channels"])
        d.setdefault("masked_context", 0)  # stored before the field existed
        return cls(**d)

    def to_dict(self) -> dict:
        return asdict(self)


def _block(cin: int, cout: int, kernel: int) -> nn.ModuleDict:
    return nn.ModuleDict({"conv1": nn.Conv1d(cin, cout, kernel, padding=kernel // 2),
                          "conv2": nn.Conv1d(cout, cout, kernel, padding=kernel // 2),
                          "skip": nn.Conv1d(cin, cout, 1, bias=False)})


def _residual(b: nn.ModuleDict, h: Tensor) -> Tensor:
    y = Fn.leaky_relu(b["conv2"](Fn.leaky_relu(b["conv1"](h), 0.2)), 0.2)
    return (y + b["skip"](h)) / _SQRT2


class Encoder(nn.Module):
    """Window (B, T, D) [and mask (B, T)] -> codes (B, T / 2**levels, w_dim).

    The masked encoder adds ``config.masked_context`` bidirectional GRU layers over the
    code positions (a residual branch), so every code sees the whole window: what the
    seen frames say about a second after them or a gap between them."""

    def __init__(self, config: LatentConfig, in_dim: int, masked: bool = False):
        super().__init__()
        self.masked = masked
        c = config.channels
        self.inp = nn.Conv1d(in_dim + int(masked), c[0], 1)
        self.blocks = nn.ModuleList(_block(c[max(i - 1, 0)], c[i], config.kernel_size) for i in range(len(c)))
        layers = config.masked_context if masked else 0
        self.context = (nn.GRU(c[-1], c[-1] // 2, num_layers=layers, batch_first=True, bidirectional=True)
                        if layers else None)
        self.out = nn.Conv1d(c[-1], config.w_dim, 1)

    def forward(self, x: Tensor, mask: Tensor | None = None) -> Tensor:
        if self.masked:
            if mask is None:
                raise ValueError("the masked encoder needs a mask of seen frames")
            m = mask.to(x)[..., None]
            x = torch.cat((x * m, m), dim=-1)
        h = Fn.leaky_relu(self.inp(x.transpose(1, 2)), 0.2)
        for b in self.blocks:
            h = Fn.avg_pool1d(_residual(b, h), 2)
        if self.context is not None:
            h = (h + self.context(h.transpose(1, 2))[0].transpose(1, 2)) / _SQRT2
        return self.out(h).transpose(1, 2).contiguous()  # contiguous: L-BFGS views the codes' gradient


class Generator(nn.Module):
    """Codes (B, num_ws, w_dim) -> features (B, window, D): the encoder's mirror image."""

    def __init__(self, config: LatentConfig, out_dim: int):
        super().__init__()
        c = config.channels[::-1]
        self.inp = nn.Conv1d(config.w_dim, c[0], 1)
        self.blocks = nn.ModuleList(_block(c[max(i - 1, 0)], c[i], config.kernel_size) for i in range(len(c)))
        self.out = nn.Conv1d(c[-1], out_dim, 1)

    def forward(self, codes: Tensor) -> Tensor:
        h = Fn.leaky_relu(self.inp(codes.transpose(1, 2)), 0.2)
        for b in self.blocks:
            h = _residual(b, Fn.interpolate(h, scale_factor=2, mode="linear", align_corners=False))
        return self.out(h).transpose(1, 2)


class LatentPrior(nn.Module):
    """The latent prior; implements ``motionopt.prior.LatentMotionPrior``.

    Buffers (filled by ``fit_code_statistics`` from the codes of training windows):
    ``w_mean``, ``w_components`` (rows: principal directions, largest first) and
    ``w_scales`` (their standard deviations) describe single codes (w_dim);
    ``wplus_mean``, ``wplus_components`` and ``wplus_scales`` whole W+ codes, flattened.
    """

    def __init__(self, spec: FeatureSpec, normalizer: Normalizer, skeleton: Skeleton,
                 config: LatentConfig = LatentConfig(), metadata: dict | None = None):
        super().__init__()
        self.spec, self.normalizer, self.skeleton = spec, normalizer, skeleton
        self.config = config
        self.metadata = dict(metadata or {})
        self.generator = Generator(config, spec.dim)
        self.encoder = Encoder(config, spec.dim)
        self.masked_encoder = Encoder(config, spec.dim, masked=True)
        wd, flat = config.w_dim, config.num_ws * config.w_dim
        k = min(config.sample_components, flat)
        self.register_buffer("w_mean", torch.zeros(wd))
        self.register_buffer("w_components", torch.eye(wd))
        self.register_buffer("w_scales", torch.ones(wd))
        self.register_buffer("wplus_mean", torch.zeros(config.num_ws, wd))
        self.register_buffer("wplus_components", torch.eye(flat)[:k])
        self.register_buffer("wplus_scales", torch.ones(k))

    # ---- protocol ----------------------------------------------------------------------
    @property
    def window(self) -> int:
        return self.config.window

    @property
    def num_ws(self) -> int:
        return self.config.num_ws

    def synthesize(self, wplus: Tensor) -> Tensor:
        """Normalised features (B, window, D) with contact *logits* in the contact dimensions."""
        return self.generator(self._check_wplus(wplus))

    def generate(self, wplus: Tensor) -> Tensor:
        """Normalised features (B, window, D) of W+ codes (B, num_ws, w_dim); contact
        dimensions hold probabilities."""
        return self.contacts_to_probabilities(self.synthesize(wplus))

    def encode(self, x: Tensor) -> Tensor:
        """W+ codes (B, num_ws, w_dim) of normalised windows (B, window, D)."""
        return self.encoder(self._check_window(x))

    def encode_masked(self, x: Tensor, mask: Tensor) -> Tensor:
        """W+ codes of windows of which only frames with ``mask (B, window)`` true are seen;
        the other frames do not influence the result."""
        return self.masked_encoder(self._check_window(x), mask)

    def sample_wplus(self, n: int, generator: torch.Generator | None = None, truncation: float = 1.0) -> Tensor:
        """n W+ codes drawn from the Gaussian of the training windows' codes, pulled toward
        its mean by ``truncation`` < 1."""
        z = torch.randn(n, len(self.wplus_scales), generator=generator, dtype=self.wplus_mean.dtype)
        offset = (truncation * z * self.wplus_scales) @ self.wplus_components
        return self.wplus_mean + offset.reshape(n, self.num_ws, self.config.w_dim)

    def whiten(self, w: Tensor) -> Tensor:
        """Coordinates of codes (..., w_dim) along the principal directions of single
        codes, in standard deviations."""
        return ((w - self.w_mean) @ self.w_components.t()) / self.w_scales

    # ---- helpers -----------------------------------------------------------------------
    def contacts_to_probabilities(self, raw: Tensor) -> Tensor:
        c = self.spec.slices()["contacts"]
        return torch.cat((raw[..., :c.start], torch.sigmoid(raw[..., c])), dim=-1)

    @torch.no_grad()
    def fit_code_statistics(self, codes: Tensor) -> None:
        """Fill the buffers from W+ codes (N, num_ws, w_dim) of training windows."""
        single = _principal(codes.reshape(-1, codes.shape[-1]).double())
        whole = _principal(codes.flatten(1).double())
        k = len(self.wplus_scales)
        self.w_mean.copy_(single[0])
        self.w_components.copy_(single[1])
        self.w_scales.copy_(single[2])
        self.wplus_mean.copy_(whole[0].reshape(self.wplus_mean.shape))
        self.wplus_components.copy_(whole[1][:k])
        self.wplus_scales.copy_(whole[2][:k])

    def _check_window(self, x: Tensor) -> Tensor:
        if x.dim() != 3 or x.shape[1] != self.window or x.shape[2] != self.spec.dim:
            raise ValueError(f"expected windows (B, {self.window}, {self.spec.dim}), got {tuple(x.shape)}")
        return x

    def _check_wplus(self, wplus: Tensor) -> Tensor:
        if wplus.dim() != 3 or wplus.shape[1:] != (self.num_ws, self.config.w_dim):
            raise ValueError(f"expected W+ codes (B, {self.num_ws}, {self.config.w_dim}), got {tuple(wplus.shape)}")
        return wplus


def _principal(x: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Mean, principal directions (rows, largest first) and their standard deviations of
    samples ``x (N, d)``; with fewer samples than dimensions the trailing ones have a
    tiny scale."""
    mean = x.mean(0)
    evals, evecs = torch.linalg.eigh(torch.cov((x - mean).t()))
    order = torch.argsort(evals, descending=True)
    return mean, evecs[:, order].t(), evals[order].clamp_min(1e-12).sqrt()
