"""The glitch finder (``motionopt.glitches``) on real capture: how many bursts it finds in
motion that has none (clean, and with 1, 3 and 5 cm of rotation noise), and how many of
the glitches injected into the same clips it finds (one per clip and noise level: a
random arm or leg joint turned 30-45 degrees for 0.1-0.4 s). Beside them, the swirls
(``find_swirls``) found in the same clips, each named: the capture's own glitches, as
far as anyone can tell by looking. Prints a table; the README's figures come from it.

    python bench/glitches.py [--data ../shared/data] [--seconds 20] [--every 3]
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from motionopt import bvh  # noqa: E402
from motionopt.glitches import find_glitches, find_swirls  # noqa: E402
from motionopt.noise import glitch, position_noise  # noqa: E402
from motionopt.table import format_table  # noqa: E402
from priors.heldout import SHARED_DATA  # noqa: E402
from problems.denoise import estimate_noise  # noqa: E402

LEVELS = (0.0, 0.01, 0.03, 0.05)
LIMBS = ("Shin", "LowerLeg", "Thigh", "UpperLeg", "Shldr", "UpperArm", "ForeArm", "LowerArm")


def files(data: Path, every: int) -> list[Path]:
    """Every ``every``-th clip of each dataset folder (the CMU folders, Bandai 1 and 2)."""
    groups = [sorted(data.glob("cmu/*/*.bvh")), sorted(data.glob("bandai/*.bvh")), sorted(data.glob("bandai2/*.bvh"))]
    return [f for g, step in zip(groups, (every, 2 * every, 20 * every)) for f in g[::step]]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=SHARED_DATA)
    ap.add_argument("--seconds", type=float, default=20.0, help="first seconds of each clip")
    ap.add_argument("--every", type=int, default=3, help="take every N-th CMU clip (Bandai: every 2N-th, 20N-th)")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    found = dict.fromkeys(LEVELS, 0)
    swirls: dict[float, list[str]] = {level: [] for level in LEVELS}
    hits = dict.fromkeys(LEVELS, 0)
    injected, seconds, t0 = 0, 0.0, time.perf_counter()
    for i, path in enumerate(files(args.data, args.every)):
        m = bvh.load(path)
        m = m[:min(m.num_frames, int(args.seconds * m.fps))]
        if m.num_frames < 2.5 * m.fps:
            continue
        seconds += m.num_frames / m.fps
        limbs = [j for j, n in enumerate(m.skeleton.names) if any(k in n for k in LIMBS)]
        joint, count = int(rng.choice(limbs)), int(rng.integers(round(0.1 * m.fps), round(0.4 * m.fps)))
        first = int(rng.integers(round(0.5 * m.fps), m.num_frames - count - round(0.5 * m.fps)))
        degrees = float(rng.uniform(30, 45))
        injected += 1
        for level in LEVELS:
            x = m if level == 0 else position_noise(m, level, seed=i)[0]
            noise = estimate_noise(x)[0]
            found[level] += len(find_glitches(x, noise))
            swirls[level] += [f"{path.relative_to(args.data)} {m.skeleton.names[w.joint]} frames {w.first}-{w.stop - 1}"
                              for w in find_swirls(x, noise)]
            seen = find_glitches(glitch(x, joint, first, count, degrees), noise)
            hits[level] += any(g.joint == joint and abs(g.first - first) <= 1 and abs(g.stop - first - count) <= 1
                               for g in seen)
    where = os.path.relpath(args.data, Path.cwd())
    print(f"Glitch finder on {seconds:.0f} s of real capture ({where}, {injected} clips; first {args.seconds:g} s of each), "
          f"{time.perf_counter() - t0:.0f} s")
    rows = [[f"{level * 100:g} cm", found[level], f"{hits[level]} of {injected}", len(swirls[level])]
            for level in LEVELS]
    print("\n".join(format_table(["noise", "bursts found in real motion", "injected glitches found", "swirls found"],
                                  rows)))
    for level in LEVELS:
        print(f"   swirls at {level * 100:g} cm: " + ("; ".join(swirls[level]) or "none"))


if __name__ == "__main__":
    main()
