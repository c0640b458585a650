"""Training of the latent prior in two phases: autoencoder, then masked encoder.

1. Autoencoder: encoder and generator together, on
   L = L_rec + L_fcon + 2 L_root + 0.01 L_pos + L_foot + code_weight * mean(w^2)
   (after MoDi's encoder losses, appendix D.4: reconstruction of normalised features,
   contact cross-entropy, root features, FK joint positions relative to the root in
   centimetres; MoDi's contact consistency, foot speed squared times contact
   probability; and a penalty on the codes' size). MoDi weighs contacts 100 and world
   positions 0.1; here the contact term would then outweigh the rest a hundredfold, and
   world positions carry the root's drift over the window, which the root term covers. The
   generator decodes the codes plus Gaussian noise of ``code_noise``, so that nearby
   codes decode to nearby, natural motion: what sampling, edits, variations and
   interpolation rely on. After each epoch the code statistics are fitted to the
   training windows' codes (``LatentPrior.fit_code_statistics``).
2. Denoising encoder, generator frozen: the same losses (without the code noise), from
   inputs with Gaussian noise in the unnormalised features (``noisy``: rotations and
   root), of a random size up to ``rotation_noise`` and ``root_noise`` per window. Trained
   on clean windows only, the encoder met captured noise far outside its training data
   (a few joints barely rotate, so their normalised features are tiny-spread) and
   decoded 1 cm of joint noise into 7 cm of error. The code statistics stay those of
   the autoencoder phase: they describe the codes the generator was trained on.
3. Masked encoder, generator frozen: the same losses on full windows, from inputs whose
   unseen frames are zeroed (random prefixes and random gaps).

``init`` starts from a latent checkpoint (its normaliser, and every weight and code
statistic whose shape the new architecture shares) and ``phases`` names the phases to
run: retraining only the masked encoder of a trained prior is ``phases=("masked",)``.

An "epoch" is ``epoch_steps`` optimiser steps; a phase ends after its epochs or its
minutes (``autoencoder_minutes``...), and one call stops after ``max_minutes``
(resumable). After each epoch, the usable checkpoint ``out`` and the resumable
``out.train-state.pt`` are written and one JSON line with validation figures goes to
``out.log``. A later call with the same ``out`` resumes.
"""
from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch
import torch.nn.functional as Fn
from torch import Tensor
from tqdm import tqdm

from motionopt.dataset import MotionDataset
from motionopt.codec import Codec
from motionopt.metrics_latent import local_position_error_mm, root_position_error_mm

from .checkpoint import atomic_torch_save, load_plain, save_prior
from .latent import LatentConfig, LatentPrior
from .semantic import fit_attribute_directions
from .style import fit_style_classifier
from .train import epoch_bar, log_path, provenance, start_run, state_path

log = logging.getLogger(__name__)

PHASES = ("autoencoder", "denoising", "masked")


@dataclass
class LatentTrainConfig:
    """Optimisation settings (see the module docstring for the loss)."""

    autoencoder_epochs: int = 60
    denoising_epochs: int = 20
    masked_epochs: int = 20
    epoch_steps: int = 200
    batch_size: int = 32
    stride: int = 4
    lr: float = 0.001
    encoder_lr: float = 0.0005
    code_noise: float = 0.1
    rotation_noise: float = 0.08
    root_noise: float = 0.015
    code_weight: float = 0.001
    foot_contact_weight: float = 1.0
    rec_weight: float = 1.0
    contact_weight: float = 1.0
    root_weight: float = 2.0
    pos_weight: float = 0.01
    autoencoder_minutes: float | None = None
    denoising_minutes: float | None = None
    masked_minutes: float | None = None
    max_minutes: float | None = None
    seed: int = 0
    threads: int | None = None
    init: str | None = None
    phases: tuple[str, ...] = PHASES
    model: LatentConfig = field(default_factory=LatentConfig)

    def __post_init__(self) -> None:
        self.phases = tuple(self.phases)
        if not self.phases or list(self.phases) != [p for p in PHASES if p in self.phases]:
            raise ValueError(f"phases must be some of {', '.join(PHASES)}, in that order; got {', '.join(self.phases)}")
        if self.phases[0] != PHASES[0] and self.init is None:
            raise ValueError(f"skipping the {PHASES[0]} phase needs a trained checkpoint to start from (--init)")

    def epochs(self, phase: str) -> int:
        return getattr(self, f"{phase}_epochs")

    def minutes(self, phase: str) -> float | None:
        return getattr(self, f"{phase}_minutes")


class Geometry:
    """Differentiable world positions of normalised feature windows on the model skeleton."""

    def __init__(self, prior: LatentPrior):
        self.prior = prior
        self.codec = Codec.of(prior)
        self.contact_idx = prior.spec.contact_indices()

    def positions(self, x: Tensor) -> Tensor:
        """(B, T, J, 3) metres, every window starting at the origin facing +z."""
        return self.codec.positions(x)

    def foot_speed_sq(self, pos: Tensor) -> Tensor:
        """Squared speed (m/s)^2 of the contact joints, (B, T-1, C)."""
        return (pos[:, 1:, self.contact_idx] - pos[:, :-1, self.contact_idx]).pow(2).sum(-1) * self.prior.spec.fps ** 2


def local(pos: Tensor) -> Tensor:
    """Joint positions (..., J, 3) relative to the root joint's."""
    return pos - pos[..., :1, :]


def random_masks(n: int, window: int, generator: torch.Generator) -> Tensor:
    """Masks (n, window) of seen frames: half random prefixes (1..window-8 frames seen),
    half random gaps (4..window-8 unseen frames, at least 2 seen on each side)."""
    mask = torch.ones(n, window)
    t = torch.arange(window)
    prefix = torch.rand(n, generator=generator) < 0.5
    for i in range(n):
        if prefix[i]:
            k = int(torch.randint(1, window - 7, (1,), generator=generator))
            mask[i] = (t < k).float()
        else:
            gap = int(torch.randint(4, window - 7, (1,), generator=generator))
            a = int(torch.randint(2, window - gap - 1, (1,), generator=generator))
            mask[i] = ((t < a) | (t >= a + gap)).float()
    return mask


class LatentTrainer:
    """Holds the model, optimisers and state of one training run."""

    def __init__(self, dataset: MotionDataset, config: LatentTrainConfig, metadata: dict):
        self.config = config
        self.gen = torch.Generator().manual_seed(config.seed)
        torch.manual_seed(config.seed)
        cfg = config.model
        start = initial_latent(config.init, dataset) if config.init else None
        self.train_w = dataset.windows("train", cfg.window, config.stride)
        self.val_w = dataset.windows("val", cfg.window, cfg.window // 4) if dataset.val else None
        self.prior = LatentPrior(dataset.spec, dataset.normalizer, dataset.skeleton, cfg, metadata)
        if start is not None:
            take_weights(self.prior, start, config.phases)
        self.geo = Geometry(self.prior)
        p = self.prior
        self.opt_a = torch.optim.Adam(list(p.encoder.parameters()) + list(p.generator.parameters()), lr=config.lr)
        self.opt_m = torch.optim.Adam(p.masked_encoder.parameters(), lr=config.encoder_lr)
        self.phase, self.epoch, self.step, self.history, self.seconds = config.phases[0], 0, 0, [], 0.0

    # ---- state -------------------------------------------------------------------------
    def state(self) -> dict:
        return {"prior": self.prior.state_dict(), "opt_a": self.opt_a.state_dict(), "opt_m": self.opt_m.state_dict(),
                "generator": self.gen.get_state(), "torch_rng": torch.get_rng_state(), "phase": self.phase,
                "epoch": self.epoch, "step": self.step, "history": self.history, "seconds": self.seconds}

    def load_state(self, s: dict) -> None:
        self.prior.load_state_dict(s["prior"])
        for k in ("opt_a", "opt_m"):
            getattr(self, k).load_state_dict(s[k])
        self.gen.set_state(s["generator"])
        torch.set_rng_state(s["torch_rng"])
        self.phase, self.epoch, self.step, self.history, self.seconds = (
            s["phase"], s["epoch"], s["step"], s["history"], s["seconds"])

    def _batch(self) -> Tensor:
        idx = torch.randint(0, len(self.train_w), (self.config.batch_size,), generator=self.gen)
        return self.train_w[idx]

    # ---- losses ------------------------------------------------------------------------
    def losses(self, real: Tensor, mask: Tensor | None) -> tuple[Tensor, dict[str, float]]:
        """The loss of a batch: through the noisy codes of the encoder (autoencoder phase)
        or the masked encoder's codes (masked phase)."""
        c, p = self.config, self.prior
        if mask is not None:
            codes = p.encode_masked(real, mask)
            raw = p.synthesize(codes)
        elif self.phase == "denoising":
            codes = p.encode(self.noisy(real))
            raw = p.synthesize(codes)
        else:
            codes = p.encode(real)
            raw = p.synthesize(codes + c.code_noise * torch.randn(codes.shape, generator=self.gen))
        s = p.spec.slices()
        pose = slice(0, p.spec.pose_dim)
        rec = Fn.mse_loss(raw[..., pose], real[..., pose])
        contact = Fn.binary_cross_entropy_with_logits(raw[..., s["contacts"]], real[..., s["contacts"]])
        root = Fn.mse_loss(raw[..., :s["root_tilt"].stop], real[..., :s["root_tilt"].stop])
        pos_fake, pos_real = self.geo.positions(raw), self.geo.positions(real)
        pos = (local(pos_fake) - local(pos_real)).mul(100).pow(2).sum(-1).mean()
        foot = (self.geo.foot_speed_sq(pos_fake) * torch.sigmoid(raw[:, 1:, s["contacts"]])).mean()
        size = codes.pow(2).mean()
        loss = (c.rec_weight * rec + c.contact_weight * contact + c.root_weight * root + c.pos_weight * pos
                + c.foot_contact_weight * foot + c.code_weight * size)
        parts = (("rec", rec), ("contact", contact), ("root", root), ("pos_cm2", pos), ("foot", foot), ("code_ms", size))
        return loss, {k: float(v.detach()) for k, v in parts}

    def noisy(self, x: Tensor) -> Tensor:
        """Normalised windows with Gaussian noise added to their unnormalised rotations
        (std up to ``rotation_noise``) and root position and steps (up to ``root_noise``
        metres), of a size drawn per window."""
        c, p = self.config, self.prior
        raw = p.normalizer.denormalize(x)
        s = p.spec.slices()
        size = torch.rand(len(x), 1, 1, generator=self.gen)
        std = torch.zeros(x.shape[-1])
        for k in ("yaw_delta", "root_tilt", "joint_rotations"):
            std[s[k]] = c.rotation_noise
        for k in ("root_delta", "root_height"):
            std[s[k]] = c.root_noise
        noise = torch.randn(raw.shape, generator=self.gen, dtype=raw.dtype) * size * std
        return p.normalizer.normalize(raw + noise).to(x.dtype)

    def train_step(self) -> dict[str, float]:
        masked = self.phase == "masked"
        for q in self.prior.generator.parameters():
            q.requires_grad_(self.phase == "autoencoder")
        real = self._batch()
        mask = random_masks(len(real), real.shape[1], self.gen) if masked else None
        loss, parts = self.losses(real, mask)
        opt = self.opt_m if masked else self.opt_a
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        return parts

    @torch.no_grad()
    def fit_code_statistics(self) -> None:
        """The prior's code statistics from the codes of every training window."""
        self.prior.fit_code_statistics(torch.cat([self.prior.encode(w) for w in self.train_w.split(512)]))

    # ---- validation --------------------------------------------------------------------
    @torch.no_grad()
    def validate(self) -> dict[str, float]:
        """Reconstruction errors (mm) of held-out windows through the phase's encoder."""
        p = self.prior
        p.eval()
        if self.val_w is None:
            return {}
        real = self.val_w[:256]
        if self.phase == "masked":
            wplus = p.encode_masked(real, random_masks(len(real), real.shape[1], torch.Generator().manual_seed(7)))
        else:
            wplus = p.encode(real)
        pr, pg = self.geo.positions(real), self.geo.positions(p.generate(wplus))
        return {"val_root_mm": root_position_error_mm(pg, pr), "val_local_mm": local_position_error_mm(pg, pr)}

    # ---- loop --------------------------------------------------------------------------
    def _phase_minutes(self) -> float:
        """Training minutes spent in the current phase, over all calls."""
        return sum(r["epoch_minutes"] for r in self.history if r["phase"] == self.phase)

    def _next_phase(self) -> None:
        phases = self.config.phases
        nxt = phases.index(self.phase) + 1
        self.phase, self.epoch = (phases[nxt] if nxt < len(phases) else None), 0

    def run(self, out: Path, progress: bool) -> LatentPrior:
        """Train until every phase is done or this call's ``max_minutes`` is spent."""
        c = self.config
        call_start = time.perf_counter()
        with log_path(out).open("a") as logf:
            while self.phase is not None:
                done = self.epoch >= c.epochs(self.phase)
                limit = c.minutes(self.phase)
                if done or (limit is not None and self._phase_minutes() >= limit):
                    if not done:
                        log.warning("%s phase stops after %d epochs: %.0f minutes reached", self.phase, self.epoch,
                                    limit)
                    self._next_phase()
                    self._save(out)
                    continue
                self._epoch(logf, progress)
                self._save(out)
                if c.max_minutes is not None and (time.perf_counter() - call_start) / 60 >= c.max_minutes:
                    log.warning("stopping: this call's %.1f minutes are spent; run again to resume", c.max_minutes)
                    break
        self.prior.eval()
        return self.prior

    def _epoch(self, logf, progress: bool) -> None:
        c = self.config
        t0 = time.perf_counter()
        sums: dict[str, float] = {}
        bar = epoch_bar(c.epoch_steps, f"{self.phase} {self.epoch + 1}/{c.epochs(self.phase)}", progress)
        for _ in bar:
            parts = self.train_step()
            self.step += 1
            for k, v in parts.items():
                sums[k] = sums.get(k, 0.0) + v / c.epoch_steps
            bar.set_postfix({k: f"{v:.3g}" for k, v in parts.items()})
        if self.phase == "autoencoder":
            self.fit_code_statistics()
        self.epoch += 1
        epoch_minutes = (time.perf_counter() - t0) / 60
        self.seconds += epoch_minutes * 60
        record = {"phase": self.phase, "epoch": self.epoch, "step": self.step, **sums, **self.validate(),
                  "epoch_minutes": epoch_minutes, "minutes": self.seconds / 60}
        self.history.append(record)
        logf.write(json.dumps(record) + "\n")
        logf.flush()
        if progress:
            tqdm.write(" ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in record.items()))

    def _save(self, out: Path) -> None:
        meta = self.prior.metadata
        meta["history"] = self.history
        meta["training_minutes"] = self.seconds / 60
        meta["steps_done"] = self.step
        meta["epochs_done"] = len(self.history)
        meta["phase_next"] = self.phase
        meta["phases_done"] = [p for p in PHASES if self.phase is None or PHASES.index(p) < PHASES.index(self.phase)]
        meta["phases_trained"] = list(self.config.phases)
        save_prior(self.prior, out, dtype=torch.float16)
        atomic_torch_save(self.state(), state_path(out))


def train_latent(dataset: MotionDataset, out: str | Path, config: LatentTrainConfig = LatentTrainConfig(),
                 metadata: dict | None = None, progress: bool = True, force: bool = False) -> LatentPrior:
    """Train a latent prior on ``dataset`` and write the checkpoint ``out`` (see module doc)."""
    out = Path(out)
    sp = start_run(out, force, config.threads, config.seed)
    meta = provenance(dataset, config, metadata)
    trainer = LatentTrainer(dataset, config, meta)
    if sp.exists():
        trainer.load_state(load_plain(sp))
        trainer.prior.metadata.update({k: v for k, v in meta.items() if k != "training_command"})
        log.warning("resuming %s: %s phase, epoch %d", out, trainer.phase, trainer.epoch)
    prior = trainer.prior if trainer.phase is None else trainer.run(out, progress)
    if trainer.phase is None and "attribute_directions" not in prior.metadata:
        add_directions(prior, dataset, config.seed)
        save_prior(prior, out, dtype=torch.float16)
    return prior.eval()


def initial_latent(path: str, dataset: MotionDataset) -> LatentPrior:
    """The latent prior a run starts from; ``dataset`` takes over its normaliser (its
    weights read features in its units). Raises ValueError when its features differ."""
    from .checkpoint import load_prior, resolve_checkpoint

    start = load_prior(resolve_checkpoint(path))
    if not isinstance(start, LatentPrior):
        raise ValueError(f"{path} is a {type(start).__name__}; --init needs a latent checkpoint")
    if start.spec != dataset.spec:
        raise ValueError(f"{path} models other features (joints {', '.join(start.spec.joints)} at "
                         f"{start.spec.fps:g} fps) than the training data: start from a prior of its skeleton")
    dataset.normalizer = start.normalizer
    return start


#: Metadata a run that trains neither the autoencoder nor the denoising encoder keeps from
#: its start: what those two alone determine.
ENCODER_METADATA = ("attribute_directions", "style_classifier")


def take_weights(prior: LatentPrior, start: LatentPrior, phases: tuple[str, ...]) -> None:
    """Copy into ``prior`` every weight and buffer of ``start`` of the same name and shape
    (float32), and the start's training record; when neither the autoencoder nor the
    denoising encoder is trained again, also its semantic directions and style classifier."""
    own = prior.state_dict()
    taken = {k: v.float() for k, v in start.state_dict().items() if k in own and own[k].shape == v.shape}
    prior.load_state_dict(taken, strict=False)
    if prior.generator.state_dict().keys() - {k.split(".", 1)[1] for k in taken if k.startswith("generator.")}:
        raise ValueError("the generator of --init does not match the architecture asked for")
    meta = start.metadata
    prior.metadata["init"] = {"training_command": meta.get("training_command"),
                              "training_minutes": meta.get("training_minutes"),
                              "weights_taken": len(taken), "weights_new": len(own) - len(taken)}
    if not {"autoencoder", "denoising"} & set(phases):
        prior.metadata.update({k: meta[k] for k in ENCODER_METADATA if k in meta})


#: Training windows the semantic directions are fitted and calibrated on: at most this
#: many, evenly spaced among those that start every ``DIRECTION_STRIDE`` frames.
DIRECTION_WINDOWS = 4000
DIRECTION_STRIDE = 4
#: With fewer training windows, the directions are fitted on motions sampled from the prior.
MIN_DIRECTION_WINDOWS = 200


def add_directions(prior: LatentPrior, dataset: MotionDataset, seed: int = 0) -> None:
    """Fit the semantic directions into ``prior.metadata['attribute_directions']``: those
    of the computed attributes, and, when the training clip names carry style labels, a
    style classifier (stored as ``style_classifier``, scored on the held-out clips) and a
    direction per style, fitted on ``DIRECTION_WINDOWS`` training windows (evenly spaced;
    on sampled motions when the data has fewer than ``MIN_DIRECTION_WINDOWS``)."""
    prior.eval()
    norm = {split: {k: prior.normalizer.normalize(v).float() for k, v in clips.items()}
            for split, clips in (("train", dataset.train), ("val", dataset.val))}
    styles = fit_style_classifier(norm["train"], norm["val"], prior.window)
    if styles is not None:
        prior.metadata["style_classifier"] = styles.to_dict()
    windows = dataset.windows("train", prior.window, DIRECTION_STRIDE)
    windows = windows[torch.linspace(0, len(windows) - 1, min(DIRECTION_WINDOWS, len(windows))).long()]
    dirs = fit_attribute_directions(prior, windows if len(windows) >= MIN_DIRECTION_WINDOWS else None, seed=seed,
                                    styles=styles)
    prior.metadata["attribute_directions"] = {k: d.to_dict() for k, d in dirs.items()}

