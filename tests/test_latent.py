"""The latent (W+) prior: protocol, checkpoint, training phases, masked encoder,
inversion, semantic directions and the latent commands, on tiny real runs."""
from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from motionopt import attributes as A
from motionopt import bvh
from motionopt.codec import Codec
from motionopt.app.cli import main
from motionopt.app.cli.latent import TINY
from motionopt.solver import InversionOptions, blend, clip_window_starts, invert
from priors.checkpoint import CheckpointError, load_prior, read_checkpoint
from priors.latent import LatentConfig, LatentPrior
from motionopt.prior import LatentMotionPrior
from priors.semantic import AttributeScorer, directions_of, edit_codes
from priors.train_latent import LatentTrainConfig, log_path, state_path, train_latent
from motionopt.rotations import quat_multiply, yaw_quat
from problems.common import prepare
from problems.latent import anchor_root, complete, fuse, infill, reconstruct
from problems.ranges import at_model_rate

from priorkit import assert_kept_the_best_sound_start, cmu_clips, tiny_dataset
from clips import BANDAI_30, DATA

WINDOW = 32


def config(**kw) -> LatentTrainConfig:
    return LatentTrainConfig(**{"autoencoder_epochs": 2, "denoising_epochs": 2, "masked_epochs": 2, "epoch_steps": 40,
                                "batch_size": 8, "stride": 2, "encoder_lr": 3e-3, "seed": 5,
                                "model": LatentConfig(**{**TINY, "window": WINDOW}), **kw})


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A tiny run stopped after its first epoch, then resumed through all phases."""
    out = tmp_path_factory.mktemp("latent") / "tiny-latent.pt"
    train_latent(tiny_dataset(), out, config(max_minutes=0.0), metadata={"licence": "test licence"}, progress=False)
    first = read_checkpoint(out)["metadata"]
    train_latent(tiny_dataset(), out, config(), metadata={"licence": "test licence"}, progress=False)
    return out, first


@pytest.fixture(scope="module")
def prior(trained) -> LatentPrior:
    return load_prior(trained[0])


def test_protocol_and_shapes(prior):
    assert isinstance(prior, LatentMotionPrior)
    d, n = prior.spec.dim, 3
    w = prior.sample_wplus(n, torch.Generator().manual_seed(0))
    assert w.shape == (n, prior.num_ws, prior.config.w_dim) and prior.num_ws == WINDOW // 4
    x = prior.generate(w)
    assert x.shape == (n, WINDOW, d)
    contacts = x[..., prior.spec.slices()["contacts"]]
    assert contacts.min() >= 0 and contacts.max() <= 1
    assert prior.encode(x).shape == (n, prior.num_ws, prior.config.w_dim)
    assert prior.encode_masked(x, torch.ones(n, WINDOW)).shape == (n, prior.num_ws, prior.config.w_dim)
    with pytest.raises(ValueError, match="expected windows"):
        prior.encode(x[:, :-1])


def test_checkpoint_metadata_and_resume(trained, prior):
    out, first = trained
    data = read_checkpoint(out)
    assert data["kind"] == "LatentPrior"
    meta = prior.metadata
    assert meta["licence"] == "test licence"
    assert meta["validation_clips"] == [cmu_clips()[-1].name]
    assert not set(meta["validation_clips"]) & set(meta["train_clips"])
    assert first["phases_done"] == [] and [r["phase"] for r in first["history"]] == ["autoencoder"]
    assert meta["phases_done"] == ["autoencoder", "denoising", "masked"]
    phases = [r["phase"] for r in meta["history"]]
    assert phases == ["autoencoder", "autoencoder", "denoising", "denoising", "masked", "masked"]  # resumed
    lines = [json.loads(s) for s in log_path(out).read_text().splitlines()]
    assert [r["epoch"] for r in lines] == [1, 2, 1, 2, 1, 2]
    assert all("val_local_mm" in r for r in lines)
    assert state_path(out).exists()
    assert set(meta["attribute_directions"]) >= {"crouch", "root_speed"}


def test_checkpoint_version_is_checked(trained, tmp_path):
    data = torch.load(trained[0], weights_only=True)
    data["spec"]["version"] = 99
    bad = tmp_path / "old.pt"
    torch.save(data, bad)
    with pytest.raises(CheckpointError, match="feature version 99"):
        load_prior(bad)


def test_generation_is_deterministic_and_loaded_prior_matches(trained, prior):
    again = load_prior(trained[0])
    w = prior.sample_wplus(2, torch.Generator().manual_seed(0))
    assert torch.equal(prior.generate(w), again.generate(w))
    assert torch.equal(w, again.sample_wplus(2, torch.Generator().manual_seed(0)))


def test_masked_encoder_ignores_unseen_frames(prior):
    x = tiny_dataset().windows("train", WINDOW, 4)[:2]
    mask = torch.zeros(2, WINDOW)
    mask[:, :12] = 1  # a prefix
    mask[1, 24:] = 1  # and, for the second window, a gap
    other = x + torch.randn(x.shape, generator=torch.Generator().manual_seed(1)) * (1 - mask[..., None])
    assert torch.allclose(prior.encode_masked(x, mask), prior.encode_masked(other, mask), atol=1e-6)
    seen_changed = x + 0.5 * mask[..., None]
    assert not torch.allclose(prior.encode_masked(x, mask), prior.encode_masked(seen_changed, mask), atol=1e-4)


def test_window_blend_covers_long_clips():
    starts = clip_window_starts(100, 32, 8)
    assert starts[0] == 0 and starts[-1] == 68 and all(b - a <= 24 for a, b in zip(starts, starts[1:]))
    windows = torch.stack([torch.full((32, 3), float(s)) for s in starts])
    out = blend(windows, starts, 100)
    assert out.shape == (100, 3)
    assert torch.all(out[1:, 0] >= out[:-1, 0])  # cross-fades between consecutive windows, no jumps back
    ones = blend(torch.ones(len(starts), 32, 3), starts, 100)
    assert torch.allclose(ones, torch.ones(100, 3))


def test_inversion_improves_the_objective(prior):
    clip = bvh.load(cmu_clips()[-1])  # held out, longer than a window
    enc = reconstruct(prior, clip, InversionOptions(overlap=8))
    ref = reconstruct(prior, clip, InversionOptions(overlap=8, refine_iters=15))
    assert len(ref.inversion.starts) > 1
    assert ref.inversion.objective_start == pytest.approx(enc.inversion.objective, rel=1e-5)
    assert ref.inversion.objective < 0.9 * ref.inversion.objective_start
    assert ref.motion.skeleton.names == clip.skeleton.names and ref.motion.fps == clip.fps
    assert ref.motion.num_frames == clip.num_frames
    pso = reconstruct(prior, clip, InversionOptions(overlap=8, pso_iters=3))
    assert pso.inversion.objective <= pso.inversion.objective_start + 1e-6


def test_inversion_needs_terms_to_refine(prior):
    x = tiny_dataset().windows("train", WINDOW, 4)[0]
    with pytest.raises(ValueError, match="need task terms"):
        invert(prior, x, options=InversionOptions(refine_iters=3))


def test_infill_keeps_seen_frames_closer_than_unseen(prior):
    clip = bvh.load(cmu_clips()[-1])
    seen = np.zeros(clip.num_frames, bool)
    seen[: clip.num_frames // 2] = True
    r = infill(prior, clip, seen, InversionOptions(refine_iters=10))
    assert r.inversion.objective < r.inversion.objective_start
    assert r.motion.num_frames == clip.num_frames
    longer = complete(prior, clip, clip.num_frames // 2, clip.num_frames + 20)
    assert longer.motion.num_frames == clip.num_frames + 20


def test_completion_carries_on_from_the_prefix(prior):
    """The completed frames start where the prefix is going: the prefix is the input's, and
    the step across the seam is no larger than the prefix's own steps, though the
    generator reproduces the prefix only approximately."""
    clip = bvh.load(cmu_clips()[-1])
    seen = np.zeros(clip.num_frames, bool)
    seen[: clip.num_frames // 2] = True
    out = infill(prior, clip, seen).model_motion
    real = prepare(clip, prior).model
    k = int(at_model_rate(seen, clip.fps, prior.spec.fps, real.num_frames).sum())
    assert np.allclose(out.rotations[:k], real.rotations[:k]) and np.allclose(out.root[:k], real.root[:k])

    def largest_steps(m) -> np.ndarray:
        """Per frame from the second, the largest joint step from the frame before (m)."""
        return np.linalg.norm(np.diff(m.positions(), axis=0), axis=-1).max(-1)

    assert largest_steps(out)[k - 1] <= 1.5 * largest_steps(real)[:k - 1].max()


def test_semantic_direction_moves_the_score(prior):
    """On a fixed seed, samples pushed along a fitted direction score higher than samples
    pushed the other way, for every computed attribute with a usable classifier."""
    scorer = AttributeScorer(prior)
    dirs = directions_of(prior)
    w = prior.sample_wplus(256, torch.Generator().manual_seed(11))
    checked = 0
    for name in ("crouch", "root_speed"):
        up = scorer(prior.generate(edit_codes(w, dirs[name], 2.0)))[name].mean()
        down = scorer(prior.generate(edit_codes(w, dirs[name], -2.0)))[name].mean()
        assert up > down, name
        checked += 1
    assert checked == 2


def test_edit_moves_every_code_alike(prior):
    d = directions_of(prior)["crouch"]
    w = prior.sample_wplus(4, torch.Generator().manual_seed(2))
    moved = edit_codes(w, d, 1.5) - w
    assert torch.allclose(moved, (1.5 * d.scale * d.vector()).expand_as(moved), atol=1e-6)


def test_code_statistics_describe_the_codes_they_are_fitted_to(prior):
    """Samples of the fitted Gaussian have the codes' mean and spread, and whitened codes
    have unit variance."""
    import copy

    fitted = copy.deepcopy(prior)
    codes = prior.encode(tiny_dataset().windows("train", WINDOW, 2)).detach()
    fitted.fit_code_statistics(codes)
    samples = fitted.sample_wplus(4000, torch.Generator().manual_seed(3))
    assert torch.allclose(samples.mean(0), codes.mean(0), atol=0.1 * float(codes.std()))
    assert float(samples.std()) == pytest.approx(float(codes.std()), rel=0.1)
    assert float(fitted.whiten(codes).pow(2).mean()) == pytest.approx(1.0, rel=0.05)


def test_denoising_phase_trains_the_encoder_on_noisy_windows():
    """The noise the denoising phase adds has the asked size in the unnormalised rotations."""
    from priors.train_latent import LatentTrainer

    trainer = LatentTrainer(tiny_dataset(), config(rotation_noise=0.2, root_noise=0.0), {})
    x = trainer.train_w[:64]
    raw = trainer.prior.normalizer.denormalize
    diff = raw(trainer.noisy(x)) - raw(x)
    rot = trainer.prior.spec.slices()["joint_rotations"]
    assert float(diff[..., trainer.prior.spec.slices()["root_delta"]].abs().max()) < 1e-5
    assert 0.05 < float(diff[..., rot].std()) < 0.2  # a size drawn up to 0.2 per window


def test_gral_score_follows_the_arm():
    t = torch.linspace(0, 1, 32)
    pos = torch.zeros(32, 3, 3)
    pos[:, 1] = torch.stack((torch.sin(t * 2), -torch.cos(t * 2), torch.zeros(32)), -1)  # elbow swings up
    pos[:, 2] = pos[:, 1] * 2
    assert float(A.gradual_right_arm_lift(pos, 0, 1, 2)) == 1.0
    assert float(A.gradual_right_arm_lift(pos.flip(0), 0, 1, 2)) == 0.0
    assert A.right_arm(("hip", "rCollar", "rShldr", "rForeArm", "rHand"), [-1, 0, 1, 2, 3]) == (2, 3, 4)
    assert A.style_of("dataset-1_walk-back_not-confident_003.bvh") == "not-confident"
    root = torch.stack((torch.arange(30.0) * 0.1, torch.ones(30), torch.zeros(30)), -1)
    assert float(A.root_speed(root, 30.0)) == pytest.approx(3.0)


def test_fuse_output_keeps_the_file_layout(prior):
    a, b = (bvh.load(p) for p in cmu_clips())
    r = fuse(prior, a, b, at=30)
    assert r.motion.skeleton.names == a.skeleton.names and r.motion.skeleton.channels == a.skeleton.channels
    assert r.motion.fps == a.fps and r.motion.source_unit == a.source_unit
    with pytest.raises(ValueError, match="must fall inside") as refused:
        fuse(prior, a, b, at=10_000)
    first, last = map(int, re.search(r"accepted: frames (\d+)-(\d+) of A", str(refused.value)).groups())
    assert 0 < first < 10 and first < last < a.num_frames
    for at in (first - 1, last + 1):
        with pytest.raises(ValueError, match="accepted: frames"):
            fuse(prior, a, b, at=at)
    assert fuse(prior, a, b, at=last).motion.num_frames > 0


def test_fuse_keeps_each_part_beyond_the_seam_and_joins_them(prior):
    """Two seam bands from the seam the output is A before it and B after it, joint for
    joint; across the seam it moves no faster than a jump-free clip (the plain
    concatenation jumps there)."""
    a, b = (bvh.load(p) for p in cmu_clips())
    codec = Codec.of(prior)
    assert (a.fps, b.fps) == (120, 60)
    r = fuse(prior, a, b, at=160)  # 1.33 s into A, 160 of its frames; B is taken from 1.33 s too
    t, tb = r.metrics["seam_frame_model"], 40
    out, ma, mb = r.model_motion, codec.model_motion(a), codec.model_motion(b)
    assert t == 40 and out.num_frames >= t + mb.num_frames - tb
    assert np.abs(out.rotations[: t - 16, 1:] - ma.rotations[: t - 16, 1:]).max() < 1e-4
    after = mb.num_frames - tb - 16
    assert np.abs(out.rotations[t + 16:t + 16 + after, 1:] - mb.rotations[tb + 16:, 1:]).max() < 1e-4
    local = out.positions() - out.positions()[:, :1]
    cat = np.concatenate((ma.positions()[:t] - ma.positions()[:t, :1], mb.positions()[tb:] - mb.positions()[tb:, :1]))
    step = lambda p: np.linalg.norm(np.diff(p, axis=0), axis=-1).max(-1)  # noqa: E731
    assert step(local)[t - 1] < 0.5 * step(cat)[t - 1]


def test_commands_write_bvh(trained, tmp_path, capsys):
    ckpt = str(trained[0])
    a, b = (str(p) for p in cmu_clips())
    out = tmp_path / "fused.bvh"
    assert main(["fuse", a, b, "--at", "30", "--out", str(out), "--prior", ckpt, "-q"]) == 0
    src = bvh.read_channels(a)
    got = bvh.read_channels(out)
    assert got[0].names == src[0].names and got[2] == pytest.approx(src[2])
    assert main(["latent-edit", b, "--attribute", "crouch", "--strength", "1", "--out", str(tmp_path / "e.bvh"),
                 "--prior", ckpt, "-q"]) == 0
    assert main(["vary", b, "--count", "2", "--out-dir", str(tmp_path / "v"), "--prior", ckpt, "-q"]) == 0
    assert sorted(p.name for p in (tmp_path / "v").iterdir()) == [f"{DATA.joinpath(b).stem}_var_0{i}.bvh"
                                                                  for i in range(2)]
    assert main(["interpolate", a, b, "--steps", "3", "--out-dir", str(tmp_path / "i"), "--prior", ckpt, "-q"]) == 0
    assert len(list((tmp_path / "i").iterdir())) == 3
    assert main(["latent-edit", b, "--attribute", "nope", "--out", str(tmp_path / "x.bvh"), "--prior", ckpt]) == 1
    assert "unknown attribute" in capsys.readouterr().err


def test_commands_take_the_common_task_options(trained, tmp_path, capsys):
    import shlex

    from motionopt.app.cli import build_parser

    ckpt = str(trained[0])
    a, b = (str(p) for p in cmu_clips())
    runs = {"fuse": [a, b, "--at", "30", "--out", tmp_path / "f.bvh"],
            "latent-edit": [b, "--attribute", "crouch", "--out", tmp_path / "e.bvh"],
            "vary": [b, "--count", "2", "--out-dir", tmp_path / "v"],
            "interpolate": [a, b, "--steps", "2", "--out-dir", tmp_path / "i"]}
    for command, argv in runs.items():
        report = tmp_path / f"{command}.json"
        page = tmp_path / f"{command}.html"
        argv = [command, *map(str, argv), "--prior", ckpt, "--seed", "3", "--plot", "--report", str(report),
                "--view", str(page), "--unit", "cm", "-q"]
        assert main(argv) == 0, capsys.readouterr().err
        rep = json.loads(report.read_text())
        assert rep["task"] == command and rep["prior"] == ckpt and len(rep["outputs"]) == (2 if "--out-dir" in argv
                                                                                             else 1)
        for out in rep["outputs"]:
            assert bvh.load(out["output"]).num_frames > 0
            assert Path(out["picture"]).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        html = page.read_text()
        assert html.count('"name":') >= len(rep["outputs"]) + (2 if command in ("fuse", "interpolate") else 1)
        again = build_parser().parse_args(shlex.split(rep["command"])[1:])
        assert again.command == command and again.seed == 3 and again.plot
        assert main(argv) == 1 and "pass --force" in capsys.readouterr().err  # nothing is overwritten


def test_two_motion_commands_refuse_motions_on_two_skeletons(trained, tmp_path, capsys):
    a, walk = str(cmu_clips()[0]), DATA / BANDAI_30
    if not walk.exists():
        pytest.skip("needs the Bandai excerpt in tests/data")
    ckpt = str(trained[0])
    for argv in (["fuse", a, str(walk), "--at", "30", "--out", str(tmp_path / "f.bvh")],
                 ["interpolate", a, str(walk), "--out-dir", str(tmp_path / "i")]):
        assert main([*argv, "--prior", ckpt]) != 0
        err = capsys.readouterr().err
        assert f"{walk} is on another skeleton than {a}: it lacks hip" in err and "one skeleton" in err
    assert list(tmp_path.iterdir()) == []


def test_training_progress_off_a_terminal_is_one_line_per_epoch(capsys, tmp_path):
    short = config(autoencoder_epochs=1, denoising_epochs=1, masked_epochs=1, epoch_steps=2)
    train_latent(tiny_dataset(), tmp_path / "l.pt", short, progress=True)
    out, err = capsys.readouterr()  # both streams captured: not terminals, as when redirected to a file
    assert "\r" not in out + err and "it/s" not in err  # no progress bar redraws
    assert [line.split()[0] for line in out.splitlines()] == ["phase=autoencoder", "phase=denoising", "phase=masked"]


def test_config_rejects_bad_window():
    with pytest.raises(ValueError, match="multiple of"):
        replace(LatentConfig(), window=62)


def test_anchor_root_removes_slow_drift_and_keeps_fast_motion():
    clip = bvh.load(cmu_clips()[-1])
    n = clip.num_frames
    drift = np.linspace(0.0, 1.0, n)  # 1 m and 0.5 rad of slow drift over the clip
    turn = torch.from_numpy(0.5 * drift)
    q = quat_multiply(yaw_quat(turn), torch.from_numpy(clip.rotations[:, 0])).numpy()
    rotations = clip.rotations.copy()
    rotations[:, 0] = q
    drifted = clip.with_frames(rotations, clip.root + drift[:, None] * [1.0, 0.0, -0.5], clip.translations)
    fixed = anchor_root(drifted, clip, np.ones(n, bool))
    assert np.abs(fixed.root - clip.root).max() < 0.02 < np.abs(drifted.root - clip.root).max()
    assert np.allclose(anchor_root(clip, clip, np.ones(n, bool)).root, clip.root)
    # Only the first half known: the correction measured there is held over the rest.
    half = anchor_root(drifted, clip, np.arange(n) < n // 2)
    assert np.abs(half.root[: n // 3] - clip.root[: n // 3]).max() < 0.03


def test_encoder_reconstruction_of_a_long_clip_follows_the_input_path(prior):
    clip = bvh.load(cmu_clips()[-1])
    assert clip.num_frames * prior.spec.fps / clip.fps > 2 * prior.window  # several windows
    out = reconstruct(prior, clip, InversionOptions()).motion
    root_error = np.linalg.norm(out.root[:, [0, 2]] - clip.root[:, [0, 2]], axis=-1)
    assert root_error.mean() < 0.1


def test_interpolation_between_clips_of_different_lengths(prior):
    """Each step lasts the blend of the two lengths; the first as long as A, the last as B."""
    from problems.latent import interpolate, played_at

    a, b = (bvh.load(p) for p in cmu_clips())
    b = b[: a.num_frames * 2 // 3]
    steps = interpolate(prior, a, b, 3)
    assert steps[0].motion.num_frames == a.num_frames
    assert steps[-1].motion.num_frames == pytest.approx(b.num_frames * a.fps / b.fps, abs=2)
    lengths = sorted((steps[0].motion.num_frames, steps[-1].motion.num_frames))
    assert steps[0].motion.num_frames != steps[-1].motion.num_frames
    assert lengths[0] < steps[1].motion.num_frames < lengths[1]
    x = tiny_dataset().windows("train", WINDOW, 4)[0]
    assert torch.allclose(played_at(prior, x, np.arange(len(x), dtype=float)), x, atol=1e-5)
    slow = Codec.of(prior).raw(played_at(prior, x, np.linspace(0, len(x) - 1, 2 * len(x))).double())
    steps_sum = slow[:, prior.spec.slices()["root_delta"]].sum(0)
    assert torch.allclose(steps_sum, Codec.of(prior).raw(x.double())[:, prior.spec.slices()["root_delta"]].sum(0),
                          rtol=0.05, atol=0.02)


def test_edit_solve_reaches_the_goal_that_the_plain_step_misses(prior):
    """A crouch at +2 asks for hips 6 cm lower: the solve gets the generated clip nearer
    that goal than the unedited clip and than MoDi's plain step; the arms, which a crouch
    leaves alone, move less than the legs."""
    from problems.latent_edit import CROUCH_M_PER_UNIT, goal_of, kept_dims, latent_edit, leg_joints

    clip = bvh.load(cmu_clips()[0])
    solved = latent_edit(prior, clip, "crouch", 2.0).metrics
    assert solved["goal_target"] == pytest.approx(solved["goal_unedited"] - 2 * CROUCH_M_PER_UNIT, abs=1e-6)
    assert abs(solved["goal_reached"] - solved["goal_target"]) < 0.5 * abs(solved["goal_unedited"] - solved["goal_target"])
    step = latent_edit(prior, clip, "crouch", 2.0, iters=0)
    unedited = latent_edit(prior, clip, "crouch", 0.0)
    hips = {k: Codec.of(prior).model_motion(r.motion).positions()[:, 0, 1].mean() for k, r in
            (("solved", latent_edit(prior, clip, "crouch", 2.0)), ("step", step), ("unedited", unedited))}
    assert hips["unedited"] - hips["solved"] > max(hips["unedited"] - hips["step"], 0.02)
    legs = leg_joints(prior)
    assert set(prior.spec.contact_joints) <= legs and prior.spec.joints[0] not in legs
    kept = kept_dims(prior, goal_of(prior, "crouch").free)
    assert len(kept) == 6 * (len(prior.spec.joints) - 1 - len(legs))
    names = prior.spec.joints
    arms = [j for j, n in enumerate(names) if "Arm" in n or "Hand" in n]
    leg_idx = [j for j, n in enumerate(names) if n in legs]
    moved = [np.abs(Codec.of(prior).model_motion(r.motion).rotations - Codec.of(prior).model_motion(unedited.motion).rotations)
             for r in (latent_edit(prior, clip, "crouch", 2.0),)][0]
    assert moved[:, arms].mean() < moved[:, leg_idx].mean()


def test_as_decoded_leaves_real_motion_alone_and_squares_up_rotations(prior):
    """Features of a real motion are already what decoding gives; a skewed 6D pair is
    made orthonormal, which is what the written motion would show."""
    from problems.latent_edit import as_decoded

    codec = Codec.of(prior)
    x = codec.features(codec.model_motion(bvh.load(cmu_clips()[0])))[:40]
    assert torch.allclose(as_decoded(codec, x), x, atol=1e-3)
    skew = x.clone()
    skew[:, prior.spec.slices()["joint_rotations"]] += 0.5
    fixed = as_decoded(codec, skew)
    assert torch.allclose(codec.positions(fixed), codec.positions(skew), atol=1e-4)
    assert (fixed - x).abs().mean() < (skew - x).abs().mean()


def test_interpolation_ends_stand_where_their_inputs_do(prior):
    """The last step of an interpolation starts where B starts and faces B's way, not A's."""
    from motionopt.features import heading_angle, wrap_angle
    from motionopt.rotations import quat_apply
    from problems.latent import interpolate

    a, b = (bvh.load(p) for p in cmu_clips())
    q = yaw_quat(torch.tensor(1.5, dtype=torch.float64))
    rot = b.rotations.copy()
    rot[:, 0] = quat_multiply(q, torch.from_numpy(rot[:, 0])).numpy()
    root = b.root[0] + quat_apply(q.expand(b.num_frames, 4), torch.from_numpy(b.root - b.root[0])).numpy()
    turned = b.with_frames(rot, root + np.array([3.0, 0.0, -2.0]), b.translations)
    steps = interpolate(prior, a, turned, 3)

    def heading(m) -> float:
        return float(heading_angle(torch.from_numpy(m.rotations[:1, 0]))[0])

    for out, given in ((steps[0].motion, a), (steps[-1].motion, turned)):
        assert np.linalg.norm(out.root[0, [0, 2]] - given.root[0, [0, 2]]) < 0.1
        assert abs(float(wrap_angle(torch.tensor(heading(out) - heading(given))))) < 0.2
    mid = steps[1].motion.root[0, [0, 2]]
    assert np.linalg.norm(mid - (a.root[0, [0, 2]] + turned.root[0, [0, 2]]) / 2) < 0.2


def test_latent_density_scores_real_motion_above_a_noisy_copy(prior):
    """As the MAP solver's prior term the latent prior scores each frame around its
    reconstruction G(I(x)): a clip scores better than the same clip with 3 cm of joint
    noise, the score is differentiable in the frames, and contacts come out as probabilities."""
    from motionopt.noise import position_noise
    from priors.latent_density import LatentDensity

    density = LatentDensity(prior)
    codec = Codec.of(prior)
    clip = codec.model_motion(bvh.load(cmu_clips()[0]))
    noisy, _ = position_noise(clip, 0.03, seed=1)
    x, xn = codec.features(clip), codec.features(noisy)
    assert float(density.nll(x[1:], x[:1]).mean()) < float(density.nll(xn[1:], xn[:1]).mean())
    window = x[10:30].clone().requires_grad_(True)
    nll, contacts = density.nll_and_contacts(window, x[:10])
    assert nll.shape == (20,) and contacts.shape == (20, prior.spec.num_contacts)
    assert float(contacts.min()) >= 0 and float(contacts.max()) <= 1
    nll.sum().backward()
    assert torch.isfinite(window.grad).all() and float(window.grad.abs().sum()) > 0
    batched = density.nll(torch.stack((x[10:30], xn[10:30])), x[:10])
    assert torch.allclose(batched[0], nll.detach(), atol=1e-4)
    with pytest.raises(NotImplementedError, match="autoregressive"):
        density.sample(x[:10], 5)


def test_between_blends_starts_the_short_way_round():
    from motionopt.features import RootStart
    from problems.latent import between

    a, b = RootStart(3.0, 0.0, 1.0, 0.0), RootStart(-3.0, 2.0, -1.0, 0.1)
    assert between(a, b, 0.0) == a
    end = between(a, b, 1.0)
    assert (end.x, end.z, end.ground) == pytest.approx((2.0, -1.0, 0.1))
    assert np.cos(end.yaw - b.yaw) == pytest.approx(1.0)
    mid = between(a, b, 0.5)
    assert np.cos(mid.yaw - np.pi) == pytest.approx(1.0, abs=1e-3)  # through pi, not through 0
    assert (mid.x, mid.z) == pytest.approx((1.0, 0.0))


def test_latent_inbetweening_solves_the_gap_and_keeps_the_kept_frames(prior):
    """With the MAP solve (the default) the kept frames are the input's exactly and the
    gap's objective goes down; without it the output is the inversion's."""
    from problems.latent import LatentTask

    clip = bvh.load(cmu_clips()[0])
    a, b = clip.num_frames // 3, clip.num_frames // 2
    task = LatentTask(clip, prior, [(0, a), (b, clip.num_frames)])
    result = task.solve()
    assert np.allclose(result.motion.rotations[:a], clip.rotations[:a])
    assert np.allclose(result.motion.root[b:], clip.root[b:])
    assert result.metrics["map_objective"] < result.metrics["map_objective_start"]
    assert any("MAP solve" in line for line in task.summary(result))
    plain = LatentTask(clip, prior, [(0, a), (b, clip.num_frames)], map_options=None).solve()
    assert "map_objective" not in plain.metrics
    assert not np.allclose(plain.motion.rotations[:a], clip.rotations[:a])


def test_masked_context_lets_the_first_frames_reach_the_last_code(prior):
    """With its GRU, the masked encoder's last code depends on the window's first frames;
    convolutions alone see only about 6 frames either side of a code."""
    x = tiny_dataset().windows("train", WINDOW, 4)[:1]
    mask = torch.zeros(1, WINDOW)
    mask[:, :4] = 1
    moved = x + 0.5 * mask[..., None]
    assert prior.config.masked_context == 1
    assert not torch.allclose(prior.encode_masked(x, mask)[:, -1], prior.encode_masked(moved, mask)[:, -1], atol=1e-5)
    local = LatentPrior(prior.spec, prior.normalizer, prior.skeleton, replace(prior.config, masked_context=0))
    assert torch.allclose(local.encode_masked(x, mask)[:, -1], local.encode_masked(moved, mask)[:, -1], atol=1e-6)


def test_configs_stored_before_the_masked_context_load_without_it():
    stored = {k: v for k, v in LatentConfig().to_dict().items() if k != "masked_context"}
    assert LatentConfig.from_dict(stored).masked_context == 0


def test_retraining_only_the_masked_encoder_keeps_the_rest(trained, tmp_path):
    start = load_prior(trained[0])
    out = tmp_path / "remasked.pt"
    cfg = config(init=str(trained[0]), phases=("masked",), masked_epochs=1,
                 model=replace(start.config, masked_context=2))
    train_latent(tiny_dataset(), out, cfg, metadata={"licence": "test licence"}, progress=False)
    new = load_prior(out)
    assert new.config.masked_context == 2
    assert [r["phase"] for r in new.metadata["history"]] == ["masked"]
    assert new.metadata["init"]["weights_new"] > 0
    for part in ("generator", "encoder"):
        for (k, a), b in zip(getattr(start, part).state_dict().items(), getattr(new, part).state_dict().values()):
            assert torch.equal(a, b), k
    assert torch.equal(start.w_components, new.w_components)
    assert new.metadata["attribute_directions"] == start.metadata["attribute_directions"]
    assert not torch.equal(start.masked_encoder.inp.weight, new.masked_encoder.inp.weight)


def test_phases_are_checked():
    with pytest.raises(ValueError, match="needs a trained checkpoint"):
        LatentTrainConfig(phases=("masked",))
    with pytest.raises(ValueError, match="in that order"):
        LatentTrainConfig(phases=("masked", "autoencoder"))


def test_variations_keep_the_input_and_add_what_the_offset_changes(prior):
    """At sigma 0 ``vary`` gives the input back (its detail is not lost to the round
    trip); at sigma 0.5 the variations differ from it and from each other."""
    from problems.latent import vary

    clip = bvh.load(cmu_clips()[0])
    clip = clip[: int(3 * clip.fps)]
    codec = Codec.of(prior)
    model = codec.model_motion(clip).positions()
    same = codec.model_motion(vary(prior, clip, 1, 0.0)[0].motion).positions()
    trip = codec.model_motion(reconstruct(prior, clip, InversionOptions()).motion).positions()
    assert np.abs(same - model).max() < 1e-3
    assert np.abs(trip - model).mean() > 10 * np.abs(same - model).mean()
    outs = [codec.model_motion(r.motion).positions() for r in vary(prior, clip, 2, 0.5)]
    assert all(np.linalg.norm(p - model, axis=-1).mean() > 0.005 for p in outs)
    assert np.linalg.norm(outs[0] - outs[1], axis=-1).mean() > 0.005


def test_vary_and_interpolate_settle_under_the_autoregressive_prior(trained, tmp_path, capsys):
    """By default each variation (and each step between the ends) is settled under the
    shipped autoregressive prior and its report says by how much; --no-settle writes the
    generated motion; a latent checkpoint is refused as --settle-prior."""
    ckpt = str(trained[0])
    b = str(cmu_clips()[1])
    runs = {}
    for flag in ([], ["--no-settle"]):
        report = tmp_path / f"vary{len(flag)}.json"
        argv = ["vary", b, "--count", "1", "--out-dir", str(tmp_path / f"v{len(flag)}"), "--prior", ckpt,
                "--report", str(report), "-q", *flag]
        assert main(argv) == 0, capsys.readouterr().err
        runs[bool(flag)] = json.loads(report.read_text())["outputs"][0]
    settled, generated = runs[False], runs[True]
    assert "settle_change_cm" not in generated["metrics"]
    assert 0 < settled["metrics"]["settle_change_cm"] < 10
    assert settled["metrics"]["settle_nll"] < settled["metrics"]["settle_nll_start"]
    moved = (bvh.load(settled["output"]).positions() - bvh.load(generated["output"]).positions())
    assert np.abs(moved).max() > 1e-3
    argv = ["vary", b, "--count", "1", "--out-dir", str(tmp_path / "x"), "--prior", ckpt, "--settle-prior", ckpt]
    assert main(argv) == 1 and "needs an autoregressive prior" in capsys.readouterr().err
    assert main(argv + ["--no-settle"]) == 1 and "drop --settle-prior or --no-settle" in capsys.readouterr().err


def test_inbetweening_starts_from_the_masked_encoder_too_and_keeps_the_lowest_objective(prior):
    """With a latent prior, in-betweening's MAP solve starts from the rollouts and from the
    masked encoder's two fills of a long gap, and keeps the lowest objective of the
    results with the fewest seconds outside the range of human motion: never above the
    rollouts' own solve, which is the first start, unless that one has more. A gap shorter than
    LATENT_SEED_MIN_SECONDS is seeded by the rollouts alone."""
    from problems.inbetween import Inbetween
    from problems.latent import LATENT_SEED_MIN_SECONDS
    from priorkit import tiny_prior

    ar = tiny_prior()
    clip = bvh.load(cmu_clips()[0])
    long_gap = int(np.ceil(2 * LATENT_SEED_MIN_SECONDS * clip.fps))
    keep = [(0, 30), (30 + long_gap, 30 + long_gap + 10)]
    seg = clip[:keep[-1][1]]
    alone = Inbetween(seg, keep, ar).solve()
    seeded = Inbetween(seg, keep, ar, latent=prior).solve()
    assert len(seeded.solver.starts_fun) == 3 and alone.solver.starts_fun == [alone.solver.fun]
    assert seeded.solver.starts_fun[0] == pytest.approx(alone.solver.fun)
    assert_kept_the_best_sound_start(seeded.solver)
    assert seeded.solver.fun <= alone.solver.fun or min(seeded.solver.starts_faults) < seeded.solver.starts_faults[0]
    for a, b in keep:
        assert np.array_equal(seeded.motion.rotations[a:b], seg.rotations[a:b])
    short = [(0, 30), (33, 43)]
    assert len(Inbetween(clip[:43], short, ar, latent=prior).solve().solver.starts_fun) == 1


def test_completion_starts_from_the_latent_continuation_too(prior):
    """With a latent prior, prefix completion's MAP solve also starts from the latent
    prior's continuation settled under the autoregressive prior: one start more than the
    rollouts', which come first as without it; the prefix is the input's."""
    from problems.inbetween import COMPLETION_ROLLOUT_STARTS, complete as complete_ar
    from priorkit import tiny_prior

    ar = tiny_prior()
    clip = bvh.load(cmu_clips()[0])[:120]
    alone = complete_ar(clip, 60, 150, ar).solve()
    seeded = complete_ar(clip, 60, 150, ar, latent=prior).solve()
    assert len(seeded.solver.starts_fun) == COMPLETION_ROLLOUT_STARTS + 1
    assert seeded.solver.starts_fun[:-1] == pytest.approx(alone.solver.starts_fun)
    assert_kept_the_best_sound_start(seeded.solver)
    assert seeded.motion.num_frames == 150 and np.array_equal(seeded.motion.rotations[:60], clip.rotations[:60])


def test_latent_completion_settles_the_new_frames_and_holds_the_prefix(trained, tmp_path, capsys):
    """complete --method latent settles the frames after the prefix under the shipped
    autoregressive prior by default, its report saying by how much, with the prefix exactly
    the input's; --no-settle writes them as the latent prior made them; --settle-prior
    without --method latent is refused. Either way each second of the output is judged
    against the autoregressive prior's held-out range, as the autoregressive tasks' are."""
    clip = str(cmu_clips()[0])
    runs = {}
    for flag in ([], ["--no-settle"]):
        out, report = tmp_path / f"c{len(flag)}.bvh", tmp_path / f"c{len(flag)}.json"
        argv = ["complete", clip, "--prefix", "40", "--frames", "100", "--method", "latent", "--prior",
                str(trained[0]), "--out", str(out), "--report", str(report), "-q", *flag]
        assert main(argv) == 0, capsys.readouterr().err
        rep = json.loads(report.read_text())
        assert len(rep["per_second"]) == 1 and rep["human_range"] is not None  # 100 frames at 120 fps: 1 s at 30
        assert set(rep["per_second"][0]) >= {"nll_per_frame", "skating_m_per_s", "hip_height_m"}
        runs[bool(flag)] = (bvh.load(out), rep["metrics"])
    (settled, m_settled), (made, m_made) = runs[False], runs[True]
    source = bvh.load(clip)
    assert np.array_equal(settled.rotations[:40], source.rotations[:40])
    assert np.array_equal(settled.root[:40], source.root[:40])
    assert "settle_change_cm" not in m_made and 0 < m_settled["settle_change_cm"] < 10
    assert np.abs(settled.positions()[40:] - made.positions()[40:]).max() > 1e-3
    argv = ["complete", clip, "--prefix", "40", "--frames", "100", "--settle-prior", "x", "--out",
            str(tmp_path / "x.bvh")]
    assert main(argv) == 1 and "add --method latent" in capsys.readouterr().err


def test_latent_inbetweening_also_starts_a_long_gap_from_the_encoders_fill(prior):
    """A refined inversion's gap of at least LATENT_SEED_MIN_SECONDS is also solved from
    the encoder's own fill and the lowest objective kept; a shorter gap, or an inversion
    that is the encoder's alone, has one start. Kept frames stay the input's."""
    from problems.latent import LATENT_SEED_MIN_SECONDS, LatentTask

    clip = bvh.load(cmu_clips()[0])
    long_gap = int(np.ceil(2 * LATENT_SEED_MIN_SECONDS * clip.fps))
    keep = [(0, 30), (30 + long_gap, 30 + long_gap + 10)]
    seg = clip[:keep[-1][1]]
    refined = InversionOptions(refine_iters=5)
    result = LatentTask(seg, prior, keep, refined).solve()
    starts = result.metrics["map_starts_objective"]
    assert len(starts) == 2 and result.metrics["map_objective"] == min(starts)
    assert result.per_second == [] and result.naturalness_line() is None  # no judge prior given
    for a, b in keep:
        assert np.array_equal(result.motion.rotations[a:b], seg.rotations[a:b])
    assert len(LatentTask(seg, prior, keep).solve().metrics["map_starts_objective"]) == 1
    short = [(0, 30), (33, 43)]
    assert len(LatentTask(clip[:43], prior, short, refined).solve().metrics["map_starts_objective"]) == 1
