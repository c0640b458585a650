"""The offline demo: path following, denoising and in-betweening on clips shipped in the
package, with the shipped priors, writing BVH files, pictures and a report."""
from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from . import bvh, plot
from .motion import Motion

DATA = Path(__file__).parent / "data"
WALK_CLIP = DATA / "bandai-walk-normal-001.bvh"
MARTIAL_CLIP = DATA / "cmu-martial-03-steps.bvh"


@dataclass
class DemoStep:
    """One task of the demo: what it did, where the files are, its key numbers."""

    name: str
    description: str
    files: list[Path]
    metrics: dict
    seconds: float


@dataclass
class DemoSummary:
    out_dir: Path
    steps: list[DemoStep] = field(default_factory=list)

    @property
    def seconds(self) -> float:
        return sum(s.seconds for s in self.steps)


def drawn_curve(start: np.ndarray, heading: np.ndarray, length: float = 4.0, turn: float = np.pi / 2,
                points: int = 25) -> np.ndarray:
    """A smooth left-turning arc of ``length`` metres from ``start`` along ``heading``."""
    heading = heading / np.linalg.norm(heading)
    left = np.array([heading[1], -heading[0]])
    radius = length / turn
    a = np.linspace(0.0, turn, points)
    return start + heading * radius * np.sin(a)[:, None] + left * radius * (1 - np.cos(a))[:, None]


def noisy_copy(motion: Motion, sigma_rad: float, seed: int) -> Motion:
    """The motion with Gaussian noise on every local joint rotation (radians, per axis)
    and on the root position (sigma_rad * 0.1 m), as capture noise looks."""
    import torch

    from .rotations import axis_angle_to_quat, quat_multiply

    rng = np.random.default_rng(seed)
    noise = rng.normal(0.0, sigma_rad, motion.rotations.shape[:-1] + (3,))
    rot = quat_multiply(torch.from_numpy(motion.rotations), axis_angle_to_quat(torch.from_numpy(noise))).numpy()
    root = motion.root + rng.normal(0.0, sigma_rad * 0.1, motion.root.shape)
    return motion.with_frames(rot, root, motion.translations)


def _write_report(path: Path, result, extra: dict) -> Path:
    path.write_text(json.dumps({**extra, **result.report()}, indent=2, default=float))
    return path


def run_demo(out_dir: str | Path, force: bool = False, fast: bool = False,
             progress: Callable[[str], None] = lambda s: None) -> DemoSummary:
    """Run the three demo tasks and write everything into ``out_dir``.

    ``fast`` walks a shorter path (for tests). Refuses to write over files that
    exist unless ``force``.
    """
    from priors.checkpoint import CHECKPOINT_DIR, load_prior
    from problems.denoise import Denoise
    from problems.inbetween import Inbetween
    from problems.path_follow import PathFollow

    out = Path(out_dir)
    names = ["path-follow.bvh", "path.csv", "path-follow.png", "path-follow.json", "noisy.bvh", "denoised.bvh",
             "denoise-trajectory.png", "denoise.json", "inbetween.bvh", "inbetween.png", "inbetween.json",
             "summary.json"]
    clash = [n for n in names if (out / n).exists()]
    if clash and not force:
        raise FileExistsError(f"{out} already holds demo files ({', '.join(clash[:3])}...); "
                              "pass --force to overwrite them or choose another --out-dir")
    out.mkdir(parents=True, exist_ok=True)
    summary = DemoSummary(out)

    # 1. Path following: continue a walk along a drawn curve (Bandai locomotion prior).
    t0 = time.perf_counter()
    progress("path following: walking along a drawn curve")
    walk = bvh.load(WALK_CLIP)
    seed = walk[:30]
    walk_prior = load_prior(CHECKPOINT_DIR / "bandai-locomotion-ccnet.pt")
    hips = seed.positions()[:, 1]
    path = drawn_curve(hips[-1, [0, 2]], hips[-1, [0, 2]] - hips[-8, [0, 2]], length=3.0 if fast else 4.5)
    np.savetxt(out / "path.csv", path, delimiter=",", header="x,z", comments="", fmt="%.4f")
    task = PathFollow(seed, path, walk_prior)
    res = task.solve()
    bvh.save(res.motion, out / "path-follow.bvh", force=True)
    plot.plot_root_paths({"output": res.motion, "seed": seed}, out / "path-follow.png", target=path,
                         title="Path following: root path against the drawn path", force=True)
    _write_report(out / "path-follow.json", res, {"task": "path-follow", "seed": str(WALK_CLIP)})
    summary.steps.append(DemoStep("path following", "a walk continued along a 90-degree left curve",
                                  [out / "path-follow.bvh", out / "path.csv", out / "path-follow.png"],
                                  {k: res.metrics[k] for k in ("path_distance_cm_mean", "foot_skating_cm_per_s",
                                                               "new_frames", "frames_per_second")},
                                  time.perf_counter() - t0))

    # 2. Denoising: noise added to a martial-arts excerpt, then cleaned (CMU prior).
    t0 = time.perf_counter()
    progress("denoising: cleaning a noised martial-arts excerpt")
    clip = bvh.load(MARTIAL_CLIP)
    clean = clip[:240].resample(30.0)
    noisy = noisy_copy(clean, 0.04, seed=0)
    cmu_prior = load_prior(CHECKPOINT_DIR / "cmu-ccnet.pt")
    res = Denoise(noisy, cmu_prior).solve()
    bvh.save(noisy, out / "noisy.bvh", force=True)
    bvh.save(res.motion, out / "denoised.bvh", force=True)
    plot.plot_joint_trajectories({"noisy": noisy, "denoised": res.motion, "clean": clean}, "lHand",
                                 out / "denoise-trajectory.png", title="Left hand before and after denoising",
                                 force=True)
    from .metrics import mpjpe
    import torch

    err = {name: float(mpjpe(torch.from_numpy(m.positions()), torch.from_numpy(clean.positions())) * 100)
           for name, m in (("noisy", noisy), ("denoised", res.motion))}
    _write_report(out / "denoise.json", res, {"task": "denoise", "mpjpe_cm": err})
    summary.steps.append(DemoStep("denoising", "rotation noise of 0.04 rad added to 2 s of martial arts, removed",
                                  [out / "noisy.bvh", out / "denoised.bvh", out / "denoise-trajectory.png"],
                                  {"mpjpe_noisy_cm": err["noisy"], "mpjpe_denoised_cm": err["denoised"],
                                   "jerk_input": res.metrics["jerk_input_m_per_s3"],
                                   "jerk_output": res.metrics["jerk_output_m_per_s3"]},
                                  time.perf_counter() - t0))

    # 3. In-betweening: a 0.5 s gap in the same excerpt synthesised (CMU prior).
    t0 = time.perf_counter()
    progress("in-betweening: filling a gap between kept frames")
    n = clip.num_frames
    keep = [(0, 180), (240, n)]
    res = Inbetween(clip, keep, cmu_prior).solve()
    bvh.save(res.motion, out / "inbetween.bvh", force=True)
    plot.plot_filmstrip({"input": clip[150:270], "in-between": res.motion[150:270]}, out / "inbetween.png",
                        frames=6, first_frame=150, title="In-betweening: frames 180-239 synthesised", force=True)
    _write_report(out / "inbetween.json", res, {"task": "inbetween", "keep": keep})
    summary.steps.append(DemoStep("in-betweening", "frames 180-239 (0.5 s at 120 fps) removed and synthesised",
                                  [out / "inbetween.bvh", out / "inbetween.png"],
                                  {"join_root_error_cm": res.metrics["join_root_error_cm"],
                                   "synthesised_frames": res.metrics["synthesised_frames"]},
                                  time.perf_counter() - t0))
    (out / "summary.json").write_text(json.dumps(
        {"steps": [{"name": s.name, "description": s.description, "files": [str(f) for f in s.files],
                    "metrics": s.metrics, "seconds": s.seconds} for s in summary.steps]}, indent=2, default=float))
    return summary
