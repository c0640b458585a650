"""Spatial edits: move chosen joints to targets at chosen frames; the rest stays close
to the input and natural."""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from motionopt.motion import Motion
from motionopt.objective import JointPositionTerm, PoseFidelityTerm
from motionopt.solver import SolverOptions

from .common import TaskResult, TermSigmas, back_to_file, nearest_model_frame, prepare, run, standard_terms


@dataclass(frozen=True)
class JointTarget:
    """One target: ``joint`` at input frames ``frames`` (inclusive range) reaches
    ``position`` (world, metres) or moves by ``offset`` from where it was."""

    joint: str
    frames: tuple[int, int]
    position: tuple[float, float, float] | None = None
    offset: tuple[float, float, float] | None = None


def load_targets(path: str | Path) -> list[JointTarget]:
    """Read TARGETS.json: a list of {"joint", "frame": i or [i, j], "position" or "offset"}."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}:{e.lineno}: not valid JSON ({e.msg})") from None
    if not isinstance(data, list) or not data:
        raise ValueError(f"{path}: expected a non-empty JSON list of targets")
    out = []
    for i, item in enumerate(data):
        where = f"{path}: target {i}"
        if not isinstance(item, dict) or "joint" not in item or "frame" not in item:
            raise ValueError(f"{where}: needs 'joint' and 'frame'")
        if ("position" in item) == ("offset" in item):
            raise ValueError(f"{where}: give exactly one of 'position' or 'offset'")
        f = item["frame"]
        frames = (int(f), int(f)) if isinstance(f, (int, float)) else tuple(int(v) for v in f)
        if len(frames) != 2 or frames[1] < frames[0]:
            raise ValueError(f"{where}: 'frame' must be a frame number or [first, last]")
        vec = item.get("position", item.get("offset"))
        if not (isinstance(vec, list) and len(vec) == 3 and all(isinstance(v, (int, float)) for v in vec)):
            raise ValueError(f"{where}: position/offset must be three numbers [x, y, z] in metres")
        out.append(JointTarget(str(item["joint"]), frames,
                               tuple(item["position"]) if "position" in item else None,
                               tuple(item["offset"]) if "offset" in item else None))
    return out


@dataclass
class SpatialEdit:
    """Meet joint position targets (sigma ``sigma_target`` m) while staying close to the
    input (``sigma_root`` m, ``sigma_angle`` rad) and natural under the prior."""

    motion: Motion
    targets: list[JointTarget]
    prior: object
    sigma_target: float = 0.003
    sigma_root: float = 0.05
    sigma_angle: float = 0.1
    sigmas: TermSigmas = field(default_factory=TermSigmas)
    options: SolverOptions = field(default_factory=lambda: SolverOptions(pso=None))

    def __post_init__(self) -> None:
        names = self.prior.spec.joints
        for t in self.targets:
            if t.joint not in self.motion.skeleton.names:
                raise ValueError(f"target joint {t.joint!r} is not in the skeleton")
            if t.joint not in names:
                raise ValueError(f"target joint {t.joint!r} is not modelled by the prior (it models {', '.join(names)})")
            if not 0 <= t.frames[0] <= t.frames[1] < self.motion.num_frames:
                raise ValueError(f"target frames {t.frames[0]}..{t.frames[1]} are outside the clip's "
                                 f"{self.motion.num_frames} frames")

    def solve(self) -> TaskResult:
        prior = self.prior
        prep = prepare(self.motion, prior)
        fps_o, fps_m = self.motion.fps, prior.spec.fps
        n = len(prep.x)
        pos_in = prep.model.positions()
        terms = [PoseFidelityTerm(prep.model.root, prep.model.rotations, self.sigma_root, self.sigma_angle,
                                  name="fidelity")]
        wanted: list[tuple[int, int, np.ndarray]] = []
        for k, t in enumerate(self.targets):
            j = prior.spec.joints.index(t.joint)
            frames = range(nearest_model_frame(t.frames[0], fps_o, fps_m),
                           min(nearest_model_frame(t.frames[1], fps_o, fps_m), n - 1) + 1)
            tg = {}
            for f in frames:
                tg[f] = np.asarray(t.position, float) if t.position is not None else pos_in[f, j] + np.asarray(t.offset)
                wanted.append((f, j, tg[f]))
            terms.append(JointPositionTerm(j, tg, self.sigma_target, name=f"target_{k}_{t.joint}"))
        terms += standard_terms(prep, prior, self.sigmas)
        result, model = run(prior, prep, prep.x.clone(), np.ones(n, bool), terms, self.options)
        pos_out = model.positions()
        errs = [np.linalg.norm(pos_out[f, j] - tg) for f, j, tg in wanted]
        target_frames = {f for f, _, _ in wanted}
        others = [f for f in range(n) if all(abs(f - g) > int(fps_m) for g in target_frames)]
        metrics = {
            "target_error_cm_max": float(max(errs) * 100),
            "target_error_cm_mean": float(np.mean(errs) * 100),
            "untouched_change_cm_mean": float(np.linalg.norm(pos_out[others] - pos_in[others], axis=-1).mean() * 100)
            if others else 0.0,
            "frames_per_second": n / max(result.timings["total"], 1e-9),
        }
        return TaskResult(back_to_file(model, prep), model, result, metrics,
                          {"sigma_target": self.sigma_target, "targets": len(self.targets)})
