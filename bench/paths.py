"""Half a minute of path following, judged every 5 s (issue 19's figures).

From the first second of held-out walks of the Bandai locomotion prior, ``PathFollow``
walks four timed 30 s paths drawn from where the seed ends: a 1.5 m circle walked twice,
a 3 m square walked twice, an S-curve, and stop-and-go (6 s walking, 3 s standing,
repeated). Each runs as the command does by default (a rollout with its root on the
path, then the MAP solver) and with ``--no-refine`` (the rollout alone). Per 5 s segment of the new motion:

- the mean distance of the root to the path (target: at most 3 cm);
- foot skating over the held-out mocap's (target: at most 1.2);
- the share of frames whose lowest foot joint is within 3 cm of its resting height
  (target: at least 90%);
- whether the hip height stays within the held-out data's 1st-99th percentile;

with, per run, the hip sway (``metrics.hip_sway``: RMS speed of the root across its
direction of travel, against the held-out walks' range; a root pinned to the path
sways at a fifth of a walk's, a corner taken dead square far above it) and the frames
per second of the whole run (target: at least 30); skating is "nan" in a
segment where no foot is planted (it fails the test). The measures and the
held-out reference are ``bench/prior.py``'s (``HumanRange``, ``segment_checks``), which
judges free rollouts the same way. The CMU prior holds no locomotion to seed a walk.
With the shipped prior the report is also written to bench/results/paths.txt.

    python bench/paths.py [--prior CKPT] [--seeds 2] [--seconds 30]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import prior as prior_bench  # noqa: E402  (bench/prior.py: the segment measures)
from tasks import seed_frame  # noqa: E402  (bench/tasks.py: paths drawn where a seed ends)
from motionopt.metrics import hip_sway  # noqa: E402
from motionopt.motion import Motion  # noqa: E402
from motionopt.objective import nearest_on_polyline_sq  # noqa: E402
from motionopt.table import format_table  # noqa: E402
from priors.checkpoint import CHECKPOINT_DIR, load_prior  # noqa: E402
from priors.heldout import held_out_clips  # noqa: E402
from problems.path_follow import PathFollow  # noqa: E402

SEGMENT = prior_bench.SEGMENT_SECONDS
SHIPPED = CHECKPOINT_DIR / "bandai-locomotion-ccnet.pt"
RESULTS = ROOT / "bench" / "results" / "paths.txt"


def drawn(seed: Motion, seconds: float) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Timed paths (points (N, 2), seconds after the seed's end (N,)) lasting ``seconds``,
    drawn in the frame where the seed ends: x to its side, z along its heading."""
    place = seed_frame(seed)

    def evenly(local: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The path walked at one pace from start to end in ``seconds``."""
        s = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(local, axis=0), axis=1))))
        return place(local), 1 / 30 + s / s[-1] * seconds

    u = np.linspace(0, 1, 241)
    circle = np.stack((1.5 - 1.5 * np.cos(4 * np.pi * u), 1.5 * np.sin(4 * np.pi * u)), -1)
    square = np.array([[0, 0], [0, 3], [3, 3], [3, 0]] * 2 + [[0, 0]], dtype=float)
    s_curve = np.stack((np.sin(2 * np.pi * u * seconds / 10), u * seconds), -1)
    # stop and go: 6 s at 1 m/s, 3 s standing (a repeated point), and again
    points, times, t, z = [[0.0, 0.0]], [1 / 30], 1 / 30, 0.0
    while t < seconds - 1e-9:
        walk = min(6.0, seconds - t)
        z, t = z + walk, t + walk
        points.append([0.0, z])
        times.append(t)
        if t < seconds - 1e-9:
            t = min(t + 3.0, seconds)
            points.append([0.0, z])
            times.append(t)
    return {"1.5 m circle twice": evenly(circle), "3 m square twice": evenly(square),
            "S-curve": evenly(s_curve), "stop and go": (place(np.array(points)), np.array(times))}


def judged(prior, motion: Motion, n_seed: int, path: np.ndarray, ground: float,
           ref: prior_bench.HumanRange) -> list[dict]:
    """Per segment of the new frames: ``segment_checks``'s measures and the mean distance
    of the root to the path (cm)."""
    pos = torch.from_numpy(motion.positions()[n_seed:])
    segs = prior_bench.segment_checks(prior, pos, ground, ref)
    dist = np.sqrt(nearest_on_polyline_sq(torch.from_numpy(motion.root[n_seed:, [0, 2]]),
                                          torch.from_numpy(path)).numpy()) * 100
    w = round(SEGMENT * prior.spec.fps)
    for i, g in enumerate(segs):
        g["dist"] = float(dist[i * w:(i + 1) * w].mean())
        g["hips"] = ref.hip_low <= g["hip5"] and g["hip95"] <= ref.hip_high
    return segs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--prior", type=Path, default=SHIPPED)
    ap.add_argument("--seeds", type=int, default=2, help="held-out walks seeding the paths")
    ap.add_argument("--seconds", type=float, default=30.0, help="length of each path in seconds")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    prior = load_prior(args.prior)
    fps = prior.spec.fps
    clips = held_out_clips(prior)
    ref = prior_bench.HumanRange.of(prior, clips)
    seeds = [c for c in clips if "_walk_" in c.name and c.motion.num_frames >= fps][:args.seeds]
    walk_sway = [float(hip_sway(torch.from_numpy(c.motion.root[:, [0, 2]]), fps)) * 100 for c in clips
                 if "walk" in c.name]
    walk_sway = [v for v in walk_sway if np.isfinite(v)]
    rows, passing, t_all = [], {}, time.perf_counter()
    for clip in seeds:
        seed = clip.motion[:int(fps)]
        for label, (path, times) in drawn(seed, args.seconds).items():
            for method, refine in (("default", True), ("--no-refine", False)):
                t0 = time.perf_counter()
                r = PathFollow(seed, path, prior, times=times, refine=refine).solve()
                rate = r.metrics["new_frames"] / (time.perf_counter() - t0)
                segs = judged(prior, r.model_motion, seed.num_frames, path, clip.start.ground, ref)
                ok = passing.setdefault(method, {"dist": 0, "skating": 0, "toe": 0, "hips": 0, "all": 0, "of": 0})
                for g in segs:
                    checks = (g["dist"] <= 3, g["skating"] <= 1.2, g["toe"] >= 0.9, g["hips"])
                    for key, good in zip(("dist", "skating", "toe", "hips"), checks):
                        ok[key] += good
                    ok["all"] += all(checks)
                    ok["of"] += 1
                sway = float(hip_sway(torch.from_numpy(r.model_motion.root[seed.num_frames:, [0, 2]]), fps)) * 100
                rows.append([label, clip.name.split("/")[-1].replace("dataset-1_", "").replace("_001.bvh", ""),
                             method, f"{rate:.0f}", f"{sway:.1f}", " ".join(f"{g['dist']:.1f}" for g in segs),
                             " ".join(f"{g['skating']:.1f}" for g in segs),
                             " ".join(f"{100 * g['toe']:.0f}" for g in segs),
                             f"{sum(g['hips'] for g in segs)}/{len(segs)}"])
    lines = [f"Path following for {args.seconds:g} s from the first second of {len(seeds)} held-out walks "
          f"({args.prior.name}); per {SEGMENT:g} s segment: root-to-path distance (cm; target <= 3), skating over "
          f"the held-out mocap's {ref.skating:.3f} m/s (target <= 1.2), lowest foot within 3 cm of its resting "
          f"height (% of frames; target >= 90), hip height within {ref.hip_low:.2f}-{ref.hip_high:.2f} m (segments); "
          f"frames/s of the whole run (target >= 30); hip sway of the run (cm/s across the direction of travel; "
          f"{len(walk_sway)} held-out walks: {min(walk_sway):.1f}-{max(walk_sway):.1f}, median "
          f"{np.median(walk_sway):.1f}); {time.perf_counter() - t_all:.0f} s"]
    lines += format_table(["path", "seed", "method", "fr/s", "sway cm/s", "dist cm per segment", "skating / mocap",
                           "lowest foot down %", "hips in range"], rows)
    lines += [f"   {method}: of {ok['of']} segments, distance {ok['dist']}, skating {ok['skating']}, "
              f"foot down {ok['toe']}, hips {ok['hips']}; all four {ok['all']}" for method, ok in passing.items()]
    print("\n".join(lines))
    if args.prior == SHIPPED and args.seconds == 30 and args.seeds == 2:
        RESULTS.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
