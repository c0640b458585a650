"""In-betweening and prefix completion: synthesise the frames outside kept ranges."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from motionopt.motion import Motion
from motionopt.objective import PoseFidelityTerm
from motionopt.solver import SolverOptions

from .common import (TaskResult, TermSigmas, back_to_file, model_frames_in, prepare, run, splice,
                     standard_terms)


def parse_ranges(text: str) -> list[tuple[int, int]]:
    """'0:30,60:90' -> [(0, 30), (60, 90)] (half-open, like Python slices)."""
    out = []
    for part in text.split(","):
        part = part.strip()
        if ":" not in part:
            raise ValueError(f"keep range {part!r} must look like START:STOP, e.g. 0:30")
        a, b = part.split(":", 1)
        try:
            out.append((int(a), int(b)))
        except ValueError:
            raise ValueError(f"keep range {part!r} must hold whole frame numbers") from None
    return out


def check_ranges(ranges: list[tuple[int, int]], n_frames: int) -> list[tuple[int, int]]:
    """Sorted, validated ranges; errors name the offending range."""
    if not ranges:
        raise ValueError("give at least one frame range to keep")
    ranges = sorted(ranges)
    for a, b in ranges:
        if not 0 <= a < b <= n_frames:
            raise ValueError(f"keep range {a}:{b} is outside the clip's frames 0:{n_frames} or empty")
    for (a0, b0), (a1, b1) in zip(ranges, ranges[1:]):
        if a1 < b0:
            raise ValueError(f"keep ranges {a0}:{b0} and {a1}:{b1} overlap")
    if ranges[0][0] != 0:
        raise ValueError(f"the first kept range starts at frame {ranges[0][0]}: keep frame 0, because the "
                         "prior synthesises forward in time from what comes before")
    return ranges


@dataclass
class Inbetween:
    """Keep the frames of ``motion`` inside ``keep`` (half-open ranges of the input's
    frame numbering), synthesise the rest so that gaps meet the kept frames.

    ``n_frames`` (input frame rate) extends the output past the input's end (prefix
    completion); the kept frames are copied from the input exactly.
    """

    motion: Motion
    keep: list[tuple[int, int]]
    prior: object
    n_frames: int | None = None
    sigma_join_root: float = 0.01
    sigma_join_angle: float = 0.02
    sigmas: TermSigmas = field(default_factory=TermSigmas)
    options: SolverOptions = field(default_factory=SolverOptions)

    def __post_init__(self) -> None:
        self.keep = check_ranges(list(self.keep), self.motion.num_frames)
        if self.n_frames is not None and self.n_frames < self.keep[-1][1]:
            raise ValueError(f"--frames {self.n_frames} is shorter than the kept frames (up to {self.keep[-1][1]})")

    def solve(self) -> TaskResult:
        prior = self.prior
        prep = prepare(self.motion, prior)
        fps_o, fps_m = self.motion.fps, prior.spec.fps
        total_o = self.n_frames or self.motion.num_frames
        n = int(np.ceil((total_o - 1) / fps_o * fps_m - 1e-6)) + 1
        n_in = min(len(prep.x), n)
        kept = model_frames_in(self.keep, fps_o, fps_m, n)
        kept[n_in:] = False
        x0 = torch.full((n, prior.spec.dim), float("nan"))
        x0[:n_in][kept[:n_in]] = prep.x[:n_in][kept[:n_in]]
        free = ~kept
        # kept frames right after a gap: their world root and pose must be met by the gap
        join = np.zeros(n, bool)
        join[1:] = kept[1:] & ~kept[:-1]
        root_t = np.zeros((n, 3))
        rot_t = np.tile(np.array([1.0, 0, 0, 0]), (n, len(prior.spec.joints), 1))
        root_t[:n_in], rot_t[:n_in] = prep.model.root[:n_in], prep.model.rotations[:n_in]
        terms = standard_terms(prep, prior, self.sigmas)
        if join.any():
            terms.insert(0, PoseFidelityTerm(root_t, rot_t, self.sigma_join_root, self.sigma_join_angle,
                                             mask=join, name="join"))
        result, model = run(prior, prep, x0, free, terms, self.options)
        synth = back_to_file(model, prep)
        keep_o = np.zeros(synth.num_frames, bool)
        for a, b in self.keep:
            keep_o[a:b] = True
        out = splice(synth[:total_o], self.motion, keep_o[:total_o])
        joins = np.nonzero(join)[0]
        metrics = {"synthesised_frames": int((~keep_o[:total_o]).sum()),
                   "join_root_error_cm": [float(np.linalg.norm(model.root[j] - root_t[j]) * 100) for j in joins],
                   "frames_per_second": int(free.sum()) / max(result.timings["total"], 1e-9)}
        return TaskResult(out, model, result, metrics, {"keep": self.keep, "frames": total_o})


def complete(motion: Motion, prefix: int, n_frames: int, prior, **kwargs) -> Inbetween:
    """Prefix completion: keep the first ``prefix`` frames, synthesise up to ``n_frames``."""
    if not 0 < prefix <= motion.num_frames:
        raise ValueError(f"--prefix {prefix} must be between 1 and the clip's {motion.num_frames} frames")
    if n_frames <= prefix:
        raise ValueError(f"--frames {n_frames} must be larger than --prefix {prefix}")
    return Inbetween(motion, [(0, prefix)], prior, n_frames=n_frames, **kwargs)
