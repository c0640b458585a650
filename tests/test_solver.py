"""The windowed MAP solver on real clips: window layout, stitching, every local optimiser,
determinism with the shipped prior, the stop callback, non-finite terms, falling back to
the best iterate, and memory on long sequences."""
from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch

from motionopt import bvh
from motionopt import solver as S
from motionopt.features import encode, to_model_motion
from motionopt.objective import ContactTerm, MAPObjective, PathTerm, PoseFidelityTerm, Term
from motionopt.solver import (PSOOptions, Problem, SolverOptions, energies_at, free_window_starts, seam_report,
                              solve)
from motionopt.solver import diagnostics
from priors.checkpoint import CHECKPOINT_DIR, load_prior

from priorkit import cmu_clips, tiny_prior
from clips import BANDAI_30, DATA

ROOT = Path(__file__).resolve().parent.parent


def prepared(prior, path: Path):
    """A clip as the prior sees it: model motion, normalised features (T, D), root start."""
    model = to_model_motion(bvh.load(path), prior.spec)
    raw, start = encode(model, prior.spec)
    return model, prior.normalizer.normalize(raw).float(), start


def contact_term(prior, model) -> ContactTerm:
    cidx = prior.spec.contact_indices()
    return ContactTerm(cidx, np.percentile(model.positions()[:, cidx, 1], 5.0, axis=0))


def denoise(prior, path: Path, n: int | None = None, extra: list[Term] = ()):
    """A denoising objective and problem on the first ``n`` frames of a real clip."""
    model, x, start = prepared(prior, path)
    n = min(n or len(x), len(x))
    model = model[:n]
    terms = [PoseFidelityTerm(model.root, model.rotations, 0.03, 0.08), contact_term(prior, model), *extra]
    return MAPObjective(prior, model.skeleton, terms), Problem(x[:n].clone(), np.ones(n, bool), start), model


def window_energy(objective: MAPObjective, x: torch.Tensor, start, n: int) -> float:
    """The objective of frames [0, n) of ``x`` as one window from the sequence start."""
    with torch.no_grad():
        st = objective.window_state(x[:n], np.arange(n), x[:0], x[:0, :], start)
        return float(sum(objective.energies(st).values()))


# ---- window layout -------------------------------------------------------------------
MASKS = {
    "all free": np.ones(100, bool),
    "after a seed": np.r_[np.zeros(30, bool), np.ones(70, bool)],
    "gap of fixed frames": np.r_[np.ones(10, bool), np.zeros(60, bool), np.ones(30, bool)],
    "short gaps": np.r_[np.zeros(5, bool), np.ones(12, bool), np.zeros(20, bool), np.ones(3, bool), np.zeros(9, bool)],
    "one frame": np.r_[np.zeros(40, bool), True],
    "shorter than a window": np.ones(20, bool),
}


@pytest.mark.parametrize("name", list(MASKS))
@pytest.mark.parametrize("window,overlap", [(34, 17), (10, 3), (8, 0)])
def test_free_window_starts_cover_every_free_frame(name, window, overlap):
    free = MASKS[name]
    starts = free_window_starts(free, window, overlap)
    covered = np.zeros(len(free), bool)
    for s in starts:
        covered[s:s + window] = True
    assert covered[free].all()
    assert starts == sorted(set(starts)) and free[starts[0]]
    for a, b in zip(starts, starts[1:]):
        # consecutive windows overlap by `overlap` frames, unless fixed frames lie between
        # them: then the next window starts at the next free frame
        if free[a + window - overlap:a + window].any() or b == a + window - overlap:
            assert b == a + window - overlap
        else:
            assert free[b] and not free[a + window:b].any()
    # no window is wasted on fixed frames only
    assert all(free[s:s + window].any() for s in starts)


def test_free_window_starts_extend_windows_past_gaps():
    free = MASKS["gap of fixed frames"]
    assert free_window_starts(free, 8, 4) == [0, 4, 8, 70, 74, 78, 82, 86, 90, 94]
    assert free_window_starts(np.zeros(10, bool), 8, 4) == []


def test_options_are_checked():
    with pytest.raises(ValueError, match="unknown optimizer"):
        SolverOptions(optimizer="bfgs")
    with pytest.raises(ValueError, match="overlap"):
        SolverOptions(window=10, overlap=10)


def test_solve_from_keeps_the_lowest_objective_of_its_starts():
    """``solve_from`` solves from each start as ``solve`` does and keeps the lowest final
    objective, or with ``faults`` the lowest among the results of fewest faults; starts of
    different sequences are refused."""
    prior = tiny_prior()
    objective, problem, _ = denoise(prior, cmu_clips()[0], 40)
    noisy = problem.x0 + 0.5 * torch.randn(problem.x0.shape, generator=torch.Generator().manual_seed(3))
    starts = [Problem(noisy, problem.free, problem.start), problem]
    opts = SolverOptions(window=20, overlap=5, max_iter=10, pso=None)
    alone = [solve(objective, p, opts) for p in starts]
    best = S.solve_from(objective, starts, opts)
    assert best.starts_fun == pytest.approx([r.fun for r in alone])
    assert best.fun == min(best.starts_fun) and alone[1].fun < alone[0].fun
    assert torch.equal(best.x, alone[1].x) and best.starts_faults == []
    # a fault the objective does not see (here: the lower objective itself) outranks the objective
    threshold = (alone[0].fun + alone[1].fun) / 2
    sound = S.solve_from(objective, starts, opts, faults=lambda r: int(r.fun < threshold))
    assert sound.starts_faults == [0, 1] and torch.equal(sound.x, alone[0].x) and sound.fun == alone[0].fun
    with pytest.raises(ValueError, match="free frames"):
        S.solve_from(objective, [problem, Problem(problem.x0, ~problem.free, problem.start)], opts)


# ---- stitching and local optimisers ---------------------------------------------------
def test_inbetween_keeps_fixed_frames_and_fills_the_gap():
    prior = tiny_prior()
    model, x, start = prepared(prior, cmu_clips()[0])
    n = 60
    free = np.zeros(n, bool)
    free[20:45] = True
    x0 = x[:n].clone()
    x0[free] = float("nan")
    join = np.zeros(n, bool)
    join[45] = True
    terms = [PoseFidelityTerm(model.root, model.rotations, 0.01, 0.02, mask=join, name="join"),
             contact_term(prior, model)]
    opts = SolverOptions(window=16, overlap=6, max_iter=8, pso=PSOOptions(particles=4, iterations=2))
    res = solve(MAPObjective(prior, model.skeleton, terms), Problem(x0, free, start), opts)
    assert torch.isfinite(res.x).all()
    # fixed frames keep their poses bit for bit; the root lives in world space, so the root
    # steps change only where a fixed frame follows a free one (it keeps its place)
    assert torch.equal(res.x[~free, 3:], x0[~free, 3:])
    after_free = np.zeros(n, bool)
    after_free[1:] = free[:-1] & ~free[1:]
    assert torch.equal(res.x[~free & ~after_free, :3], x0[~free & ~after_free, :3])
    covered = np.zeros(n, bool)
    for w in res.windows:
        covered[w["frames"][0]:w["frames"][1]] = True
    assert covered[free].all() and len(res.windows) == len(free_window_starts(free, 16, 6))
    assert res.success and res.fun < res.fun_start and set(res.terms) == {"prior", "join", "contact"}
    assert res.timings["pso"] > 0 and res.nfev > opts.pso.particles * opts.pso.iterations


@pytest.mark.parametrize("optimizer", list(S.OPTIMIZERS))
def test_every_local_optimiser_lowers_the_objective(optimizer):
    prior = tiny_prior()
    objective, problem, _ = denoise(prior, cmu_clips()[0], n=30)
    res = solve(objective, problem, SolverOptions(optimizer=optimizer, max_iter=10, pso=None))
    assert res.success, res.message
    assert res.fun < res.fun_start - 1.0
    assert res.nfev >= res.windows[0]["nfev"] > 0 and res.timings["lbfgs"] > 0


def test_stitched_result_has_no_seam():
    """Boundary accelerations of a three-window denoise stay within the inner frames'."""
    prior = tiny_prior()
    objective, problem, _ = denoise(prior, cmu_clips()[0])
    res = solve(objective, problem, SolverOptions(max_iter=15, pso=None))
    assert len(res.windows) == 3
    assert res.seam["ratio"] < 1.5, res.seam


def test_seam_report_is_the_same_in_chunks(monkeypatch):
    prior = tiny_prior()
    _, x, start = prepared(prior, cmu_clips()[0])
    objective = MAPObjective(prior, prior.skeleton, [])
    whole = seam_report(objective, x, start, [0, 17, 34, 51])
    monkeypatch.setattr(diagnostics, "SEAM_CHUNK", 7)
    chunked = seam_report(objective, x, start, [0, 17, 34, 51])
    assert whole.keys() == chunked.keys() and whole
    for k in whole:
        assert abs(whole[k] - chunked[k]) <= 1e-6 * max(1.0, abs(whole[k])), k


# ---- energies without optimising ------------------------------------------------------
def test_energies_at_evaluates_the_solvers_windows():
    """``energies_at`` on the solver's windows, each with the log-std and contact weights
    of the point itself: the solve's start terms when one window covers it, and at its
    result (windows side by side, overlap 0) the same fidelity.

    The prior and contact terms at the result differ from the solve's: a local solve
    holds the log-std and the contact weights of where it started, ``energies_at`` takes
    those of ``x`` (the same definition for the clean clip, the start and the result).
    At the start, only the first window starts from ``x0`` itself: later ones start
    after the solved windows before them, so E(x0) is ``terms_start`` for a one-window
    solve only."""
    prior = tiny_prior()
    objective, problem, _ = denoise(prior, cmu_clips()[0], n=60)
    side_by_side = SolverOptions(window=20, overlap=0, max_iter=10, pso=None)
    res = solve(objective, problem, side_by_side)
    at = energies_at(objective, problem, res.x, side_by_side)
    assert len(res.windows) == 3 and at.keys() == res.terms.keys()
    assert at["fidelity"] == pytest.approx(res.terms["fidelity"], rel=1e-3)

    objective, problem, _ = denoise(prior, cmu_clips()[0], n=30)
    one = SolverOptions(max_iter=10, pso=None)
    res = solve(objective, problem, one)
    assert len(res.windows) == 1
    assert energies_at(objective, problem, problem.x0, one) == pytest.approx(res.terms_start, rel=1e-6)
    with pytest.raises(ValueError, match="finite features"):
        energies_at(objective, problem, torch.full_like(problem.x0, float("nan")), one)


# ---- determinism with the shipped prior -----------------------------------------------
@pytest.fixture(scope="module")
def bandai_prior():
    path = CHECKPOINT_DIR / "bandai-locomotion-ccnet.pt"
    if not path.exists():
        pytest.skip("the shipped Bandai prior is not there")
    return load_prior(path)


def path_problem(prior, n_seed: int = 30, n_new: int = 20):
    """Continue the first second of the shipped Bandai walk along the clip's own root path."""
    model, x, start = prepared(prior, DATA / BANDAI_30)
    n = n_seed + n_new
    x0 = torch.full((n, prior.spec.dim), float("nan"))
    x0[:n_seed] = x[:n_seed]
    free = np.zeros(n, bool)
    free[n_seed:] = True
    path = model.root[n_seed - 1:n, [0, 2]]
    terms = [PathTerm(path, 0.05, mask=free), contact_term(prior, model)]
    return MAPObjective(prior, model.skeleton, terms), Problem(x0, free, start)


def test_same_seed_same_result_bit_for_bit(bandai_prior):
    objective, problem = path_problem(bandai_prior)
    opts = SolverOptions(max_iter=5, pso=PSOOptions(particles=4, iterations=2), seed=3)
    a = solve(objective, problem, opts)
    b = solve(objective, problem, opts)
    assert a.timings["pso"] > 0 and torch.isfinite(a.x).all()
    assert torch.equal(a.x, b.x) and a.fun == b.fun and a.nfev == b.nfev
    c = solve(objective, problem, SolverOptions(max_iter=5, pso=PSOOptions(particles=4, iterations=2), seed=4))
    assert not torch.equal(a.x, c.x)


# ---- stopping, non-finite terms, best iterates -----------------------------------------
@pytest.mark.parametrize("stop_in_window,raise_it", [(0, False), (1, False), (1, True)])
def test_callback_stops_the_run(stop_in_window, raise_it):
    prior = tiny_prior()
    objective, problem, _ = denoise(prior, cmu_clips()[0])
    seen: list[dict] = []

    def callback(info: dict) -> bool:
        seen.append(info)
        if raise_it and info["window"] == stop_in_window:
            raise S.StopSolve
        return info["window"] == stop_in_window

    res = solve(objective, problem, SolverOptions(max_iter=10, pso=None, callback=callback))
    assert len(res.windows) == stop_in_window + 1 < len(free_window_starts(problem.free, 34, 17))
    assert not res.success and "stopped by callback" in res.message
    assert res.windows[-1]["message"] == "stopped by callback"
    assert set(seen[0]) == {"window", "frames", "x", "best"} and seen[-1]["window"] == stop_in_window
    # frames after the stop are the input's, the rest solved and finite
    assert torch.isfinite(res.x).all()
    end = res.windows[-1]["frames"][1]
    torch.testing.assert_close(res.x[end:, :prior.spec.pose_dim], problem.x0[end:, :prior.spec.pose_dim])


def test_nan_target_stops_its_window_and_names_the_term():
    prior = tiny_prior()
    model, x, start = prepared(prior, cmu_clips()[0])
    n = 60                                        # windows [0, 34), [17, 51), [34, 60)
    root = model.root[:n].copy()
    root[55, 1] = np.nan                           # only the last window sees it
    bad = PoseFidelityTerm(root, None, 0.03, name="bad_target")
    objective, problem, _ = denoise(prior, cmu_clips()[0], n=n, extra=[bad])
    res = solve(objective, problem, SolverOptions(max_iter=10, pso=None))
    assert not res.success
    assert "window 2" in res.message and "'bad_target'" in res.message and "not finite" in res.message
    assert any("bad_target" in w and "kept the best iterate" in w for w in res.warnings)
    assert [w["message"].startswith("term 'bad_target'") for w in res.windows] == [False, False, True]
    assert all(w["fun"] < w["fun_start"] for w in res.windows[:2])
    assert torch.isfinite(res.x).all()
    # the stopped window keeps its start: the input beyond the previous window
    p = prior.spec.pose_dim
    torch.testing.assert_close(res.x[51:, :p], problem.x0[51:, :p], atol=1e-3, rtol=0)


class FailsAfter(Term):
    """A real term whose data turn to NaN after ``n`` evaluations (a target stream that
    breaks during the run): the solver must stop and keep the best iterate before it."""

    def __init__(self, term: Term, n: int):
        self.term, self.n, self.calls, self.name = term, n, 0, "flaky"

    def energy(self, state):
        self.calls += 1
        e = self.term.energy(state)
        return e * float("nan") if self.calls > self.n else e


def test_failure_mid_run_keeps_the_best_iterate():
    prior = tiny_prior()
    model, x, start = prepared(prior, cmu_clips()[0])
    n = 30
    real = PoseFidelityTerm(model.root[:n], model.rotations[:n], 0.03, 0.08)
    objective, problem, _ = denoise(prior, cmu_clips()[0], n=n)
    objective.terms[0] = FailsAfter(real, 12)
    res = solve(objective, problem, SolverOptions(max_iter=40, pso=None))
    assert not res.success and "'flaky'" in res.message and res.windows[0]["nfev"] >= 5
    assert torch.isfinite(res.x).all()
    assert res.windows[0]["fun"] < res.windows[0]["fun_start"] - 1.0    # the best iterate before the NaNs
    kept = [real if t is objective.terms[0] else t for t in objective.terms]
    assert energies_at(MAPObjective(prior, model.skeleton, kept), problem, res.x)["fidelity"] < float("inf")


def test_diverging_optimiser_falls_back_to_its_best_iterate():
    """Adam with too large a step ends above its best iterate; the result is the best."""
    prior = tiny_prior()
    objective, problem, _ = denoise(prior, cmu_clips()[0], n=30)
    bests: list[float] = []
    res = solve(objective, problem, SolverOptions(optimizer="adam", adam_lr=0.1, max_iter=4, pso=None,
                                                  callback=lambda info: bests.append(info["best"])))
    assert res.success and res.windows[0]["nit"] == 20
    assert res.windows[0]["fun"] == pytest.approx(min(bests), rel=1e-6)
    assert min(bests) < res.fun_start
    assert res.warnings == ["window 0: the optimiser ended above its best iterate; kept the best"]


def test_time_budget_ends_each_window():
    prior = tiny_prior()
    objective, problem, _ = denoise(prior, cmu_clips()[0], n=30)
    res = solve(objective, problem, SolverOptions(max_iter=10_000, ftol=0, gtol=0, pso=None, time_budget=0.3))
    assert res.windows[0]["message"] == "time budget reached" and res.success
    assert res.timings["lbfgs"] < 2.0


# ---- memory ---------------------------------------------------------------------------
MEMORY_RUN = textwrap.dedent("""
    import json, re, sys
    import numpy as np, torch
    sys.path.insert(0, {tests!r})
    torch.set_num_threads(1)
    from priorkit import tiny_prior, cmu_clips
    from test_solver import denoise
    from motionopt.solver import Problem, SolverOptions, solve
    n = int(sys.argv[1])
    prior = tiny_prior()
    objective, problem, model = denoise(prior, cmu_clips()[0])
    reps = -(-n // len(problem.x0))
    x = problem.x0.repeat(reps, 1)[:n]          # features are per-frame deltas: tiling is a valid motion
    def vm(key):
        return int(re.search(key + r":\\s+(\\d+)", open("/proc/self/status").read()).group(1))
    open("/proc/self/clear_refs", "w").write("5")   # reset the peak resident size (Linux)
    before = vm("VmRSS")
    res = solve(objective, Problem(x, np.ones(n, bool), problem.start), SolverOptions(max_iter=1, pso=None))
    after = vm("VmHWM")
    print(json.dumps({{"before_kb": before, "after_kb": after, "windows": len(res.windows)}}))
""")


def peak_rss_kb(n: int) -> dict:
    code = MEMORY_RUN.format(tests=str(Path(__file__).parent))
    out = subprocess.run([sys.executable, "-c", code, str(n)], capture_output=True, text=True, check=True, cwd=ROOT)
    return json.loads(out.stdout.strip().splitlines()[-1])


def growth_kb(short: int, long: int) -> tuple[int, dict, dict]:
    """Extra memory (kB, peak during the solve over resident before it) that the solve of
    ``long`` frames takes over that of ``short``."""
    a, b = peak_rss_kb(short), peak_rss_kb(long)
    assert b["windows"] > 4 * a["windows"]
    return (b["after_kb"] - b["before_kb"]) - (a["after_kb"] - a["before_kb"]), a, b


def test_memory_does_not_grow_with_length():
    """Peak memory of a 1500-frame solve against a 300-frame one: the difference stays
    within a few times the longer output and input (1500 x 132 float32: 0.8 MB each)."""
    grow, a, b = growth_kb(300, 1500)
    assert grow < 8 * 1024, (grow, a, b)


@pytest.mark.slow
def test_memory_of_10000_frames():
    """The same for 10 000 frames against 2 000 (output and input 5.3 MB each)."""
    grow, a, b = growth_kb(2000, 10_000)
    assert grow < 32 * 1024, (grow, a, b)
