"""Training of the latent prior in three phases: GAN, encoder, masked encoder.

1. GAN (MoDi section 3.3): non-saturating adversarial loss, lazy R1 on real windows,
   style mixing, and the two foot-contact losses (touch: -log sigmoid(contact logit);
   consistency: foot speed squared times contact probability); an exponential moving
   average of the generator is what gets shipped.
2. Encoder (section 3.4) with the generator frozen:
   L = L_rec + 100 L_fcon + 2 L_root + 0.1 L_pos (reconstruction of normalised features,
   contact cross-entropy, root features, FK positions in centimetres).
3. Masked encoder: the same losses on full windows, from inputs whose unseen frames are
   zeroed (random prefixes and random gaps).

An "epoch" is ``epoch_steps`` optimiser steps; a phase ends after its epochs or its
minutes (``gan_minutes``...), and one call stops after ``max_minutes`` (resumable).
After each epoch, the usable checkpoint ``out`` and the resumable ``out.train-state.pt``
are written and one JSON line with validation figures goes to ``out.log``. A later call
with the same ``out`` resumes.
"""
from __future__ import annotations

import copy
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
from motionopt.metrics_latent import frechet_distance, local_position_error_mm, root_position_error_mm, \
    window_descriptors

from .checkpoint import atomic_torch_save, load_plain, save_prior
from .latent import Discriminator, LatentConfig, LatentPrior
from .semantic import fit_attribute_directions
from .style import fit_style_classifier
from .train import epoch_bar, log_path, provenance, start_run, state_path

log = logging.getLogger(__name__)

PHASES = ("gan", "encoder", "masked")


@dataclass
class LatentTrainConfig:
    """Optimisation settings; the loss weights are the paper's (MoDi appendix D.2, D.4)."""

    gan_epochs: int = 60
    encoder_epochs: int = 20
    masked_epochs: int = 20
    epoch_steps: int = 200
    batch_size: int = 16
    stride: int = 4
    lr: float = 0.002
    encoder_lr: float = 0.0005
    r1_gamma: float = 5.0
    r1_interval: int = 16
    mixing_prob: float = 0.9
    ema_beta: float = 0.998
    touch_weight: float = 0.01
    foot_contact_weight: float = 1.0
    rec_weight: float = 1.0
    enc_contact_weight: float = 100.0
    root_weight: float = 2.0
    pos_weight: float = 0.1
    gan_minutes: float | None = None
    encoder_minutes: float | None = None
    masked_minutes: float | None = None
    max_minutes: float | None = None
    seed: int = 0
    threads: int | None = None
    model: LatentConfig = field(default_factory=LatentConfig)

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
    """Holds the models, optimisers and state of one training run."""

    def __init__(self, dataset: MotionDataset, config: LatentTrainConfig, metadata: dict):
        self.config = config
        self.gen = torch.Generator().manual_seed(config.seed)
        cfg = config.model
        self.train_w = dataset.windows("train", cfg.window, config.stride)
        self.val_w = dataset.windows("val", cfg.window, cfg.window // 4) if dataset.val else None
        self.prior = LatentPrior(dataset.spec, dataset.normalizer, dataset.skeleton, cfg, metadata)
        self.student = copy.deepcopy(self.prior)  # trained generator; self.prior holds its moving average
        self.disc = Discriminator(cfg, dataset.spec.dim)
        self.geo = Geometry(self.prior)
        self.geo_student = Geometry(self.student)
        g_params = list(self.student.mapping_net.parameters()) + list(self.student.synthesis.parameters())
        self.opt_g = torch.optim.Adam(g_params, lr=config.lr, betas=(0.0, 0.99))
        r1_ratio = config.r1_interval / (config.r1_interval + 1)
        self.opt_d = torch.optim.Adam(self.disc.parameters(), lr=config.lr * r1_ratio,
                                      betas=(0.0, 0.99 ** r1_ratio))
        self.opt_e = torch.optim.Adam(self.prior.encoder.parameters(), lr=config.encoder_lr)
        self.opt_m = torch.optim.Adam(self.prior.masked_encoder.parameters(), lr=config.encoder_lr)
        self.phase, self.epoch, self.step, self.history, self.seconds = PHASES[0], 0, 0, [], 0.0
        self._freeze_generator(self.prior)

    @staticmethod
    def _freeze_generator(prior: LatentPrior) -> None:
        for p in list(prior.mapping_net.parameters()) + list(prior.synthesis.parameters()):
            p.requires_grad_(False)

    # ---- state -------------------------------------------------------------------------
    def state(self) -> dict:
        return {"prior": self.prior.state_dict(), "student": self.student.state_dict(), "disc": self.disc.state_dict(),
                "opt_g": self.opt_g.state_dict(), "opt_d": self.opt_d.state_dict(), "opt_e": self.opt_e.state_dict(),
                "opt_m": self.opt_m.state_dict(), "generator": self.gen.get_state(),
                "torch_rng": torch.get_rng_state(), "phase": self.phase, "epoch": self.epoch, "step": self.step,
                "history": self.history, "seconds": self.seconds}

    def load_state(self, s: dict) -> None:
        self.prior.load_state_dict(s["prior"])
        self.student.load_state_dict(s["student"])
        self.disc.load_state_dict(s["disc"])
        for k in ("opt_g", "opt_d", "opt_e", "opt_m"):
            getattr(self, k).load_state_dict(s[k])
        self.gen.set_state(s["generator"])
        torch.set_rng_state(s["torch_rng"])
        self.phase, self.epoch, self.step, self.history, self.seconds = (
            s["phase"], s["epoch"], s["step"], s["history"], s["seconds"])

    # ---- GAN ---------------------------------------------------------------------------
    def _batch(self) -> Tensor:
        idx = torch.randint(0, len(self.train_w), (self.config.batch_size,), generator=self.gen)
        return self.train_w[idx]

    def _styles(self, n: int) -> Tensor:
        """W+ codes of fresh samples, with style mixing (two w, one crossover layer)."""
        m = self.student
        w = m.mapping(torch.randn(2 * n, m.config.z_dim, generator=self.gen)).reshape(2, n, -1)
        ws = m.broadcast(w[0]).clone()
        if torch.rand((), generator=self.gen) < self.config.mixing_prob:
            cut = int(torch.randint(1, m.num_ws, (1,), generator=self.gen))
            ws[:, cut:] = w[1][:, None]
        return ws

    def _fake(self, raw: Tensor) -> Tensor:
        """What the discriminator sees of generated windows: contacts as probabilities."""
        return self.student.contacts_to_probabilities(raw)

    def gan_step(self) -> dict[str, float]:
        c = self.config
        real = self._batch()
        # discriminator
        with torch.no_grad():
            fake = self._fake(self.student.synthesize(self._styles(len(real))))
        loss_d = Fn.softplus(self.disc(fake)).mean() + Fn.softplus(-self.disc(real)).mean()
        self.opt_d.zero_grad(set_to_none=True)
        loss_d.backward()
        r1 = torch.zeros(())
        if self.step % c.r1_interval == 0:
            real_r = real.detach().requires_grad_(True)
            (grad,) = torch.autograd.grad(self.disc(real_r).sum(), real_r, create_graph=True)
            r1 = grad.pow(2).sum(dim=(1, 2)).mean()
            (c.r1_gamma / 2 * r1 * c.r1_interval).backward()
        self.opt_d.step()
        # generator
        raw = self.student.synthesize(self._styles(len(real)))
        logits = raw[..., self.student.spec.slices()["contacts"]]
        adv = Fn.softplus(-self.disc(self._fake(raw))).mean()
        touch = Fn.softplus(-logits).mean()
        speed = self.geo_student.foot_speed_sq(self.geo_student.positions(raw))
        foot = (speed * torch.sigmoid(logits[:, 1:])).mean()
        loss_g = adv + c.touch_weight * touch + c.foot_contact_weight * foot
        self.opt_g.zero_grad(set_to_none=True)
        loss_g.backward()
        self.opt_g.step()
        self._ema()
        return {k: float(v.detach()) for k, v in (("d", loss_d), ("g_adv", adv), ("touch", touch), ("foot", foot), ("r1", r1))}

    @torch.no_grad()
    def _ema(self) -> None:
        beta = self.config.ema_beta if self.step > 100 else 0.0
        for name in ("mapping_net", "synthesis"):
            for pe, ps in zip(getattr(self.prior, name).parameters(), getattr(self.student, name).parameters()):
                pe.lerp_(ps, 1.0 - beta)

    # ---- encoders ----------------------------------------------------------------------
    def encoder_losses(self, real: Tensor, mask: Tensor | None) -> tuple[Tensor, dict[str, float]]:
        """The paper's encoder loss of a batch, through the frozen (averaged) generator."""
        c, p = self.config, self.prior
        wplus = p.encode(real) if mask is None else p.encode_masked(real, mask)
        raw = p.synthesize(wplus)
        s = p.spec.slices()
        pose = slice(0, p.spec.pose_dim)
        rec = Fn.mse_loss(raw[..., pose], real[..., pose])
        contact = Fn.binary_cross_entropy_with_logits(raw[..., s["contacts"]], real[..., s["contacts"]])
        root = Fn.mse_loss(raw[..., :s["root_tilt"].stop], real[..., :s["root_tilt"].stop])
        pos = (self.geo.positions(raw) - self.geo.positions(real)).mul(100).pow(2).sum(-1).mean()
        loss = c.rec_weight * rec + c.enc_contact_weight * contact + c.root_weight * root + c.pos_weight * pos
        return loss, {k: float(v.detach()) for k, v in (("rec", rec), ("contact", contact), ("root", root), ("pos_cm2", pos))}

    def encoder_step(self, masked: bool) -> dict[str, float]:
        real = self._batch()
        mask = random_masks(len(real), real.shape[1], self.gen) if masked else None
        loss, parts = self.encoder_losses(real, mask)
        opt = self.opt_m if masked else self.opt_e
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        return parts

    # ---- validation --------------------------------------------------------------------
    @torch.no_grad()
    def validate(self) -> dict[str, float]:
        """Figures on held-out windows: Fréchet distance of samples (GAN phase) or
        reconstruction errors in mm (encoder phases)."""
        p = self.prior
        p.eval()
        out: dict[str, float] = {}
        if self.val_w is None:
            return out
        if self.phase == "gan":
            g = torch.Generator().manual_seed(1234)
            fake = p.generate(p.broadcast(p.sample_w(len(self.val_w), g)))
            out["val_fd"] = frechet_distance(window_descriptors(fake), window_descriptors(self.val_w))
            out["sample_foot_speed_in_contact"] = float(
                (self.geo.foot_speed_sq(self.geo.positions(fake)).sqrt() *
                 fake[:, 1:, p.spec.slices()["contacts"]]).mean())
        else:
            real = self.val_w[:256]
            if self.phase == "encoder":
                wplus = p.encode(real)
            else:
                wplus = p.encode_masked(real, random_masks(len(real), real.shape[1], torch.Generator().manual_seed(7)))
            pr, pg = self.geo.positions(real), self.geo.positions(p.generate(wplus))
            out["val_root_mm"] = root_position_error_mm(pg, pr)
            out["val_local_mm"] = local_position_error_mm(pg, pr)
        return out

    # ---- loop --------------------------------------------------------------------------
    def _phase_minutes(self) -> float:
        """Training minutes spent in the current phase, over all calls."""
        return sum(r["epoch_minutes"] for r in self.history if r["phase"] == self.phase)

    def _next_phase(self) -> None:
        nxt = PHASES.index(self.phase) + 1
        self.phase, self.epoch = (PHASES[nxt] if nxt < len(PHASES) else None), 0

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
            parts = self.gan_step() if self.phase == "gan" else self.encoder_step(self.phase == "masked")
            self.step += 1
            for k, v in parts.items():
                sums[k] = sums.get(k, 0.0) + v / c.epoch_steps
            bar.set_postfix({k: f"{v:.3g}" for k, v in parts.items()})
        if self.phase == "gan":
            self.prior.fit_w_statistics(generator=torch.Generator().manual_seed(c.seed))
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


def add_directions(prior: LatentPrior, dataset: MotionDataset, seed: int = 0) -> None:
    """Fit the semantic directions into ``prior.metadata['attribute_directions']``: those
    of the computed attributes, and, when the training clip names carry style labels, a
    style classifier (stored as ``style_classifier``, scored on the held-out clips) and a
    direction per style."""
    prior.eval()
    norm = {split: {k: prior.normalizer.normalize(v).float() for k, v in clips.items()}
            for split, clips in (("train", dataset.train), ("val", dataset.val))}
    styles = fit_style_classifier(norm["train"], norm["val"], prior.window)
    if styles is not None:
        prior.metadata["style_classifier"] = styles.to_dict()
    dirs = fit_attribute_directions(prior, seed=seed, styles=styles)
    prior.metadata["attribute_directions"] = {k: d.to_dict() for k, d in dirs.items()}

