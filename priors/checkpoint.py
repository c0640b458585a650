"""Checkpoint files for priors: weights plus everything needed to use them correctly.

A checkpoint carries the feature definition and version, the skeleton, normalisation
statistics, frame rate, architecture, training command, data provenance and licence.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import torch

from motionopt.dataset import Normalizer
from motionopt.features import FEATURE_VERSION, FeatureSpec
from motionopt.skeleton import Skeleton

CHECKPOINT_DIR = Path(__file__).parent / "checkpoints"
#: Shipped checkpoints in order of preference when a skeleton matches several.
SHIPPED = ("cmu-ccnet.pt", "bandai-locomotion-ccnet.pt")
#: Shipped latent (W+) priors, in the same order of preference.
SHIPPED_LATENT = ("cmu-latent.pt", "bandai-latent.pt")


class CheckpointError(ValueError):
    """A checkpoint that cannot be used: missing, wrong version, wrong skeleton."""


def skeleton_to_dict(sk: Skeleton) -> dict:
    return {"names": list(sk.names), "parents": sk.parents.tolist(), "offsets": sk.offsets.tolist(),
            "channels": [list(c) for c in sk.channels]}


def skeleton_from_dict(d: dict) -> Skeleton:
    return Skeleton(tuple(d["names"]), np.array(d["parents"]), np.array(d["offsets"]),
                    tuple(tuple(c) for c in d["channels"]))


def atomic_torch_save(obj: object, path: Path) -> None:
    """torch.save through a temporary file and a rename, so a stop leaves no half file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        torch.save(obj, tmp)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def save_prior(prior, path: str | Path, extra: dict | None = None, dtype: torch.dtype = torch.float32) -> None:
    """Write a prior's weights and metadata. ``dtype`` float16 halves the file (the latent
    priors ship so: joint positions of generated windows move 0.4 mm on average, 5 mm
    at most, against float32 weights); loading always gives float32."""
    state = {k: v.detach().to(dtype).clone() if v.is_floating_point() else v.clone()
             for k, v in prior.state_dict().items()}
    atomic_torch_save({
        "kind": type(prior).__name__,
        "config": prior.config.to_dict(),
        "spec": prior.spec.to_dict(),
        "skeleton": skeleton_to_dict(prior.skeleton),
        "normalizer": {"mean": prior.normalizer.mean.float(), "std": prior.normalizer.std.float()},
        "metadata": prior.metadata,
        "state_dict": state,
        **(extra or {}),
    }, Path(path))


def read_checkpoint(path: str | Path) -> dict:
    path = Path(path)
    if not path.exists():
        raise CheckpointError(f"checkpoint {path} does not exist")
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - any unreadable file gets the same clear message
        raise CheckpointError(f"{path} is not a motionopt checkpoint ({type(e).__name__}: {e})") from None
    if not isinstance(data, dict) or "spec" not in data or "state_dict" not in data:
        raise CheckpointError(f"{path} is not a motionopt prior checkpoint")
    version = data["spec"].get("version")
    if version != FEATURE_VERSION:
        raise CheckpointError(f"{path} uses feature version {version}; this motionopt reads version "
                              f"{FEATURE_VERSION}. Retrain the prior with `motionopt train-prior`.")
    return data


def load_prior(path: str | Path):
    """Load a prior checkpoint, ready for evaluation (eval mode, float32)."""
    from .ccnet import CCNetConfig, CCNetPrior
    from .latent import LatentConfig, LatentPrior

    data = read_checkpoint(path)
    kinds = {"CCNetPrior": (CCNetPrior, CCNetConfig), "LatentPrior": (LatentPrior, LatentConfig)}
    if data["kind"] not in kinds:
        raise CheckpointError(f"{path}: unknown prior kind {data['kind']!r}")
    cls, cfg = kinds[data["kind"]]
    spec = FeatureSpec.from_dict(data["spec"])
    norm = Normalizer(data["normalizer"]["mean"].double(), data["normalizer"]["std"].double())
    prior = cls(spec, norm, skeleton_from_dict(data["skeleton"]), cfg.from_dict(data["config"]), data["metadata"])
    prior.load_state_dict(data["state_dict"])
    prior.eval()
    for p in prior.parameters():
        p.requires_grad_(False)
    return prior


def shipped_checkpoints(names: tuple[str, ...] = SHIPPED) -> list[Path]:
    return [CHECKPOINT_DIR / n for n in names if (CHECKPOINT_DIR / n).exists()]


def check_compatible(spec: FeatureSpec, skeleton: Skeleton, path: str | Path = "the prior") -> None:
    """Raise a clear error unless the motion skeleton has every joint the prior models."""
    missing = [n for n in spec.joints if n not in skeleton.names]
    if missing:
        raise CheckpointError(
            f"{path} models a skeleton with joints {', '.join(spec.joints[:4])}, ...; the motion lacks "
            f"{', '.join(missing[:6])}{' ...' if len(missing) > 6 else ''}. Use a prior trained on this "
            "skeleton (`motionopt train-prior --data YOUR_BVH_FOLDER`).")


def find_prior_for(skeleton: Skeleton, names: tuple[str, ...] = SHIPPED,
                   train_command: str = "train-prior") -> Path:
    """The first shipped checkpoint (of ``names``) whose modelled joints the skeleton has."""
    for path in shipped_checkpoints(names):
        spec = FeatureSpec.from_dict(read_checkpoint(path)["spec"])
        if all(n in skeleton.names for n in spec.joints):
            return path
    raise CheckpointError(
        f"no shipped prior models this skeleton (root {skeleton.names[0]!r}, {skeleton.num_joints} joints); "
        f"train one with `motionopt {train_command} --data YOUR_BVH_FOLDER --out my-prior.pt` and pass --prior")
