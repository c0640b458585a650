"""Training of the causal-convolution prior: resumable, logged, seeded, CPU-friendly."""
from __future__ import annotations

import json
import logging
import math
import platform
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Iterable

import torch
from torch import Tensor
from tqdm import tqdm

from motionopt.codec import Codec
from motionopt.dataset import MotionDataset
from motionopt.metrics import acceleration
from motionopt.naturalness import METADATA_KEY, HumanRange

from .ccnet import CCNetConfig, CCNetPrior
from .checkpoint import atomic_torch_save, load_plain, load_prior, resolve_checkpoint, save_prior
from .heldout import held_out_clips
from .temperature import calibrate

log = logging.getLogger(__name__)


@dataclass
class TrainConfig:
    """Optimisation settings; the defaults train the shipped priors on a 2-core CPU."""

    epochs: int = 40
    window: int = 96
    stride: int = 8
    batch_size: int = 32
    lr: float = 1e-3
    lr_min: float = 2e-5
    noise_std: float = 0.03
    #: Passes per batch; passes after the first predict from the model's own draws.
    passes: int = 2
    #: Clips shorter than ``window`` but at least this long are trained on, padded.
    min_clip_frames: int = 8
    smooth_weight: float = 10.0
    contact_weight: float = 2.0
    #: Weight of the ranking loss that keeps degraded copies of each window (frozen,
    #: low-passed, retimed, noisy: ``priors.degrade``) a margin above the real window's
    #: NLL; 0 trains on likelihood alone, which scores still and smoothed motion best.
    contrast_weight: float = 1.0
    #: That margin, in nats per frame and moving dimension.
    contrast_margin: float = 0.1
    #: Frames at the end of each window that a free-running pass predicts from the
    #: model's own draws (0: none; ``CCNetPrior.loss``), and the temperature of those draws.
    rollout_frames: int = 0
    rollout_temperature: float = 0.5
    #: A checkpoint whose weights (and normaliser) the run starts from: fine-tuning.
    init: str | None = None
    seed: int = 0
    max_minutes: float | None = None
    threads: int | None = None
    #: Torch device of the training ("cpu", "cuda"); checkpoints are always written for the CPU.
    device: str = "cpu"
    #: Seconds of the rollouts the sampling temperature is calibrated on after training
    #: (``priors.temperature``; about 1.5 min for the shipped CMU prior on one core).
    calibration_seconds: float = 30.0
    model: CCNetConfig = field(default_factory=CCNetConfig)


def state_path(out: Path) -> Path:
    return out.with_suffix(".train-state.pt")


def log_path(out: Path) -> Path:
    return out.with_suffix(".log")


def start_run(out: Path, force: bool, threads: int | None, seed: int) -> Path:
    """Checks before a training run writes ``out``; sets threads and the seed; removes the
    log of a run that a fresh one replaces. Returns the training-state path (resume when
    it exists)."""
    sp = state_path(out)
    if out.exists() and not sp.exists() and not force:
        raise FileExistsError(f"{out} exists and has no training state to resume; pass force=True (--force) to retrain")
    if not sp.exists():  # a fresh run: the log of a run that --force replaces goes with it
        log_path(out).unlink(missing_ok=True)
    if threads:
        torch.set_num_threads(threads)
    torch.manual_seed(seed)
    return sp


def provenance(dataset: MotionDataset, config, metadata: dict | None) -> dict:
    """What a checkpoint records about its training: data split, settings (a dataclass
    whose ``model`` field is the architecture, stored apart), platform."""
    return {
        **(metadata or {}),
        "train_clips": sorted(dataset.train),
        "validation_clips": sorted(dataset.val),
        "train_frames": dataset.num_train_frames,
        "fps": dataset.spec.fps,
        "train_config": {k: v for k, v in asdict(config).items() if k != "model"},
        "platform": platform.platform(),
        "torch": str(torch.__version__),
    }


@torch.no_grad()
def validation_nll(prior: CCNetPrior, windows: torch.Tensor, valid: torch.Tensor | None = None,
                   batch: int = 128) -> tuple[float, float]:
    """Mean and median per-frame NLL (moving pose dimensions, nats) of validation windows,
    all frames after the first where ``valid`` (N, T) is True. The median is what selects
    the shipped weights: a single capture glitch in a held-out clip (CMU salsa/15 has
    one) dominates the mean."""
    prior.eval()
    parts = [prior.nll(windows[i:i + batch, 1:], context=windows[i:i + batch, :1])
             for i in range(0, len(windows), batch)]
    prior.train()
    allv = torch.cat(parts)
    if valid is not None:
        allv = allv[valid[:, 1:]]
    return float(allv.mean()), float(allv.median())


def resumed_architecture(state: dict, requested: CCNetConfig) -> CCNetConfig:
    """The architecture a training state was started with; it wins over ``requested``, so
    that a resumed run keeps the meaning of its weights (states from before the
    architecture was stored hold the same settings with changes predicted for the root)."""
    stored = (CCNetConfig.from_dict(state["model_config"]) if "model_config" in state
              else replace(requested, absolute_root=False, absolute_height=False))
    if stored != requested:
        log.warning("resuming with the architecture the run was started with: %s", stored)
    return stored


def epoch_bar(steps: int, desc: str, progress: bool) -> tqdm:
    """A bar over an epoch's ``steps`` on stderr, with ``progress`` and only on a terminal:
    off one (output redirected to a file) its redraws would fill the file several times a
    second, and the line each epoch prints says enough."""
    return tqdm(range(steps), desc=desc, disable=None if progress else True, leave=False)


def train_prior(dataset: MotionDataset, out: str | Path, config: TrainConfig = TrainConfig(),
                metadata: dict | None = None, progress: bool = True, force: bool = False) -> CCNetPrior:
    """Train a CCNet prior on ``dataset`` and write the checkpoint ``out``.

    Writes ``out.train-state.pt`` (weights, optimiser and progress) after every epoch; a
    later call with the same ``out`` resumes from that state. ``out`` (the usable
    checkpoint) holds the weights of the epoch with the best median validation NLL (every
    epoch's when there are no validation clips). ``out.log`` gets one JSON line per epoch.
    ``progress``: a line per epoch on stdout, and a bar over its steps on a terminal.
    """
    out = Path(out)
    sp = start_run(out, force, config.threads, config.seed)
    start = initial_weights(config.init, dataset) if config.init else None
    gen = torch.Generator().manual_seed(config.seed)
    dev = torch.device(config.device)
    train_w, train_valid = (t.to(dev) for t in dataset.padded_windows("train", config.window, config.stride,
                                                                        config.min_clip_frames))
    val_w, val_valid = ((t.to(dev) for t in dataset.padded_windows("val", config.window, config.window // 2,
                                                                    config.min_clip_frames))
                        if dataset.val else (None, None))
    meta = provenance(dataset, config, metadata)
    state = load_plain(sp) if sp.exists() else None
    model = config.model if start is None else start.config
    model = model if state is None else resumed_architecture(state, model)
    prior = CCNetPrior(dataset.spec, dataset.normalizer, dataset.skeleton, model, meta).to(dev)
    if start is not None:
        prior.load_state_dict(start.state_dict())
    opt = torch.optim.Adam(prior.parameters(), lr=config.lr)
    steps_per_epoch = math.ceil(len(train_w) / config.batch_size)
    total_steps = steps_per_epoch * config.epochs
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, total_steps, eta_min=config.lr_min)
    start_epoch, history, seconds = 0, [], 0.0
    if state is not None:
        prior.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        sched.load_state_dict(state["scheduler"])
        gen.set_state(state["generator"])
        torch.set_rng_state(state["torch_rng"])
        start_epoch, history, seconds = state["epoch"], state["history"], state["seconds"]
        log.warning("resuming %s from epoch %d", out, start_epoch)
    prior.train()
    t_start = time.perf_counter() - seconds
    logf = log_path(out).open("a")
    for epoch in range(start_epoch, config.epochs):
        order = torch.randperm(len(train_w), generator=gen)
        bar = epoch_bar(steps_per_epoch, f"epoch {epoch + 1}/{config.epochs}", progress)
        sums = {"loss": 0.0, "nll": 0.0, "nll_own": 0.0, "nll_rollout": 0.0, "ranked": 0.0}
        for step in bar:
            idx = order[step * config.batch_size:(step + 1) * config.batch_size].to(dev)
            loss, parts = prior.loss(train_w[idx], train_valid[idx], config.noise_std, config.smooth_weight,
                                     config.contact_weight, config.passes, config.contrast_weight,
                                     config.contrast_margin, gen, config.rollout_frames, config.rollout_temperature)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(prior.parameters(), 1.0)
            opt.step()
            sched.step()
            sums["loss"] += float(loss.detach())
            sums["nll"] += parts["nll"]
            sums["nll_own"] += parts["nll_own"]
            sums["nll_rollout"] += parts.get("nll_rollout", 0.0)
            sums["ranked"] += parts.get("ranked", 0.0)
            bar.set_postfix(nll=f"{parts['nll']:.1f}")
        record = {
            "epoch": epoch + 1,
            "train_loss": sums["loss"] / steps_per_epoch,
            "train_nll_per_frame": sums["nll"] / steps_per_epoch,
            "train_nll_own_history": sums["nll_own"] / steps_per_epoch,
            #: NLL per frame after the model's own free-running draws (None: no such pass)
            "train_nll_rollout": sums["nll_rollout"] / steps_per_epoch if config.rollout_frames else None,
            #: share of degraded copies ranked behind their window by the margin (None: no ranking loss)
            "train_ranked": sums["ranked"] / steps_per_epoch if config.contrast_weight > 0 else None,
            "val_nll_per_frame": None,
            "val_nll_median": None,
            "lr": sched.get_last_lr()[0],
            "minutes": (time.perf_counter() - t_start) / 60,
        }
        if val_w is not None:
            record["val_nll_per_frame"], record["val_nll_median"] = validation_nll(prior, val_w, val_valid)
        history.append(record)
        logf.write(json.dumps(record) + "\n")
        logf.flush()
        if progress:
            ranked = "-" if record["train_ranked"] is None else f"{record['train_ranked']:.2f}"
            tqdm.write(f"epoch {epoch + 1}: train nll/frame {record['train_nll_per_frame']:.2f}, "
                       f"val nll/frame {record['val_nll_per_frame']}, degraded copies ranked "
                       f"{ranked}, {record['minutes']:.1f} min")
        prior.metadata["history"] = history
        prior.metadata["training_minutes"] = record["minutes"]
        prior.metadata["epochs_done"] = epoch + 1
        medians = [r["val_nll_median"] for r in history if r.get("val_nll_median") is not None]
        if not medians or record["val_nll_median"] <= min(medians):
            prior.metadata["selected_epoch"] = epoch + 1
            save_prior(prior, out)
        atomic_torch_save({"model": prior.state_dict(), "model_config": model.to_dict(), "optimizer": opt.state_dict(),
                           "scheduler": sched.state_dict(), "generator": gen.get_state(),
                           "torch_rng": torch.get_rng_state(), "epoch": epoch + 1, "history": history,
                           "seconds": time.perf_counter() - t_start}, sp)
        if config.max_minutes and record["minutes"] >= config.max_minutes:
            log.warning("stopping after %d epochs: time budget of %.0f minutes reached", epoch + 1, config.max_minutes)
            break
    logf.close()
    prior.eval()
    calibrate_checkpoint(out, dataset, config)
    store_human_range(out)
    store_joint_acceleration(out, dataset.train.values())
    return prior.cpu()


def initial_weights(path: str, dataset: MotionDataset) -> CCNetPrior:
    """The prior a fine-tuning run starts from: its architecture and weights, and its
    normaliser, which ``dataset`` takes over (the weights read features in its units).
    Raises ValueError when its features are not the dataset's."""
    start = load_prior(resolve_checkpoint(path))
    if not isinstance(start, CCNetPrior):
        raise ValueError(f"{path} is a {type(start).__name__}; --init needs an autoregressive (CCNet) checkpoint")
    if start.spec != dataset.spec:
        raise ValueError(f"{path} models other features (joints {', '.join(start.spec.joints)} at "
                         f"{start.spec.fps:g} fps) than the training data (joints {', '.join(dataset.spec.joints)} "
                         f"at {dataset.spec.fps:g} fps): fine-tune on motion of its skeleton, at its frame rate")
    dataset.normalizer = start.normalizer
    return start


def calibrate_checkpoint(out: Path, dataset: MotionDataset, config: TrainConfig) -> None:
    """Store the sampling temperature (``priors.temperature.calibrate``, on the training
    clips) in the checkpoint ``out``, unless it holds one for its current weights."""
    saved = load_prior(out)
    if "sample_temperature" in saved.metadata:
        return
    clips = {k: saved.normalizer.normalize(v).float() for k, v in dataset.train.items()}
    best = calibrate(saved, clips, config.seed, config.calibration_seconds)
    log.info("sampling temperature %g: rollouts at %.2f-%.2f times the data's joint speed", best.temperature,
             best.speed_min, best.speed_max)
    save_prior(saved, out)


#: Metadata key of the RMS acceleration (m/s^2) of each modelled joint over the training
#: clips: what the MAP solve's acceleration term scales its sigmas by.
ACCELERATION_KEY = "joint_acceleration_rms"


def store_joint_acceleration(out: Path, clips: Iterable[Tensor]) -> None:
    """Store in the checkpoint ``out`` the RMS acceleration of each modelled joint over
    ``clips`` (its training clips, raw features at its rate), unless it holds them."""
    saved = load_prior(out)
    if ACCELERATION_KEY in saved.metadata:
        return
    codec, fps = Codec.of(saved), saved.spec.fps
    squares, frames = 0.0, 0
    for raw in clips:
        acc = acceleration(codec.positions(saved.normalizer.normalize(raw).double()), fps)
        squares = squares + acc.pow(2).sum(-1).sum(0)
        frames += len(acc)
    saved.metadata[ACCELERATION_KEY] = [round(float(v), 3) for v in (squares / frames).sqrt()]
    log.info("joint accelerations, RMS over the training clips (m/s^2): %s", saved.metadata[ACCELERATION_KEY])
    save_prior(saved, out)


def store_human_range(out: Path) -> None:
    """Store the range of human motion of the checkpoint ``out``'s validation clips
    (``motionopt.naturalness.HumanRange``: what every task's per-second report is judged
    against), unless it holds one or its clips cannot be read."""
    saved = load_prior(out)
    if METADATA_KEY in saved.metadata or not saved.metadata.get("validation_clips"):
        return
    try:
        clips = held_out_clips(saved)
    except (OSError, ValueError, KeyError) as err:
        log.warning("%s: no range of human motion stored, its validation clips could not be read (%s)", out, err)
        return
    saved.metadata[METADATA_KEY] = HumanRange.of(saved, [c.motion for c in clips]).to_dict()
    log.info("range of human motion from %d validation clips: %s", len(clips), saved.metadata[METADATA_KEY])
    save_prior(saved, out)
