"""Semantic directions in the latent prior's W space (MoDi section 4.1, appendix C.2).

A direction is the unit normal of a linear classifier in W:
- for computed attributes (``motionopt.attributes``): sample w from the mapping network,
  generate, score each motion, label it by whether its score is above the median, fit
  a logistic regression on w;
- for style labels (Bandai file names) the same, with a style's score the probability
  that ``priors.style.StyleClassifier`` (fitted on windows of the labelled training clips)
  gives it. (Fitting on encoder codes of the labelled clips instead gave directions whose
  edits the style could not be read back from: the encoder maps far from W's samples.)

An edit adds ``strength * scale * direction`` to the direction's layers of a W+ code,
where ``scale`` is the standard deviation of sampled w along the direction: strength is
in standard deviations of W. The layers of a computed attribute are the run of layers
whose edit moves the other attributes least for how far it moves its own, chosen on
sampled motions apart from those the direction was fitted on (as StyleGAN edits are
restricted to the layers that carry a property): the Bandai prior's root speed is edited
on layers 1-2, because editing layer 0 too moves the arm lift with it. Styles, which
are about the whole motion, edit every layer.
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
    """A unit direction in W, its scale (std of W along it) and the classifier's accuracy
    on held-out samples."""

    name: str
    direction: list[float]
    scale: float
    accuracy: float
    source: str
    #: W+ layers an edit moves; None for every layer.
    layers: list[int] | None = None

    def vector(self) -> Tensor:
        return torch.tensor(self.direction, dtype=torch.float32)

    def offset(self, num_ws: int) -> Tensor:
        """Unit edit of a W+ code (num_ws, w_dim): the direction on its layers, zero elsewhere."""
        mask = torch.zeros(num_ws, 1)
        mask[list(range(num_ws)) if self.layers is None else self.layers] = 1.0
        return mask * self.vector()

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
def fit_attribute_directions(prior: LatentPrior, n: int = 2000, seed: int = 0,
                             styles: StyleClassifier | None = None) -> dict[str, Direction]:
    """Directions of the computed attributes, and of the styles of ``styles`` (scored by
    the classifier's probability), from ``n`` sampled motions."""
    g = torch.Generator().manual_seed(seed)
    w = prior.sample_w(n, g)
    scorer = AttributeScorer(prior)
    scores: dict[str, list[Tensor]] = {k: [] for k in A.ATTRIBUTES}
    for i in range(0, n, 256):
        x = prior.generate(prior.broadcast(w[i:i + 256]))
        s = scorer(x)
        if styles is not None:
            p = styles.probabilities(x)
            s.update({f"style:{name}": p[:, j] for j, name in enumerate(styles.styles)})
        for k, v in s.items():
            scores.setdefault(k, []).append(v)
    wn = w.double().numpy()
    out = {}
    for k, v in scores.items():
        sc = torch.cat(v).numpy()
        what = "probability of the style classifier" if k.startswith("style:") else "score"
        d = _fit(k, wn, (sc > np.median(sc)).astype(int), f"{n} sampled motions, above/below median {what}", wn,
                 seed)
        if d is not None:
            out[k] = d
    probe = prior.broadcast(prior.sample_w(LAYER_PROBE_SAMPLES, torch.Generator().manual_seed(seed + 1)))
    for k in A.ATTRIBUTES:
        if k in out:
            out[k].layers = choose_layers(prior, out[k], probe, scorer)
    return out


#: Sampled motions the layers of a direction are chosen on, and the strength they are edited by.
LAYER_PROBE_SAMPLES = 256
LAYER_PROBE_STRENGTH = 2.0
#: A run of layers must move its attribute at least this share of what editing every layer does.
LAYER_MIN_SHARE = 0.5


@torch.no_grad()
def choose_layers(prior: LatentPrior, d: Direction, wplus: Tensor, scorer: AttributeScorer) -> list[int]:
    """The run of W+ layers a..b whose edit of ``wplus`` by +-``LAYER_PROBE_STRENGTH``
    moves the other attributes least relative to ``d``'s own (changes of the mean score in
    standard deviations of the unedited scores), among the runs that move it at least
    ``LAYER_MIN_SHARE`` as far as editing every layer does."""
    base = scorer(prior.generate(wplus))
    std = {k: v.std().clamp_min(1e-12) for k, v in base.items()}
    L = prior.num_ws

    def moves(layers: list[int]) -> tuple[float, float]:
        edit = replace(d, layers=layers).offset(L) * d.scale
        own, ratio = [], 0.0
        for s in (-LAYER_PROBE_STRENGTH, LAYER_PROBE_STRENGTH):
            sc = scorer(prior.generate(wplus + s * edit))
            shift = {k: float((sc[k].mean() - base[k].mean()).abs() / std[k]) for k in sc}
            own.append(shift[d.name])
            ratio = max(ratio, max(v for k, v in shift.items() if k != d.name) / max(shift[d.name], 1e-9))
        return min(own), ratio

    runs = {(a, b): moves(list(range(a, b + 1))) for a in range(L) for b in range(a, L)}
    every = runs[0, L - 1][0]
    a, b = min((run for run, (own, _) in runs.items() if own >= LAYER_MIN_SHARE * every), key=lambda r: runs[r][1])
    return list(range(a, b + 1))


def directions_of(prior: LatentPrior) -> dict[str, Direction]:
    """Directions stored in the checkpoint's metadata (``attribute_directions``)."""
    return {k: Direction(**v) for k, v in prior.metadata.get("attribute_directions", {}).items()}


def edit_codes(wplus: Tensor, d: Direction, strength: float) -> Tensor:
    """W+ codes moved by ``strength`` standard deviations along a direction, on its layers."""
    return wplus + strength * d.scale * d.offset(wplus.shape[-2]).to(wplus)
