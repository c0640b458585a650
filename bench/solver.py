"""Benchmark of the MAP solver (``motionopt.solver``) on held-out clips.

Clips: the validation clips named in the shipped checkpoints' metadata (CMU prior: all of
them; Bandai locomotion prior: its walking clips) that last 2 s or more, at the prior's
30 fps on its joints.
Problems are built here from the objective terms, the same way the tasks build them,
so that only the solver varies:

- path following: seed = the clip's first second, path = the clip's own root path over
  the next ``--seconds``, walked at the clip's mean speed over that span; terms: nearest
  point on the path (sigma 2 cm), timed point (sigma 30 cm), contacts. Task error: mean
  distance (cm) from the new frames' root to the path; foot skating (cm/s).
- denoising: the clip's first ``--seconds`` with joint positions moved 3 cm RMS by
  rotation noise (``bench/prior.py``'s ``position_noise``); terms: fidelity to the noisy
  root and rotations (3 cm, 0.08 rad), contacts. Task error: MPJPE (cm) to the clean clip.

Sections:
1. Ablation: PSO+L-BFGS (``PSOOptions()``) against L-BFGS alone (defaults, then with the same
   time per window as PSO+L-BFGS) and Adam with that same time per window: final
   objective (nats, summed over windows) and task error. Denoising has no new frames,
   so the particle swarm has nothing to steer there (it is off by default).
2. Overhead: total solve time against the time spent in objective evaluations with
   gradient (L-BFGS function evaluations x the time of one, measured in the same run),
   with a profile (cProfile) of where the rest goes.
3. Throughput: output frames per second of windowed path following with the Bandai
   prior at several settings, with their task errors.
4. Memory: peak resident memory during a solve of 10 000 against 2 000 frames of denoising
   (max_iter=1).

One torch thread throughout (``torch.set_num_threads(1)``): the machine is shared, and
spinning threads slow small models down. Times are wall-clock on a busy machine: compare
rows of one run, not runs.

Run ``python bench/solver.py [--seconds S] [--sections ...]``; the printed report is
written to bench/results/solver.txt when every section runs.
"""
from __future__ import annotations

import argparse
import cProfile
import json
import os
import pstats
import subprocess
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.prior import table  # noqa: E402
from motionopt.codec import Codec  # noqa: E402
from motionopt.metrics import foot_skating  # noqa: E402
from motionopt.motion import Motion  # noqa: E402
from motionopt.noise import position_noise  # noqa: E402
from motionopt.objective import MAPObjective, PathTerm, nearest_on_polyline_sq  # noqa: E402
from motionopt.solver import MAPResult, Problem, PSOOptions, SolverOptions, solve  # noqa: E402
from motionopt.solver.diagnostics import energies_at  # noqa: E402
from priors.checkpoint import CHECKPOINT_DIR, load_prior  # noqa: E402
from priors.heldout import held_out_clips  # noqa: E402
from problems.common import TermSigmas, prepare, standard_terms  # noqa: E402
from problems.denoise import Denoise  # noqa: E402

RESULTS = ROOT / "bench" / "results" / "solver.txt"
CMU = CHECKPOINT_DIR / "cmu-ccnet.pt"
BANDAI = CHECKPOINT_DIR / "bandai-locomotion-ccnet.pt"
SECTIONS = ("ablation", "overhead", "throughput", "memory")


# ---- problems -------------------------------------------------------------------------
@dataclass
class Case:
    """One solver problem on a held-out clip, with what its task error needs."""

    task: str
    clip: str
    objective: MAPObjective
    problem: Problem
    clean: Motion            # the held-out clip (model joints, 30 fps)
    first: int               # first synthesised or edited frame
    path: np.ndarray | None = None
    input_error_cm: float | None = None   # denoising: MPJPE of the noisy input
    input_skating_cm_s: float | None = None
    truth: Problem | None = None          # denoising: the clean clip's features, from its own root start

    def error_cm(self, res: MAPResult) -> float:
        pos = positions(self, res)
        if self.task == "path":
            xz = torch.from_numpy(pos[self.first:, 0, [0, 2]])
            return float(nearest_on_polyline_sq(xz, torch.from_numpy(self.path)).sqrt().mean()) * 100
        return float(np.linalg.norm(pos - self.clean.positions()[:len(pos)], axis=-1).mean()) * 100

    def skating_cm_s(self, res: MAPResult) -> float:
        prior = self.objective.prior
        cidx = prior.spec.contact_indices()
        pos = torch.from_numpy(positions(self, res)[self.first:])
        return float(foot_skating(pos, prior.spec.fps, cidx)) * 100


def positions(case: Case, res: MAPResult) -> np.ndarray:
    return Codec.of(case.objective.prior, case.clean.skeleton).positions(res.x.double(), case.problem.start).numpy()


def held_out(prior, walking_only: bool, min_seconds: float = 2.0) -> list[tuple[str, Motion]]:
    """Validation clips of the prior (walking ones only, if asked) at least ``min_seconds``
    long, on its joints at its frame rate."""
    return [(c.name, c.motion) for c in held_out_clips(prior, contains="_walk" if walking_only else None,
                                                       min_seconds=min_seconds)]


def path_case(prior, name: str, model: Motion, seconds: float) -> Case:
    fps = prior.spec.fps
    n_seed = int(fps)
    n = min(len(model.root), n_seed + int(round(seconds * fps)))
    seed = prepare(model, prior)
    x, start = seed.x, seed.start
    route = model.root[n_seed - 1:n, [0, 2]]
    path = route[np.r_[np.arange(0, len(route) - 1, 5), len(route) - 1]]
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    s = arc[-1] * np.arange(1, n - n_seed + 1) / (n - n_seed)       # the clip's mean speed
    timed = np.zeros((n, 2))
    timed[n_seed:] = np.stack([np.interp(s, arc, path[:, 0]), np.interp(s, arc, path[:, 1])], -1)
    free = np.zeros(n, bool)
    free[n_seed:] = True
    x0 = torch.full((n, prior.spec.dim), float("nan"))
    x0[:n_seed] = x[:n_seed]
    terms = [PathTerm(path, 0.02, mask=free, name="path"),
             PathTerm(path, 0.3, targets=timed, mask=free, name="path_timing"),
             *standard_terms(prepare(model[:n_seed], prior), prior, TermSigmas())]
    return Case("path", name, MAPObjective(prior, model.skeleton, terms), Problem(x0, free, start), model[:n],
                n_seed, path)


def denoise_case(prior, name: str, model: Motion, seconds: float, rms: float = 0.03) -> Case:
    """Denoising as the task sets it up (``Denoise.setup``: fidelity at the estimated
    noise, contacts, started from the filtered input)."""
    n = min(len(model.root), int(round(seconds * prior.spec.fps)))
    clean = model[:n]
    noisy, _ = position_noise(clean, rms)
    setup = Denoise(noisy, prior).setup()
    truth = prepare(clean, prior)
    err = float(np.linalg.norm(noisy.positions() - clean.positions(), axis=-1).mean()) * 100
    cidx = prior.spec.contact_indices()
    skate = float(foot_skating(torch.from_numpy(noisy.positions()), prior.spec.fps, cidx)) * 100
    return Case("denoise", name, setup.objective, setup.problem, clean, 0, input_error_cm=err,
                input_skating_cm_s=skate, truth=Problem(truth.x, setup.problem.free, truth.start))


def cases(task: str, seconds: float) -> list[Case]:
    out = []
    for ckpt, walking in ((CMU, False), (BANDAI, True)):
        prior = load_prior(ckpt)
        for name, model in held_out(prior, walking):
            out.append(path_case(prior, name, model, seconds) if task == "path"
                       else denoise_case(prior, name, model, seconds))
    return out


# ---- 1. ablation ----------------------------------------------------------------------
def ablation(seconds: float) -> list[str]:
    lines = []
    for task in ("path", "denoise"):
        rows = [["clip", "method", "windows", "time s", "fun start", "fun end", "E(x)", "error cm", "skating cm/s"]]
        wins = {"fun": 0, "err": 0, "n": 0}
        for case in cases(task, seconds):
            runs: dict[str, MAPResult] = {}
            if task == "path":
                runs["PSO+L-BFGS"] = solve(case.objective, case.problem, SolverOptions(pso=PSOOptions()))
                ref = runs["PSO+L-BFGS"]
            runs["L-BFGS"] = solve(case.objective, case.problem, SolverOptions(pso=None))
            if task == "denoise":
                ref = runs["L-BFGS"]
            budget = (ref.timings["pso"] + ref.timings["lbfgs"]) / len(ref.windows)
            if task == "path":
                runs["L-BFGS, same time"] = solve(case.objective, case.problem, SolverOptions(
                    pso=None, max_iter=100_000, time_budget=budget))
            runs["Adam, same time"] = solve(case.objective, case.problem, SolverOptions(
                pso=None, optimizer="adam", max_iter=100_000, time_budget=budget))
            if case.truth is not None:
                rows.append([case.clip, "noisy input", "", "", "", "", "", f"{case.input_error_cm:.2f}",
                             f"{case.input_skating_cm_s:.1f}"])
                e_clean = energies_at(case.objective, case.truth, case.truth.x0)
                e_start = energies_at(case.objective, case.problem, case.problem.x0)
                rows += [[case.clip, "clean clip", "", "", "", "", f"{sum(e_clean.values()):.0f}", "0.00", ""],
                         [case.clip, "start (filtered)", "", "", "", "", f"{sum(e_start.values()):.0f}", "", ""]]
            for label, r in runs.items():
                e_end = sum(energies_at(case.objective, case.problem, r.x).values())
                rows.append([case.clip, label, str(len(r.windows)), f"{r.timings['total']:.1f}",
                             f"{r.fun_start:.0f}", f"{r.fun:.0f}", f"{e_end:.0f}", f"{case.error_cm(r):.2f}",
                             f"{case.skating_cm_s(r):.1f}"])
            if task == "path":
                pso, alone = runs["PSO+L-BFGS"], runs["L-BFGS, same time"]
                wins["fun"] += pso.fun < alone.fun
                wins["err"] += case.error_cm(pso) < case.error_cm(alone)
                wins["n"] += 1
        title = (f"path following: seed = first second, path = the clip's next {seconds:g} s of root path; "
                 "error = mean root distance to the path" if task == "path" else
                 f"denoising: first {seconds:g} s, joints moved 3 cm RMS; error = MPJPE to the clean clip; "
                 "E(x) = the objective at the point, each window with the log-std and contacts of the point "
                 "itself (energies_at; fun start/end hold those of each window's start): the clean clip below a "
                 "result means the search failed; "
                 "PSO: not applicable (no new frames to steer)")
        lines += [title, table(rows), ""]
        if task == "path":
            lines += [f"PSO+L-BFGS against L-BFGS alone with the same time per window: lower final objective on "
                      f"{wins['fun']}/{wins['n']} clips, lower path error on {wins['err']}/{wins['n']}", ""]
    return lines


# ---- 2. overhead ----------------------------------------------------------------------
PROFILE_GROUPS = {  # label -> (file, function, caller or None): cumulative time of those calls
    "objective f+b (Window.fun)": ("solver/window.py", "fun", None),
    "particle swarm (rollouts and batched objective)": ("solver/swarm.py", "rollout_swarm", None),
    "window set-up (rebase: whitening, fixed contacts)": ("solver/window.py", "rebase", None),
    "L-BFGS-B itself (scipy setulb)": ("~", "<built-in method scipy.optimize._lbfgsb.setulb>", None),
    "contacts of the solved window (prior pass)": ("ccnet.py", "nll_and_contacts", "_solve"),
    "root state (advance)": ("features.py", "advance", "open"),   # WindowWalk.open advances it
    "seam report": ("solver/diagnostics.py", "seam_report", None),
}


def profile_groups(stats: pstats.Stats) -> dict[str, float]:
    """Seconds per ``PROFILE_GROUPS`` entry; with a caller, only the calls made from it."""
    out = {k: 0.0 for k in PROFILE_GROUPS}
    for (file, _, func), (_, _, _, cum, callers) in stats.stats.items():  # type: ignore[attr-defined]
        for label, (f, name, caller) in PROFILE_GROUPS.items():
            if file.endswith(f) and func == name:
                out[label] += cum if caller is None else sum(c[3] for k, c in callers.items() if k[2] == caller)
    return out


def overhead(seconds: float) -> list[str]:
    prior = load_prior(BANDAI)
    name, model = held_out(prior, True)[0]
    rows = [["run", "total s", "nfev", "objective f+b s", "ms per f+b", "total / (nfev x f+b)"]]
    profiles = []
    for label, case, opts in (("path, L-BFGS", path_case(prior, name, model, seconds), SolverOptions(pso=None)),
                              ("denoise, L-BFGS", denoise_case(prior, name, model, seconds), SolverOptions(pso=None)),
                              ("path, PSO+L-BFGS", path_case(prior, name, model, seconds),
                               SolverOptions(pso=PSOOptions()))):
        solve(case.objective, case.problem, replace(opts, max_iter=2))  # warm-up (imports, allocations)
        res = solve(case.objective, case.problem, opts)
        lbfgs_fev = res.nfev - (opts.pso.particles * opts.pso.iterations * len(res.windows) if opts.pso else 0)
        per = res.timings["objective"] / lbfgs_fev
        rows.append([label, f"{res.timings['total']:.2f}", str(lbfgs_fev), f"{res.timings['objective']:.2f}",
                     f"{per * 1000:.1f}", f"{res.timings['total'] / res.timings['objective']:.2f}"])
        prof = cProfile.Profile()
        prof.enable()
        profiled = solve(case.objective, case.problem, opts)
        prof.disable()
        groups = profile_groups(pstats.Stats(prof))
        groups["rollouts of new frames (prior.sample; solver timing)"] = profiled.timings["rollout"]
        profiles.append((label, profiled.timings["total"], groups))
    lines = [f"overhead on {name} ({seconds:g} s; nfev counts L-BFGS evaluations only; ms per f+b = time in "
             "objective evaluations with gradient / nfev, in the same run)", table(rows), ""]
    for label, total, groups in profiles:
        rows = [[f"where the time goes ({label}; a second run, under cProfile)", "s", "% of total"]]
        for k, v in groups.items():
            rows.append([k, f"{v:.2f}", f"{100 * v / total:.0f}"])
        rest = total - sum(groups.values())
        rows.append(["everything else (bookkeeping, write-back)", f"{rest:.2f}", f"{100 * rest / total:.0f}"])
        lines += [table(rows), ""]
    return lines


# ---- 3. throughput --------------------------------------------------------------------
THROUGHPUT = {
    "PSO 12x4, 30 it (B=34, b=17)": SolverOptions(pso=PSOOptions()),
    "PSO off, 40 it": SolverOptions(pso=None, max_iter=40),
    "PSO off, 30 it (the defaults)": SolverOptions(pso=None),
    "PSO off, 20 it": SolverOptions(pso=None, max_iter=20),
    "PSO off, 20 it, b=8": SolverOptions(pso=None, max_iter=20, overlap=8),
    "PSO off, 12 it, b=8": SolverOptions(pso=None, max_iter=12, overlap=8),
}


def throughput(seconds: float) -> list[str]:
    prior = load_prior(BANDAI)
    clips = held_out(prior, True)
    seconds = max(m.num_frames for _, m in clips) / prior.spec.fps   # every clip to its end
    rows = [["settings", "new frames", "time s", "frames/s", "path error cm", "skating cm/s", "seam ratio"]]
    for label, opts in THROUGHPUT.items():
        frames = total = err = skate = 0.0
        ratios = []
        for name, model in clips:
            case = path_case(prior, name, model, seconds)
            res = solve(case.objective, case.problem, opts)
            n_new = int(case.problem.free.sum())
            frames += n_new
            total += res.timings["total"]
            err += case.error_cm(res) * n_new
            skate += case.skating_cm_s(res) * n_new
            ratios.append(res.seam.get("ratio", float("nan")))
        rows.append([label, f"{frames:.0f}", f"{total:.1f}", f"{frames / total:.1f}", f"{err / frames:.2f}",
                     f"{skate / frames:.1f}", f"{np.nanmax(ratios):.2f}"])
    return [f"throughput: windowed path following with {BANDAI.name} on its {len(clips)} held-out walking clips "
            "of 2 s or more (each to its end after a 1 s seed); frames/s = new frames / total solve time; errors "
            "weighted by frames; seam ratio = largest over clips of boundary / inner max acceleration", table(rows), ""]


# ---- 4. memory ------------------------------------------------------------------------
MEMORY_RUN = """
import json, re, sys
import numpy as np, torch
sys.path.insert(0, {root!r})
torch.set_num_threads(1)
from bench.solver import BANDAI, denoise_case, held_out
from motionopt.solver import Problem, SolverOptions, solve
from priors.checkpoint import load_prior
n = int(sys.argv[1])
prior = load_prior(BANDAI)
name, model = held_out(prior, True)[0]
case = denoise_case(prior, name, model, 1e9)
x0 = case.problem.x0
reps = -(-n // len(x0))
x = x0.repeat(reps, 1)[:n]   # per-frame deltas: a tiled clip is a valid motion
fid = case.objective.terms[0]
fid.root, fid.rotations = np.tile(fid.root, (reps, 1))[:n], np.tile(fid.rotations, (reps, 1, 1))[:n]
def vm(key):
    return int(re.search(key + r":\\s+(\\d+)", open("/proc/self/status").read()).group(1))
open("/proc/self/clear_refs", "w").write("5")   # reset the peak resident size (Linux)
before = vm("VmRSS")
res = solve(case.objective, Problem(x, np.ones(n, bool), case.problem.start), SolverOptions(max_iter=1, pso=None))
after = vm("VmHWM")
print(json.dumps({{"before_kb": before, "after_kb": after, "windows": len(res.windows),
                  "seconds": res.timings["total"], "x_mb": x.numel() * 4 / 1e6,
                  "targets_mb": (fid.root.nbytes + fid.rotations.nbytes) / 1e6}}))
"""


def memory() -> list[str]:
    rows = [["frames", "windows", "solve s", "RSS before MB", "peak RSS during MB", "growth MB", "x MB",
             "targets MB"]]
    growth = {}
    for n in (2000, 10_000):
        code = MEMORY_RUN.format(root=str(ROOT))
        out = subprocess.run([sys.executable, "-c", code, str(n)], capture_output=True, text=True, check=True,
                             cwd=ROOT)
        r = json.loads(out.stdout.strip().splitlines()[-1])
        growth[n] = (r["after_kb"] - r["before_kb"]) / 1024
        rows.append([str(n), str(r["windows"]), f"{r['seconds']:.0f}", f"{r['before_kb'] / 1024:.0f}",
                     f"{r['after_kb'] / 1024:.0f}", f"{growth[n]:.1f}", f"{r['x_mb']:.1f}", f"{r['targets_mb']:.1f}"])
    return ["memory: denoising a tiled held-out Bandai clip (fidelity to the tiled input, contacts), max_iter=1, "
            "PSO off; resident memory of a fresh process just before the solve (prior, input and targets built) "
            "and its peak during the solve (/proc/self/status VmHWM, reset before)",
            table(rows), "",
            f"10 000 frames take {growth[10_000] - growth[2000]:+.1f} MB more than 2 000 frames "
            f"(the output itself: {(10_000 - 2000) * 134 * 4 / 1e6:.1f} MB more)", ""]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=4.0, help="new (path) or denoised seconds per clip (default 4)")
    ap.add_argument("--sections", nargs="+", choices=SECTIONS, default=list(SECTIONS))
    args = ap.parse_args()
    torch.set_num_threads(1)
    load = os.getloadavg()[0]
    report = [f"solver benchmark ({time.strftime('%Y-%m-%d %H:%M')}, torch {torch.__version__}, "
              f"{torch.get_num_threads()} torch thread, load average {load:.1f} on {os.cpu_count()} CPUs)", ""]
    for section in args.sections:
        t0 = time.perf_counter()
        part = {"ablation": lambda: ablation(args.seconds), "overhead": lambda: overhead(args.seconds),
                "throughput": lambda: throughput(args.seconds), "memory": memory}[section]()
        report += part + [f"({section}: {time.perf_counter() - t0:.0f} s)", ""]
        print("\n".join(part), flush=True)
    report[0] += f"; load average at the end {os.getloadavg()[0]:.1f}"
    text = "\n".join(report)
    if list(args.sections) == list(SECTIONS):
        RESULTS.parent.mkdir(parents=True, exist_ok=True)
        RESULTS.write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
