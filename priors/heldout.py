"""The clips a prior was not trained on, as the prior sees them: one loader for the
benchmarks and notebooks. A checkpoint's metadata names its data folder and its
validation clips (split by clip at training time)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from torch import Tensor

from motionopt import bvh
from motionopt.codec import Codec
from motionopt.features import RootStart
from motionopt.motion import Motion

ROOT = Path(__file__).resolve().parent.parent
#: Where the shared data lives on the project's machines, beside the repository.
SHARED_DATA = ROOT.parent / "shared" / "data"


def data_folder(meta: dict) -> Path:
    """The checkpoint's data folder: as recorded, relative to the repository, or the
    folder of that name under ``../shared/data``."""
    recorded = Path(meta["data"])
    for p in (ROOT / recorded, recorded, SHARED_DATA / recorded.name):
        if p.is_dir():
            return p
    raise FileNotFoundError(f"training data {meta['data']} not found; held-out clips need ../shared/data")


@dataclass
class Clip:
    """A held-out clip on the prior's joints at its rate: model motion, normalised
    features and the root state decoding starts from."""

    name: str
    motion: Motion
    x: Tensor
    start: RootStart


def held_out_clips(prior, folder: Path | None = None, limit: int | None = None, min_seconds: float = 0.0,
                   contains: str | None = None) -> list[Clip]:
    """The prior's validation clips (the first ``limit``, those whose name has
    ``contains``, at least ``min_seconds`` long) from ``folder`` (default: the
    checkpoint's data folder)."""
    folder = data_folder(prior.metadata) if folder is None else folder
    codec = Codec.of(prior)
    names = [n for n in prior.metadata["validation_clips"] if contains is None or contains in n][:limit]
    clips = []
    for name in names:
        model = codec.model_motion(bvh.load(folder / name))
        if model.num_frames < min_seconds * prior.spec.fps:
            continue
        _, x, start = codec.encode(model)
        clips.append(Clip(name, model, x, start))
    return clips
