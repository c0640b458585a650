"""Semantic directions in the latent prior's code space (MoDi section 4.1, appendix C.2).

A direction is the unit normal of a linear classifier on codes: windows of real motion
(the training data) are encoded and scored, labelled by whether the score is above the
median, and a logistic regression is fitted on each window's mean code. For computed
attributes (``motionopt.attributes``) the score is the attribute; for style labels
(Bandai file names) it is the probability that ``priors.style.StyleClassifier``
(fitted on windows of the labelled training clips) gives the style.

An edit adds ``strength * scale * direction`` to every code of a W+ code (each code
covers a few frames of the window, so the whole window changes alike). ``scale`` is
calibrated in user terms: strength 1 moves the score by one standard deviation of the
score over the training windows (``calibrate``; e.g. the crouch depth by the spread of
crouch depths in the data), as far as the generator follows: the step is at most
``MAX_SCALE`` standard deviations of the windows' mean codes along the direction, so
that edits stay where the generator was trained.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np
import torch
from torch import Tensor

from motionopt import attributes as A
from motionopt.codec import Codec
from motionopt.features import RootStart, decode

from .latent import LatentPrior
from .style import StyleClassifier


@dataclass
class Direction:
    """A unit direction in code space (w_dim), its scale (what strength 1 adds along it,
    ``calibrate``) and the classifier's accuracy on held-out windows."""

    name: str
    direction: list[float]
    scale: float
    accuracy: float
    source: str

    def vector(self) -> Tensor:
        return torch.tensor(self.direction, dtype=torch.float32)

    def to_dict(self) -> dict:
        return asdict(self)


class AttributeScorer:
    """Scores of normalised windows (B, T, D) of one prior: gral, root speed, crouch depth."""

    def __init__(self, prior: LatentPrior):
        self.prior = prior
        sk = prior.skeleton
        self.arm = A.right_arm(sk.names, sk.parents)
        cidx = prior.spec.contact_indices()
        self.standing = A.standing_height(sk, cidx)
        self.height_dim = prior.spec.slices()["root_height"].start

    def __call__(self, x: Tensor) -> dict[str, Tensor]:
        codec = Codec.of(self.prior)
        raw = codec.raw(x.double())
        pos = codec.positions(x.double())
        return {"gral": A.gradual_right_arm_lift(pos, *self.arm),
                "root_speed": A.root_speed(pos[..., 0, :], self.prior.spec.fps),
                "crouch": A.crouch_depth(raw[..., self.height_dim], self.standing)}

    def root_path(self, x: Tensor) -> Tensor:
        """Root positions (B, T, 3) of windows decoded from the origin."""
        return decode(Codec.of(self.prior).raw(x.double()), self.prior.spec, RootStart())[1]


def _fit(name: str, w: np.ndarray, labels: np.ndarray, source: str, w_all: np.ndarray, seed: int) -> Direction | None:
    """Logistic regression on codes ``w``; None when the codes do not separate at all."""
    from sklearn.linear_model import LogisticRegression
    from sklearn.model_selection import train_test_split

    if labels.min() == labels.max() or np.bincount(labels).min() < 5:
        return None
    wtr, wte, ytr, yte = train_test_split(w, labels, test_size=0.2, random_state=seed, stratify=labels)
    clf = LogisticRegression(max_iter=2000, C=1.0, class_weight="balanced").fit(wtr, ytr)
    norm = np.linalg.norm(clf.coef_[0])
    if not norm > 0:
        return None
    n = clf.coef_[0] / norm
    scale = float((w_all @ n).std())
    return Direction(name, n.tolist(), scale, float(clf.score(wte, yte)), source)


@torch.no_grad()
def fit_attribute_directions(prior: LatentPrior, windows: Tensor | None = None, n: int = 2000, seed: int = 0,
                             styles: StyleClassifier | None = None) -> dict[str, Direction]:
    """Directions of the computed attributes, and of the styles of ``styles`` (scored by
    the classifier's probability), fitted on the codes of ``windows`` (normalised windows
    of real motion, the training data; default: ``n`` motions sampled from the prior) and
    calibrated to the spread of each score over them."""
    if windows is None:
        windows = prior.generate(prior.sample_wplus(n, torch.Generator().manual_seed(seed)))
    scorer = AttributeScorer(prior)
    codes = torch.cat([prior.encode(w) for w in windows.split(256)])
    parts = [_scores(w, scorer, styles) for w in windows.split(256)]
    scores = {k: torch.cat([p[k] for p in parts]).numpy() for k in parts[0]}
    wn = codes.mean(1).double().numpy()
    probe = codes[torch.linspace(0, len(codes) - 1, min(CALIBRATION_WINDOWS, len(codes))).long()]
    fitted = {}
    for k, sc in scores.items():
        what = "probability of the style classifier" if k.startswith("style:") else "score"
        d = _fit(k, wn, (sc > np.median(sc)).astype(int), f"{len(wn)} windows, above/below median {what}", wn, seed)
        if d is not None:
            fitted[k] = d
    if PACE in fitted:
        fitted = {k: d if k == PACE or k.startswith("style:") else without(d, fitted[PACE], wn)
                  for k, d in fitted.items()}
    return {k: calibrate(prior, d, probe, scorer, styles, float(scores[k].std())) for k, d in fitted.items()}


#: The attribute the other computed attributes' directions are made independent of.
PACE = "root_speed"


def without(d: Direction, other: Direction, w: np.ndarray) -> Direction:
    """``d`` with its component along ``other`` removed (conditional editing, as in
    InterFaceGAN): moving along it leaves ``other``'s classifier score unchanged, so a
    crouch does not also change the pace. Its scale is re-measured on the codes ``w``."""
    a, b = np.asarray(d.direction), np.asarray(other.direction)
    n = a - (a @ b) * b
    n /= max(np.linalg.norm(n), 1e-12)
    return replace(d, direction=n.tolist(), scale=float((w @ n).std()), source=d.source + f", {other.name} projected out")


def _scores(x: Tensor, scorer: AttributeScorer, styles: StyleClassifier | None) -> dict[str, Tensor]:
    """Every attribute's score of windows ``x``, and each style's probability."""
    s = scorer(x)
    if styles is not None:
        p = styles.probabilities(x)
        s.update({f"style:{name}": p[:, j] for j, name in enumerate(styles.styles)})
    return s


#: Windows the strength scale is calibrated on, and the largest scale allowed (standard
#: deviations of the windows' mean codes along the direction).
CALIBRATION_WINDOWS = 256
MAX_SCALE = 8.0


@torch.no_grad()
def calibrate(prior: LatentPrior, d: Direction, codes: Tensor, scorer: AttributeScorer,
              styles: StyleClassifier | None, score_std: float) -> Direction:
    """``d`` with its scale set so that strength 1 moves the score by ``score_std``,
    measured at strength +-1 on the windows of ``codes``; at most ``MAX_SCALE`` times the
    spread of mean codes along the direction."""

    def score(strength: float) -> float:
        return float(_scores(prior.generate(edit_codes(codes, d, strength)), scorer, styles)[d.name].mean())

    per_unit = (score(1.0) - score(-1.0)) / 2
    factor = MAX_SCALE if per_unit <= 0 else min(score_std / per_unit, MAX_SCALE)
    return replace(d, scale=d.scale * factor)


def directions_of(prior: LatentPrior) -> dict[str, Direction]:
    """Directions stored in the checkpoint's metadata (``attribute_directions``)."""
    return {k: Direction(**v) for k, v in prior.metadata.get("attribute_directions", {}).items()}


def edit_codes(wplus: Tensor, d: Direction, strength: float) -> Tensor:
    """W+ codes with every code moved by ``strength`` standard deviations along a direction."""
    return wplus + strength * d.scale * d.vector().to(wplus)
