"""Benchmark of the editing tasks (``problems``) on held-out clips, against the baselines
an animator would use. Everything runs at the prior's 30 fps on the prior's joints (clips
are resampled to it first, so that baselines and ours see the same frames), on the
validation clips named in the checkpoint's metadata (no model was trained on them);
clips shorter than a section needs are left out of it.

1. Path following: seed = a clip's first second, path = its root path over the next
   ``--seconds`` (timed by the clip); plus drawn paths (circle, S-curve, sharp turn, stop
   and restart) from held-out walking seeds. The task clamps the root channels to the
   path, so the distance is near zero by construction; what tells is foot skating
   (``metrics.foot_skating``) of ours against the held-out mocap of the same segment
   (drawn paths: the mean of the held-out segments), prior NLL per frame of ours and of
   the mocap, and output frames per second (rollout and foot IK included).
2. Denoising: joint positions moved by 1, 3 and 5 cm RMS, made in the motion's own
   degrees of freedom: every local rotation turned by an axis-angle from N(0, s^2 I), s
   calibrated per clip for that RMS displacement (``bench/prior.py``'s noise; the root
   path is left alone). Baselines on joint positions: 4th-order Butterworth (filtfilt)
   with the cutoff in 2-12 Hz that is best per noise level on these very clips (an
   oracle choice), Savitzky-Golay with the best window (5-31 frames) and order (2, 3).
   Ours (default, no oracle): the MAP solve (fidelity, prior, contacts, joint
   accelerations) started from the per-joint low-pass at the cutoff of least Stein risk
   for the noise level estimated from the input; also that filter alone, with foot IK,
   and the MAP solve without the prior (what the learned prior adds). MPJPE to the clean
   clip, foot skating, jerk (the jitter measure); the MAP objective's terms at the clean
   clip, the start and the result. 2b: the same at the file's own rate on every joint;
   2c: a 0.25 s glitch of 30 degrees on one knee.
3. In-betweening (LAFAN1 protocol): 10 context frames, a gap of 5, 15 or 30 frames, 1
   target frame; L2P (metres, unnormalised), L2Q and NPSS (world quaternions) against
   SLERP of local rotations plus linear root interpolation; ours with the autoregressive
   prior (the default) and with ``--method latent`` (the shipped latent prior).
4. Prefix completion: 1 s continuation after 1 s of a clip, from every 2 s of each
   held-out clip: MPJPE to the real
   continuation against zero-velocity (last frame held) and constant-velocity (root
   velocity and per-joint angular velocity of the last frame kept) extrapolation; prior
   NLL per frame of the completion and of the real continuation. Ours as ``complete``
   runs it (its solve also seeded by the shipped latent prior's continuation), with the
   rollouts alone (``--latent-seed none``) and with ``--method latent``.
5. Spatial edits: hand and foot targets moved 10-20 cm at single frames and ranges:
   target error and the change of frames more than the falloff away from any target.

Run ``python bench/tasks.py [--prior CKPT] [--clips N] [--tasks path denoise ...]``; the
printed report is written to bench/results/tasks.txt (``--out``) when every task runs.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from scipy.signal import butter, filtfilt, savgol_filter

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from motionopt import bvh  # noqa: E402
from motionopt import rotations as R  # noqa: E402
from motionopt.codec import Codec  # noqa: E402
from motionopt.kinematics import fk  # noqa: E402
from motionopt.metrics import foot_skating, jerk, l2p, l2q, npss, rest_heights  # noqa: E402
from motionopt.motion import Motion  # noqa: E402
from motionopt.naturalness import HumanRange, flagged_seconds, out_of_range, per_second, spans  # noqa: E402
from motionopt.noise import glitch, position_noise  # noqa: E402
from motionopt.table import format_table  # noqa: E402
from motionopt.solver import Problem, SolverOptions  # noqa: E402
from motionopt.solver.diagnostics import energies_at  # noqa: E402
from priors.checkpoint import CheckpointError, load_prior  # noqa: E402
from priors.heldout import data_folder, held_out_clips  # noqa: E402
from problems.common import prepare  # noqa: E402
from problems.denoise import Denoise, denoise_options  # noqa: E402
from problems.edit import JointTarget, SpatialEdit  # noqa: E402
from problems.inbetween import Inbetween, complete  # noqa: E402
from problems.latent import LatentTask, gap_inversion_options, load_latent_for  # noqa: E402
from problems.path_follow import PathFollow  # noqa: E402

RESULTS = ROOT / "bench" / "results" / "tasks.txt"
LOCOMOTION = ROOT / "priors" / "checkpoints" / "bandai-locomotion-ccnet.pt"


def short(name: str) -> str:
    return name.replace("dataset-1_", "").replace("_001", "").replace(".bvh", "")


def continuation_nll(prior, m: Motion, start: int) -> float:
    """Mean prior NLL per frame of frames ``start:`` given the frames before them."""
    x = Codec.of(prior).features(m)
    with torch.no_grad():
        return float(prior.nll(x[start:], x[max(0, start - prior.receptive_field):start]).mean())


def skating(prior, m: Motion) -> float:
    return float(foot_skating(torch.from_numpy(m.positions()), m.fps, prior.spec.contact_indices())) * 100


# ---- 1. path following ----------------------------------------------------------------
def seed_frame(seed: Motion) -> Callable[[np.ndarray], np.ndarray]:
    """Ground points (N, 2) drawn where the seed ends (x to its side, z along its heading)
    to the seed's world coordinates."""
    end = seed.root[-1, [0, 2]]
    q = seed.rotations[-1, 0]
    yaw = 2 * np.arctan2(q[2], q[0])
    fwd, side = np.array([np.sin(yaw), np.cos(yaw)]), np.array([np.cos(yaw), -np.sin(yaw)])
    return lambda local: end + local[:, :1] * side + local[:, 1:] * fwd


def drawn_paths(seed: Motion) -> dict[str, tuple[np.ndarray, np.ndarray | None]]:
    """Paths (N, 2) from where the seed ends along its heading, with times (stop and restart)."""
    place = seed_frame(seed)
    u = np.linspace(0, 1, 60)
    circle = np.stack((1.5 - 1.5 * np.cos(2 * np.pi * u), 1.5 * np.sin(2 * np.pi * u)), -1)
    s_curve = np.stack((0.8 * np.sin(2 * np.pi * u), 4.0 * u), -1)
    turn = np.array([[0.0, 0.0], [0.0, 2.0], [2.0, 2.0]])
    stop = np.array([[0.0, 0.0], [0.0, 1.5], [0.0, 1.5], [0.0, 3.0]])
    return {"circle r=1.5 m": (place(circle), None), "S-curve": (place(s_curve), None),
            "sharp 90 deg turn": (place(turn), None),
            "stop 1.5 s and restart": (place(stop), np.array([0.0, 1.6, 3.1, 4.7]) + 1 / 30)}


def bench_path(prior, clips: list[tuple[str, Motion]], seconds: float) -> list[str]:
    fps = prior.spec.fps
    rows, ours_sk, ref_sk, nll_ref = [], [], [], []
    n_seed = int(fps)
    for name, m in clips:
        n_new = min(int(seconds * fps), m.num_frames - n_seed)
        if n_new < fps:
            continue
        seg = m[n_seed:n_seed + n_new]
        path = seg.root[:, [0, 2]]
        r = PathFollow(m[:n_seed], path, prior, times=np.arange(1, n_new + 1) / fps).solve()
        ref = skating(prior, seg)
        real_nll = continuation_nll(prior, m[:n_seed + n_new], n_seed)
        mt = r.metrics
        rows.append([short(name), mt["path_distance_cm_mean"],
                     mt["path_distance_cm_max"], mt["foot_skating_cm_per_s"], ref,
                     mt["foot_skating_cm_per_s"] / ref, mt["prior_nll_per_frame"], real_nll,
                     mt["frames_per_second"]])
        nll_ref.append(real_nll)
        ours_sk.append(mt["foot_skating_cm_per_s"])
        ref_sk.append(ref)
    walk_ref = float(np.mean(ref_sk))
    seeds = [(n, m) for n, m in clips if "_walk_" in n][:2] or clips[:1]
    for name, m in seeds:
        for label, (path, times) in drawn_paths(m[:n_seed]).items():
            r = PathFollow(m[:n_seed], path, prior, times=times, speed=None if times is not None else 1.0).solve()
            mt = r.metrics
            rows.append([f"{label} ({short(name)} seed)", mt["path_distance_cm_mean"],
                         mt["path_distance_cm_max"], mt["foot_skating_cm_per_s"], walk_ref,
                         mt["foot_skating_cm_per_s"] / walk_ref, mt["prior_nll_per_frame"], float(np.mean(nll_ref)),
                         mt["frames_per_second"]])
    held = rows[:len(ref_sk)]
    lines = [f"1. Path following (prior trained on {prior.metadata.get('data', '')}; seed = first second; held-out "
             f"paths: the clip's root path over the next {seconds:g} s, timed by the clip; drawn paths at 1 m/s, "
             "mocap reference for them = mean of the held-out segments)"]
    lines += format_table(["path", "dist cm mean", "dist cm max", "skate cm/s", "mocap cm/s", "ratio", "NLL/frame",
                    "mocap NLL", "frames/s"], rows)
    lines.append(f"   held-out paths: mean distance {np.mean([r[1] for r in held]):.2f} cm; skating "
                 f"{np.mean(ours_sk):.1f} vs mocap {np.mean(ref_sk):.1f} cm/s (ratio of means "
                 f"{np.mean(ours_sk) / np.mean(ref_sk):.2f}); all paths: {np.mean([r[8] for r in rows]):.0f} frames/s")
    return lines


# ---- 2. denoising ---------------------------------------------------------------------
def best_filter(noisy: list[np.ndarray], clean: list[np.ndarray], make) -> tuple[float, str, list[np.ndarray]]:
    """The setting (of ``make``'s candidates) with the lowest mean MPJPE over the clips."""
    best = None
    for label, f in make():
        out = [np.ascontiguousarray(f(p)) for p in noisy]
        err = float(np.mean([np.linalg.norm(o - c, axis=-1).mean() for o, c in zip(out, clean)]))
        if best is None or err < best[0]:
            best = (err, label, out)
    return best


def butterworth(fps: float):
    for fc in range(2, 13):
        yield f"{fc} Hz", (lambda p, fc=fc: filtfilt(*butter(4, fc / (fps / 2)), p, axis=0))


def savgol():
    for w in range(5, 32, 2):
        for order in (2, 3):
            yield f"{w} fr, order {order}", (lambda p, w=w, o=order: savgol_filter(p, w, o, axis=0))


DEFAULT_DENOISE = "ours (MAP, default)"


def bench_denoise(prior, clips: list[tuple[str, Motion]], seconds: float, iters: int) -> list[str]:
    fps = prior.spec.fps
    cidx = prior.spec.contact_indices()
    lines = [f"2. Denoising ({len(clips)} held-out clips at the prior's "
             f"{fps:g} fps, first {seconds:g} s of each; MAP: {iters} L-BFGS iterations per window)"]
    long = {"options": denoise_options(max_iter=60)}
    variants = {"per-joint filter (--no-refine)": {"refine": False},
                "filter + foot IK": {"refine": False, "clean_feet": True},
                "MAP without the prior": {"prior_weight": 0.0},
                DEFAULT_DENOISE: {},
                "MAP without the prior, 60 it.": {"prior_weight": 0.0, **long},
                "ours, --iterations 60": long}
    rows, energy_rows = [], []
    for level in (0.01, 0.03, 0.05):
        clean, noisy, sig = [], [], []
        energies: dict[str, dict[str, float]] = {"clean": {}, "start": {}, "result": {}}
        outs: dict[str, list[np.ndarray]] = {k: [] for k in variants}
        secs = dict.fromkeys(variants, 0.0)
        for i, (_, m) in enumerate(clips):
            c = m[:int(seconds * fps)]
            nz, s = position_noise(c, level, seed=i)
            clean.append(c.positions())
            noisy.append(nz.positions())
            for label, kwargs in variants.items():
                task = Denoise(nz, prior, **{"options": denoise_options(max_iter=iters), **kwargs})
                t0 = time.perf_counter()
                r = task.solve()
                secs[label] += time.perf_counter() - t0
                outs[label].append(r.model_motion.positions())
                if r.solver is not None and label == DEFAULT_DENOISE:
                    add_energies(energies, task, c, r.solver)
            sig.append((s, r.settings["sigma_angle"]))
        bw = best_filter(noisy, clean, lambda: butterworth(fps))
        sg = best_filter(noisy, clean, savgol)

        def stats(ps: list[np.ndarray]) -> list[float]:
            t = [torch.from_numpy(p) for p in ps]
            return [float(np.mean([np.linalg.norm(p - c, axis=-1).mean() * 100 for p, c in zip(ps, clean)])),
                    float(np.mean([float(foot_skating(p, fps, cidx)) * 100 for p in t])),
                    float(np.mean([float(jerk(p, fps)) for p in t]))]

        n_frames = sum(len(c) for c in clean)
        rows += [[f"{level * 100:g} cm", "clean", "", *stats(clean)],
                 [f"{level * 100:g} cm", "noisy", "", *stats(noisy)],
                 [f"{level * 100:g} cm", "Butterworth (best)", bw[1], *stats(bw[2])],
                 [f"{level * 100:g} cm", "Savitzky-Golay (best)", sg[1], *stats(sg[2])]]
        rows += [[f"{level * 100:g} cm", label, f"{n_frames / secs[label]:.0f} fr/s", *stats(outs[label])]
                 for label in variants]
        lines.append(f"   {level * 100:g} cm: rotation noise s = {np.mean([a for a, _ in sig]):.4f} rad, "
                     f"estimated from the input {np.mean([b for _, b in sig]):.4f} rad")
        for point, e in energies.items():
            energy_rows.append([f"{level * 100:g} cm", point, *[e[k] for k in e], sum(e.values())])
    lines += format_table(["noise", "method", "setting", "MPJPE cm", "skate cm/s", "jerk m/s^3"], rows)
    terms = list(energies["clean"])
    lines += ["   MAP (default): objective terms (nats, summed over the clips and the solver's windows) at the clean clip, "
              "at the start (the filtered input) and at the solver's result; the clean clip lower than the result "
              "means the search fails, the result lower means the objective prefers the wrong answer"]
    lines += format_table(["noise", "point", *terms, "total"], energy_rows)
    return lines


def add_energies(energies: dict[str, dict[str, float]], task: Denoise, clean: Motion, result) -> None:
    """Add the MAP objective's terms at the clean clip, the start and the result of one
    denoising to ``energies``: each evaluated over the solver's windows (``energies_at``)."""
    setup = task.setup()
    truth = prepare(clean, task.prior)
    points = {"clean": (truth.x, Problem(truth.x, setup.problem.free, truth.start)),
              "start": (setup.problem.x0, setup.problem), "result": (result.x, setup.problem)}
    for point, (x, problem) in points.items():
        for k, v in energies_at(setup.objective, problem, x, task.options).items():
            energies[point][k] = energies[point].get(k, 0.0) + v


def bench_denoise_files(prior, names: list[str], seconds: float) -> list[str]:
    """Denoising each held-out file as a user has it (its own frame rate, every joint,
    fingers included): joint positions moved 1, 3 and 5 cm RMS by rotation noise on every
    joint, against the Butterworth on all joints' positions at the file's rate with the
    cutoff that is best for that very file (an oracle per file)."""
    folder = data_folder(prior.metadata)
    files = [(n, bvh.load(folder / n)) for n in names]
    files = [(n, m[:int(seconds * m.fps)]) for n, m in files]
    rates = ", ".join(sorted({f"{m.fps:g} fps, {m.skeleton.num_joints} joints" for _, m in files}))
    lines = [f"2b. Denoising at the file's rate ({len(files)} held-out files, first {seconds:g} s; {rates}): "
             "MPJPE and jitter (mean jerk) over every joint of the file"]
    rows = []
    for level in (0.01, 0.03, 0.05):
        clean, noisy, ours, ours_filter, filtered, cutoffs, secs = [], [], [], [], [], [], 0.0
        for i, (_, m) in enumerate(files):
            nz, _ = position_noise(m, level, seed=i)
            t0 = time.perf_counter()
            out = Denoise(nz, prior).solve().motion
            secs += time.perf_counter() - t0
            clean.append(m.positions())
            noisy.append(nz.positions())
            ours.append(out.positions())
            ours_filter.append(Denoise(nz, prior, refine=False).solve().motion.positions())
            _, cutoff, (best,) = best_filter(noisy[-1:], clean[-1:], lambda: butterworth(m.fps))
            filtered.append(best)
            cutoffs.append(cutoff)

        def mpjpe_cm(ps: list[np.ndarray]) -> float:
            return float(np.mean([np.linalg.norm(p - c, axis=-1).mean() * 100 for p, c in zip(ps, clean)]))

        def jitter(ps: list[np.ndarray]) -> float:
            return float(np.mean([float(jerk(torch.from_numpy(p), m.fps)) for p, (_, m) in zip(ps, files)]))

        def sliding(ps: list[np.ndarray]) -> float:
            return float(np.nanmean([file_skating(prior, p, c, m) for p, c, (_, m) in zip(ps, clean, files)]))

        frames = sum(len(c) for c in clean)
        rows += [[f"{level * 100:g} cm", "clean", "", 0.0, jitter(clean), sliding(clean)],
                 [f"{level * 100:g} cm", "noisy", "", mpjpe_cm(noisy), jitter(noisy), sliding(noisy)],
                 [f"{level * 100:g} cm", "Butterworth (best per file)", " ".join(c.split()[0] for c in cutoffs) + " Hz",
                  mpjpe_cm(filtered), jitter(filtered), sliding(filtered)]]
        rows += [[f"{level * 100:g} cm", "per-joint filter (--no-refine)", "", mpjpe_cm(ours_filter), jitter(ours_filter),
                  sliding(ours_filter)],
                 [f"{level * 100:g} cm", "ours (MAP, default)", f"{frames / secs:.0f} fr/s", mpjpe_cm(ours), jitter(ours),
                  sliding(ours)]]
    return lines + format_table(["noise", "method", "setting", "MPJPE cm", "jerk m/s^3", "sliding cm/s"], rows)


def file_skating(prior, positions: np.ndarray, clean: np.ndarray, motion: Motion) -> float:
    """Foot sliding (cm/s) at the file's own rate, of the file's joints that the prior
    calls contact joints, planted heights from the clean file's."""
    names = motion.skeleton.names
    idx = [names.index(n) for n in prior.spec.contact_joints if n in names]
    p, c = torch.from_numpy(positions), torch.from_numpy(clean)
    return float(foot_skating(p, motion.fps, idx, rest=rest_heights(c, idx))) * 100


def bench_glitch(prior, clips: list[tuple[str, Motion]], seconds: float) -> list[str]:
    """A capture glitch: 1 cm of rotation noise, then one knee turned 30 degrees about the
    axis it bends about most for 0.25 s (from 1.5 s on); the error of the foot below it
    over the burst, for the input, the best Butterworth for these very frames (oracle),
    the per-joint filter (after the glitch repair), the MAP solve without the repair and
    ours. Each held-out clip twice: at the prior's rate on its joints, and as the file
    is (its own rate, every joint)."""
    folder = data_folder(prior.metadata)
    cases = [(f"{short(n)} ({prior.spec.fps:g} fps)", m[:int(seconds * prior.spec.fps)]) for n, m in clips]
    for n, _ in clips:
        f = bvh.load(folder / n)
        if f.fps != prior.spec.fps:
            cases.append((f"{short(n)} (file, {f.fps:g} fps)", f[:int(seconds * f.fps)]))
    names = cases[0][1].skeleton.names
    knee, foot = next((k, f) for k, f in (("LowerLeg_L", "Foot_L"), ("lShin", "lFoot"), ("LeftLeg", "LeftFoot"))
                      if k in names)
    lines = [f"2c. Glitch repair ({len(clips)} held-out clips, first {seconds:g} s, 1 cm noise; {knee} turned 30 degrees "
             f"for 0.25 s from 1.5 s): mean error of {foot} over the burst, cm"]
    rows = []
    for i, (name, c) in enumerate(cases):
        fps = c.fps
        burst = slice(round(1.5 * fps), round(1.5 * fps) + round(0.25 * fps))
        noisy, _ = position_noise(c, 0.01, seed=i)
        glitched = glitch(noisy, c.skeleton.names.index(knee), burst.start, burst.stop - burst.start)
        j = c.skeleton.names.index(foot)
        clean = c.positions()[burst, j]

        def err(p: np.ndarray) -> float:
            return float(np.linalg.norm(p[burst, j] - clean, axis=-1).mean() * 100)

        best = min(err(f(glitched.positions())) for _, f in butterworth(fps))
        filtered = Denoise(glitched, prior, refine=False).solve().motion.positions()
        kept = Denoise(glitched, prior, repair_glitches=False).solve().motion.positions()
        ours = Denoise(glitched, prior).solve().motion.positions()
        rows.append([name, err(glitched.positions()), best, err(filtered), err(kept), err(ours)])
    rows.append(["mean", *np.mean([r[1:] for r in rows], axis=0)])
    return lines + format_table(["clip", "glitched input", "Butterworth (best)", "per-joint filter",
                                 "MAP, --keep-glitches", "ours (MAP, default)"], rows)


# ---- 3. in-betweening -----------------------------------------------------------------
def global_quats(m: Motion) -> np.ndarray:
    _, g = fk(m.skeleton.parents, torch.from_numpy(m.rotations), torch.from_numpy(m.root),
              torch.from_numpy(m.skeleton.offsets), return_global_rotations=True)
    return g.numpy()


def slerp_fill(m: Motion, a: int, b: int) -> Motion:
    """Frames [a, b) by SLERP of local rotations and linear root between a - 1 and b."""
    rot, root = m.rotations.copy(), m.root.copy()
    w = (np.arange(a, b) - (a - 1)) / (b - (a - 1))
    q0, q1 = torch.from_numpy(rot[a - 1]), torch.from_numpy(rot[b])
    ww = torch.from_numpy(np.broadcast_to(w[:, None], (len(w), rot.shape[1])).copy())
    rot[a:b] = R.quat_slerp(q0.expand(len(w), *q0.shape), q1.expand(len(w), *q1.shape), ww).numpy()
    root[a:b] = root[a - 1] + w[:, None] * (root[b] - root[a - 1])
    return m.with_frames(rot, root, None)


def bench_inbetween(prior, clips: list[tuple[str, Motion]], starts: int) -> list[str]:
    """The LAFAN1 protocol against SLERP: ours with the autoregressive prior (``Inbetween``,
    the default, seeded also by the masked encoder of the latent prior for the skeleton,
    where one ships, as ``inbetween`` is) and, with such a prior, ours seeded by the
    rollouts alone (``--latent-seed none``) and ``inbetween --method latent``
    (``LatentTask``: the masked encoder, L-BFGS, the MAP solve of the gap)."""
    rows = []
    cidx = prior.spec.contact_indices()
    latent = latent_for(clips)
    ours = {"ours": lambda seg, keep: Inbetween(seg, keep, prior, latent=latent).solve().model_motion}
    if latent is not None:
        ours["ours, --latent-seed none"] = lambda seg, keep: Inbetween(seg, keep, prior).solve().model_motion
        ours["ours, --method latent"] = lambda seg, keep: LatentTask(seg, latent, keep,
                                                                      gap_inversion_options()).solve().motion
    for gap in (5, 15, 30):
        res = {"SLERP + linear root": [], **{k: [] for k in ours}}
        skate = {k: 0.0 for k in res} | {"mocap": 0.0}
        secs, n_syn = dict.fromkeys(ours, 0.0), 0
        for name, m in clips:
            total = 10 + gap + 1
            for k in range(starts):
                s0 = k * 40
                if s0 + total > m.num_frames:
                    break
                seg = m[s0:s0 + total]
                outs = {"SLERP + linear root": slerp_fill(seg, 10, 10 + gap)}
                for label, fill in ours.items():
                    t0 = time.perf_counter()
                    outs[label] = fill(seg, [(0, 10), (10 + gap, total)])
                    secs[label] += time.perf_counter() - t0
                n_syn += gap
                # feet in the gap (and its step in and out), each clip judged against its own resting heights
                rest = rest_heights(torch.from_numpy(seg.positions()), cidx)
                for label, out in (*outs.items(), ("mocap", seg)):
                    feet = torch.from_numpy(out.positions()[9:11 + gap])
                    sk = foot_skating(feet, seg.fps, cidx, rest=rest)
                    skate[label] += 0.0 if torch.isnan(sk) else float(sk)
                for label, out in outs.items():
                    pp = torch.from_numpy(out.positions()[10:10 + gap])
                    pt = torch.from_numpy(seg.positions()[10:10 + gap])
                    qp = torch.from_numpy(global_quats(out)[10:10 + gap])
                    qt = torch.from_numpy(global_quats(seg)[10:10 + gap])
                    sign = torch.where((qp * qt).sum(-1, keepdim=True) < 0, -1.0, 1.0).to(qp)
                    res[label].append((float(l2p(pp, pt)), float(l2q(qp, qt)), (qp * sign).flatten(-2), qt.flatten(-2)))
        for label, v in res.items():
            n = float(npss(torch.stack([a[2] for a in v]), torch.stack([a[3] for a in v])))
            rows.append([str(gap), label, len(v), float(np.mean([a[0] for a in v])), float(np.mean([a[1] for a in v])),
                         n, skate[label] / max(skate["mocap"], 1e-9), f"{n_syn / secs[label]:.0f}" if label in secs else ""])
    lines = ["3. In-betweening (LAFAN1 protocol: 10 context frames, gap, 1 target frame; windows every 40 frames "
             "from the start of each held-out clip, at most 5 per clip; L2P in metres without LAFAN1's normalisation; "
             "skating: of the feet within 3 cm of their resting height in the gap, summed over the cases, over the "
             "held-out mocap's in the same gaps)"]
    lines += format_table(["gap", "method", "cases", "L2P m", "L2Q", "NPSS", "skating / mocap", "frames/s"], rows)
    return lines


# ---- 4. prefix completion -------------------------------------------------------------
def extrapolate(m: Motion, n: int, velocity: bool) -> Motion:
    """``m`` followed by ``n`` frames: the last frame held, or its velocities kept."""
    rot, root = [m.rotations], [m.root]
    q1, r1 = torch.from_numpy(m.rotations[-1]), m.root[-1]
    step = R.quat_multiply(R.quat_conjugate(torch.from_numpy(m.rotations[-2])), q1)
    dr = (m.root[-1] - m.root[-2]) if velocity else np.zeros(3)
    q = q1
    for k in range(1, n + 1):
        if velocity:
            q = R.quat_multiply(q, step)
        rot.append(q.numpy()[None])
        root.append((r1 + k * dr)[None])
    return Motion(m.skeleton, np.concatenate(rot), np.concatenate(root), m.fps)


#: Seconds between the starts of the completion cases cut from each held-out clip.
COMPLETION_EVERY_S = 2


def bench_complete(prior, clips: list[tuple[str, Motion]]) -> list[str]:
    """Prefix completion over 1 s: ours as ``complete`` runs it (seeded also by the latent
    prior's continuation where a latent prior ships for the skeleton) and, with such a
    prior, seeded by the rollouts alone (``--latent-seed none``) and ``--method latent``."""
    fps = int(prior.spec.fps)
    prefix, n = fps, fps
    latent = latent_for(clips)
    res = {"zero velocity": [], "constant velocity": [], "ours": []} | (
        {"ours, --latent-seed none": [], "ours, --method latent": []} if latent else {})
    nll_ours, nll_real = [], []
    secs = dict.fromkeys(res, 0.0)
    cases = [(name, m[s:s + prefix + n]) for name, m in clips
             for s in range(0, m.num_frames - prefix - n + 1, COMPLETION_EVERY_S * fps)]

    def timed(label: str, make: Callable[[], object]) -> tuple[str, object]:
        t0 = time.perf_counter()
        out = make()
        secs[label] += time.perf_counter() - t0
        return label, out

    for _, real in cases:
        start = real[:prefix]
        r = timed("ours", lambda: complete(start, prefix, prefix + n, prior, latent=latent).solve())[1]
        outs = [("zero velocity", extrapolate(start, n, False)), ("constant velocity", extrapolate(start, n, True)),
                ("ours", r.model_motion)]
        if latent:
            outs += [timed("ours, --latent-seed none",
                           lambda: complete(start, prefix, prefix + n, prior).solve().model_motion),
                     timed("ours, --method latent",
                           lambda: prepare(latent_completion(start, prefix, prefix + n, latent, prior), prior).model)]
        p_real = real.positions()[prefix:]
        for label, out in outs:
            res[label].append(np.linalg.norm(out.positions()[prefix:prefix + n] - p_real, axis=-1).mean() * 100)
        nll_ours.append(continuation_nll(prior, r.model_motion, prefix))
        nll_real.append(continuation_nll(prior, real, prefix))
    rows = [[label, len(v), float(np.mean(v)), f"{secs[label] / len(v):.1f}" if secs[label] else ""]
            for label, v in res.items()]
    lines = [f"4. Prefix completion (1 s prefix, 1 s continuation, from every {COMPLETION_EVERY_S} s of "
             f"{len({c[0] for c in cases})} held-out clips: {len(cases)} cases)"]
    lines += format_table(["method", "clips", "MPJPE cm", "s/case"], rows)
    lines.append(f"   prior NLL per frame of the continuation (lower is more likely): ours {np.mean(nll_ours):.1f}, "
                 f"real {np.mean(nll_real):.1f}")
    return lines


#: Seconds of prefix completion judged second by second (issue 19: 5 s after a 1 s prefix).
LONG_COMPLETION_S = 5


def bench_complete_long(prior, clips: list[tuple[str, Motion]]) -> list[str]:
    """Each held-out clip's first second completed for ``LONG_COMPLETION_S`` s; each new
    second judged against the held-out data's range (``naturalness.out_of_range``)."""
    fps = int(prior.spec.fps)
    measures = ("hips", "floating", "skating", "unlikely")
    rows, inside, total = [], dict.fromkeys(measures + ("all",), 0), 0
    latent = latent_for(clips)
    for name, m in clips:
        if m.num_frames < fps:
            continue
        r = complete(m[:fps], fps, fps * (1 + LONG_COMPLETION_S), prior, latent=latent).solve()
        new = r.per_second[1:1 + LONG_COMPLETION_S]
        out = out_of_range(new, r.human_range)
        bad = flagged_seconds(out)
        for k in measures:
            inside[k] += len(new) - len(out[k])
        inside["all"] += len(new) - len(bad)
        total += len(new)
        rows.append([short(name), len(new) - len(bad),
                     "; ".join(f"{k} {spans(out[k])}" for k in measures if out[k]) or "-"])
    lines = [f"4b. Prefix completion for {LONG_COMPLETION_S} s after the first second of {len(rows)} held-out clips: "
             "seconds of new motion within the held-out data's 1st-99th percentile range (hip height, lowest foot "
             "joint's height, foot skating, prior NLL per frame)"]
    lines += format_table(["clip", f"seconds in range of {LONG_COMPLETION_S}", "outside (seconds from the start)"],
                          rows)
    lines.append(f"   of {total} seconds: " + ", ".join(f"{k} {inside[k]}" for k in measures) +
                 f"; all four {inside['all']}")
    if latent:
        known, inside_latent, inside_alone, total_latent = HumanRange.of_prior(prior), 0, 0, 0
        for name, m in clips:
            if m.num_frames < fps:
                continue
            alone = complete(m[:fps], fps, fps * (1 + LONG_COMPLETION_S), prior).solve()
            new = alone.per_second[1:1 + LONG_COMPLETION_S]
            inside_alone += len(new) - len(flagged_seconds(out_of_range(new, known)))
            out = latent_completion(m[:fps], fps, fps * (1 + LONG_COMPLETION_S), latent, prior)
            ground = prepare(m[:fps], prior).start.ground
            new = per_second(prior, prepare(out, prior).model, ground)[1:1 + LONG_COMPLETION_S]
            inside_latent += len(new) - len(flagged_seconds(out_of_range(new, known)))
            total_latent += len(new)
        lines.append(f"   the same cases, judged the same way, all four in range: --latent-seed none (the rollouts alone) "
                     f"{inside_alone} of {total_latent} seconds, complete --method latent {inside_latent}")
    return lines


def latent_for(clips: list[tuple[str, Motion]]):
    """The shipped latent prior for the clips' skeleton, or None."""
    try:
        return load_latent_for(clips[0][1])
    except CheckpointError:
        return None


def latent_completion(prefix_clip: Motion, prefix: int, n_frames: int, latent, settle_prior) -> Motion:
    """``complete --method latent``'s output (``LatentTask.completion``), settled under
    the autoregressive ``settle_prior`` as the command settles it by default."""
    return LatentTask.completion(prefix_clip, prefix, n_frames, latent, settle_prior=settle_prior).solve().motion


# ---- 5. spatial edits -----------------------------------------------------------------
def bench_edit(prior, clips: list[tuple[str, Motion]]) -> list[str]:
    hand, foot = ("Hand_L", "Foot_R") if "Hand_L" in prior.spec.joints else ("lHand", "rFoot")
    cases = {"hand +20 cm up, one frame": [JointTarget(hand, (60, 60), offset=(0.0, 0.2, 0.0))],
             "hand +10 cm fwd, 10 frames": [JointTarget(hand, (50, 59), offset=(0.0, 0.0, 0.1))],
             "hand and foot, two frames": [JointTarget(hand, (40, 40), offset=(0.1, 0.1, 0.0)),
                                           JointTarget(foot, (80, 80), offset=(0.0, 0.1, 0.0))]}
    rows = []
    for name, m in clips:
        seg = m[:120]
        for label, targets in cases.items():
            r = SpatialEdit(seg, targets, prior).solve().metrics
            rows.append([short(name), label, r["target_error_cm_max"],
                         r["untouched_frames_change_cm_max"], r["edited_frames_change_cm_mean"],
                         f"{r['frames_per_second']:.0f}"])
    lines = ["5. Spatial edits (first 4 s of held-out clips; falloff 0.5 s; untouched = frames more than the falloff "
             "from every target, and all joints outside the edited limbs: tolerance 0 cm, they are copied)"]
    lines += format_table(["clip", "edit", "target err cm max", "untouched change cm max", "edited frames change cm",
                    "frames/s"], rows)
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--prior", type=Path, default=LOCOMOTION)
    ap.add_argument("--clips", type=int, default=10, help="held-out clips to use (path following, completion)")
    ap.add_argument("--small", type=int, default=3,
                    help="held-out clips of 4 s or more for the slower denoising, in-betweening and edits")
    ap.add_argument("--seconds", type=float, default=3.0, help="path length in seconds of the held-out clips")
    ap.add_argument("--iters", type=int, default=SolverOptions.max_iter,
                    help=f"L-BFGS iterations per window for denoising (default {SolverOptions.max_iter}, the task's)")
    ap.add_argument("--tasks", nargs="+", default=["path", "denoise", "denoise-files", "glitch", "inbetween", "complete",
                                                   "complete-long", "edit"])
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", type=Path, default=RESULTS, help="where the report goes when every task runs")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    prior = load_prior(args.prior)
    clips = [(c.name, c.motion) for c in held_out_clips(prior, limit=args.clips)]
    small = [c for c in clips if c[1].num_frames >= 4 * prior.spec.fps][:args.small]
    name = args.prior.relative_to(ROOT) if args.prior.is_relative_to(ROOT) else args.prior
    lines = [f"Tasks on held-out clips of {name} (weights of epoch {prior.metadata.get('selected_epoch')} of "
             f"{prior.metadata.get('epochs_done')}; torch threads {args.threads}; 2 shared CPU cores)", ""]
    jobs = {"path": lambda: bench_path(prior, clips, args.seconds),
            "denoise": lambda: bench_denoise(prior, small, 4.0, args.iters),
            "denoise-files": lambda: bench_denoise_files(prior, [n for n, _ in small], 4.0),
            "glitch": lambda: bench_glitch(prior, small, 4.0),
            "inbetween": lambda: bench_inbetween(prior, clips, 5),
            "complete": lambda: bench_complete(prior, clips),
            "complete-long": lambda: bench_complete_long(prior, clips),
            "edit": lambda: bench_edit(prior, small)}
    for task in args.tasks:
        t0 = time.perf_counter()
        part = jobs[task]()
        part.append(f"   ({time.perf_counter() - t0:.0f} s)")
        print("\n".join(part) + "\n", flush=True)
        lines += part + [""]
    if set(args.tasks) == set(jobs):
        args.out.write_text("\n".join(lines))


if __name__ == "__main__":
    main()
