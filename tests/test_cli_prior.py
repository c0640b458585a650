"""The prior commands: score, prior-info, train-prior, run as a user runs them."""
from __future__ import annotations

import json

import pytest
import torch

from motionopt import bvh
from motionopt.app.cli import main
from priors.checkpoint import CHECKPOINT_DIR, read_checkpoint, save_prior
from priors.score import score_motion

from priorkit import cmu_clip, cmu_clips, tiny_prior
from clips import DATA, CMU_60, BANDAI_30


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory):
    path = tmp_path_factory.mktemp("ckpt") / "tiny.pt"
    save_prior(tiny_prior(), path)
    return path


def run(capsys, *argv) -> tuple[int, str, str]:
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def score_json(capsys, clip, ckpt, *extra) -> dict:
    rc, out, err = run(capsys, "score", clip, "--prior", ckpt, "--json", *extra)
    assert rc == 0, err
    return json.loads(out)


@pytest.mark.parametrize("fps", [120, 60])
def test_score_prints_nll_per_frame_for_any_frame_rate(capsys, ckpt, fps):
    clip = cmu_clip(fps)
    report = score_json(capsys, clip, ckpt)
    motion = bvh.load(clip)
    assert report["nll_per_frame"] == pytest.approx(score_motion(tiny_prior(), motion).nll_per_frame, rel=1e-5, abs=1e-4)
    assert report["frames"] == motion.num_frames and report["prior_fps"] == 30.0
    ranges = sorted((w["start"], w["stop"]) for w in report["worst"])
    assert 1 <= len(ranges) <= 3
    for (a, b), nxt in zip(ranges, ranges[1:] + [(motion.num_frames, None)]):
        assert 0 <= a and b <= nxt[0]  # in the clip and not overlapping
        assert b - a == pytest.approx(fps, abs=1)  # one second, in the file's own frame numbers
    means = [w["nll_per_frame"] for w in report["worst"]]
    assert means == sorted(means, reverse=True) and means[0] > report["nll_per_frame"]


def test_score_resamples_to_the_prior_rate(capsys, ckpt, tmp_path):
    clip = cmu_clip(120)
    at30 = tmp_path / "at30.bvh"
    bvh.save(bvh.load(clip).resample(30.0), at30)
    a, b = score_json(capsys, clip, ckpt), score_json(capsys, at30, ckpt)
    assert a["nll_per_frame"] == pytest.approx(b["nll_per_frame"], abs=1e-3 * abs(b["nll_per_frame"]))
    assert [w["start"] for w in a["worst"]] == [4 * w["start"] for w in b["worst"]]


def test_score_frame_rate_override_changes_what_the_prior_sees(capsys, ckpt):
    clip = cmu_clip(60)
    normal, fast = score_json(capsys, clip, ckpt), score_json(capsys, clip, ckpt, "--fps", "120")
    assert fast["frames"] == normal["frames"]
    assert fast["worst"][0]["stop"] - fast["worst"][0]["start"] == 120
    assert fast["nll_per_frame"] != pytest.approx(normal["nll_per_frame"], rel=1e-3)


def test_score_of_a_clip_shorter_than_a_window(capsys, ckpt, tmp_path):
    short = tmp_path / "short.bvh"
    bvh.save(bvh.load(cmu_clips()[0])[:12], short)
    report = score_json(capsys, short, ckpt)
    assert len(report["worst"]) == 1
    worst = report["worst"][0]
    assert (worst["start"], worst["stop"]) == (0, 12)
    per = score_motion(tiny_prior(), bvh.load(short)).per_frame
    assert worst["nll_per_frame"] == pytest.approx(per.mean())


def test_score_text_output(capsys, ckpt):
    rc, out, _ = run(capsys, "score", cmu_clips()[0], "--prior", ckpt)
    assert rc == 0 and "nats per frame under tiny.pt" in out and "\nleast natural 1 s stretches" in out
    assert "  frames 0:120 (0.0-1.0 s)" in out


def test_score_heading_gives_whole_seconds_at_ntsc_rate(capsys, ckpt, tmp_path):
    ntsc = tmp_path / "ntsc.bvh"
    bvh.save(bvh.load(cmu_clips()[0]).resample(29.97), ntsc)
    rc, out, _ = run(capsys, "score", ntsc, "--prior", ckpt)
    assert rc == 0 and "\nleast natural 1 s stretches" in out, out


def test_score_refuses_a_skeleton_the_prior_does_not_model(capsys, ckpt, tmp_path):
    legless = tmp_path / "legless.bvh"
    bvh.save(bvh.load(cmu_clips()[0]).remove_joints(["lThigh", "lShin", "lFoot"]), legless)
    rc, out, err = run(capsys, "score", legless, "--prior", ckpt)
    assert rc == 1 and out == ""
    assert "lacks lThigh, lShin, lFoot" in err and "train-prior" in err and len(err.splitlines()) == 1


@pytest.mark.parametrize("clip, expected", [(CMU_60, "cmu-ccnet.pt"),
                                             (BANDAI_30, "bandai-locomotion-ccnet.pt")])
def test_score_picks_the_shipped_prior_of_the_skeleton(capsys, clip, expected):
    if not (CHECKPOINT_DIR / expected).exists() or not (DATA / clip).exists():
        pytest.skip(f"needs the shipped {expected} and tests/data/{clip}")
    rc, out, err = run(capsys, "score", DATA / clip, "--json")
    assert rc == 0, err
    report = json.loads(out)
    assert report["prior"] == str(CHECKPOINT_DIR / expected)
    assert report["prior_fps"] == read_checkpoint(CHECKPOINT_DIR / expected)["spec"]["fps"]
    assert report["frames"] == bvh.load(DATA / clip).num_frames


@pytest.mark.parametrize("kind", ["latent", "ccnet"])
def test_score_takes_a_shipped_prior_by_name_and_says_which_kind_it_needs(capsys, kind):
    name = f"cmu-{kind}.pt"
    if not (CHECKPOINT_DIR / name).exists():
        pytest.skip(f"needs the shipped {name}")
    rc, out, err = run(capsys, "score", DATA / CMU_60, "--prior", name, "--json")
    if kind == "ccnet":
        assert rc == 0, err
        assert json.loads(out)["prior"] == str(CHECKPOINT_DIR / name)
        return
    assert rc == 1 and out == ""
    line, = err.strip().splitlines()
    assert f"{name} is a latent (W+) prior; score needs an autoregressive prior" in line
    assert "cmu-ccnet.pt, bandai-locomotion-ccnet.pt" in line and "train-prior" in line


def test_prior_info_takes_a_shipped_checkpoint_by_name_and_lists_them(capsys):
    if not (CHECKPOINT_DIR / "cmu-ccnet.pt").exists():
        pytest.skip("needs the shipped cmu-ccnet.pt")
    rc, out, err = run(capsys, "prior-info", "cmu-ccnet.pt", "--json")
    assert rc == 0, err
    assert json.loads(out)["kind"] == "CCNetPrior"
    rc, out, err = run(capsys, "prior-info", "no-such.pt")
    assert rc == 1 and "does not exist" in err and "cmu-ccnet.pt" in err and "--list" in err
    rc, out, err = run(capsys, "prior-info", "--list", "--json")
    assert rc == 0, err
    listed = {r["name"]: r for r in json.loads(out)}
    shipped = [p.name for p in CHECKPOINT_DIR.glob("*.pt")]
    assert set(listed) == set(shipped)
    assert listed["cmu-ccnet.pt"]["kind"] == "autoregressive" and listed["cmu-ccnet.pt"]["fps"] == 30.0
    assert listed["cmu-latent.pt"]["kind"] == "latent (W+)" and listed["cmu-latent.pt"]["megabytes"] > 0
    rc, out, err = run(capsys, "prior-info", "--list")
    assert rc == 0 and out.split()[:5] == ["name", "kind", "skeleton", "fps", "size"]
    assert all(name in out for name in shipped)


def test_prior_info_prints_licence_and_metadata(capsys, ckpt):
    rc, out, _ = run(capsys, "prior-info", ckpt)
    assert rc == 0
    assert "licence: test licence" in out and "feature_version: 1" in out
    rc, out, _ = run(capsys, "prior-info", ckpt, "--json")
    info = json.loads(out)
    assert info["licence"] == "test licence"
    assert info["parameters"] == sum(p.numel() for p in tiny_prior().state_dict().values())
    assert info["joints"] == list(tiny_prior().spec.joints)


def test_prior_info_refuses_an_old_feature_version(capsys, ckpt, tmp_path):
    data = read_checkpoint(ckpt)
    data["spec"]["version"] = 0
    old = tmp_path / "old.pt"
    torch.save(data, old)
    rc, out, err = run(capsys, "prior-info", old)
    assert rc == 1 and "feature version 0" in err and "train-prior" in err


def test_shipped_locomotion_prior_says_it_is_non_commercial(capsys):
    path = CHECKPOINT_DIR / "bandai-locomotion-ccnet.pt"
    if not path.exists():
        pytest.skip("shipped Bandai prior not built")
    rc, out, _ = run(capsys, "prior-info", path)
    assert rc == 0 and "NON-COMMERCIAL" in out and "Bandai Namco Research" in out


def test_train_prior_command_writes_a_usable_checkpoint(capsys, tmp_path):
    clips = cmu_clips()
    out = tmp_path / "cli.pt"
    rc, _, err = run(capsys, "train-prior", "--data", DATA, "--include", *[c.name for c in clips], "--val",
                     clips[-1].name, "--out", out, "--epochs", "1", "--window", "32", "--licence", "CC0 test", "-q")
    assert rc == 0, err
    rc, text, _ = run(capsys, "prior-info", out, "--json")
    info = json.loads(text)
    assert info["licence"] == "CC0 test" and info["epochs"] == 1
    assert info["validation_clips"] == [clips[-1].name] and info["train_clips"] == len(clips) - 1
    assert info["training_command"].startswith("motionopt train-prior --data ")
    assert "--epochs 1 " in info["training_command"] and "--licence 'CC0 test'" in info["training_command"]
    assert score_json(capsys, clips[0], out)["frames"] == bvh.load(clips[0]).num_frames


def test_train_prior_records_model_options_and_its_command_reproduces_them(capsys, tmp_path):
    import shlex

    from motionopt.app.cli import build_parser
    from motionopt.app.cli.prior import train_config

    clips = cmu_clips()[:3]
    out = tmp_path / "small.pt"
    rc, _, err = run(capsys, "train-prior", "--data", DATA, "--include", *[c.name for c in clips], "--val",
                     clips[-1].name, "--out", out, "--epochs", "1", "--window", "32", "--channels", "16",
                     "--log-std-min", "-3", "--input-dropout", "0.2", "-q")
    assert rc == 0, err
    data = read_checkpoint(out)
    cfg = data["config"]
    assert (cfg["channels"], cfg["skip_channels"], cfg["log_std_min"], cfg["input_dropout"]) == (16, 32, -3.0, 0.2)
    command = data["metadata"]["training_command"]
    assert "--channels 16" in command and "--log-std-min -3" in command and "--noise-std" not in command
    again = train_config(build_parser().parse_args(shlex.split(command)[1:]))
    assert again.model.to_dict() == cfg and again.epochs == 1 and again.window == 32


def test_train_prior_defaults_are_the_configs_defaults():
    from motionopt.app.cli.prior import TRAIN_DEFAULTS
    from priors.ccnet import CCNetConfig
    from priors.train import TrainConfig

    train, model = TrainConfig(), CCNetConfig()
    assert model.skip_channels == 2 * model.channels
    for key, value in TRAIN_DEFAULTS.items():
        assert getattr(train if hasattr(train, key) else model, key) == value, key


def test_score_copies_lists_every_degraded_copy(capsys, ckpt):
    report = score_json(capsys, DATA / CMU_60, ckpt, "--copies")
    assert set(report["copies"]) == {"noise 1 cm", "low-pass 2 Hz", "low-pass 1 Hz", "frozen", "half speed",
                                     "double speed"}
    assert all(isinstance(v, float) for v in report["copies"].values())
    rc, out, _ = run(capsys, "score", DATA / CMU_60, "--prior", ckpt, "--copies")
    assert rc == 0 and out.count("nats per frame:") == 6


@pytest.mark.parametrize("clip", ["bandai2/dataset-2_walk_normal_002.bvh", "bandai2/dataset-2_run_active_002.bvh",
                                  "bandai/dataset-1_walk-left_feminine_001.bvh"])
def test_shipped_bandai_prior_ranks_held_out_capture_above_its_degraded_copies(capsys, clip):
    """Issue 21's first test on clips the shipped prior held out (needs ../shared/data)."""
    from clips import SHARED

    if not (SHARED / clip).exists():
        pytest.skip(f"needs {SHARED / clip}")
    report = score_json(capsys, SHARED / clip, "bandai-locomotion-ccnet.pt", "--copies")
    assert clip in read_checkpoint(CHECKPOINT_DIR / "bandai-locomotion-ccnet.pt")["metadata"]["validation_clips"]
    worse = {k: v for k, v in report["copies"].items() if v <= report["copy_scored_nll_per_frame"]}
    assert not worse, f"scored as natural as the clip or more: {worse}"
