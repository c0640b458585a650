"""Training data for priors: a folder of BVH files turned into normalised feature clips.

Clips are split into training and validation by clip, never by frame.
"""
from __future__ import annotations

import fnmatch
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch
from torch import Tensor

from . import bvh
from .features import FeatureSpec, default_spec, encode, to_model_motion
from .skeleton import Skeleton

log = logging.getLogger(__name__)

#: Smallest per-dimension std of a normaliser; a dimension at this floor never moves in
#: training (CMU's collar and buttock joints, one axis of a hinge) and priors leave it out.
STATIC_STD = 1e-3


@dataclass(frozen=True)
class Normalizer:
    """Per-dimension mean and std of features; contact labels are left as 0/1."""

    mean: Tensor
    std: Tensor

    def normalize(self, x: Tensor) -> Tensor:
        return (x - self.mean.to(x)) / self.std.to(x)

    def denormalize(self, x: Tensor) -> Tensor:
        return x * self.std.to(x) + self.mean.to(x)

    def moving(self) -> Tensor:
        """True for the dimensions that vary in the training data (std above the floor)."""
        return self.std > STATIC_STD * (1 + 1e-4)

    @classmethod
    def fit(cls, clips: list[Tensor], spec: FeatureSpec) -> "Normalizer":
        allx = torch.cat(clips)
        mean = allx.mean(0)
        std = allx.std(0).clamp_min(STATIC_STD)
        c = spec.slices()["contacts"]
        mean[c], std[c] = 0.0, 1.0
        return cls(mean, std)


@dataclass
class MotionDataset:
    """Feature clips (unnormalised, float64) of one skeleton, split by clip."""

    spec: FeatureSpec
    skeleton: Skeleton
    train: dict[str, Tensor]
    val: dict[str, Tensor]
    source: str = ""
    seconds_to_build: float = 0.0
    normalizer: Normalizer = field(init=False)

    def __post_init__(self) -> None:
        if not self.train:
            raise ValueError("no training clips: every clip was held out for validation")
        self.normalizer = Normalizer.fit(list(self.train.values()), self.spec)

    @property
    def num_train_frames(self) -> int:
        return sum(len(x) for x in self.train.values())

    def windows(self, split: str, length: int, stride: int) -> Tensor:
        """Overlapping normalised windows (N, length, D) cut from every clip of a split."""
        return self.padded_windows(split, length, stride, min_length=length)[0]

    def padded_windows(self, split: str, length: int, stride: int, min_length: int = 8) -> tuple[Tensor, Tensor]:
        """Like ``windows``, plus every clip shorter than ``length`` (but at least
        ``min_length`` frames) as one window padded with its last frame, so that short
        clips (Bandai's dashes and backward walks) are trained on too. Returns the windows
        (N, length, D) and a mask (N, length) that is False on padding."""
        clips = self.train if split == "train" else self.val
        xs, valid = [], []
        for x in clips.values():
            if len(x) >= length:
                w = x.unfold(0, length, stride).permute(0, 2, 1)
                xs.append(w)
                valid.append(torch.ones(len(w), length, dtype=torch.bool))
            elif len(x) >= min_length:
                pad = x[-1:].expand(length - len(x), -1)
                xs.append(torch.cat((x, pad))[None])
                valid.append((torch.arange(length) < len(x))[None])
        if not xs:
            raise ValueError(f"no {split} clip is at least {min_length} frames long")
        return self.normalizer.normalize(torch.cat(xs)).float(), torch.cat(valid)


def find_bvh(folder: str | Path) -> list[Path]:
    files = sorted(Path(folder).rglob("*.bvh"))
    if not files:
        raise FileNotFoundError(f"no .bvh files under {folder}")
    return files


def default_validation(files: list[Path], root: Path, every: int = 10) -> list[str]:
    """Clips held out when none are named: the last clip of each sub-folder, or every
    ``every``-th clip of a flat folder (deterministic, by sorted name)."""
    names = [str(f.relative_to(root)) for f in files]
    folders = sorted({str(Path(n).parent) for n in names})
    if folders != ["."]:
        return [max(n for n in names if str(Path(n).parent) == d) for d in folders]
    return names[every - 1::every]


#: Suffix of the name of a training clip's mirror image (``build_dataset(mirror=True)``).
MIRRORED = " (mirrored)"
#: Largest rest-offset asymmetry (m) of a skeleton whose clips may be mirrored: CMU's is 5 mm.
MIRROR_TOLERANCE = 0.01


def build_dataset(folder: str | Path, spec: FeatureSpec | None = None, fps: float = 30.0,
                  val: list[str] | None = None, unit: str = "auto",
                  fps_overrides: dict[str, float] | None = None,
                  include: list[str] | None = None, mirror: bool = False) -> MotionDataset:
    """Load every BVH under ``folder``, convert to the spec's joints and frame rate, encode.

    Args:
        spec: what to model; default ``default_spec`` of the first file's skeleton.
        val: clip names (relative paths, shell patterns allowed) to hold out.
        fps_overrides: frame rates for clips whose header is wrong, by relative-path pattern.
        include: only clips whose relative path matches one of these patterns.
        mirror: also train on each training clip's left/right mirror image (named with
            ``MIRRORED``), twice the data for a small dataset; held-out clips are not
            mirrored. The skeleton must be symmetric (``Skeleton.mirror_asymmetry``).
    """
    t0 = time.perf_counter()
    root = Path(folder)
    files = find_bvh(root)
    if include:
        files = [f for f in files if any(fnmatch.fnmatch(str(f.relative_to(root)), p) for p in include)]
        if not files:
            raise FileNotFoundError(f"no .bvh file under {folder} matches {include}")
    val_patterns = val if val is not None else default_validation(files, root)
    train: dict[str, Tensor] = {}
    held: dict[str, Tensor] = {}
    skeleton = None
    for f in files:
        name = str(f.relative_to(root))
        fps_override = next((v for p, v in (fps_overrides or {}).items() if fnmatch.fnmatch(name, p)), None)
        motion = bvh.load(f, unit=unit, fps=fps_override)
        if spec is None:
            spec = default_spec(motion.skeleton, fps=fps)
        try:
            model = to_model_motion(motion, spec)
        except ValueError as e:
            raise ValueError(f"{f}: {e}") from None
        if skeleton is None:
            skeleton = model.skeleton
            asymmetry = skeleton.mirror_asymmetry() if mirror else 0.0
            if asymmetry > MIRROR_TOLERANCE:
                raise ValueError(f"{f}: cannot mirror this skeleton's clips: the rest offsets of left and right "
                                 f"joints differ by up to {100 * asymmetry:.0f} cm (its joints' "
                                 "local axes are not the body's); train without --mirror")
        if len(model) < 2:
            log.warning("%s: skipped, shorter than two frames at %g fps", f, spec.fps)
            continue
        x, _ = encode(model, spec)
        if any(fnmatch.fnmatch(name, p) for p in val_patterns):
            held[name] = x
            continue
        train[name] = x
        if mirror:
            train[name + MIRRORED] = encode(model.mirror(), spec)[0]
    assert spec is not None and skeleton is not None
    return MotionDataset(spec, skeleton, train, held, source=str(root), seconds_to_build=time.perf_counter() - t0)
