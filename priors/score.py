"""How natural a motion is under a prior: per-frame NLL and the worst stretches."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from motionopt.codec import Codec
from motionopt.copies import window_copies
from motionopt.features import estimate_ground
from motionopt.motion import Motion

from .checkpoint import CheckpointError, check_compatible


@dataclass
class ScoreReport:
    """Mean per-frame negative log-likelihood and the frame ranges that score worst.

    Frames are numbered in the input motion's frame rate; ``worst`` holds
    ``(start, stop, mean_nll)`` half-open ranges, worst first.
    """

    nll_per_frame: float
    frames: int
    prior_fps: float
    per_frame: np.ndarray = field(repr=False)
    worst: list[tuple[int, int, float]]

    def to_dict(self) -> dict:
        return {"nll_per_frame": self.nll_per_frame, "frames": self.frames, "prior_fps": self.prior_fps,
                "worst": [{"start": a, "stop": b, "nll_per_frame": v} for a, b, v in self.worst]}


def checked_model_motion(prior, motion: Motion) -> Motion:
    """Any motion on ``prior``'s joints at its rate (resampled, joints selected), after
    checking that its skeleton is the prior's (``CheckpointError`` says how not)."""
    check_compatible(prior.spec, motion.skeleton, kind=type(prior).__name__)
    model = Codec.of(prior).model_motion(motion)
    if not model.skeleton.same_hierarchy(prior.skeleton):
        raise CheckpointError("the motion's joints have the prior's names but another hierarchy (parents "
                              "differ); use a prior trained on this skeleton (`motionopt train-prior`)")
    return model


def checked_features(prior, motion: Motion) -> torch.Tensor:
    """Normalised features (T, D) of any motion for ``prior`` (``checked_model_motion``)."""
    return Codec.of(prior).features(checked_model_motion(prior, motion))


@torch.no_grad()
def score_motion(prior, motion: Motion, window_seconds: float = 1.0, n_worst: int = 3) -> ScoreReport:
    """Score every frame after the first under the prior; report the worst windows."""
    x = checked_features(prior, motion)
    if len(x) < 2:
        raise ValueError("the clip is too short to score: it needs at least two frames at the prior's rate")
    nll = prior.nll(x[1:], context=x[:1]).double().numpy()
    per = np.concatenate([[nll[0]], nll])
    w = min(len(per), max(1, int(round(window_seconds * prior.spec.fps))))  # a short clip is one window
    scale = motion.fps / prior.spec.fps
    sums = np.convolve(per, np.ones(w) / w, mode="valid")
    worst: list[tuple[int, int, float]] = []
    taken = np.zeros(len(sums), bool)
    for i in np.argsort(-sums):
        if len(worst) >= n_worst:
            break
        if taken[max(0, i - w + 1): i + w].any():
            continue
        taken[i] = True
        worst.append((int(round(i * scale)), min(motion.num_frames, int(round((i + w) * scale))), float(sums[i])))
    return ScoreReport(float(nll.mean()), motion.num_frames, prior.spec.fps, per, worst)


@dataclass
class CopyVerdict:
    """NLL per frame of one window of a motion (``start``, ``frames`` at the prior's rate)
    and of each of its degraded copies (``motionopt.copies``)."""

    start: int
    frames: int
    real: float
    copies: dict[str, float]


@torch.no_grad()
def copy_verdicts(prior, motion: Motion, window_seconds: float | None = 4.0, stride_seconds: float | None = None
                  ) -> list[CopyVerdict]:
    """The prior's NLL per frame of each ``window_seconds`` window of ``motion`` (every
    ``stride_seconds``, default the window; None: the whole clip as one window) against
    its degraded copies. Heights of every copy are measured from the motion's ground."""
    codec = Codec.of(prior)
    model = checked_model_motion(prior, motion)
    ground = estimate_ground(model.positions(), prior.spec.contact_indices())
    n = model.num_frames if window_seconds is None else int(round(window_seconds * prior.spec.fps))
    step = n if stride_seconds is None else int(round(stride_seconds * prior.spec.fps))
    starts = list(range(0, model.num_frames - n + 1, step))
    if not starts or n < 3:
        raise ValueError(f"the clip is too short for {window_seconds} s windows at the prior's rate")

    def nll(m: Motion) -> float:
        x = codec.features(m, ground)
        return float(prior.nll(x[1:], context=x[:1]).mean())

    out = []
    for s, copies in zip(starts, window_copies(model, starts, n)):
        out.append(CopyVerdict(s, n, nll(model[s:s + n]), {k: nll(v) for k, v in copies.items() if len(v) >= 3}))
    return out
