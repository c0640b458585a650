"""Benchmark of the foot-contact cleanup (``motionopt.footik.clean_contacts``).

On held-out Bandai walking clips (on the prior's joints at 30 fps, ``to_model_motion``
with ``default_spec``), contact labels are taken from the clean clip
(``features.contact_labels``); the root is then carried along at a constant horizontal
velocity (default 0.3 m/s along +x) so that planted feet slide, and the slid clip is
cleaned with the default settings. Per clip and for the clean clip itself (drift 0):

- skating (m/s, ``metrics.foot_skating``): mean horizontal speed of the contact joints
  over frame steps on which they are within 1 cm, and within 3 cm (the metric's
  default), of their planted height; the 3 cm figure also counts swing frames near the
  floor that no contact label covers;
- contact speed (m/s): on frame steps where a foot is labelled, the speed of its
  slowest labelled joint (the point that should stand still), averaged;
- lifted: share of contact frames on which the cleanup left the foot more than 1 cm above
  its plane because the leg could not reach it, and the largest such lift (cm);
- acceleration: largest joint acceleration of the result over that of the clean clip;
- time: wall-clock milliseconds of ``clean_contacts`` per 1000 frames (median of 5).

Run ``python bench/footik.py [--drift 0.3] [--threads 1]``; the report is printed.
"""
from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from motionopt import bvh, metrics
from motionopt.features import contact_labels, default_spec, estimate_ground, to_model_motion
from motionopt.footik import clean_contacts, find_legs
from motionopt.motion import Motion

ROOT = Path(__file__).resolve().parent.parent
BANDAI = ROOT.parent / "shared" / "data" / "bandai"
CLIPS = ("dataset-1_walk_proud_002.bvh", "dataset-1_walk_childish_002.bvh", "dataset-1_walk_masculinity_002.bvh")


@dataclass
class Row:
    clip: str
    drift: float
    frames: int
    skate_1cm: tuple[float, float]  # before, after
    skate_3cm: tuple[float, float]
    contact_speed: tuple[float, float]
    lifted: float
    lift_max: float
    accel_ratio: float
    ms_per_1000: float


def contact_speed(m: Motion, joints: list[str], contacts: np.ndarray) -> float:
    """Mean over labelled frame steps of each foot of its slowest labelled joint's
    horizontal speed (m/s)."""
    p = torch.from_numpy(m.positions()) * torch.tensor([1.0, 0.0, 1.0], dtype=torch.float64)
    idx = [m.skeleton.index(n) for n in joints]
    speed = metrics.joint_speed(p[:, idx], m.fps).numpy()
    out = []
    for leg in find_legs(m.skeleton, joints):
        on = contacts[:, list(leg.columns)] > 0.5
        both = on[1:] & on[:-1]
        out.append(np.where(both, speed[:, list(leg.columns)], np.inf).min(axis=1)[both.any(axis=1)])
    return float(np.concatenate(out).mean())


def lifted(m: Motion, joints: list[str], contacts: np.ndarray, heights: np.ndarray) -> tuple[float, float]:
    """Share of contact frames with the foot's lowest joint over 1 cm above its plane, and
    the largest height (cm) of that joint."""
    y = m.positions()[:, [m.skeleton.index(n) for n in joints], 1] - heights
    lows = [y[(contacts[:, list(leg.columns)] > 0.5).any(axis=1)][:, list(leg.columns)].min(axis=1)
            for leg in find_legs(m.skeleton, joints)]
    low = np.concatenate(lows)
    return float(np.mean(low > 0.01)), float(low.max() * 100)


def max_acceleration(m: Motion) -> float:
    p = m.positions()
    return float(np.linalg.norm(p[2:] - 2 * p[1:-1] + p[:-2], axis=-1).max() * m.fps ** 2)


def bench_clip(path: Path, drift: float) -> list[Row]:
    motion = bvh.load(path)
    spec = default_spec(motion.skeleton)
    clean = to_model_motion(motion, spec)
    joints = list(spec.contact_joints)
    idx = [clean.skeleton.index(n) for n in joints]
    pos = clean.positions()
    contacts = contact_labels(pos, idx, clean.fps, estimate_ground(pos, idx), spec.contact_height,
                              spec.contact_speed)
    rows = []
    for v in (0.0, drift):
        t = np.arange(clean.num_frames)[:, None] / clean.fps
        slid = clean.with_frames(clean.rotations, clean.root + t * np.array([v, 0.0, 0.0]))
        times = []
        for _ in range(5):
            start = time.perf_counter()
            cleaned = clean_contacts(slid, joints, contacts)
            times.append(time.perf_counter() - start)
        heights = metrics.rest_heights(torch.from_numpy(slid.positions()), idx).numpy()

        def skate(m: Motion, threshold: float) -> float:
            return float(metrics.foot_skating(torch.from_numpy(m.positions()), m.fps, idx, threshold=threshold))

        share, top = lifted(cleaned, joints, contacts, heights)
        rows.append(Row(path.stem.removeprefix("dataset-1_"), v, clean.num_frames,
                        (skate(slid, 0.01), skate(cleaned, 0.01)), (skate(slid, 0.03), skate(cleaned, 0.03)),
                        (contact_speed(slid, joints, contacts), contact_speed(cleaned, joints, contacts)),
                        share, top, max_acceleration(cleaned) / max_acceleration(clean),
                        statistics.median(times) / clean.num_frames * 1e6))
    return rows


def report(rows: list[Row]) -> str:
    head = (f"{'clip':<22} {'drift':>5} {'frames':>6} | {'skate 1cm':>13} | {'skate 3cm':>13} | "
            f"{'contact speed':>13} | {'lifted':>6} {'max':>5} | {'accel':>5} | {'ms/1000 fr':>10}")
    lines = [head, f"{'':<22} {'m/s':>5} {'':>6} | {'before  after':>13} | {'before  after':>13} | "
                   f"{'before  after':>13} | {'>1cm':>6} {'cm':>5} | {'ratio':>5} |", "-" * len(head)]
    for r in rows:
        lines.append(f"{r.clip:<22} {r.drift:>5.2f} {r.frames:>6} | {r.skate_1cm[0]:>6.3f} {r.skate_1cm[1]:>6.3f} | "
                     f"{r.skate_3cm[0]:>6.3f} {r.skate_3cm[1]:>6.3f} | {r.contact_speed[0]:>6.3f} "
                     f"{r.contact_speed[1]:>6.3f} | {r.lifted:>6.1%} {r.lift_max:>5.1f} | {r.accel_ratio:>5.2f} | "
                     f"{r.ms_per_1000:>10.1f}")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--drift", type=float, default=0.3, help="root drift in m/s along +x (default 0.3)")
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    missing = [c for c in CLIPS if not (BANDAI / c).exists()]
    if missing:
        raise SystemExit(f"clips not found in {BANDAI}: {', '.join(missing)}")
    rows = [row for clip in CLIPS for row in bench_clip(BANDAI / clip, args.drift)]
    print(f"foot-contact cleanup, {time.strftime('%Y-%m-%d %H:%M')}, torch {torch.__version__}, "
          f"{args.threads} thread(s)\n{report(rows)}")


if __name__ == "__main__":
    main()
