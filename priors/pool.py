"""An autoregressive prior made of two trained ones: a change-predicting prior and an
absolute-pose anchor whose next-frame Gaussians are pooled (``CCNetConfig.anchor``)."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import torch

from .ccnet import CCNetPrior
from .checkpoint import for_evaluation, load_prior, resolve_checkpoint

#: Metadata keys of the anchor's checkpoint kept in the pooled one's, under "anchor".
ANCHOR_KEYS = ("training_command", "train_clips", "train_frames", "validation_clips", "selected_epoch",
               "training_minutes", "val_nll_per_frame", "val_nll_median")


def pool_priors(prior_path: str | Path, anchor_path: str | Path, weight: float) -> CCNetPrior:
    """The prior of ``prior_path`` with the absolute-pose prior of ``anchor_path`` as its
    anchor at ``weight`` (0 < weight < 1). Both must model the same features with the
    same normaliser (trained on the same clips); the pooled prior keeps the first one's
    metadata except its sampling temperature, which the pool changes (recalibrate)."""
    if not 0 < weight < 1:
        raise ValueError(f"the anchor's weight must lie between 0 and 1, got {weight}")
    prior, anchor = (load_prior(resolve_checkpoint(p)) for p in (prior_path, anchor_path))
    for path, p in ((prior_path, prior), (anchor_path, anchor)):
        if not isinstance(p, CCNetPrior):
            raise ValueError(f"{path} is a {type(p).__name__}; pooling needs autoregressive (CCNet) checkpoints")
        if p.anchor is not None:
            raise ValueError(f"{path} is already pooled with an anchor")
    for path, p in ((prior_path, prior), (anchor_path, anchor)):
        if p.config.tail_dof > 0:
            raise ValueError(f"{path} scores with a Student-t (--tail-dof); the pool is of two Gaussians")
    if not anchor.config.absolute_pose:
        raise ValueError(f"{anchor_path} predicts changes of the pose; the anchor must predict the pose itself "
                         "(train it with train-prior --absolute-pose)")
    if prior.spec != anchor.spec:
        raise ValueError(f"{prior_path} and {anchor_path} model different features")
    if not (torch.equal(prior.normalizer.mean, anchor.normalizer.mean)
            and torch.equal(prior.normalizer.std, anchor.normalizer.std)):
        raise ValueError(f"{prior_path} and {anchor_path} normalise their features differently: "
                         "train both on the same clips")
    metadata = {k: v for k, v in prior.metadata.items() if k not in ("sample_temperature", "temperature_calibration")}
    metadata["anchor"] = {k: anchor.metadata[k] for k in ANCHOR_KEYS if k in anchor.metadata}
    config = replace(prior.config, anchor=anchor.config, anchor_weight=float(weight))
    pooled = CCNetPrior(prior.spec, prior.normalizer, prior.skeleton, config, metadata)
    state = dict(prior.state_dict())
    state.update({f"anchor.{k}": v for k, v in anchor.state_dict().items()})
    state["pool_log_scale"] = torch.zeros(prior.spec.pose_dim)
    pooled.load_state_dict(state)
    return for_evaluation(pooled)


@torch.no_grad()
def fit_pool_spread(pooled: CCNetPrior, clips: list[torch.Tensor]) -> torch.Tensor:
    """Set the pooled prior's ``pool_log_scale`` so that its one-step z-scores have RMS 1
    per pose dimension over ``clips`` (normalised features, teacher-forced, every frame
    after the first); returns the RMS before the correction."""
    pooled.pool_log_scale.zero_()
    squares, frames = 0.0, 0
    for x in clips:
        mean, log_std, _ = pooled.gaussian(x[1:], context=x[:1])
        squares = squares + ((x[1:, :pooled.spec.pose_dim] - mean) * torch.exp(-log_std)).pow(2).sum(0)
        frames += len(mean)
    rms = (squares / max(frames, 1)).sqrt()
    pooled.pool_log_scale.copy_(torch.where(pooled.moving.bool(), torch.log(rms.clamp_min(1e-3)), 0.0))
    return rms


def calibrate_pooled(pooled: CCNetPrior, seed: int = 0, seconds: float | None = None) -> float:
    """Fit the pool's spread (``fit_pool_spread``) and choose its sampling temperature
    (``priors.temperature.calibrate``) on its training clips, read again from the data
    folder its metadata names; returns the temperature."""
    from motionopt.dataset import build_dataset

    from .heldout import data_folder
    from .temperature import SECONDS, calibrate

    meta = pooled.metadata
    data = build_dataset(data_folder(meta), spec=pooled.spec, val=[], include=meta["train_clips"])
    clips = {k: pooled.normalizer.normalize(v).float() for k, v in data.train.items()}
    fit_pool_spread(pooled, list(clips.values()))
    return calibrate(pooled, clips, seed, SECONDS if seconds is None else seconds).temperature
