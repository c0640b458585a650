"""Motion the tests make themselves, so that no clip of ``../shared/data`` lives in the
repository.

Each clip is sampled from a shipped latent prior (``priors.sampling``), then dressed as
the files users bring:

- ``cmu-like-120fps.bvh`` (2 s) and ``cmu-like-60fps.bvh`` (4 s): the CMU layout, 43
  joints (the prior's 21 plus eyes and two bones per finger, which the priors do not
  model and tests drop or restore), rotations in Z X Y order, centimetres, at 120 and
  60 fps;
- ``bandai-like-30fps.bvh``: 2 s in the Bandai layout, 22 joints from ``joint_Root`` (a ground
  joint above ``Hips``), position and rotation channels on every joint, centimetres,
  30 fps.

The clips are written once per test process into a temporary folder, ``DATA``. Tests
that need real capture (planted feet as mocap has them, say) take an excerpt of
``../shared/data`` with ``shared_excerpt`` and skip when it is absent.
"""
from __future__ import annotations

import atexit
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
import torch

from motionopt import bvh
from motionopt import rotations as R
from motionopt.motion import Motion
from motionopt.skeleton import Skeleton
from priors.checkpoint import CHECKPOINT_DIR, load_prior_cached
from priors.sampling import sample_motion

SHARED = Path(__file__).resolve().parent.parent.parent / "shared" / "data"
CMU_120 = "cmu-like-120fps.bvh"
CMU_60 = "cmu-like-60fps.bvh"
BANDAI_30 = "bandai-like-30fps.bvh"
FINGERS = ("Thumb", "Index", "Mid", "Ring", "Pinky")
ZXY = ("Zrotation", "Xrotation", "Yrotation")


def _with_extra_joints(motion: Motion, extra: dict[str, list[tuple[str, str, np.ndarray]]]) -> Motion:
    """``motion`` with joints added under leaves: ``extra[parent]`` lists (name, parent name,
    offset in metres). Each added joint turns slowly about its own x axis (a finger
    curling), so its channels are not constant."""
    sk = motion.skeleton
    names, parents, offsets, channels, source = [], [], [], [], []
    for j, name in enumerate(sk.names):
        names.append(name)
        parents.append(-1 if sk.parents[j] < 0 else names.index(sk.names[sk.parents[j]]))
        offsets.append(sk.offsets[j])
        channels.append(sk.channels[j])
        source.append(j)
        for new, parent, offset in extra.get(name, []):
            names.append(new)
            parents.append(names.index(parent))
            offsets.append(offset)
            channels.append(ZXY)
            source.append(-1)
    t = np.arange(motion.num_frames) / motion.fps
    rot = np.zeros((motion.num_frames, len(names), 4))
    for k, j in enumerate(source):
        if j >= 0:
            rot[:, k] = motion.rotations[:, j]
        else:
            angle = 0.2 + 0.15 * np.sin(2 * np.pi * 0.7 * t + k)
            aa = np.stack([angle, np.zeros_like(angle), np.zeros_like(angle)], axis=-1)
            rot[:, k] = R.axis_angle_to_quat(torch.from_numpy(aa)).numpy()
    skeleton = Skeleton(tuple(names), np.array(parents), np.array(offsets), tuple(channels))
    return Motion(skeleton, rot, motion.root, motion.fps, source_unit=motion.source_unit)


def cmu_like(seed: int, fps: float, seconds: float) -> Motion:
    """A CMU-layout clip (43 joints, centimetres) of ``seconds``: a window sampled from the
    shipped CMU latent prior, continued by the shipped autoregressive prior (prefix
    completion) where it is longer than the window."""
    from problems.inbetween import complete

    model = sample_motion(load_prior_cached(CHECKPOINT_DIR / "cmu-latent.pt"), seed=seed, speed=0.3)
    n = int(round(seconds * model.fps)) + 1
    if n > model.num_frames:
        ar = load_prior_cached(CHECKPOINT_DIR / "cmu-ccnet.pt")
        model = complete(model, model.num_frames, n, ar).solve().motion
    extra: dict[str, list[tuple[str, str, np.ndarray]]] = {
        "head": [(f"{side}Eye", "head", np.array([x, 0.03, 0.08])) for side, x in (("left", 0.03), ("right", -0.03))]}
    for side, sign in (("r", -1.0), ("l", 1.0)):
        bones = []
        for i, finger in enumerate(FINGERS):
            base = np.array([sign * 0.04, -0.01 * i, 0.01])
            bones += [(f"{side}{finger}1", f"{side}Hand", base),
                      (f"{side}{finger}2", f"{side}{finger}1", np.array([sign * 0.025, 0.0, 0.0]))]
        extra[f"{side}Hand"] = bones
    return _with_extra_joints(model, extra).resample(fps)


def bandai_like(seed: int) -> Motion:
    """A Bandai-layout clip (``joint_Root`` above ``Hips``, six channels on every joint)
    sampled from the shipped Bandai latent prior."""
    model = sample_motion(load_prior_cached(CHECKPOINT_DIR / "bandai-latent.pt"), seed=seed, speed=0.6)
    sk = model.skeleton
    six = ("Xposition", "Yposition", "Zposition") + ZXY
    skeleton = Skeleton(("joint_Root",) + sk.names, np.concatenate([[-1], sk.parents + 1]),
                        np.concatenate([np.zeros((1, 3)), sk.offsets]), (six,) * (sk.num_joints + 1))
    ground = model.root * np.array([1.0, 0.0, 1.0])
    identity = np.tile([1.0, 0.0, 0.0, 0.0], (model.num_frames, 1, 1))
    translations = np.broadcast_to(skeleton.offsets, (model.num_frames, skeleton.num_joints, 3)).copy()
    translations[:, 1] = model.root - ground
    return Motion(skeleton, np.concatenate([identity, model.rotations], axis=1), ground, model.fps,
                  translations=translations, source_unit="cm")


def shared_excerpt(relative: str, start: int, stop: int) -> Motion:
    """Frames ``start:stop`` of ``../shared/data/<relative>``; skips the test without it."""
    path = SHARED / relative
    if not path.exists():
        pytest.skip(f"needs real capture: ../shared/data/{relative} is absent")
    return bvh.load(path)[start:stop]


def slide(motion: Motion, velocity: np.ndarray | list[float]) -> Motion:
    """The motion with its root carried along at a constant horizontal velocity (m/s)."""
    t = np.arange(motion.num_frames)[:, None] / motion.fps
    return motion.with_frames(motion.rotations, motion.root + t * np.asarray(velocity), motion.translations)


def _write_all() -> Path:
    folder = Path(tempfile.mkdtemp(prefix="motionopt-test-clips-"))
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    bvh.save(cmu_like(seed=3, fps=120.0, seconds=2.0)[:240], folder / CMU_120)
    bvh.save(cmu_like(seed=2, fps=60.0, seconds=4.0)[:240], folder / CMU_60)
    bvh.save(bandai_like(seed=3)[:60], folder / BANDAI_30)
    return folder


#: The folder holding the generated clips (one per test process).
DATA = _write_all()
