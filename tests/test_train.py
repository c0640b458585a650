"""Training the prior: a tiny real run, its log and checkpoint, and resuming it."""
from __future__ import annotations

import json
import math

import pytest
import torch

from priors.checkpoint import load_prior, read_checkpoint
from priors.temperature import CANDIDATES, Trial, choose
from priors.train import TrainConfig, log_path, state_path, train_prior, validation_nll

from priorkit import TINY, tiny_dataset


def config(**kw) -> TrainConfig:
    """Three short epochs on likelihood alone (tests/test_degrade.py trains the ranking part,
    which raises the NLL of the first epochs while it sharpens the prior)."""
    return TrainConfig(**{"epochs": 3, "window": 16, "stride": 1, "batch_size": 4, "lr": 3e-3, "seed": 3,
                          "calibration_seconds": 6.0, "model": TINY, "contrast_weight": 0.0, **kw})


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """Three epochs in one go."""
    out = tmp_path_factory.mktemp("run") / "tiny.pt"
    train_prior(tiny_dataset(), out, config(), metadata={"licence": "test licence"}, progress=False)
    return out


def test_training_writes_checkpoint_state_and_log(trained):
    assert trained.exists() and state_path(trained).exists()
    records = [json.loads(line) for line in log_path(trained).read_text().splitlines()]
    assert [r["epoch"] for r in records] == [1, 2, 3]
    assert all(math.isfinite(r["val_nll_per_frame"]) and math.isfinite(r["train_loss"]) for r in records)
    meta = load_prior(trained).metadata
    best = min(records, key=lambda r: r["val_nll_median"])["epoch"]
    assert meta["selected_epoch"] == best and meta["history"] == records[:best]
    assert meta["licence"] == "test licence"
    ds = tiny_dataset()
    assert meta["validation_clips"] == sorted(ds.val) and meta["train_clips"] == sorted(ds.train)
    assert not set(meta["validation_clips"]) & set(meta["train_clips"])
    assert meta["fps"] == 30.0 and meta["train_config"]["seed"] == 3


def test_progress_off_a_terminal_is_one_line_per_epoch(capsys, tmp_path):
    train_prior(tiny_dataset(), tmp_path / "p.pt", config(epochs=2), progress=True)
    out, err = capsys.readouterr()  # both streams captured: not terminals, as when redirected to a file
    assert "\r" not in out + err and "it/s" not in err  # no progress bar redraws
    assert [line.split(":")[0] for line in out.splitlines()] == ["epoch 1", "epoch 2"]


def test_training_lowers_nll_and_ships_the_selected_epoch(trained):
    records = [json.loads(line) for line in log_path(trained).read_text().splitlines()]
    # one training clip: the held-out one (another dancer, another root height) says little
    assert records[-1]["train_nll_per_frame"] < records[0]["train_nll_per_frame"] - 20
    c = config()
    val, valid = tiny_dataset().padded_windows("val", c.window, c.window // 2, c.min_clip_frames)
    meta = read_checkpoint(trained)["metadata"]
    selected = meta["history"][meta["selected_epoch"] - 1]
    mean, median = validation_nll(load_prior(trained), val, valid)
    assert (mean, median) == (pytest.approx(selected["val_nll_per_frame"], rel=1e-5),
                              pytest.approx(selected["val_nll_median"], rel=1e-5))


def test_interrupted_training_resumes_to_the_same_weights(trained, tmp_path):
    out = tmp_path / "resumed.pt"
    first = train_prior(tiny_dataset(), out, config(max_minutes=1e-9), progress=False)
    assert torch.load(state_path(out), weights_only=False)["epoch"] == 1 and first is not None
    train_prior(tiny_dataset(), out, config(), progress=False)
    for a, b in ((read_checkpoint(trained)["state_dict"], read_checkpoint(out)["state_dict"]),
                 (torch.load(state_path(trained))["model"], torch.load(state_path(out))["model"])):
        assert all(torch.equal(a[k], b[k]) for k in a)
    assert [json.loads(line)["epoch"] for line in log_path(out).read_text().splitlines()] == [1, 2, 3]


def test_existing_checkpoint_without_state_is_not_overwritten(trained, tmp_path):
    out = tmp_path / "done.pt"
    out.write_bytes(trained.read_bytes())
    with pytest.raises(FileExistsError, match="--force"):
        train_prior(tiny_dataset(), out, config(), progress=False)


def test_forced_retraining_starts_a_fresh_log(trained, tmp_path):
    out = tmp_path / "again.pt"
    out.write_bytes(trained.read_bytes())
    log_path(out).write_text(log_path(trained).read_text())
    train_prior(tiny_dataset(), out, config(epochs=1), progress=False, force=True)
    assert [json.loads(line)["epoch"] for line in log_path(out).read_text().splitlines()] == [1]


def test_resume_keeps_the_architecture_the_run_started_with(tmp_path):
    from dataclasses import replace

    out = tmp_path / "legacy.pt"
    train_prior(tiny_dataset(), out, config(max_minutes=1e-9), progress=False)
    state = torch.load(state_path(out))
    assert state["model_config"]["absolute_root"] is True
    del state["model_config"]  # a state written before the architecture was stored
    torch.save(state, state_path(out))
    train_prior(tiny_dataset(), out, config(epochs=2), progress=False)
    assert torch.load(state_path(out))["model_config"]["absolute_root"] is False
    # a run started with one architecture is not resumed with another
    train_prior(tiny_dataset(), out, config(epochs=3, model=replace(TINY, absolute_root=True)), progress=False)
    assert load_prior(out).config.absolute_root is False


def test_training_calibrates_the_sampling_temperature(trained):
    """After training, rollouts from the training clips at every candidate temperature are
    scored, and the one chosen is stored and used by the prior."""
    prior = load_prior(trained)
    cal = prior.metadata["temperature_calibration"]
    found = [Trial(**t) for t in cal["trials"]]
    assert cal["seconds"] == 6.0 and set(cal["clips"]) <= set(prior.metadata["train_clips"])
    assert [t.temperature for t in found] == list(CANDIDATES)
    assert all(0 < t.speed_min <= t.speed_max for t in found)
    # skating is NaN where a tiny prior's rollouts never put a foot down (documented)
    assert all(math.isnan(t.skating) or t.skating >= 0 for t in found)
    assert any(math.isfinite(t.skating) for t in found)
    assert prior.sample_temperature == choose(found).temperature


def test_training_stores_each_joints_acceleration_over_its_training_clips(trained):
    """The RMS acceleration of every modelled joint over the training clips, which the
    denoising solve scales its acceleration sigmas by: one positive figure per joint, the
    hands and feet faster than the hips, and recomputed to the same figures."""
    from motionopt.codec import Codec
    from motionopt.metrics import acceleration

    prior = load_prior(trained)
    rms = prior.metadata["joint_acceleration_rms"]
    names = prior.spec.joints
    assert len(rms) == len(names) and all(v > 0 for v in rms)
    assert max(rms[names.index(j)] for j in ("lHand", "rHand", "lFoot", "rFoot")) > rms[0]
    codec, fps = Codec.of(prior), prior.spec.fps
    squares = frames = 0
    for raw in tiny_dataset().train.values():
        acc = acceleration(codec.positions(prior.normalizer.normalize(raw).double()), fps)
        squares = squares + acc.pow(2).sum(-1).sum(0)
        frames += len(acc)
    assert rms == pytest.approx((squares / frames).sqrt().tolist(), abs=2e-3)


def test_the_chosen_temperature_keeps_the_data_pace_without_skating():
    found = [Trial(0.1, 0.2, 0.9, 1.0),   # freezes: a fifth of the data's speed
             Trial(0.3, 0.6, 1.8, 1.2),
             Trial(0.5, 0.8, 1.3, 2.5),   # closest pace, but feet slide
             Trial(1.0, 5.0, 9.0, 3.0)]
    assert choose(found).temperature == 0.3
    assert choose([Trial(1.0, 5.0, 9.0, 3.0), Trial(2.0, 9.0, 20.0, 4.0)]).temperature == 1.0


def test_fine_tuning_starts_from_the_checkpoints_weights_and_normaliser(trained, tmp_path):
    tuned = train_prior(tiny_dataset(), tmp_path / "ft.pt", config(epochs=1, lr=1e-12, lr_min=1e-12, init=str(trained)),
                        progress=False)
    start = load_prior(trained)
    assert all(torch.allclose(a, b, atol=1e-8) for a, b in zip(start.parameters(), tuned.parameters()))
    assert torch.equal(tuned.normalizer.mean, start.normalizer.mean)
    assert read_checkpoint(tmp_path / "ft.pt")["metadata"]["train_config"]["init"] == str(trained)


def test_fine_tuning_refuses_a_checkpoint_of_other_features(trained, tmp_path):
    from motionopt.dataset import build_dataset
    from priorkit import DATA, cmu_clips

    other = build_dataset(DATA, fps=15.0, include=[p.name for p in cmu_clips()], val=[cmu_clips()[-1].name])
    with pytest.raises(ValueError, match="15 fps"):
        train_prior(other, tmp_path / "ft.pt", config(init=str(trained)), progress=False)
