"""The latent prior as the MAP solver's prior term: a per-frame energy from how far a
motion lies from what the latent autoencoder makes of it.

The MAP tasks score frames with an autoregressive density (``motionopt.prior.MotionPrior``).
A latent prior has no per-frame likelihood, but its denoising encoder and generator give a
reconstruction D(x) = G(I(x)) that moves a motion toward the motions it was trained on; the
residual x - D(x) of a denoising autoencoder points along the gradient of the data's log
density (Alain and Bengio 2014), and regularisation by denoising (Romano et al. 2017)
uses it as a prior. Here each frame's pose is scored as a Gaussian around its
reconstruction, with standard deviation ``tau`` (normalised units), so that the MAP
objective, its floors on the predictive spread and its solver run unchanged: ``Denoise``
with this prior is ``denoise --method latent``.

The reconstruction of a window covers its context and its frames (cut into the latent
prior's windows, overlapping and blended, as inversion does); the gradient flows through
encoder and generator.
"""
from __future__ import annotations

import math

import torch
from torch import Tensor

from motionopt.prior import gaussian_nll, scoring_log_std
from motionopt.solver import blend, clip_window_starts

from .latent import LatentPrior

#: Standard deviation (normalised units) of a frame's pose around its reconstruction.
#: Measured with ``Denoise`` on the first 10 s of 4 held-out clips per prior at 1 / 3 / 5
#: cm of joint noise (MPJPE, cm; runs/diag/latent_map.py): CMU 0.241 / 0.525 / 0.761 at
#: 1.0, 0.251 / 0.634 / 1.095 at 0.3, against 0.239 / 0.520 / 0.751 with no prior term
#: and 0.238 / 0.515 / 0.747 with the autoregressive prior; Bandai (2 clips) 0.183 /
#: 0.429 / 0.649 at 1.0, 0.227 / 0.605 / 0.994 at 0.1. Tighter, the term pulls frames
#: toward reconstructions 1.3-2.8 cm off (the round trip's error): it does not yet help.
TAU = 1.0
#: Frames of context the reconstruction sees before a window's frames.
CONTEXT = 16


class LatentDensity:
    """``MotionPrior``'s scoring methods over a ``LatentPrior`` (no sampling)."""

    def __init__(self, latent: LatentPrior, tau: float = TAU, context: int = CONTEXT):
        if not tau > 0:
            raise ValueError(f"tau must be positive, got {tau}")
        self.latent = latent
        self.spec, self.normalizer = latent.spec, latent.normalizer
        self.skeleton, self.metadata = latent.skeleton, latent.metadata
        self.tau = tau
        self.receptive_field = context
        self.sample_temperature = 1.0

    def reconstruction(self, x: Tensor, context: Tensor | None = None) -> Tensor:
        """D(x) of frames ``x (..., T, D)`` after ``context (C, D)``: (..., T, D), contacts as probabilities."""
        lead = x.shape[:-2]
        flat = x.reshape(-1, *x.shape[-2:])
        if context is not None and context.shape[-2]:
            flat = torch.cat((context.to(flat).expand(len(flat), *context.shape[-2:]), flat), dim=-2)
        n, w = flat.shape[1], self.latent.window
        if n < w:
            flat = torch.cat((flat, flat[:, -1:].expand(-1, w - n, -1)), dim=1)
        starts = clip_window_starts(flat.shape[1], w, w // 4)
        out = []
        for clip in flat:
            windows = torch.stack([clip[s:s + w] for s in starts])
            out.append(blend(self.latent.generate(self.latent.encode(windows)), starts, flat.shape[1]))
        rec = torch.stack(out)[:, n - x.shape[-2]:n]
        return rec.reshape(*lead, *rec.shape[-2:])

    def gaussian(self, x: Tensor, context: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor]:
        rec = self.reconstruction(x, context)
        p = self.spec.pose_dim
        probs = rec[..., p:].clamp(1e-4, 1 - 1e-4)
        return rec[..., :p], torch.full_like(rec[..., :p], math.log(self.tau)), torch.log(probs) - torch.log1p(-probs)

    def nll_and_contacts(self, x: Tensor, context: Tensor | None = None, min_log_std: float | Tensor | None = None,
                         log_std: Tensor | None = None) -> tuple[Tensor, Tensor]:
        mean, predicted, logits = self.gaussian(x, context)
        ls = scoring_log_std(predicted, log_std, min_log_std)
        return gaussian_nll(x[..., :self.spec.pose_dim], mean, ls).sum(-1), torch.sigmoid(logits).detach()

    def nll(self, x: Tensor, context: Tensor | None = None) -> Tensor:
        return self.nll_and_contacts(x, context)[0]

    def predict_contacts(self, x: Tensor, context: Tensor | None = None) -> Tensor:
        return self.nll_and_contacts(x, context)[1]

    def cache_context(self, context: Tensor) -> Tensor:
        return context

    def sample(self, *args, **kwargs) -> Tensor:
        raise NotImplementedError("the latent prior does not roll motion out frame by frame; use an autoregressive prior")
