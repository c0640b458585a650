"""The skeleton: joint names, parents, rest offsets and end sites. No motion."""
from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True, eq=False)
class Skeleton:
    """A joint hierarchy in topological order (every parent precedes its children).

    ``offsets`` (J, 3) are rest translations of each joint from its parent, in the
    motion's length unit; ``end_sites`` maps a joint index to the offset of its BVH
    End Site. ``channels`` keeps each joint's BVH channel names so a file is written
    back with the layout it was read with.
    """

    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    end_sites: dict[int, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        parents = np.asarray(self.parents, dtype=np.int64)
        offsets = np.asarray(self.offsets, dtype=np.float64)
        object.__setattr__(self, "parents", parents)
        object.__setattr__(self, "offsets", offsets)
        n = len(self.names)
        if parents.shape != (n,) or offsets.shape != (n, 3) or len(self.channels) != n:
            raise ValueError(
                f"skeleton arrays disagree: {n} names, parents {parents.shape}, "
                f"offsets {offsets.shape}, {len(self.channels)} channel lists"
            )
        if n == 0 or parents[0] != -1:
            raise ValueError("the first joint must be the root (parent -1)")
        for j in range(1, n):
            if not 0 <= parents[j] < j:
                raise ValueError(
                    f"joint {self.names[j]!r} has parent index {parents[j]}: joints must be in "
                    "topological order (parents before children)"
                )
        if len(set(self.names)) != n:
            dup = sorted({x for x in self.names if self.names.count(x) > 1})
            raise ValueError(f"duplicate joint names: {dup}")

    @property
    def num_joints(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        """Index of a joint by name, with an error that lists the valid names."""
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"joint {name!r} is not in the skeleton; joints are: {', '.join(self.names)}") from None

    def children(self, j: int) -> list[int]:
        return [int(c) for c in np.nonzero(self.parents == j)[0]]

    def descendants(self, j: int) -> list[int]:
        """All joints below ``j`` (not including ``j``)."""
        out: list[int] = []
        inside = {j}
        for k in range(j + 1, self.num_joints):
            if self.parents[k] in inside:
                inside.add(k)
                out.append(k)
        return out

    def same_hierarchy(self, other: "Skeleton") -> bool:
        return self.names == other.names and np.array_equal(self.parents, other.parents)

    def scaled(self, factor: float) -> "Skeleton":
        """Same skeleton with lengths multiplied by ``factor`` (unit conversion)."""
        return Skeleton(
            self.names,
            self.parents,
            self.offsets * factor,
            self.channels,
            {k: v * factor for k, v in self.end_sites.items()},
        )

    def subset(self, keep: list[int], offsets: np.ndarray | None = None) -> "Skeleton":
        """Skeleton with only the joints ``keep`` (sorted, root included); each kept joint is
        re-parented to its nearest kept ancestor."""
        keep = sorted(keep)
        if keep[0] != 0:
            raise ValueError("the root joint cannot be removed this way")
        remap = {old: new for new, old in enumerate(keep)}
        parents = []
        for j in keep:
            p = int(self.parents[j])
            while p != -1 and p not in remap:
                p = int(self.parents[p])
            parents.append(remap[p] if p != -1 else -1)
        offs = self.offsets[keep] if offsets is None else offsets
        ends = {remap[k]: v for k, v in self.end_sites.items() if k in remap}
        return Skeleton(tuple(self.names[j] for j in keep), np.array(parents), offs,
                        tuple(self.channels[j] for j in keep), ends)

    def mirror_map(self) -> np.ndarray:
        """For each joint the index of its left/right counterpart (itself if none).

        Recognises the usual conventions: ``left``/``right`` anywhere in the name,
        ``l``/``r`` prefixes before a capital letter (``lFoot``), and ``_L``/``_R``,
        ``.L``/``.R`` suffixes.
        """
        out = np.arange(self.num_joints)
        for j, name in enumerate(self.names):
            other = _mirror_name(name)
            if other != name and other in self.names:
                out[j] = self.names.index(other)
        return out

    def mirror_asymmetry(self) -> float:
        """Largest distance between a joint's rest offset and its counterpart's mirrored
        across x = 0 (``mirror_map``), in the skeleton's units: 0 for a symmetric skeleton,
        whose ``Motion.mirror`` is exactly the mirror image. Skeletons whose joints' local
        axes are not the body's (Bandai's) have offsets that differ by tens of centimetres."""
        off = np.asarray(self.offsets, dtype=np.float64)
        return float(np.abs(off[self.mirror_map()] * np.array([-1.0, 1.0, 1.0]) - off).max())


_MIRROR_RULES = [
    (re.compile(r"Left"), "Right"), (re.compile(r"Right"), "Left"),
    (re.compile(r"left"), "right"), (re.compile(r"right"), "left"),
    (re.compile(r"^l(?=[A-Z])"), "r"), (re.compile(r"^r(?=[A-Z])"), "l"),
    (re.compile(r"^L(?=[A-Z_])"), "R"), (re.compile(r"^R(?=[A-Z_])"), "L"),
    (re.compile(r"([_.])L$"), r"\1R"), (re.compile(r"([_.])R$"), r"\1L"),
    (re.compile(r"([_.])l$"), r"\1r"), (re.compile(r"([_.])r$"), r"\1l"),
]


def _mirror_name(name: str) -> str:
    for pattern, repl in _MIRROR_RULES:
        if pattern.search(name):
            return pattern.sub(repl, name, count=1)
    return name
