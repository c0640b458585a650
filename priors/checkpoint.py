"""Checkpoint files for priors: weights plus everything needed to use them correctly.

A checkpoint carries the feature definition and version, the skeleton, normalisation
statistics, frame rate, architecture, training command, data provenance and licence.
"""
from __future__ import annotations

import functools
import pickle
import re
import warnings
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import torch

from motionopt.atomic import atomic_file
from motionopt.dataset import Normalizer
from motionopt.features import FEATURE_VERSION, FeatureSpec, missing_joints
from motionopt.skeleton import Skeleton

CHECKPOINT_DIR = Path(__file__).parent / "checkpoints"
#: Shipped checkpoints in order of preference when a skeleton matches several.
SHIPPED = ("cmu-ccnet.pt", "bandai-locomotion-ccnet.pt")
#: Shipped latent (W+) priors, in the same order of preference.
SHIPPED_LATENT = ("cmu-latent.pt", "bandai-latent.pt")


@dataclass(frozen=True)
class PriorKind:
    """A kind of prior as users meet it: its name, its shipped checkpoints (in order of
    preference) and the command that trains one."""

    name: str
    shipped: tuple[str, ...]
    train_command: str


#: The kinds of prior by the ``kind`` their checkpoints record (the class that loads them).
KINDS = {"CCNetPrior": PriorKind("autoregressive", SHIPPED, "train-prior"),
         "LatentPrior": PriorKind("latent (W+)", SHIPPED_LATENT, "train-latent")}


class CheckpointError(ValueError):
    """A checkpoint that cannot be used: missing, wrong version, wrong skeleton, wrong kind."""


def resolve_checkpoint(path: str | Path) -> Path:
    """The checkpoint a user names: the file ``path`` when it exists, else the shipped
    checkpoint of that name (``cmu-ccnet.pt`` or ``cmu-ccnet``), else a CheckpointError
    that lists the shipped ones."""
    path = Path(path)
    if path.exists():
        return path
    for name in (path.name, path.name + ".pt"):
        if path.parent == Path(".") and (CHECKPOINT_DIR / name).is_file():
            return CHECKPOINT_DIR / name
    names = ", ".join(p.name for p in shipped_checkpoints(SHIPPED + SHIPPED_LATENT))
    raise CheckpointError(f"checkpoint {path} does not exist; name a file, or a shipped checkpoint: {names} "
                          "(`motionopt prior-info --list` describes them)")


def skeleton_to_dict(sk: Skeleton) -> dict:
    return {"names": list(sk.names), "parents": sk.parents.tolist(), "offsets": sk.offsets.tolist(),
            "channels": [list(c) for c in sk.channels]}


def skeleton_from_dict(d: dict) -> Skeleton:
    return Skeleton(tuple(d["names"]), np.array(d["parents"]), np.array(d["offsets"]),
                    tuple(tuple(c) for c in d["channels"]))


def atomic_torch_save(obj: object, path: Path) -> None:
    """torch.save through a temporary file and a rename, so a stop leaves no half file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_file(path, "wb") as f:
        torch.save(obj, f)


def save_prior(prior, path: str | Path, extra: dict | None = None, dtype: torch.dtype = torch.float32) -> None:
    """Write a prior's weights and metadata. ``dtype`` float16 halves the file (the latent
    priors ship so: joint positions of generated windows move 0.4 mm on average, 5 mm
    at most, against float32 weights); loading always gives float32."""
    state = {k: v.detach().to("cpu", dtype).clone() if v.is_floating_point() else v.cpu().clone()
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
    """The sections of a prior checkpoint, loaded without running any code from the file
    (``weights_only``: tensors and plain data only) and checked before anything uses them,
    so a damaged, foreign or hostile file fails with a one-line ``CheckpointError``."""
    path = Path(path)
    if not path.exists():
        raise CheckpointError(f"checkpoint {path} does not exist")
    data = load_plain(path)
    _check_sections(data, path)
    return data


def load_plain(path: Path) -> object:
    """``torch.load`` of tensors and plain data only; what it refuses or cannot read, as a CheckpointError."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # torch warns about the pickle protocol of files it did not write
            return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as e:
        text = str(e)
        if "Weights only load failed" in text and "Unsupported operand" not in text:
            named = re.search(r"GLOBAL ([\w.]+)", text)
            raise CheckpointError(
                f"{path} is refused: it holds Python objects other than tensors and plain data"
                f"{f' ({named.group(1)})' if named else ''}, which could run code when loaded; only load "
                "checkpoints you trust (motionopt writes tensors and plain data only)") from None
        raise CheckpointError(f"{path} is not a motionopt checkpoint: not a file torch.save writes "
                              f"({_first_sentence(text)})") from None
    except Exception as e:  # noqa: BLE001 - any unreadable file gets the same clear message
        detail = _first_sentence(str(e))
        raise CheckpointError(f"{path} is not a motionopt checkpoint, or is damaged (cut short?): "
                              f"{type(e).__name__}{': ' + detail if detail else ''}") from None


def _first_sentence(text: str) -> str:
    """The informative part of a library's (often multi-line) error message, for one line."""
    lines = [s.strip() for s in text.splitlines() if s.strip() and "Weights only load failed" not in s
             and "WeightsUnpickler" not in s and "Check the documentation" not in s]
    first = (lines[0] if lines else text.strip()).split(". ")[0]
    return first if len(first) <= 160 else first[:157] + "..."


#: The sections ``save_prior`` writes and their types (a checkpoint may hold more).
SECTIONS = {"kind": str, "config": dict, "spec": dict, "skeleton": dict, "normalizer": dict, "metadata": dict,
            "state_dict": dict}
#: Largest whole number a prior's config may hold: a size or a dilation (the shipped ones stay under 300),
#: bounded so that a hostile config cannot ask for padding or layers that exhaust memory.
MAX_CONFIG_INT = 2**14


def _check_sections(data: object, path: Path) -> None:
    """Raise a CheckpointError naming the first section of ``data`` that is not what
    ``save_prior`` writes: missing, of another type, or inconsistent with the spec."""
    if not isinstance(data, dict):
        raise CheckpointError(f"{path} is not a motionopt prior checkpoint: it holds a {type(data).__name__}, "
                              "not a dict of sections")
    missing = [k for k in SECTIONS if k not in data]
    if missing:
        raise CheckpointError(f"{path} is not a motionopt prior checkpoint: it lacks {', '.join(missing)}")
    for key, kind in SECTIONS.items():
        _need(isinstance(data[key], kind), path, f"its {key} must be a {kind.__name__}, got {type(data[key]).__name__}")
    version = data["spec"].get("version")
    if version != FEATURE_VERSION:
        raise CheckpointError(f"{path} uses feature version {shown(version)}; this motionopt reads version "
                              f"{FEATURE_VERSION}. Retrain the prior with `motionopt train-prior`.")
    spec = _check_spec(data["spec"], path)
    _check_skeleton(data["skeleton"], spec, path)
    _check_normalizer(data["normalizer"], spec.dim, path)
    _need(all(isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in data["state_dict"].items()), path,
          "its state_dict must map parameter names to tensors")
    _need(all(isinstance(k, str) and _config_value(v) for k, v in data["config"].items()), path,
          f"its config must map names to numbers, strings or lists of them, whole numbers within 0 to "
          f"{MAX_CONFIG_INT} (sizes and dilations)")
    history = data["metadata"].get("history", [])
    _need(isinstance(history, list) and all(isinstance(r, dict) for r in history), path,
          "its metadata history must be a list of records")


def _config_value(value: object, nested: bool = True) -> bool:
    """A number (whole numbers within 0 to ``MAX_CONFIG_INT``), bool, string or None, or a
    list of them; with ``nested``, also a config of such values (a pooled prior's anchor)."""
    if nested and isinstance(value, dict):
        return all(isinstance(k, str) and _config_value(v, nested=False) for k, v in value.items())
    items = value if isinstance(value, (list, tuple)) else [value]
    return all(v is None or isinstance(v, (bool, str))
               or (_number(v) and (isinstance(v, float) or 0 <= v <= MAX_CONFIG_INT)) for v in items)


def _need(ok: bool, path: Path, what: str) -> None:
    if not ok:
        raise CheckpointError(f"{path} is not a usable prior checkpoint: {what}")


def shown(value: object, width: int = 40) -> str:
    """``repr`` of a value read from a file, for an error message: cut to ``width`` characters."""
    text = repr(value)
    return text if len(text) <= width else text[:width - 3] + "..."


def _number(value: object) -> bool:
    """A finite int or float (not a bool)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and abs(value) < float("inf")


def _names(value: object) -> bool:
    return isinstance(value, (list, tuple)) and all(isinstance(n, str) for n in value)


def _check_spec(d: dict, path: Path) -> FeatureSpec:
    """The spec of a checkpoint, its entries checked."""
    unknown = [k for k in d if k not in {f.name for f in fields(FeatureSpec)}]
    _need(not unknown, path, f"its spec has unknown entries {shown(unknown)}")
    for key in ("joints", "contact_joints"):
        _need(_names(d.get(key)), path, f"its spec's {key} must be a list of joint names, got {shown(d.get(key))}")
    joints = d["joints"]
    _need(len(joints) > 0 and len(set(joints)) == len(joints), path, "its spec's joints must be distinct names")
    _need(set(d["contact_joints"]) <= set(joints), path, "its spec's contact joints must be among its joints")
    for key in ("fps", "contact_height", "contact_speed"):
        _need(_number(d.get(key, 1.0)) and d.get(key, 1.0) > 0, path,
              f"its spec's {key} must be a positive number, got {shown(d.get(key))}")
    return FeatureSpec.from_dict(d)


def _check_skeleton(d: dict, spec: FeatureSpec, path: Path) -> None:
    """The skeleton section: lists of the right types that make a valid Skeleton with the spec's joints."""
    _need(_names(d.get("names")), path, "its skeleton's names must be a list of joint names")
    parents, offsets, channels = d.get("parents"), d.get("offsets"), d.get("channels")
    _need(isinstance(parents, list) and all(isinstance(p, int) and not isinstance(p, bool) for p in parents), path,
          "its skeleton's parents must be a list of joint indices")
    _need(isinstance(offsets, list) and all(isinstance(o, list) and len(o) == 3 and all(map(_number, o))
                                            for o in offsets), path,
          "its skeleton's offsets must be a list of [x, y, z] numbers")
    _need(isinstance(channels, list) and all(_names(c) for c in channels), path,
          "its skeleton's channels must be a list of channel-name lists")
    try:
        skeleton = skeleton_from_dict(d)
    except ValueError as e:
        raise CheckpointError(f"{path} is not a usable prior checkpoint: its skeleton is invalid ({e})") from None
    missing = missing_joints(spec, skeleton)
    _need(not missing, path, f"its skeleton lacks the modelled joints {shown(missing)}")


def _check_normalizer(d: dict, dim: int, path: Path) -> None:
    """Mean and std: finite float tensors of the spec's feature size, std positive."""
    for key in ("mean", "std"):
        v = d.get(key)
        shape = tuple(v.shape) if isinstance(v, torch.Tensor) else type(v).__name__
        _need(isinstance(v, torch.Tensor) and v.is_floating_point() and tuple(v.shape) == (dim,), path,
              f"its normalizer {key} must be {dim} floats (the spec's feature size), got {shape}")
        _need(bool(torch.isfinite(v).all()), path, f"its normalizer {key} holds NaN or infinite values")
    _need(bool((d["std"] > 0).all()), path, "its normalizer std must be positive")


def load_prior(path: str | Path):
    """Load a prior checkpoint, ready for evaluation (eval mode, float32)."""
    from .ccnet import CCNetConfig, CCNetPrior
    from .latent import LatentConfig, LatentPrior

    data = read_checkpoint(path)
    kinds = {"CCNetPrior": (CCNetPrior, CCNetConfig), "LatentPrior": (LatentPrior, LatentConfig)}
    if data["kind"] not in kinds:
        raise CheckpointError(f"{path}: unknown prior kind {shown(data['kind'])}")
    cls, cfg = kinds[data["kind"]]
    parts = (FeatureSpec.from_dict(data["spec"]),
             Normalizer(data["normalizer"]["mean"].double(), data["normalizer"]["std"].double()),
             skeleton_from_dict(data["skeleton"]))
    try:
        config = cfg.from_dict(data["config"])
        with torch.device("meta"):  # shapes only: a hostile config cannot make it allocate
            shell = cls(*parts, config, data["metadata"])
    except (TypeError, ValueError, KeyError, RuntimeError) as e:
        raise CheckpointError(f"{path}: its config does not describe a {data['kind']} "
                              f"({type(e).__name__}: {_first_sentence(str(e))})") from None
    _check_shapes(shell.state_dict(), data["state_dict"], path)
    prior = cls(*parts, config, data["metadata"])
    prior.load_state_dict(data["state_dict"])
    return for_evaluation(prior)


def for_evaluation(prior: torch.nn.Module) -> torch.nn.Module:
    """``prior`` in eval mode with its weights frozen, as loaded priors are used."""
    prior.eval()
    for p in prior.parameters():
        p.requires_grad_(False)
    return prior


def _check_shapes(want: dict, got: dict, path: Path) -> None:
    """The stored weights are exactly those the config builds, shape for shape."""
    for key in sorted(want.keys() | got.keys()):
        a = tuple(want[key].shape) if key in want else None
        b = tuple(got[key].shape) if key in got else None
        if a != b:
            raise CheckpointError(f"{path}: its weights do not fit its config: {key} is "
                                  f"{'missing' if b is None else b}, the config makes "
                                  f"{'no such weight' if a is None else a}")


def load_prior_cached(path: str | Path):
    """``load_prior``, read once per process for each version of a file (its resolved path,
    size and modification time), so that looking a prior up and then using it loads it once.
    The prior is shared: treat it as read-only."""
    path = Path(path)
    if not path.exists():
        raise CheckpointError(f"checkpoint {path} does not exist")
    st = path.stat()
    return _load_prior_once(str(path.resolve()), st.st_size, st.st_mtime_ns)


@functools.lru_cache(maxsize=8)
def _load_prior_once(path: str, size: int, mtime_ns: int):
    """``load_prior`` of ``path``; size and time only key the cache, so a changed file is read again."""
    return load_prior(path)


def shipped_checkpoints(names: tuple[str, ...] = SHIPPED) -> list[Path]:
    """The paths of the shipped checkpoints ``names`` that are present."""
    return [CHECKPOINT_DIR / n for n in names if (CHECKPOINT_DIR / n).exists()]


def check_compatible(spec: FeatureSpec, skeleton: Skeleton, path: str | Path = "the prior",
                     kind: str = "CCNetPrior") -> None:
    """Raise a clear error unless the motion skeleton has every joint the prior models,
    naming the shipped checkpoint of ``kind`` (a key of ``KINDS``) that models it, if one
    does, or else the command that trains one."""
    missing = missing_joints(spec, skeleton)
    if missing:
        raise CheckpointError(
            f"{path} models a skeleton with joints {', '.join(spec.joints[:4])}, ...; the motion lacks "
            f"{', '.join(missing[:6])}{' ...' if len(missing) > 6 else ''}. {_fitting_prior(skeleton, kind)}")


def _fitting_prior(skeleton: Skeleton, kind: str) -> str:
    """What to use instead for ``skeleton``: a shipped prior of ``kind`` that models it, or
    training one (a kind without shipped checkpoints, as the latent prior's density wrapper: training)."""
    want = KINDS.get(kind)
    if want is None:
        return "Use a prior trained on this skeleton."
    try:
        fit = find_prior_for(skeleton, want.shipped, want.train_command)
    except CheckpointError:
        return f"Use a prior trained on this skeleton (`motionopt {want.train_command} --data YOUR_BVH_FOLDER`)."
    return f"The shipped {fit.name} models this skeleton: pass --prior {fit.stem}, or leave --prior out."


def load_prior_of_kind(skeleton: Skeleton, path: str | Path | None, kind: str, needed_by: str,
                       otherwise: str = ""):
    """The prior a command uses, and its path: the checkpoint ``path`` names (a file or a
    shipped checkpoint's name), or the first shipped one of ``kind`` (a key of ``KINDS``)
    whose modelled joints the skeleton has. A checkpoint of another kind is refused with a
    message saying what ``needed_by`` (the command, for the message) needs, which
    checkpoints are of that kind and, when given, ``otherwise`` (how to use the one given);
    a skeleton the prior does not model, by ``check_compatible``."""
    want = KINDS[kind]
    path = resolve_checkpoint(path) if path else find_prior_for(skeleton, want.shipped, want.train_command)
    prior = load_prior_cached(path)
    got = type(prior).__name__
    if got != kind:
        raise CheckpointError(f"{path} is {_a(KINDS[got].name)} prior; {needed_by} needs {_a(want.name)} prior: "
                              f"a shipped one ({', '.join(want.shipped)}) or one trained with "
                              f"`motionopt {want.train_command}`{'; ' + otherwise if otherwise else ''}")
    check_compatible(prior.spec, skeleton, path, kind)
    return prior, Path(path)


def _a(word: str) -> str:
    """``word`` with its indefinite article."""
    return f"{'an' if word[0] in 'aeiou' else 'a'} {word}"


def find_prior_for(skeleton: Skeleton, names: tuple[str, ...] = SHIPPED,
                   train_command: str = "train-prior") -> Path:
    """The first shipped checkpoint (of ``names``) whose modelled joints the skeleton has."""
    for path in shipped_checkpoints(names):
        if not missing_joints(load_prior_cached(path).spec, skeleton):
            return path
    raise CheckpointError(
        f"no shipped prior models this skeleton (root {skeleton.names[0]!r}, {skeleton.num_joints} joints); "
        f"train one with `motionopt {train_command} --data YOUR_BVH_FOLDER --out my-prior.pt` and pass --prior")
