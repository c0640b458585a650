"""The protocol every autoregressive motion prior follows.

The solver and the problems depend on this protocol only, so a new prior (a recurrent
GMM, a transformer) plugs in without touching them. Features are the normalised
per-frame vectors of ``motionopt.features`` (``spec`` and ``normalizer`` say how).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import torch
from torch import Tensor

from .dataset import Normalizer
from .features import FeatureSpec
from .skeleton import Skeleton

_HALF_LOG_2PI = 0.5 * math.log(2 * math.pi)


class Steer(Protocol):
    """What a rollout does to new frame ``t`` (normalised (..., D), drawn after ``last``)
    before it becomes history: returns the frame kept."""

    def __call__(self, t: int, last: Tensor, drawn: Tensor) -> Tensor: ...


@dataclass
class ChannelClamp:
    """A ``Steer`` that sets feature ``channels`` of new frame t to ``values[t]``
    (normalised, (n_frames, K)): the prior draws the rest of each frame knowing them (the
    pose for a given root path)."""

    channels: slice
    values: Tensor

    def __call__(self, t: int, last: Tensor, drawn: Tensor) -> Tensor:
        out = drawn.clone()
        out[..., self.channels] = self.values[t].to(drawn)
        return out


def gaussian_nll(x: Tensor, mean: Tensor, log_std: Tensor, mask: Tensor | None = None) -> Tensor:
    """-log N(x; mean, exp(log_std)^2) per dimension (broadcast shape), the one Gaussian
    score of every prior and baseline. ``mask`` (0/1, broadcast) zeroes dimensions left out
    of the likelihood before squaring, so that a far-off value there gives 0, not inf * 0."""
    z = (x - mean) * torch.exp(-log_std)
    norm = log_std + _HALF_LOG_2PI
    if mask is not None:
        z, norm = z * mask, norm * mask
    return 0.5 * z * z + norm


def student_nll(x: Tensor, mean: Tensor, log_scale: Tensor, dof: float, mask: Tensor | None = None) -> Tensor:
    """-log t_dof(x; mean, exp(log_scale)) per dimension: Student's t with ``dof`` degrees of
    freedom, whose cost grows with the log of a far-off value's square rather than with
    the square, so that a few dimensions a clip moves as the training data never did do
    not outweigh every other dimension of the frame. ``mask`` as ``gaussian_nll``'s."""
    z = (x - mean) * torch.exp(-log_scale)
    norm = log_scale + (math.lgamma(dof / 2) - math.lgamma((dof + 1) / 2) + 0.5 * math.log(dof * math.pi))
    if mask is not None:
        z, norm = z * mask, norm * mask
    return 0.5 * (dof + 1) * torch.log1p(z * z / dof) + norm


def scoring_log_std(predicted: Tensor, log_std: Tensor | None = None,
                    min_log_std: float | Tensor | None = None) -> Tensor:
    """The log-std a frame is scored with (``MotionPrior.nll_and_contacts``): ``log_std``
    where the caller holds it, else the predicted one; floored at ``min_log_std``."""
    out = predicted if log_std is None else log_std.to(predicted)
    return out if min_log_std is None else torch.maximum(out, torch.as_tensor(min_log_std).to(out))


@runtime_checkable
class MotionPrior(Protocol):
    """A differentiable autoregressive density over normalised feature sequences."""

    spec: FeatureSpec
    normalizer: Normalizer
    skeleton: Skeleton
    metadata: dict

    @property
    def receptive_field(self) -> int:
        """How many past frames can influence the prediction of a frame."""

    @property
    def sample_temperature(self) -> float:
        """The temperature at which long rollouts keep the data's pace (calibrated after
        training, ``priors.temperature``): what the tasks sample at unless told otherwise."""

    def nll(self, x: Tensor, context: Tensor | None = None) -> Tensor:
        """Per-frame negative log-likelihood -log p(x_t | x_<t) of frames ``x (..., T, D)``.

        ``context (..., C, D)`` holds frames before ``x``; returns ``(..., T)``, one
        teacher-forced pass, differentiable in ``x`` and ``context``. Contact dimensions
        of ``x`` are history only; they are not scored.
        """

    def gaussian(self, x: Tensor, context: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor]:
        """The one-step predictions for frames of ``x``: mean and log-std (..., T, P) of the
        pose dimensions, contact logits (..., T, C)."""

    def nll_and_contacts(self, x: Tensor, context: Tensor | None = None, min_log_std: float | Tensor | None = None,
                         log_std: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """``nll`` and ``predict_contacts`` from one pass (what the solver calls).

        ``min_log_std`` floors the predictive log-std (normalised units): a tempered,
        less stiff prior that optimisers can trade against task terms. ``log_std
        (..., T, P)``, when given, replaces the predicted log-std: a local solve holds it
        fixed, so that it cannot lower the energy by making frames less certain."""

    def cache_context(self, context: Tensor) -> object:
        """What to pass as ``context`` instead of ``context (C, D)`` to ``gaussian`` and
        ``nll_and_contacts`` when scoring many windows after the same context (the solver's
        iterations): the context's share of the pass computed once. It has ``shape``, the
        context's; a prior with nothing to cache returns ``context``."""

    def predict_contacts(self, x: Tensor, context: Tensor | None = None) -> Tensor:
        """Probability (..., T, C) that each contact joint touches the ground at each frame."""

    def sample(self, context: Tensor, n_frames: int, generator: torch.Generator | None = None,
               temperature: float = 1.0, noise: Tensor | None = None, plant: bool = True,
               steer: Steer | None = None) -> Tensor:
        """Roll out ``n_frames`` new frames (..., n_frames, D) after ``context (..., C, D)``.

        ``noise (..., n_frames, P)``, when given, replaces the standard normal draws of the
        pose dimensions (a rollout is then a deterministic function of it: what the
        particle swarm searches over). With ``plant`` the root of each new frame moves so
        that the contact joints the prior calls planted stay still (no foot sliding);
        callers that set the root themselves turn it off. ``steer`` changes each new frame
        before it becomes history (``Steer``; e.g. ``ChannelClamp`` sets its root channels
        to a path's): the prior draws the frames after it knowing the change."""


@runtime_checkable
class LatentMotionPrior(Protocol):
    """A generator of fixed-length windows driven by W+ codes, with encoders into W+
    (``priors.latent.LatentPrior``). Windows are normalised features (B, window, D);
    W+ codes are (B, num_ws, w_dim), one code per stretch of frames of the window;
    contact dimensions of generated windows hold probabilities."""

    spec: FeatureSpec
    normalizer: Normalizer
    skeleton: Skeleton
    metadata: dict
    #: Principal directions of single codes (rows, largest first) and their standard
    #: deviations: the subspace the inversion's particle swarm searches.
    w_components: Tensor
    w_scales: Tensor

    @property
    def window(self) -> int:
        """Frames per generated window."""

    @property
    def num_ws(self) -> int:
        """Codes per W+ code (one per stretch of frames)."""

    def sample_wplus(self, n: int, generator: torch.Generator | None = None, truncation: float = 1.0) -> Tensor:
        """n W+ codes (n, num_ws, w_dim) drawn from the prior's distribution of codes."""

    def generate(self, wplus: Tensor) -> Tensor:
        """Windows (B, window, D) of W+ codes; differentiable."""

    def encode(self, x: Tensor) -> Tensor:
        """W+ codes of windows, in one forward pass."""

    def encode_masked(self, x: Tensor, mask: Tensor) -> Tensor:
        """W+ codes of windows of which only frames with ``mask (B, window)`` true are seen."""

    def whiten(self, w: Tensor) -> Tensor:
        """Coordinates of codes (..., w_dim) along W's principal directions, in standard deviations."""
