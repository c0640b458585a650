"""The Motion type: a skeleton plus per-frame local rotations and root positions.

Arrays are plain numpy float64 inside; every operation returns a new Motion.
Lengths are in metres; ``source_unit`` remembers what the file used so that
saving writes the same unit back.
"""
from __future__ import annotations

import fnmatch
from dataclasses import dataclass, replace

import numpy as np
import torch

from . import rotations as R
from .kinematics import fk
from .skeleton import Skeleton

UNIT_SCALE = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}


def unit_scale(unit: str) -> float:
    """Metres per ``unit``."""
    try:
        return UNIT_SCALE[unit]
    except KeyError:
        raise ValueError(f"unknown length unit {unit!r}; use one of {', '.join(UNIT_SCALE)}") from None


@dataclass(frozen=True, eq=False)
class Motion:
    """Local joint rotations ``(T, J, 4)`` (w first), root positions ``(T, 3)`` in metres.

    ``translations`` (T, J, 3), when present, holds per-frame local translations of
    joints that carry BVH position channels (they replace the skeleton offsets).
    ``euler_hint`` (T, J, 3), when present, holds Euler angles (radians, each joint's
    channel order) that a writer should stay nearest to: a file read and written back
    keeps its own angle wrapping, and an edited motion keeps the curves of its source.
    """

    skeleton: Skeleton
    rotations: np.ndarray
    root: np.ndarray
    fps: float
    translations: np.ndarray | None = None
    source_unit: str = "m"
    euler_hint: np.ndarray | None = None

    def __post_init__(self) -> None:
        rot = np.asarray(self.rotations, dtype=np.float64)
        root = np.asarray(self.root, dtype=np.float64)
        object.__setattr__(self, "rotations", rot)
        object.__setattr__(self, "root", root)
        t, j = rot.shape[0], self.skeleton.num_joints
        if rot.shape != (t, j, 4) or root.shape != (t, 3):
            raise ValueError(f"expected rotations ({t}, {j}, 4) and root ({t}, 3), got {rot.shape} and {root.shape}")
        if self.translations is not None:
            tr = np.asarray(self.translations, dtype=np.float64)
            if tr.shape != (t, j, 3):
                raise ValueError(f"translations must be ({t}, {j}, 3), got {tr.shape}")
            object.__setattr__(self, "translations", tr)
        if not self.fps > 0:
            raise ValueError(f"frame rate must be positive, got {self.fps}")

    # ---- basic facts -------------------------------------------------------------------
    @property
    def num_frames(self) -> int:
        return self.rotations.shape[0]

    def __len__(self) -> int:
        return self.num_frames

    @property
    def duration(self) -> float:
        """Seconds from the first to the last frame."""
        return (self.num_frames - 1) / self.fps

    def local_translations(self) -> np.ndarray:
        """(T, J, 3) local translation of every joint (root included) per frame."""
        if self.translations is not None:
            tr = self.translations.copy()
        else:
            tr = np.broadcast_to(self.skeleton.offsets, (self.num_frames, self.skeleton.num_joints, 3)).copy()
        tr[:, 0] = self.root
        return tr

    def positions(self) -> np.ndarray:
        """World joint positions (T, J, 3) in metres."""
        pos = fk(self.skeleton.parents, torch.from_numpy(self.rotations), torch.from_numpy(self.root),
                 torch.from_numpy(self.skeleton.offsets),
                 None if self.translations is None else torch.from_numpy(self.translations))
        return pos.numpy()

    # ---- new motions -------------------------------------------------------------------
    def __getitem__(self, frames: slice) -> "Motion":
        """Frames selected by a slice (``motion[10:50]``), as a new Motion."""
        if not isinstance(frames, slice):
            raise TypeError("index a Motion with a slice of frames, e.g. motion[10:50]")
        step = frames.step or 1
        return replace(
            self,
            rotations=self.rotations[frames].copy(),
            root=self.root[frames].copy(),
            translations=None if self.translations is None else self.translations[frames].copy(),
            euler_hint=None if self.euler_hint is None else self.euler_hint[frames].copy(),
            fps=self.fps / step,
        )

    def with_frames(self, rotations: np.ndarray, root: np.ndarray, translations: np.ndarray | None = None) -> "Motion":
        """Same skeleton and frame rate, new frame data (the Euler hint is kept when the
        frame count is unchanged, so curves keep the source's angle wrapping)."""
        hint = self.euler_hint if len(rotations) == self.num_frames else None
        return replace(self, rotations=rotations, root=root, translations=translations, euler_hint=hint)

    def resample(self, fps: float) -> "Motion":
        """The same motion at another frame rate: slerp for rotations, linear for positions.

        The new frames cover ``[0, duration]``; the last frame falls on or before the end.
        """
        if abs(fps - self.fps) < 1e-4 * self.fps:  # header rounding, e.g. 0.0333333 s
            return self if fps == self.fps else replace(self, fps=float(fps))
        n_new = int(np.floor(self.duration * fps + 1e-6)) + 1
        times = np.arange(n_new) / fps * self.fps  # in source frame units
        i0 = np.clip(np.floor(times).astype(int), 0, self.num_frames - 1)
        i1 = np.clip(i0 + 1, 0, self.num_frames - 1)
        w = times - i0
        rot = R.quat_slerp(torch.from_numpy(self.rotations[i0]), torch.from_numpy(self.rotations[i1]),
                           torch.from_numpy(np.broadcast_to(w[:, None], (n_new, self.skeleton.num_joints)).copy())).numpy()

        def lerp(a: np.ndarray) -> np.ndarray:
            shape = (-1,) + (1,) * (a.ndim - 1)
            return a[i0] * (1 - w).reshape(shape) + a[i1] * w.reshape(shape)

        return replace(self, rotations=rot, root=lerp(self.root),
                       translations=None if self.translations is None else lerp(self.translations), fps=float(fps),
                       euler_hint=None)

    def mirror(self) -> "Motion":
        """Left/right mirror image across the x = 0 plane.

        Joint data is swapped between counterparts found by name (``Skeleton.mirror_map``)
        and rotations are reflected; world positions are exactly mirrored when the
        skeleton's rest offsets are left/right symmetric.
        """
        m = self.skeleton.mirror_map()
        rot = self.rotations[:, m] * np.array([1.0, 1.0, -1.0, -1.0])
        root = self.root * np.array([-1.0, 1.0, 1.0])
        tr = None if self.translations is None else self.translations[:, m] * np.array([-1.0, 1.0, 1.0])
        return replace(self, rotations=rot, root=root, translations=tr, euler_hint=None)

    def remove_joints(self, patterns: str | list[str]) -> "Motion":
        """Drop joints whose names match any shell-style pattern (``"*Thumb*"``), keeping the
        world positions of the remaining joints unchanged.

        Joints whose parent stays keep their data exactly. A joint whose parent is removed
        takes the removed joints' transforms folded in; when that makes its translation vary
        over time it is stored per frame and the joint gains position channels, so a saved
        file keeps the motion. A joint left without children gets an End Site where its
        first removed child was.
        """
        pats = [patterns] if isinstance(patterns, str) else list(patterns)
        sk = self.skeleton
        drop = {j for j, n in enumerate(sk.names) if any(fnmatch.fnmatchcase(n, p) for p in pats)}
        if not drop:
            return self
        if 0 in drop:
            raise ValueError(f"cannot remove the root joint {sk.names[0]!r}")
        keep = [j for j in range(sk.num_joints) if j not in drop]
        sub = sk.subset(keep)
        rot = self.rotations[:, keep].copy()
        tr = self.local_translations()[:, keep].copy()
        moved = [n for n in range(1, len(keep)) if keep[sub.parents[n]] != sk.parents[keep[n]]]
        varying: set[int] = set()
        if moved:
            # re-express each moved joint relative to its new parent, from world transforms
            pos, grot = fk(sk.parents, torch.from_numpy(self.rotations), torch.from_numpy(self.root),
                           torch.from_numpy(sk.offsets), torch.from_numpy(self.local_translations()),
                           return_global_rotations=True)
            old = [keep[n] for n in moved]
            old_parent = [keep[sub.parents[n]] for n in moved]
            inv = R.quat_conjugate(grot[:, old_parent])
            rot[:, moved] = R.quat_multiply(inv, grot[:, old]).numpy()
            tr[:, moved] = R.quat_apply(inv, pos[:, old] - pos[:, old_parent]).numpy()
            varying = {n for n in moved if np.abs(tr[:, n] - tr[:1, n]).max() > 1e-9}
        offsets = sk.offsets[keep].copy()
        offsets[moved] = tr[0, moved]
        channels = list(sub.channels)
        for n in varying:
            if not any("position" in c for c in channels[n]):
                channels[n] = ("Xposition", "Yposition", "Zposition") + channels[n]
        end_sites = dict(sub.end_sites)
        for n, j in enumerate(keep):
            dropped_children = [c for c in sk.children(j) if c in drop]
            if n not in end_sites and dropped_children and not sub.children(n):
                end_sites[n] = sk.offsets[dropped_children[0]].copy()
        sub = replace(sub, offsets=offsets, channels=tuple(channels), end_sites=end_sites)
        keep_tr = self.translations is not None or bool(varying)
        return Motion(sub, rot, self.root.copy(), self.fps, translations=tr if keep_tr else None,
                      source_unit=self.source_unit,
                      euler_hint=None if self.euler_hint is None else self.euler_hint[:, keep].copy())

    def select_joints(self, names: list[str]) -> "Motion":
        """Keep only the named joints (and the root), as ``remove_joints`` of the rest."""
        missing = [n for n in names if n not in self.skeleton.names]
        if missing:
            raise KeyError(f"joints not in the skeleton: {missing}")
        drop = [n for n in self.skeleton.names[1:] if n not in names]
        return self.remove_joints(drop) if drop else self

    def reroot(self) -> "Motion":
        """Fold a top joint with a single child (as Bandai's ``joint_Root``) into that child,
        which becomes the root; world positions stay the same. Returns ``self`` when the
        root has several children."""
        sk = self.skeleton
        children = sk.children(0)
        if len(children) != 1:
            return self
        c = children[0]
        tr = self.local_translations()
        root = self.root + R.quat_apply(torch.from_numpy(self.rotations[:, 0]), torch.from_numpy(tr[:, c])).numpy()
        rot = self.rotations[:, 1:].copy()
        rot[:, 0] = R.quat_multiply(torch.from_numpy(self.rotations[:, 0]), torch.from_numpy(self.rotations[:, c])).numpy()
        offsets = sk.offsets[1:].copy()
        offsets[0] = 0.0
        sub = Skeleton(sk.names[1:], np.concatenate([[-1], sk.parents[2:] - 1]), offsets, sk.channels[1:],
                       {k - 1: v for k, v in sk.end_sites.items() if k > 0})
        new_tr = None
        if self.translations is not None:
            new_tr = self.translations[:, 1:].copy()
            new_tr[:, 0] = root
        return Motion(sub, rot, root, self.fps, new_tr, self.source_unit)

    def bake_translations(self, tolerance: float = 1e-6) -> "Motion":
        """Replace per-frame joint translations by skeleton offsets where they are constant
        (within ``tolerance`` metres); leaves the motion unchanged otherwise."""
        if self.translations is None:
            return self
        tr = self.translations[:, 1:]
        if np.abs(tr - tr[:1]).max() > tolerance:
            return self
        offsets = self.skeleton.offsets.copy()
        offsets[1:] = tr[0]
        sk = replace(self.skeleton, offsets=offsets,
                     channels=tuple(c if j == 0 else tuple(x for x in c if "rotation" in x)
                                    for j, c in enumerate(self.skeleton.channels)))
        return Motion(sk, self.rotations, self.root, self.fps, None, self.source_unit, self.euler_hint)
