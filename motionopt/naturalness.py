"""Is a motion still human, second by second? Measures of each second of a motion against
the range of held-out mocap that a prior's checkpoint carries.

A mean over a whole output hides a walk that collapses after 6 s, so every task reports
these per second (``per_second``) and warns about the seconds that leave the data's range
(``out_of_range``): prior NLL per frame, foot skating, the lowest contact joint's height
above the floor, and the hip height above the floor. The range
(``HumanRange``) is measured on the prior's validation clips (``HumanRange.of``) and
stored in its metadata under ``human_range``.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Sequence

import numpy as np
import torch

from . import metrics
from .codec import Codec
from .features import estimate_ground
from .motion import Motion

#: Metadata key of a checkpoint's ``HumanRange``.
METADATA_KEY = "human_range"
#: Percentile of the held-out seconds that bounds each measure (and 100 minus it, below).
PERCENTILE = 99.0


@dataclass(frozen=True)
class HumanRange:
    """What held-out mocap does in a second, each the ``PERCENTILE``-th percentile over
    every second of the prior's validation clips (the hips also the lower one): mean hip
    height above the floor (m), median height of the lowest contact joint above the floor
    (m), foot skating (m/s) and mean NLL per frame under the prior (nats). Held-out
    seconds themselves leave it about 1% of the time for each measure."""

    hip_low: float
    hip_high: float
    lowest_high: float
    skating_high: float
    nll_high: float

    @classmethod
    def of(cls, prior, motions: Sequence[Motion]) -> "HumanRange":
        """Measured on ``motions`` (model motions of the prior's skeleton and rate: its
        validation clips), each on the floor its feet give (``estimate_ground``, as encoding does)."""
        cidx = prior.spec.contact_indices()
        seconds = [s for m in motions for s in per_second(prior, m, estimate_ground(m.positions(), cidx))]

        def pct(key: str, q: float = PERCENTILE) -> float:
            v = np.array([s[key] for s in seconds])
            return float(np.percentile(v[np.isfinite(v)], q))

        return cls(pct("hip_height_m", 100 - PERCENTILE), pct("hip_height_m"), pct("lowest_contact_m"),
                   pct("skating_m_per_s"), pct("nll_per_frame"))

    @classmethod
    def of_prior(cls, prior) -> "HumanRange | None":
        """The range stored in ``prior``'s metadata, or None for a checkpoint without one."""
        stored = prior.metadata.get(METADATA_KEY)
        return None if stored is None else cls(**stored)

    def to_dict(self) -> dict:
        return asdict(self)


@torch.no_grad()
def _frame_nll(prior, x: torch.Tensor) -> np.ndarray:
    """The prior's NLL of every frame of features ``x (T, D)`` after the first (frame 0: NaN)."""
    nll = prior.nll(x[1:].float(), x[:1].float()).double().numpy()
    return np.concatenate(([np.nan], nll))


def per_second(prior, motion: Motion, ground: float) -> list[dict]:
    """For each second of ``motion`` (a model motion at the prior's rate, floor at height
    ``ground``; a last part second of at least half a second counts): its start (s), mean
    NLL per frame under the prior, foot skating (m/s, NaN when no foot is planted), the
    median height of the lowest contact joint above the floor (m) and the mean hip height
    above the floor (m)."""
    fps = prior.spec.fps
    cidx = prior.spec.contact_indices()
    pos = torch.from_numpy(motion.positions())
    lowest = pos[:, cidx, 1].min(-1).values - ground
    nll = _frame_nll(prior, Codec.of(prior).features(motion, ground))
    w = max(int(round(fps)), 1)
    out = []
    for a in range(0, len(pos), w):
        seg = slice(a, a + w)
        if len(pos[seg]) < w / 2:
            break
        scored = nll[seg][np.isfinite(nll[seg])]
        out.append({"second": a / fps, "nll_per_frame": float(scored.mean()) if len(scored) else float("nan"),
                    "skating_m_per_s": float(metrics.foot_skating(pos[seg], fps, cidx, ground=ground)),
                    "lowest_contact_m": float(lowest[seg].median()),
                    "hip_height_m": float((pos[seg, 0, 1] - ground).mean())})
    return out


def out_of_range(seconds: list[dict], known: HumanRange | None) -> dict[str, list[float]]:
    """The seconds (their starts) where each measure leaves ``known``: 'hips' outside the
    hip range, 'floating', 'skating' and 'unlikely' above the range of the lowest contact
    joint's height, of foot skating and of the prior's NLL. Empty without a range."""
    if known is None:
        return {}
    tests = {
        "hips": lambda s: not known.hip_low <= s["hip_height_m"] <= known.hip_high,
        "floating": lambda s: s["lowest_contact_m"] > known.lowest_high,
        "skating": lambda s: s["skating_m_per_s"] > known.skating_high,
        "unlikely": lambda s: s["nll_per_frame"] > known.nll_high,
    }
    return {k: [s["second"] for s in seconds if test(s)] for k, test in tests.items()}


#: What each measure of ``out_of_range`` means, for warnings.
WHAT = {"hips": "hip height", "floating": "the lowest foot joint's height above the floor",
        "skating": "foot sliding", "unlikely": "the prior's NLL"}


def flagged_seconds(out: dict[str, list[float]]) -> list[float]:
    """The starts of the seconds where any measure of ``out`` (``out_of_range``'s result)
    leaves the range, in order."""
    return sorted({s for found in out.values() for s in found})


def spans(starts: list[float]) -> str:
    """'0-3, 7' for seconds starting at 0, 1, 2, 3 and 7."""
    whole = sorted(int(round(s)) for s in starts)
    parts, i = [], 0
    while i < len(whole):
        j = i
        while j + 1 < len(whole) and whole[j + 1] == whole[j] + 1:
            j += 1
        parts.append(str(whole[i]) if i == j else f"{whole[i]}-{whole[j]}")
        i = j + 1
    return ", ".join(parts)


def warnings_for(seconds: list[dict], known: HumanRange | None, what: str = "output") -> list[str]:
    """One warning per measure that leaves the data's range, naming the seconds (counted
    from 0), e.g. 'output: hip height leaves ... in seconds 2-3 (of seconds 0-5)'."""
    whole = "second 0" if len(seconds) == 1 else f"seconds 0-{len(seconds) - 1}"
    return [f"{what}: {WHAT[k]} leaves the held-out data's {100 - PERCENTILE:g}-{PERCENTILE:g}th percentile "
            f"range of human motion in second{'s' if len(starts) > 1 else ''} {spans(starts)} (of {whole})"
            for k, starts in out_of_range(seconds, known).items() if starts]


def summary_line(seconds: list[dict], known: HumanRange | None) -> str:
    """One sentence for the command line: how many seconds stay in the data's range."""
    if known is None:
        return (f"naturalness per second: {len(seconds)} seconds measured (in the report); the prior's checkpoint "
                "carries no data range to judge them against")
    bad = out_of_range(seconds, known)
    flagged = flagged_seconds(bad)
    if not flagged:
        return f"naturalness per second: all {len(seconds)} seconds within the held-out data's range"
    return (f"naturalness per second: {len(seconds) - len(flagged)} of {len(seconds)} seconds within the held-out "
            f"data's range; outside: {', '.join(f'{k} in {spans(v)}' for k, v in bad.items() if v)}")
