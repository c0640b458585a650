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
