"""The prior feature representation: exact decoding over whole clips, gradients, contact labels."""
from __future__ import annotations

import functools
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from motionopt import bvh
from motionopt.features import (FeatureSpec, contact_heights, contact_labels, decode, decode_positions, default_spec, encode,
                                estimate_ground, floored_root_height, planted_root_step, to_model_motion)
from clips import DATA, CMU_120, BANDAI_30

MARTIAL = DATA / CMU_120
BANDAI = DATA / BANDAI_30
SHARED_CMU = Path(__file__).parent.parent.parent / "shared" / "data" / "cmu" / "martial" / "03.bvh"


@functools.lru_cache(maxsize=None)
def encoded(path: Path):
    """The clip, its default spec, its model motion, features and decoding start (cached: read-only)."""
    motion = bvh.load(path)
    spec = default_spec(motion.skeleton)
    model = to_model_motion(motion, spec)
    x, start = encode(model, spec)
    return motion, spec, model, x, start


def test_default_spec_on_cmu_drops_fingers_and_eyes():
    spec = default_spec(bvh.load(MARTIAL).skeleton)
    assert len(spec.joints) == 21 and spec.joints[0] == "hip"
    assert not any("Thumb" in n or "Eye" in n for n in spec.joints)
    assert spec.contact_joints == ("rFoot", "lFoot") and spec.fps == 30.0
    assert spec.dim == 10 + 6 * 20 + 2
    assert FeatureSpec.from_dict(spec.to_dict()) == spec


@pytest.mark.parametrize("path", [MARTIAL, BANDAI], ids=["cmu", "bandai"])
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_decode_reproduces_world_positions_of_a_whole_clip(path, dtype):
    motion, spec, model, x, start = encoded(path)
    assert x.shape == (model.num_frames, spec.dim)
    pos = decode_positions(x.to(dtype), spec, model.skeleton, start)
    assert pos.dtype == dtype
    assert np.abs(pos.double().numpy() - model.positions()).max() < 1e-3  # metres, every frame: no drift
    if dtype == torch.float64:
        # and they are the file's own joint positions, at every 4th (120 -> 30 fps) or every frame
        step = round(motion.fps / spec.fps)
        idx = [motion.skeleton.index(n) for n in spec.joints]
        ref = motion.positions()[::step][:model.num_frames, idx]
        np.testing.assert_allclose(pos.numpy(), ref, atol=1e-9)


@pytest.mark.skipif(not SHARED_CMU.exists(), reason="../shared/data is absent")
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_decode_of_a_whole_shared_cmu_clip_stays_within_a_millimetre(dtype):
    _, spec, model, x, start = encoded(SHARED_CMU)
    assert model.num_frames > 600  # about 23 seconds at 30 fps
    pos = decode_positions(x.to(dtype), spec, model.skeleton, start).double().numpy()
    err = np.abs(pos - model.positions()).max(axis=(1, 2))
    assert err.max() < 1e-3 and err[-1] < 1e-3


def test_decode_is_differentiable_and_causal():
    _, spec, model, x, start = encoded(MARTIAL)
    base = x[:5].clone()
    cols = list(range(0, 16))  # root features and the first joint's rotation

    def positions(v):
        full = torch.cat((v, base[:, 16:]), dim=-1)
        return decode_positions(full, spec, model.skeleton, start)

    assert torch.autograd.gradcheck(positions, (base[:, cols].clone().requires_grad_(True),))
    v = x[:8].clone().requires_grad_(True)
    pos = decode_positions(v, spec, model.skeleton, start)
    pos[3].sum().backward()
    assert v.grad[:4].abs().sum() > 0 and torch.all(v.grad[4:] == 0)  # frame 3 depends on frames 0..3 only


def test_decode_batched_equals_unbatched():
    _, spec, model, x, start = encoded(MARTIAL)
    batch = torch.stack((x[:20], x[20:40], x[40:60]))
    rot, root = decode(batch, spec, start)
    for b in range(3):
        r, p = decode(batch[b], spec, start)
        torch.testing.assert_close(rot[b], r, rtol=0, atol=1e-12)
        torch.testing.assert_close(root[b], p, rtol=0, atol=1e-12)


def test_encode_wants_the_prior_joints():
    motion = bvh.load(MARTIAL)
    with pytest.raises(ValueError, match="to_model_motion"):
        encode(motion, default_spec(motion.skeleton))


def test_bandai_model_motion_is_rooted_at_the_hips_at_30_fps():
    motion, spec, model, _, _ = encoded(BANDAI)
    assert spec.joints[0] == "Hips" and model.skeleton.names == spec.joints
    assert model.translations is None and model.fps == 30.0 and model.num_frames == motion.num_frames


def test_contact_labels_follow_the_feet():
    motion, spec, model, x, _ = encoded(MARTIAL)
    c = x[:, spec.slices()["contacts"]].numpy()
    assert set(np.unique(c)) <= {0.0, 1.0}
    pos = model.positions()
    feet = pos[:, spec.contact_indices()]
    speed = np.zeros(c.shape)
    speed[1:] = np.linalg.norm(np.diff(feet, axis=0), axis=-1) * model.fps
    height = feet[..., 1] - feet[..., 1].min(axis=0)
    lifted = height > spec.contact_height + 0.03
    resting = (height < 0.01) & (speed < 0.5 * spec.contact_speed)
    resting[0] = False  # the first frame's speed is copied from the second
    # a foot that leaves the ground is not in contact; one resting at its lowest is
    assert lifted.sum() >= 5 and resting.sum() >= 5
    assert np.all(c[lifted] == 0) and np.all(c[resting] == 1)


def test_contact_thresholds_are_parameters_that_change_labels():
    _, spec, model, _, _ = encoded(MARTIAL)
    pos = model.positions()
    idx = spec.contact_indices()
    ground = estimate_ground(pos, idx)

    def labels(height, speed):
        return contact_labels(pos, idx, model.fps, ground, height, speed)

    default = labels(spec.contact_height, spec.contact_speed)
    assert labels(1e-4, spec.contact_speed).sum() < default.sum()  # stricter height
    assert labels(spec.contact_height, 0.05).sum() < default.sum()  # stricter speed
    assert labels(10.0, 100.0).all()  # anything goes
    assert not labels(-1.0, spec.contact_speed).any()
    # the spec carries the thresholds into the features
    strict = replace(spec, contact_height=0.005, contact_speed=0.1)
    x_strict, _ = encode(model, strict)
    assert x_strict[:, strict.slices()["contacts"]].sum() < default.sum()


@pytest.mark.parametrize("path", [MARTIAL, BANDAI], ids=["cmu", "bandai"])
def test_planted_root_step_is_carried_by_the_lowest_planted_joint(path):
    """Two planted joints needing different steps: the step is the lower one's, each
    weighed by its height over its rest; with an infinite sharpness, their mean."""
    _, spec, model, x, _ = encoded(path)
    s = spec.slices()
    x = x.clone()
    x[:, s["contacts"]] = 0.0
    x[:, s["contacts"].start:s["contacts"].start + 2] = 1.0  # the first two contact joints planted
    t = len(x) // 2
    heights = contact_heights(x[t - 1:t + 1], spec, model.skeleton).amax(0)  # (C,) the higher of both frames
    rest = heights.clone()[None]
    rest[0, 1] -= 0.05  # the second joint 5 cm above its rest, the first on it
    rest[0, 2:] = -10.0  # the others far above theirs: not planted
    prev, new = x[t - 1:t], x[t:t + 1]
    alone = x.clone()
    alone[:, s["contacts"].start + 1] = 0.0
    first_only = planted_root_step(alone[t - 1:t], alone[t:t + 1], spec, model.skeleton)[0, s["root_delta"]]
    second = x.clone()
    second[:, s["contacts"].start] = 0.0
    second_only = planted_root_step(second[t - 1:t], second[t:t + 1], spec, model.skeleton)[0, s["root_delta"]]
    assert torch.linalg.norm(first_only - second_only) > 1e-3  # the two joints need different steps
    both = planted_root_step(prev, new, spec, model.skeleton, rest)[0, s["root_delta"]]
    w = torch.exp(torch.tensor(-5.0, dtype=x.dtype))  # 5 cm over a sharpness of 1 cm
    assert torch.allclose(both, (first_only + w * second_only) / (1 + w), atol=1e-6)
    mean = planted_root_step(prev, new, spec, model.skeleton, rest, sharpness=float("inf"))[0, s["root_delta"]]
    assert torch.allclose(mean, (first_only + second_only) / 2, atol=1e-6)
    with pytest.raises(ValueError, match="sharpness must be positive"):
        planted_root_step(prev, new, spec, model.skeleton, rest, sharpness=0.0)


@pytest.mark.parametrize("path", [MARTIAL, BANDAI], ids=["cmu", "bandai"])
def test_floored_root_height_lifts_a_sunken_body_onto_the_floor_and_leaves_a_standing_one(path):
    _, spec, model, x, _ = encoded(path)
    s = spec.slices()
    frames = x[::40]
    rest = contact_heights(frames, spec, model.skeleton).amin(-1, keepdim=True).expand(-1, len(spec.contact_joints))
    assert torch.equal(floored_root_height(frames, spec, model.skeleton, rest), frames)
    sunk = frames.clone()
    sunk[:, s["root_height"]] -= 0.1
    lifted = floored_root_height(sunk, spec, model.skeleton, rest)
    assert torch.allclose(lifted, frames, atol=1e-6)
    # without a rest height the ground itself is the floor
    below = contact_heights(sunk, spec, model.skeleton).amin(-1)
    ground = floored_root_height(sunk, spec, model.skeleton)
    assert torch.allclose(ground[:, s["root_height"]], sunk[:, s["root_height"]] - below[:, None].clamp_max(0), atol=1e-6)
    assert torch.allclose(contact_heights(ground, spec, model.skeleton).amin(-1).clamp_max(0), torch.zeros(len(frames),
                          dtype=x.dtype), atol=1e-6)


@pytest.mark.parametrize("path", [MARTIAL, BANDAI], ids=["cmu", "bandai"])
def test_settling_brings_a_floating_planted_foot_down_and_leaves_a_flight_in_the_air(path):
    """With ``settle``, a frame lifted 5 cm comes back down when a contact joint is called
    planted, to the lowest planted joint's rest (never a joint below its own rest); with
    no joint planted (a run's flight) it stays up."""
    _, spec, model, x, _ = encoded(path)
    s = spec.slices()
    frames = x[::40].clone()
    heights = contact_heights(frames, spec, model.skeleton)
    rest = heights.amin(-1, keepdim=True).expand(-1, len(spec.contact_joints)).clone()
    frames[:, s["contacts"]] = 0.0
    lowest = heights.argmin(-1)
    frames[torch.arange(len(frames)), s["contacts"].start + lowest] = 1.0   # the lowest joint planted
    lifted = frames.clone()
    lifted[:, s["root_height"]] += 0.05
    settled = floored_root_height(lifted, spec, model.skeleton, rest, settle=True)
    assert torch.allclose(settled, frames, atol=1e-6)
    assert torch.equal(floored_root_height(lifted, spec, model.skeleton, rest), lifted)  # raised only: stays up
    flight = lifted.clone()
    flight[:, s["contacts"]] = 0.0
    assert torch.equal(floored_root_height(flight, spec, model.skeleton, rest, settle=True), flight)
    # a planted joint higher than an unplanted one: lowered only until the unplanted one is at its rest
    other = frames.clone()
    other[:, s["contacts"]] = 0.0
    highest = heights.argmax(-1)
    other[torch.arange(len(frames)), s["contacts"].start + highest] = 1.0
    other[:, s["root_height"]] += 0.05
    down = floored_root_height(other, spec, model.skeleton, rest, settle=True)
    assert torch.allclose(contact_heights(down, spec, model.skeleton).amin(-1), rest[:, 0], atol=1e-6)


@pytest.mark.parametrize("path", [MARTIAL, BANDAI], ids=["cmu", "bandai"])
def test_planted_root_step_holds_the_planted_joint_still(path):
    """A root step pushed off by 10 cm is replaced by the one that keeps the single
    planted contact joint still on the ground plane; unplanted frames keep theirs."""
    _, spec, model, x, start = encoded(path)
    s = spec.slices()
    x = x.clone()
    x[:, s["contacts"]] = 0.0
    x[:, s["contacts"].start] = 1.0  # only the first contact joint planted, in every frame
    j = spec.joints.index(spec.contact_joints[0])
    t = len(x) // 2
    pushed = x[t].clone()
    pushed[s["root_delta"]] += 0.1
    fixed = planted_root_step(x[t - 1:t], pushed[None], spec, model.skeleton)[0]
    y = x[:t + 1].clone()
    y[t] = fixed
    pos = decode_positions(y, spec, model.skeleton, start)
    assert torch.linalg.norm(pos[t, j, [0, 2]] - pos[t - 1, j, [0, 2]]) < 1e-4
    x[t - 1:t + 1, s["contacts"]] = 0.0
    assert torch.equal(planted_root_step(x[t - 1:t], pushed[None], spec, model.skeleton)[0], pushed)
    # no contact flags, but the first contact joint low above its resting height: planted too
    rest = torch.full((1, len(spec.contact_joints)), -10.0, dtype=x.dtype)  # the others far above theirs
    rest[0, 0] = contact_heights(x[t - 1:t + 1], spec, model.skeleton)[:, 0].max() - 0.01
    fixed = planted_root_step(x[t - 1:t], pushed[None], spec, model.skeleton, rest)[0]
    assert torch.allclose(fixed[s["root_delta"]], y[t, s["root_delta"]], atol=1e-6)
