"""A style classifier of motion windows, fitted on the style labels of Bandai clip names.

Style labels (old, tired, proud...) are known only for the training clips, not for
motions the latent prior generates. This classifier scores any window from its motion:
multinomial logistic regression on ``window_descriptors`` (per-dimension mean, standard
deviation and mean frame-to-frame change of the normalised features), fitted on windows
of the labelled training clips. A style's score is the classifier's probability of that
style. Semantic directions for styles are then fitted as those of computed attributes
are (on sampled motions labelled by their score), and edits are checked against the
score of the edited motion itself, not against a re-encoding of it.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import Tensor

from motionopt import attributes as A
from motionopt.metrics_latent import window_descriptors

#: Inverse regularisation strength of the logistic regression, chosen on the Bandai latent
#: prior's 17 held-out clips: window accuracy over 15 styles 0.64 at 0.01, 0.68 at 0.1,
#: 0.69 at 0.3, 0.68 at 1, 0.59 at 10 (chance 0.07).
STYLE_C = 0.3


@dataclass
class StyleClassifier:
    """Linear softmax classifier of styles over standardised window descriptors."""

    styles: list[str]
    mean: list[float]
    std: list[float]
    coef: list[list[float]]
    intercept: list[float]
    #: Windows it was fitted on, and its accuracy on windows of held-out clips (None: none held out).
    train_windows: int
    heldout_accuracy: float | None
    heldout_windows: int

    def probabilities(self, x: Tensor) -> Tensor:
        """Probability of each style (N, S) for normalised windows (N, T, D)."""
        return self.probabilities_of_descriptors(window_descriptors(x.double()))

    def probabilities_of_descriptors(self, d: Tensor) -> Tensor:
        """Probability of each style (N, S) for window descriptors (N, F)."""
        z = (d - torch.tensor(self.mean, dtype=d.dtype)) / torch.tensor(self.std, dtype=d.dtype)
        logits = z @ torch.tensor(self.coef, dtype=d.dtype).T + torch.tensor(self.intercept, dtype=d.dtype)
        return torch.softmax(logits, dim=-1)

    def score(self, x: Tensor, style: str) -> Tensor:
        """Probability (N,) that each window shows ``style``."""
        if style not in self.styles:
            raise ValueError(f"unknown style {style!r}; the classifier knows: {', '.join(self.styles)}")
        return self.probabilities(x)[:, self.styles.index(style)]

    def to_dict(self) -> dict:
        return asdict(self)


def style_classifier_of(metadata: dict) -> StyleClassifier | None:
    """The classifier stored in a checkpoint's metadata (``style_classifier``), if any."""
    d = metadata.get("style_classifier")
    return StyleClassifier(**d) if d else None


def labelled_windows(clips: dict[str, Tensor], window: int, stride: int) -> tuple[Tensor, list[str]]:
    """Descriptors (N, F) of windows of the clips whose names carry a style label, and their labels;
    a clip shorter than ``window`` (but of at least a quarter of it) is one window of its own
    length, so Bandai's short dashes count too."""
    descs, labels = [], []
    for name, x in clips.items():
        style = A.style_of(name)
        if style is None or len(x) < max(2, window // 4):
            continue
        win = x.unfold(0, window, stride).permute(0, 2, 1) if len(x) >= window else x[None]
        descs.append(window_descriptors(win.double()))
        labels += [style] * len(win)
    return (torch.cat(descs) if descs else torch.zeros(0)), labels


def fit_style_classifier(train: dict[str, Tensor], heldout: dict[str, Tensor], window: int, stride: int = 8,
                         min_windows: int = 20) -> StyleClassifier | None:
    """Fit on windows of the labelled clips of ``train`` (normalised features by clip
    name), styles with fewer than ``min_windows`` windows left out; score on ``heldout``.
    None when fewer than two styles are left."""
    from sklearn.linear_model import LogisticRegression

    d, labels = labelled_windows(train, window, stride)
    counts = {s: labels.count(s) for s in set(labels)}
    styles = sorted(s for s, n in counts.items() if n >= min_windows)
    if len(styles) < 2:
        return None
    keep = np.array([s in styles for s in labels])
    d = d.numpy()[keep]
    y = np.array([styles.index(s) for s, k in zip(labels, keep) if k])
    mean, std = d.mean(0), d.std(0) + 1e-6
    clf = LogisticRegression(C=STYLE_C, max_iter=5000, class_weight="balanced").fit((d - mean) / std, y)
    out = StyleClassifier(styles, mean.tolist(), std.tolist(), clf.coef_.tolist(), clf.intercept_.tolist(),
                          int(len(y)), None, 0)
    hd, hl = labelled_windows(heldout, window, stride)
    known = [i for i, s in enumerate(hl) if s in styles]
    if known:
        pred = out.probabilities_of_descriptors(hd[known]).argmax(-1)
        truth = torch.tensor([styles.index(hl[i]) for i in known])
        out.heldout_accuracy, out.heldout_windows = float((pred == truth).double().mean()), len(known)
    return out
