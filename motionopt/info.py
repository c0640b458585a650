"""A short factual summary of a motion: what ``motionopt info`` prints."""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from .motion import Motion


@dataclass(frozen=True)
class ClipInfo:
    """Facts about a clip; lengths in metres, times in seconds."""

    joints: tuple[str, ...]
    frames: int
    fps: float
    duration: float
    unit: str
    root_joint: str
    root_path_length: float
    bbox_min: tuple[float, float, float]
    bbox_max: tuple[float, float, float]

    def to_dict(self) -> dict:
        d = asdict(self)
        d["joints"] = list(self.joints)
        d["bbox_min"], d["bbox_max"] = list(self.bbox_min), list(self.bbox_max)
        return d


def describe(motion: Motion) -> ClipInfo:
    """Summary of ``motion``: the root path length is the distance the body's root travels on
    the ground plane (x, z), where a top joint with a single child (as Bandai's static
    ``joint_Root``) does not count as the body's root; the bounding box holds every joint's
    world position over the clip."""
    pos = motion.positions()
    body = motion.reroot()
    root_xz = body.root[:, [0, 2]]
    path = float(np.linalg.norm(np.diff(root_xz, axis=0), axis=1).sum())
    flat = pos.reshape(-1, 3)
    return ClipInfo(
        joints=motion.skeleton.names,
        frames=motion.num_frames,
        fps=float(motion.fps),
        duration=float(motion.duration),
        unit=motion.source_unit,
        root_joint=body.skeleton.names[0],
        root_path_length=path,
        bbox_min=tuple(float(v) for v in flat.min(0)),
        bbox_max=tuple(float(v) for v in flat.max(0)),
    )


#: Faster than this (m/s) is beyond what a person does: a fast run (sprinters peak near 10 m/s, briefly).
MAX_HUMAN_SPEED = 8.0
#: Faster than this (m/s) a person's limbs do not move against the hips, as the 99th percentile of every
#: joint's speed over a clip: real capture stays well under it (dashes reach 6.3, kicks 5.3, walks 1.6-3.4,
#: over 368 CMU and Bandai clips at their true rates).
MAX_LIMB_SPEED = 8.0
#: Frame rates capture files commonly have, in the order tried for a rate a clip's speeds fit (30 first:
#: the most common).
COMMON_RATES = (30.0, 24.0, 25.0, 50.0, 60.0, 100.0, 120.0)


def clip_speeds(motion: Motion) -> tuple[float, float]:
    """How fast a clip moves at its frame rate (m/s): the body root's fastest mean speed
    over the ground in a second, and the 99th percentile of every joint's speed against
    the body root (a top joint with a single child, as Bandai's ``joint_Root``, is not the body's root)."""
    body = motion.reroot()
    pos = body.positions()
    step = np.linalg.norm(np.diff(pos[:, 0, [0, 2]], axis=0), axis=-1) * motion.fps
    k = min(len(step), max(1, int(round(motion.fps))))
    travel = float(np.convolve(step, np.ones(k) / k, mode="valid").max()) if len(step) else 0.0
    local = pos - pos[:, :1]
    limbs = np.linalg.norm(np.diff(local, axis=0), axis=-1) * motion.fps
    return travel, float(np.percentile(limbs, 99)) if limbs.size else 0.0


def frame_rate_doubt(motion: Motion, name: str) -> str | None:
    """A warning when the clip ``name`` moves faster than a person at its frame rate
    (``clip_speeds`` beyond ``MAX_HUMAN_SPEED`` or ``MAX_LIMB_SPEED``) but like one at a
    lower common rate (``COMMON_RATES``): its header's rate is likely wrong (a 30 fps clip
    whose header says 120 walks at four times its pace). None when the speeds fit the
    rate, or fit no common rate (then the rate is not what is wrong)."""
    travel, limbs = clip_speeds(motion)
    if travel <= MAX_HUMAN_SPEED and limbs <= MAX_LIMB_SPEED:
        return None
    fits = [r for r in COMMON_RATES if r < motion.fps and travel * r / motion.fps <= MAX_HUMAN_SPEED
            and limbs * r / motion.fps <= MAX_LIMB_SPEED]
    if not fits:
        return None
    rate = fits[0]
    return (f"{name}: at the {motion.fps:g} fps its header gives, its limbs move at {limbs:.1f} m/s against the "
            f"hips (99th percentile) and its body travels at up to {travel:.1f} m/s, faster than a person (limbs "
            f"about {MAX_LIMB_SPEED:g} m/s, the body about {MAX_HUMAN_SPEED:g} m/s at most); at {rate:g} fps they "
            f"would be {limbs * rate / motion.fps:.1f} and {travel * rate / motion.fps:.1f} m/s. If the header's "
            f"frame rate is wrong, pass the true one with --fps (e.g. --fps {rate:g})")
