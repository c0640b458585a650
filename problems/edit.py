"""Spatial edits: move chosen joints to targets at chosen frames; the rest stays close
to the input and natural."""
from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from motionopt import rotations as R
from motionopt.kinematics import fk
from motionopt.motion import Motion
from motionopt.objective import JointPositionTerm, PoseFidelityTerm
from motionopt.smoothing import smoothstep
from motionopt.solver import SolverOptions
from priors.checkpoint import shown

from .common import (MAX_COORDINATE, TaskResult, judged, TermSigmas, nearest_model_frame, prepare, read_text,
                     run, standard_terms, warned)

#: A target missed by more than this (m) is reported.
TARGET_TOLERANCE = 0.01
#: Most targets a TARGETS.json may hold.
MAX_TARGETS = 1000
#: Largest TARGETS.json read (checked before reading): 1000 targets take about 100 kB.
MAX_TARGETS_BYTES = 5 * 2**20
#: What a target may say.
TARGET_KEYS = ("joint", "frame", "position", "offset")


@dataclass(frozen=True)
class JointTarget:
    """One target: ``joint`` at input frames ``frames`` (inclusive range) reaches
    ``position`` (world, metres) or moves by ``offset`` from where it was."""

    joint: str
    frames: tuple[int, int]
    position: tuple[float, float, float] | None = None
    offset: tuple[float, float, float] | None = None


def load_targets(path: str | Path) -> list[JointTarget]:
    """Read TARGETS.json: a list of {"joint", "frame": i or [i, j], "position" or "offset"}.

    The file is data, never evaluated: UTF-8 (a BOM is fine) of at most ``MAX_TARGETS_BYTES``,
    at most ``MAX_TARGETS`` targets, no other keys, whole non-negative frame numbers, three
    finite numbers within ``MAX_COORDINATE`` metres. Errors are ``ValueError`` naming the
    file and the target (its index in the list)."""
    path = Path(path)
    data = _parse_json(path)
    if not isinstance(data, list) or not data:
        raise ValueError(f"{path}: expected a non-empty JSON list of targets")
    if len(data) > MAX_TARGETS:
        raise ValueError(f"{path}: {len(data)} targets; at most {MAX_TARGETS} are taken")
    return [_target(item, f"{path}: target {i}") for i, item in enumerate(data)]


def _parse_json(path: Path) -> object:
    """The JSON value of a file, objects with repeated keys refused; errors name the file (and line)."""
    text = read_text(path, "a JSON list of targets", MAX_TARGETS_BYTES)
    if not text.strip():
        raise ValueError(f"{path}: the file is empty; expected a JSON list of targets")
    try:
        return json.loads(text, object_pairs_hook=_unique_keys, parse_int=_short_int)
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}:{e.lineno}: not valid JSON ({e.msg})") from None
    except RecursionError:
        raise ValueError(f"{path}: not a list of targets (lists or objects nested too deeply)") from None
    except ValueError as e:  # from the hooks
        raise ValueError(f"{path}: {e}") from None


def _unique_keys(pairs: list[tuple[str, object]]) -> dict:
    """A JSON object, refused if it gives a key twice (JSON would keep the last silently)."""
    out = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"an object gives {shown(key)} twice")
        out[key] = value
    return out


def _short_int(text: str) -> int:
    """A JSON integer of at most 15 digits (no frame number or coordinate needs more)."""
    if len(text.lstrip("-")) > 15:
        raise ValueError(f"the integer {text[:12]}... has {len(text.lstrip('-'))} digits; no target needs that many")
    return int(text)


def _target(item: object, where: str) -> JointTarget:
    """One entry of TARGETS.json, checked; errors start with ``where``."""
    if not isinstance(item, dict):
        raise ValueError(f"{where}: expected an object like {{\"joint\": ..., \"frame\": ..., \"offset\": [...]}}, "
                         f"got {shown(item)}")
    unknown = [k for k in item if k not in TARGET_KEYS]
    if unknown:
        raise ValueError(f"{where}: unknown key {shown(unknown[0])}; a target has {', '.join(TARGET_KEYS)}")
    if "joint" not in item or "frame" not in item:
        raise ValueError(f"{where}: needs 'joint' and 'frame'")
    if ("position" in item) == ("offset" in item):
        raise ValueError(f"{where}: give exactly one of 'position' or 'offset'")
    if not isinstance(item["joint"], str) or not item["joint"]:
        raise ValueError(f"{where}: 'joint' must be a joint name, got {shown(item['joint'])}")
    key = "position" if "position" in item else "offset"
    vec = _vector(item[key], where, key)
    return JointTarget(item["joint"], _frames(item["frame"], where),
                       vec if key == "position" else None, vec if key == "offset" else None)


def _whole(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _frames(value: object, where: str) -> tuple[int, int]:
    """'frame': a whole frame number or [first, last], counted from 0."""
    if _whole(value):
        frames = (value, value)
    elif isinstance(value, list) and len(value) == 2 and all(map(_whole, value)):
        frames = (value[0], value[1])
    else:
        raise ValueError(f"{where}: 'frame' must be a whole frame number or [first, last], got {shown(value)}")
    if not 0 <= frames[0] <= frames[1]:
        raise ValueError(f"{where}: 'frame' {shown(value)}: frames count from 0 and the last may not come "
                         "before the first")
    return frames


def _vector(value: object, where: str, key: str) -> tuple[float, float, float]:
    """'position' or 'offset' (``key``): three finite numbers within ``MAX_COORDINATE`` metres."""
    if not (isinstance(value, list) and len(value) == 3
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
        raise ValueError(f"{where}: '{key}' must be three numbers [x, y, z] in metres, got {shown(value)}")
    if not all(abs(v) <= MAX_COORDINATE for v in value):  # False for NaN and infinity too
        raise ValueError(f"{where}: '{key}' {shown(value)} holds a value that is not a number within "
                         f"{MAX_COORDINATE:g} m (it is in metres)")
    return tuple(float(v) for v in value)


def reach(skeleton, rotations: np.ndarray, root: np.ndarray, joint: int, target: np.ndarray, depth: int = 3,
          iterations: int = 20, damping: float = 1e-3) -> np.ndarray:
    """Rotation vectors (depth, 3) for the ``depth`` joints above ``joint`` (never the
    root) that bring ``joint`` to ``target`` in one frame (``rotations`` (J, 4), ``root``
    (3,)): damped Gauss-Newton on the world position, the smallest turn that reaches."""
    chain = limb(skeleton, joint, depth)
    if not chain:
        raise ValueError(f"joint {skeleton.names[joint]!r} hangs from the root: no limb to reach with")
    q0 = torch.from_numpy(rotations)
    offsets, tgt = torch.from_numpy(skeleton.offsets), torch.from_numpy(np.asarray(target, float))
    root_t = torch.from_numpy(root)

    def pos(w: torch.Tensor) -> torch.Tensor:
        q = q0.clone()
        q[chain] = R.quat_multiply(q0[chain], R.axis_angle_to_quat(w))
        return fk(skeleton.parents, q[None], root_t[None], offsets)[0, joint]

    w = torch.zeros(len(chain), 3, dtype=torch.float64)
    for _ in range(iterations):
        r = pos(w) - tgt
        if float(r.norm()) < 1e-5:
            break
        jac = torch.autograd.functional.jacobian(pos, w).reshape(3, -1)
        step = torch.linalg.solve(jac.T @ jac + damping * torch.eye(jac.shape[1], dtype=w.dtype), jac.T @ r)
        w = w - step.reshape(w.shape)
    out = np.zeros((skeleton.num_joints, 3))
    out[chain] = w.numpy()
    return out


def limb(skeleton, joint: int, depth: int = 3) -> list[int]:
    """The ``depth`` joints above ``joint`` (fewer near the root, never the root), nearest first:
    the joints ``reach`` turns."""
    chain, j = [], int(skeleton.parents[joint])
    while j > 0 and len(chain) < depth:
        chain.append(j)
        j = int(skeleton.parents[j])
    return chain


def limb_length(skeleton, joint: int, top: int) -> float:
    """Length of the bones from joint ``top`` down to ``joint``: the farthest ``joint`` gets from ``top``."""
    length, j = 0.0, joint
    while j != top:
        length += float(np.linalg.norm(skeleton.offsets[j]))
        j = int(skeleton.parents[j])
    return length


@dataclass
class SpatialEdit:
    """Meet joint position targets while the rest of the motion stays as it was.

    Each target frame is met by inverse kinematics on the limb above the joint (the
    smallest turn of its three nearest joints, not the root); the same turns fade in and
    out over ``falloff`` seconds around the targets (smoothstep), so the limb moves there
    and back as a whole; frames further away and the other joints keep the input's values
    exactly. With ``refine`` the MAP solver (targets with ``sigma_target`` m, fidelity
    ``sigma_root`` m, ``sigma_angle`` rad, the prior and contacts) then polishes the edited
    frames, and the targets are met again by IK.

    A target missed by more than ``TARGET_TOLERANCE`` (out of the limb's reach, or fighting
    another target) gives the nearest pose, with ``TaskResult.warnings`` saying by how much.
    """

    motion: Motion
    targets: list[JointTarget]
    prior: object
    sigma_target: float = 0.003
    sigma_root: float = 0.05
    sigma_angle: float = 0.1
    sigmas: TermSigmas = field(default_factory=TermSigmas)
    options: SolverOptions = field(default_factory=lambda: SolverOptions(pso=None))
    falloff: float = 0.5
    refine: bool = False

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
        if not self.falloff >= 0:
            raise ValueError(f"falloff is in seconds, 0 or more; got {self.falloff}")

    def wanted(self, prep) -> list[list[tuple[int, int, np.ndarray]]]:
        """(model frame, joint, target position) of each frame of each target, target by target."""
        fps_o, fps_m = self.motion.fps, self.prior.spec.fps
        n = len(prep.x)
        pos_in = prep.model.positions()
        out = []
        for t in self.targets:
            j = self.prior.spec.joints.index(t.joint)
            out.append([(f, j, np.asarray(t.position, float) if t.position is not None
                         else pos_in[f, j] + np.asarray(t.offset))
                        for f in range(nearest_model_frame(t.frames[0], fps_o, fps_m),
                                       min(nearest_model_frame(t.frames[1], fps_o, fps_m), n - 1) + 1)])
        return out

    def miss_warnings(self, model: Motion, wanted: list[list[tuple[int, int, np.ndarray]]]) -> list[str]:
        """For each target (``wanted``, as ``wanted`` gives) missed by more than ``TARGET_TOLERANCE``
        in the model motion: at how many of its frames, the worst miss and its frame (the
        input's numbering), and whether it lies beyond the reach of the limb ``reach`` turns."""
        pos, sk = model.positions(), model.skeleton
        out = []
        for k, (t, mine) in enumerate(zip(self.targets, wanted)):
            miss = np.array([np.linalg.norm(pos[f, j] - tg) for f, j, tg in mine])
            if miss.max() <= TARGET_TOLERANCE:
                continue
            f, j, tg = mine[int(miss.argmax())]
            top = limb(sk, j)[-1]
            far, length = float(np.linalg.norm(tg - pos[f, top])), limb_length(sk, j, top)
            why = (f"; the target is {far:.2f} m from {sk.names[top]}, out of reach of the {length:.2f} m limb"
                   if far > length else "")
            out.append(f"edit: target {k} ({t.joint}) is missed by more than {TARGET_TOLERANCE * 100:g} cm at "
                       f"{int((miss > TARGET_TOLERANCE).sum())} of its {len(mine)} frames, by up to "
                       f"{miss.max() * 100:.1f} cm at frame {round(f * self.motion.fps / self.prior.spec.fps)}{why}")
        return out

    def _meet(self, skeleton, rot: np.ndarray, root: np.ndarray, wanted: list[tuple[int, int, np.ndarray]]) -> np.ndarray:
        """Rotations with every target met at its frame and the turns faded around it."""
        n = len(rot)
        fade = max(int(round(self.falloff * self.prior.spec.fps)), 0)
        out = rot.copy()
        for joint in sorted({j for _, j, _ in wanted}):
            mine = sorted(((f, tg) for f, j, tg in wanted if j == joint), key=lambda m: m[0])
            frames = np.array([f for f, _ in mine])
            turns = np.stack([reach(skeleton, out[f], root[f], joint, tg) for f, tg in mine])
            # each frame takes the turn of the nearest target frame, faded with distance
            idx = np.arange(n)
            nearest = np.abs(idx[:, None] - frames[None]).argmin(1)
            dist = np.abs(idx - frames[nearest])
            inside = (idx >= frames.min()) & (idx <= frames.max())
            between = np.interp(idx, frames, np.arange(len(frames)))
            lo = np.floor(between).astype(int)
            hi = np.minimum(lo + 1, len(frames) - 1)
            a = (between - lo)[:, None, None]
            turn = np.where(inside[:, None, None], (1 - a) * turns[lo] + a * turns[hi], turns[nearest])
            w = smoothstep(np.where(inside, 1.0, 1 - dist / (fade + 1)))
            q = R.quat_multiply(torch.from_numpy(out), R.axis_angle_to_quat(torch.from_numpy(turn * w[:, None, None])))
            out = q.numpy()
        return out

    def solve(self) -> TaskResult:
        prior = self.prior
        prep = prepare(self.motion, prior)
        n = len(prep.x)
        t0 = time.perf_counter()
        per_target = self.wanted(prep)
        wanted = [w for mine in per_target for w in mine]
        rot = self._meet(prep.model.skeleton, prep.model.rotations, prep.model.root, wanted)
        model = prep.model.with_frames(rot, prep.model.root.copy(), None)
        result = None
        if self.refine:
            terms = [PoseFidelityTerm(model.root, model.rotations, self.sigma_root, self.sigma_angle, name="fidelity")]
            for k, t in enumerate(self.targets):
                j = prior.spec.joints.index(t.joint)
                tg = {f: p for f, jj, p in wanted if jj == j}
                terms.append(JointPositionTerm(j, tg, self.sigma_target, name=f"target_{k}_{t.joint}"))
            terms += standard_terms(prep, prior, self.sigmas)
            start = prepare(model, prior)
            result, model = run(prior, start, start.x.clone(), np.ones(n, bool), terms, self.options)
            model = model.with_frames(self._meet(model.skeleton, model.rotations, model.root, wanted), model.root, None)
        seconds = time.perf_counter() - t0
        pos_in, pos_out = prep.model.positions(), model.positions()
        errs = [np.linalg.norm(pos_out[f, j] - tg) for f, j, tg in wanted]
        target_frames = sorted({f for f, _, _ in wanted})
        fade = int(round(self.falloff * prior.spec.fps))
        others = [f for f in range(n) if all(abs(f - g) > fade for g in target_frames)]
        change = np.linalg.norm(pos_out - pos_in, axis=-1)
        metrics = {
            "target_error_cm_max": float(max(errs) * 100),
            "target_error_cm_mean": float(np.mean(errs) * 100),
            "untouched_frames_change_cm_max": float(change[others].max() * 100) if others else 0.0,
            "edited_frames_change_cm_mean": float(np.delete(change, others, axis=0).mean() * 100),
            "frames_per_second": n / max(seconds, 1e-9),
        }
        return judged(TaskResult(prep.to_file(model), model, result, metrics,
                                 {"sigma_target": self.sigma_target, "targets": len(self.targets),
                                  "falloff": self.falloff, "refine": self.refine},
                                 warned(self.miss_warnings(model, per_target))), prior, prep.start.ground)

    def summary(self, result: TaskResult) -> list[str]:
        """The metrics of ``result`` (of ``solve``) in sentences, for the command line."""
        m = result.metrics
        return [f"targets met within {m['target_error_cm_max']:.2f} cm ({m['target_error_cm_mean']:.2f} cm on average)",
                f"frames away from the targets moved {m['untouched_frames_change_cm_max']:.2f} cm at most, the "
                f"frames near them {m['edited_frames_change_cm_mean']:.2f} cm on average",
                f"speed: {m['frames_per_second']:.0f} frames per second"]
