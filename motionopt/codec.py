"""One codec for a prior's features: motion -> normalised features -> motion or positions.

A prior sees motion as normalised feature vectors (``features.encode`` then its
``Normalizer``) on its own joints at its own frame rate; the way back integrates the
root from a ``RootStart`` and runs forward kinematics on a skeleton. ``Codec`` holds the
three things those conversions need (feature spec, normaliser, skeleton) so that every
caller converts the same way.
"""
from __future__ import annotations

from dataclasses import dataclass

from torch import Tensor

from .dataset import Normalizer
from .features import FeatureSpec, RootStart, decode_motion, decode_positions, encode, to_model_motion
from .motion import Motion
from .skeleton import Skeleton


@dataclass(frozen=True)
class Codec:
    """Conversions for one prior. ``skeleton`` is what decoding builds on: the prior's own,
    or a user's motion's model skeleton (same joints, the actor's bone lengths)."""

    spec: FeatureSpec
    normalizer: Normalizer
    skeleton: Skeleton

    @classmethod
    def of(cls, prior, skeleton: Skeleton | None = None) -> "Codec":
        """The codec of ``prior`` (anything with ``spec``, ``normalizer`` and ``skeleton``),
        decoding onto ``skeleton`` (default the prior's)."""
        return cls(prior.spec, prior.normalizer, prior.skeleton if skeleton is None else skeleton)

    def model_motion(self, motion: Motion) -> Motion:
        """``motion`` on the prior's joints at its frame rate (``features.to_model_motion``)."""
        return to_model_motion(motion, self.spec)

    def encode(self, motion: Motion, ground: float | None = None) -> tuple[Tensor, Tensor, RootStart]:
        """Raw features (T, D) float64, normalised features (T, D) float32 and the root state
        decoding starts from, of a motion on the prior's joints and rate; heights are
        measured from ``ground`` (default: estimated from the clip's feet)."""
        raw, start = encode(motion, self.spec, ground=ground)
        return raw, self.normalizer.normalize(raw).float(), start

    def features(self, motion: Motion, ground: float | None = None) -> Tensor:
        """Normalised features (T, D) float32 of a motion on the prior's joints and rate."""
        return self.encode(motion, ground)[1]

    def raw(self, x: Tensor) -> Tensor:
        """Unnormalised features of normalised ones ``x (..., T, D)``, in ``x``'s dtype."""
        return self.normalizer.denormalize(x)

    def positions(self, x: Tensor, start: RootStart = RootStart()) -> Tensor:
        """World joint positions (..., T, J, 3) of normalised features ``x``, the root
        integrated from ``start``; differentiable, in ``x``'s dtype (pass float64 for long
        clips: the root is a sum of steps)."""
        return decode_positions(self.raw(x), self.spec, self.skeleton, start)

    def motion(self, x: Tensor, start: RootStart = RootStart(), like: Motion | None = None) -> Motion:
        """The ``Motion`` of normalised features (T, D), the root integrated from ``start``;
        ``like`` lends its unit (``features.decode_motion``); decoded in float64."""
        return decode_motion(self.raw(x), self.spec, self.skeleton, start, like=like)
