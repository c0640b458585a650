"""Benchmark of the motion core on every clip in ../shared/data (CMU and Bandai).

1. BVH round trip: load, save, read again. Maximum relative channel error
   |a - b| / max(|a|, 1) (values below 1 compared absolutely), whether names,
   hierarchy, channels and frame time are unchanged, and the largest change of a world
   joint position.
2. Forward kinematics: ``motionopt.kinematics.fk`` (quaternions, torch) against a plain
   numpy reference (rotation matrices from scipy, 4x4 transforms joint by joint), in
   float64 and float32, on every frame of every clip.
3. Features: ``to_model_motion`` (prior joints, 30 fps), ``encode``, then
   ``decode_positions`` in float64 and float32; the largest world joint position error
   over every frame of every clip, and the largest on a clip's last frame (drift).
4. Dataset preparation: ``build_dataset`` on each folder (load, resample, drop joints,
   encode, normalise), wall-clock seconds with one torch thread and with the number
   ``--threads`` sets (torch's default otherwise). Many small tensor operations: when
   other processes keep the CPUs busy, torch's threads wait on each other and one thread
   is faster; the load average printed in the header tells how busy the machine was.

Run ``python bench/core.py [--threads N]``; the report is printed and written to
bench/results/core.txt.
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from motionopt import bvh
from motionopt.dataset import build_dataset
from motionopt.features import decode_positions, default_spec, encode, to_model_motion
from motionopt.kinematics import fk

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared" / "data"
RESULTS = ROOT / "bench" / "results" / "core.txt"
DATASETS = ("cmu", "bandai")


def numpy_fk(parents: np.ndarray, quats: np.ndarray, root: np.ndarray, local_t: np.ndarray) -> np.ndarray:
    """World positions (T, J, 3) by 4x4 homogeneous transforms, joint by joint over all frames."""
    t, j = quats.shape[:2]
    local = np.zeros((t, j, 4, 4))
    local[..., :3, :3] = Rotation.from_quat(quats.reshape(-1, 4), scalar_first=True).as_matrix().reshape(t, j, 3, 3)
    local[..., :3, 3] = local_t
    local[:, 0, :3, 3] = root
    local[..., 3, 3] = 1.0
    world = np.zeros_like(local)
    world[:, 0] = local[:, 0]
    for k in range(1, j):
        world[:, k] = world[:, parents[k]] @ local[:, k]
    return world[..., :3, 3]


@dataclass
class Row:
    """Worst figures over the clips of one dataset."""

    clips: int = 0
    frames: int = 0
    channel_rel: float = 0.0
    layout_same: bool = True
    position_m: float = 0.0
    fk64_m: float = 0.0
    fk32_m: float = 0.0
    decode64_m: float = 0.0
    decode32_m: float = 0.0
    drift32_m: float = 0.0
    seconds: dict[str, float] = field(default_factory=dict)


def round_trip(path: Path, tmp: Path, row: Row) -> None:
    sk, values, frame_time = bvh.read_channels(path)
    motion = bvh.load(path)
    out = bvh.save(motion, tmp / "out.bvh", force=True)
    sk2, values2, frame_time2 = bvh.read_channels(out)
    back = bvh.load(out)
    row.layout_same &= (sk2.names == sk.names and np.array_equal(sk2.parents, sk.parents)
                        and sk2.channels == sk.channels and frame_time2 == frame_time
                        and values2.shape == values.shape and np.allclose(sk2.offsets, sk.offsets, atol=1e-9))
    if values2.shape == values.shape:
        row.channel_rel = max(row.channel_rel, float((np.abs(values2 - values) / np.maximum(np.abs(values), 1)).max()))
    row.position_m = max(row.position_m, float(np.abs(back.positions() - motion.positions()).max()))


def kinematics(path: Path, row: Row) -> None:
    m = bvh.load(path)
    ref = numpy_fk(m.skeleton.parents, m.rotations, m.root, m.local_translations())
    for dtype, attr in ((torch.float64, "fk64_m"), (torch.float32, "fk32_m")):
        pos = fk(m.skeleton.parents, torch.from_numpy(m.rotations).to(dtype), torch.from_numpy(m.root).to(dtype),
                 torch.from_numpy(m.skeleton.offsets).to(dtype), torch.from_numpy(m.local_translations()).to(dtype))
        setattr(row, attr, max(getattr(row, attr), float(np.abs(pos.double().numpy() - ref).max())))


def features(path: Path, row: Row) -> None:
    m = bvh.load(path)
    spec = default_spec(m.skeleton)
    model = to_model_motion(m, spec)
    x, start = encode(model, spec)
    ref = model.positions()
    for dtype, attr in ((torch.float64, "decode64_m"), (torch.float32, "decode32_m")):
        err = np.abs(decode_positions(x.to(dtype), spec, model.skeleton, start).double().numpy() - ref).max(axis=(1, 2))
        setattr(row, attr, max(getattr(row, attr), float(err.max())))
        if dtype == torch.float32:
            row.drift32_m = max(row.drift32_m, float(err[-1]))


def timed(fn, *args) -> float:
    t0 = time.perf_counter()
    fn(*args)
    return time.perf_counter() - t0


def run(folder: str) -> Row:
    clips = sorted((SHARED / folder).rglob("*.bvh"))
    row = Row(clips=len(clips))
    with tempfile.TemporaryDirectory() as tmp:
        row.seconds["round trip"] = sum(timed(round_trip, p, Path(tmp), row) for p in clips)
    row.frames = sum(bvh.read_channels(p)[1].shape[0] for p in clips)
    row.seconds["fk"] = sum(timed(kinematics, p, row) for p in clips)
    row.seconds["features"] = sum(timed(features, p, row) for p in clips)
    threads = torch.get_num_threads()
    for n in sorted({1, threads}):
        torch.set_num_threads(n)
        t0 = time.perf_counter()
        ds = build_dataset(SHARED / folder)
        row.seconds[f"dataset {n}"] = time.perf_counter() - t0
    torch.set_num_threads(threads)
    row.seconds["dataset frames"] = ds.num_train_frames + sum(len(x) for x in ds.val.values())
    return row


def report(rows: dict[str, Row], threads: int) -> str:
    def mm(v: float) -> str:
        return f"{v * 1000:.2e} mm"

    lines = [f"motion core on ../shared/data ({time.strftime('%Y-%m-%d')}, torch {torch.__version__}, "
             f"{threads} torch thread(s), load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs)", ""]
    header = f"{'':50s}" + "".join(f"{name:>22s}" for name in rows)
    lines.append(header)

    def line(label: str, fmt) -> None:
        lines.append(f"{label:50s}" + "".join(f"{fmt(r):>22s}" for r in rows.values()))

    line("clips / frames", lambda r: f"{r.clips} / {r.frames}")
    line("round trip: max relative channel error", lambda r: f"{r.channel_rel:.1e}")
    line("round trip: names, hierarchy, frame time same", lambda r: "yes" if r.layout_same else "NO")
    line("round trip: max world position change", lambda r: mm(r.position_m))
    line("fk vs numpy reference, float64", lambda r: mm(r.fk64_m))
    line("fk vs numpy reference, float32", lambda r: mm(r.fk32_m))
    line("encode/decode max position error, float64", lambda r: mm(r.decode64_m))
    line("encode/decode max position error, float32", lambda r: mm(r.decode32_m))
    line("  of which on a clip's last frame, float32", lambda r: mm(r.drift32_m))
    for n in sorted({1, threads}):
        line(f"dataset preparation (build_dataset), {n} thread{'s' if n > 1 else ''}",
             lambda r, n=n: f"{r.seconds[f'dataset {n}']:.1f} s")
    line("  frames prepared (30 fps)", lambda r: f"{int(r.seconds['dataset frames'])}")
    line("time: load+save+reload all clips", lambda r: f"{r.seconds['round trip']:.1f} s")
    line("time: fk checks / feature checks", lambda r: f"{r.seconds['fk']:.1f} s / {r.seconds['features']:.1f} s")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    missing = [d for d in DATASETS if not (SHARED / d).is_dir()]
    if missing:
        raise SystemExit(f"bench/core.py needs {SHARED}/{{{','.join(DATASETS)}}}; missing: {', '.join(missing)}")
    rows = {name: run(name) for name in DATASETS}
    text = report(rows, torch.get_num_threads())
    print(text, end="")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(text)


if __name__ == "__main__":
    main()
