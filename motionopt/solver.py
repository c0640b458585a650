"""MAP solver: particle swarm initialisation, then L-BFGS over sliding windows.

``solve(objective, problem, options)`` optimises the normalised features of the free
frames of a sequence, window by window (B frames, overlap b). Each window is
conditioned on the solved frames before it; its overlap starts from the previous
window's solution and its new frames from a rollout of the prior. The call and the
result are shaped like ``scipy.optimize.minimize``.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import torch
from threadpoolctl import threadpool_limits
from torch import Tensor

from . import rotations as R
from .features import RootStart, advance, decode_positions
from .objective import MAPObjective, NonFiniteTermError

log = logging.getLogger(__name__)

METHODS = ("scipy", "nlopt", "torch", "adam")
#: Cosine components over a window added to the per-frame variables (see ``_Window``).
BASIS_SIZE = 8
#: Frames decoded at a time by ``seam_report`` (bounds its memory on long sequences).
SEAM_CHUNK = 256


class StopSolve(Exception):
    """Raised by a callback (or returned True) to stop the run; the best iterate is kept."""


@dataclass
class PSOOptions:
    """Particle swarm on a low-dimensional parametrisation: ``n_coeffs`` DCT coefficients
    (over the window's new frames) of offsets to the prior's sampling noise of the root
    displacement and yaw-change features, i.e. ``3 * n_coeffs`` dimensions, never the
    full pose of every frame. A particle is a whole rollout of the prior."""

    particles: int = 12
    iterations: int = 4
    n_coeffs: int = 3
    bound: float = 1.5
    c1: float = 0.5
    c2: float = 0.3
    w: float = 0.7


@dataclass
class SolverOptions:
    """How to solve. ``method`` is the local optimiser: 'scipy' (L-BFGS-B), 'nlopt'
    (LD_LBFGS), 'torch' (torch.optim.LBFGS)
    or 'adam' (plain first-order baseline). ``time_budget`` (seconds per window) stops
    any of them when spent (for comparisons at equal time)."""

    window: int = 34
    overlap: int = 17
    method: str = "scipy"
    # 30: bench/solver.py (throughput) puts it at about 43 new frames/s for path following
    # on this 2-core CPU with 1.1 cm path error; 40 gives about the same error at 35 frames/s.
    max_iter: int = 30
    ftol: float = 1e-7
    gtol: float = 1e-5
    history: int = 10
    # Off by default: in bench/solver.py, against plain L-BFGS given the same time, the swarm
    # lowered the final objective on 0 and the path error on 2 of 10 held-out clips.
    # Pass PSOOptions() to turn it on.
    pso: PSOOptions | None = None
    #: Sampling temperature of the rollouts that initialise new frames; None: the prior's
    #: own (``sample_temperature``, calibrated after training).
    temperature: float | None = None
    seed: int = 0
    adam_lr: float = 0.02
    time_budget: float | None = None
    callback: Callable[[dict], bool | None] | None = None
    progress: bool = False

    def temperature_for(self, prior) -> float:
        """``temperature``, or the prior's calibrated one when it is None."""
        return prior.sample_temperature if self.temperature is None else self.temperature

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"unknown method {self.method!r}; choose one of {', '.join(METHODS)}")
        if not 0 <= self.overlap < self.window:
            raise ValueError(f"overlap must be in [0, window): got window {self.window}, overlap {self.overlap}")


@dataclass
class MAPResult:
    """What ``solve`` returns; shaped like scipy's OptimizeResult."""

    x: Tensor                       # (N, D) normalised features of the whole sequence
    fun: float                      # objective at the end, summed over windows
    fun_start: float                # objective at each window's initialisation, summed
    terms_start: dict[str, float]
    terms: dict[str, float]
    nit: int
    nfev: int
    success: bool
    message: str
    warnings: list[str]
    timings: dict[str, float]       # seconds: pso, rollout, lbfgs (local solves), objective (its
                                    # evaluations with gradient, within lbfgs), prior (decoding and
                                    # scoring windows, within objective), total
    windows: list[dict]
    seam: dict[str, float] = field(default_factory=dict)

    def __getitem__(self, key: str):
        return getattr(self, key)


@dataclass
class Problem:
    """The sequence to solve: ``x0 (N, D)`` normalised features (NaN rows where nothing
    is known yet: those frames are rolled out from the prior), ``free (N,)`` frames the
    solver may change, and the root state before frame 0."""

    x0: Tensor
    free: np.ndarray
    start: RootStart


def _dct_basis(n: int, k: int) -> Tensor:
    t = torch.arange(n, dtype=torch.float32)
    rows = [torch.cos(math.pi * (t + 0.5) * j / n) for j in range(k)]
    return torch.stack(rows)  # (k, n)


def _coarse_basis(n: int, k: int, power: float = 1.0) -> Tensor:
    """(n, k) orthonormal cosine columns, column j scaled by (n / (pi (j + 1/2)))^power.

    The prior scores each frame against the one before it, so its curvature along the
    j-th cosine over n frames is about (pi j / n)^2 times that of a single frame: with
    ``power`` 1 a step on a column moves the slow directions as far as the per-frame
    variables move the fast ones (a diagonal preconditioner in the cosine basis). The
    root displacement and yaw channels integrate into positions, where task terms make
    the slow directions stiff again; they take ``power`` 1/2 (with 1 the first L-BFGS
    step can throw the root a metre when the start is already on target)."""
    b = _dct_basis(n, k).T
    b = b / b.norm(dim=0, keepdim=True)
    return b * (n / (math.pi * (torch.arange(k, dtype=torch.float32) + 0.5))) ** power


_HAT = torch.tensor([[[0, 0, 0], [0, 0, -1], [0, 1, 0]],
                     [[0, 0, 1], [0, 0, 0], [-1, 0, 0]],
                     [[0, -1, 0], [1, 0, 0], [0, 0, 0]]], dtype=torch.float64)


def _tangent_whitening(base: Tensor, std6: Tensor) -> Tensor:
    """(..., R, 3, 3) matrices P such that a rotation vector ``P z`` applied on the right of
    ``base (..., R, 3, 3)`` changes the normalised 6D features (std ``std6 (R, 6)``) by
    about |z|: the prior's curvature is then alike in every direction of every joint
    (a hinge-like joint's 6D entries vary 100 times less than a shoulder's)."""
    g = base[..., None, :, :] @ _HAT.to(base)                                # (..., R, 3, 3, 3)
    jac = torch.cat((g[..., :, 0], g[..., :, 1]), dim=-1) / std6[:, None, :]  # (..., R, 3, 6)
    evals, evecs = torch.linalg.eigh(jac @ jac.transpose(-1, -2))
    return evecs @ torch.diag_embed(evals.clamp_min(1e-12).rsqrt()) @ evecs.transpose(-1, -2)


class _Window:
    """One window's optimisation.

    Variables per free frame: offsets to the four root features (normalised units) and a
    rotation vector per joint applied on the right of the frame's starting rotation, so
    every iterate holds valid rotations (never a 6D vector off the rotation manifold the
    prior was trained on); plus the prior's input noise when the objective has one.
    Rotation vectors are whitened (see ``_tangent_whitening``) so that all variables share
    the normalised units the prior scores. The offsets are the sum of a per-frame part
    and a few scaled cosine components over the window (see ``_coarse_basis``): a step on
    those moves many frames together, which the prior's stiff coupling between
    neighbouring frames otherwise makes L-BFGS do very slowly. Contact weights are fixed
    at the start (``rebase``), so the objective is smooth during a local solve.
    """

    def __init__(self, objective: MAPObjective, x: Tensor, frames: np.ndarray, free_local: np.ndarray,
                 context: Tensor, lead_raw: Tensor, start: RootStart, with_noise: bool):
        self.obj = objective
        self.x = x.clone()
        self.frames = frames
        self.free_np = free_local
        self.free = torch.from_numpy(free_local)
        self.all_free = bool(free_local.all())
        self.context = context
        self.lead_raw = lead_raw
        self.start = start
        self.p = objective.spec.pose_dim
        self.n_rot = len(objective.spec.joints)
        self.k = 4 + 3 * self.n_rot
        self.with_noise = with_noise
        self.n_free = int(free_local.sum())
        self.n_basis = min(BASIS_SIZE, self.n_free)
        self.basis = _coarse_basis(self.n_free, self.n_basis) if self.n_free else torch.zeros(0, 0)
        self.basis_root = _coarse_basis(self.n_free, self.n_basis, 0.5) if self.n_free else torch.zeros(0, 0)
        self.n_vars = (self.n_basis + self.n_free) * self.k
        self.size = self.n_vars + (self.n_free * self.p if with_noise else 0)
        norm = objective.prior.normalizer
        self._mean6 = norm.mean[4:self.p].float()
        self._std6 = norm.std[4:self.p].float()
        self.nfev = 0
        self.prior_seconds = 0.0       # decoding windows and scoring them under the prior
        self.objective_seconds = 0.0   # objective and gradient evaluations, all included
        self.best = (math.inf, None)
        self.best_terms: dict[str, float] = {}
        self.first_terms: dict[str, float] | None = None
        self.seen: dict[int, float] = {}   # objective of every evaluated point, by hash
        self._base_rot: Tensor | None = None
        self._whiten: Tensor | None = None
        self.contacts: Tensor | None = None

    # --- variables <-> window tensors -------------------------------------------------
    def rebase(self) -> None:
        """Take the current window frames as the point that zero variables stand for, and
        fix the contact weights to the prior's prediction there."""
        norm = self.obj.prior.normalizer
        raw = norm.denormalize(self.x[self.free].double())
        base = R.sixd_to_matrix(raw[:, 4:self.p].reshape(self.n_free, self.n_rot, 6))
        self._base_rot = base.float()
        self._whiten = _tangent_whitening(base, norm.std[4:self.p].double().reshape(self.n_rot, 6)).float()
        self._root0 = self.x[self.free, :4]
        self._tail = self.x[self.free, self.p:]
        with torch.no_grad():
            _, self.contacts = self.obj.prior.nll_and_contacts(self.x, self.context)
        self.best = (math.inf, None)
        self.best_terms, self.first_terms, self.seen = {}, None, {}

    def pack(self) -> np.ndarray:
        """The variables of the current base: all zeros."""
        return np.zeros(self.size)

    def unpack(self, v: Tensor) -> tuple[Tensor, Tensor | None]:
        if self._base_rot is None:
            self.rebase()
        lead = v.shape[:-1]
        nk = self.n_vars
        coarse = v[..., :self.n_basis * self.k].reshape(*lead, self.n_basis, self.k)
        u = v[..., self.n_basis * self.k:nk].reshape(*lead, self.n_free, self.k) + torch.cat(
            (self.basis_root @ coarse[..., :4], self.basis @ coarse[..., 4:]), dim=-1)
        z = u[..., 4:].reshape(*lead, self.n_free, self.n_rot, 3, 1)
        mats = self._base_rot @ R.axis_angle_to_matrix((self._whiten @ z)[..., 0])
        six = (R.matrix_to_6d(mats).reshape(*lead, self.n_free, 6 * self.n_rot) - self._mean6) / self._std6
        rows = torch.cat((self._root0 + u[..., :4], six, self._tail.expand(*lead, *self._tail.shape)), dim=-1)
        if self.all_free:
            x = rows
        else:
            x = self.x.expand(*lead, *self.x.shape).clone()
            x[..., self.free, :] = rows
        noise = None
        if self.with_noise:
            noise = torch.zeros_like(x)
            noise[..., self.free, :self.p] = v[..., nk:].reshape(*lead, self.n_free, self.p)
        return x, noise

    def state(self, v: Tensor):
        x, noise = self.unpack(v)
        t0 = time.perf_counter()
        st = self.obj.window_state(x, self.frames, self.context, self.lead_raw, self.start, noise, self.contacts)
        self.prior_seconds += time.perf_counter() - t0
        return st

    def energies(self, v: Tensor) -> dict[str, Tensor]:
        """Every active term's energy."""
        return self.obj.energies(self.state(v))

    def _check(self, e: dict[str, Tensor]) -> None:
        for name, val in e.items():
            if not bool(torch.isfinite(val).all()):
                raise NonFiniteTermError(name, f"in frames {self.frames[0]}-{self.frames[-1]}")

    # --- scalar objective with gradient -----------------------------------------------
    def fun(self, v_np: np.ndarray) -> tuple[float, np.ndarray]:
        t0 = time.perf_counter()
        v = torch.tensor(v_np, dtype=torch.float32, requires_grad=True)
        st = self.state(v)
        e = self.obj.energies(st)
        self._check(e)
        total = sum(e.values())
        (g,) = torch.autograd.grad(total, v)
        self.nfev += 1
        terms = {k: float(t.detach()) for k, t in e.items()}
        f = sum(terms.values())
        g = g.numpy().astype(np.float64)
        if not np.isfinite(g).all():
            raise NonFiniteTermError("gradient", f"in frames {self.frames[0]}-{self.frames[-1]}")
        if self.first_terms is None:
            self.first_terms = terms
        self.seen[hash(v_np.tobytes())] = f
        if f < self.best[0]:
            self.best, self.best_terms = (f, v_np.copy()), terms
        self.objective_seconds += time.perf_counter() - t0
        return f, g

    def values(self, v_np: np.ndarray) -> dict[str, float]:
        """Every term's value at ``v_np`` (no gradient)."""
        with torch.no_grad():
            return {k: float(t) for k, t in self.energies(torch.tensor(v_np, dtype=torch.float32)).items()}


def _pso_rollout(win: _Window, prior, context: Tensor, first: int, unknown: Tensor, base_noise: Tensor,
                 opts: PSOOptions, temperature: float, seed: int) -> tuple[Tensor, float, int]:
    """Particle swarm over the prior's sampling noise of the window's new frames.

    A particle is ``3 * n_coeffs`` DCT coefficients added to the standard normal draws of
    the root displacement and yaw-change features (``base_noise`` elsewhere), so each
    particle is a whole coherent rollout from window frame ``first``, used where
    ``unknown``; its cost is the window objective. Returns the best rollout (n_new, D),
    its cost and the number of evaluations.
    """
    import pyswarms as ps

    n_new = base_noise.shape[0]
    basis = _dct_basis(n_new, opts.n_coeffs)
    dims = 3 * opts.n_coeffs
    best: list = [None, math.inf]

    def cost(c: np.ndarray) -> np.ndarray:
        coef = torch.from_numpy(c).float().reshape(len(c), 3, opts.n_coeffs)
        eps = base_noise.expand(len(c), -1, -1).clone()
        eps[..., :3] += torch.einsum("pck,kn->pnc", coef, basis)
        roll = prior.sample(context.expand(len(c), *context.shape), n_new, temperature=temperature, noise=eps)
        xw = win.x.expand(len(c), *win.x.shape).clone()
        xw[:, first:] = torch.where(unknown[:, None], roll, xw[:, first:])
        with torch.no_grad():
            st = win.obj.window_state(xw, win.frames, win.context, win.lead_raw, win.start)
            total = sum(win.obj.energies(st).values())
        total = torch.nan_to_num(total, nan=1e30, posinf=1e30)
        i = int(total.argmin())
        if float(total[i]) < best[1]:
            best[:] = [roll[i], float(total[i])]
        return total.double().numpy()

    rng = np.random.default_rng(seed)
    init = rng.uniform(-opts.bound, opts.bound, (opts.particles, dims)) * 0.5
    init[0] = 0.0  # one particle is the plain rollout
    np.random.seed(seed)  # pyswarms draws its velocities from numpy's global generator
    optimizer = ps.single.GlobalBestPSO(n_particles=opts.particles, dimensions=dims,
                                        options={"c1": opts.c1, "c2": opts.c2, "w": opts.w},
                                        bounds=(np.full(dims, -opts.bound), np.full(dims, opts.bound)),
                                        init_pos=init)
    optimizer.optimize(cost, iters=opts.iterations, verbose=False)
    return best[0], best[1], opts.particles * opts.iterations


class _Stopped(Exception):
    """Internal: the callback or the time budget ended a local solve."""


def _local_solve(win: _Window, v0: np.ndarray, opts: SolverOptions,
                 stop: Callable[[np.ndarray], str | None]) -> tuple[np.ndarray, int, bool, str]:
    """Run the chosen local optimiser from v0; returns (v, iterations, success, message).

    ``stop(v)`` is asked after every iteration; a reason it returns ends the run at the
    best iterate so far."""
    reason: list[str] = []

    def check(v: np.ndarray) -> None:
        why = stop(v)
        if why:
            reason.append(why)
            raise _Stopped

    def best_or(v: np.ndarray) -> np.ndarray:
        return win.best[1] if win.best[1] is not None else v

    if opts.method == "scipy":
        from scipy.optimize import minimize

        it = [0]

        def cb(intermediate_result):
            it[0] += 1
            check(intermediate_result.x)

        try:
            r = minimize(win.fun, v0, jac=True, method="L-BFGS-B", callback=cb,
                         options={"maxiter": opts.max_iter, "ftol": opts.ftol, "gtol": opts.gtol,
                                  "maxcor": opts.history})
        except _Stopped:
            return best_or(v0), it[0], True, reason[0]
        # status 1 is the iteration limit, which windowed solving uses on purpose
        return r.x, int(r.nit), r.status in (0, 1), str(r.message)
    if opts.method == "nlopt":
        import nlopt

        n = len(v0)
        it = [0]
        local = nlopt.opt(nlopt.LD_LBFGS, n)
        local.set_vector_storage(opts.history)

        def f(v, grad):
            val, g = win.fun(v)
            if grad.size > 0:
                grad[:] = g
            it[0] += 1
            why = stop(v)
            if why:
                reason.append(why)
                raise nlopt.ForcedStop
            return val

        opt = local
        opt.set_maxeval(opts.max_iter)
        opt.set_min_objective(f)
        opt.set_ftol_rel(opts.ftol)
        try:
            v = opt.optimize(v0.copy())
            return v, it[0], True, f"nlopt result code {opt.last_optimize_result()}"
        except nlopt.ForcedStop:
            return best_or(v0), it[0], True, reason[0] if reason else "stopped"
        except NonFiniteTermError:
            raise
        except (nlopt.RoundoffLimited, RuntimeError, ValueError) as e:
            return best_or(v0), it[0], False, f"nlopt failed ({type(e).__name__}: {e}); kept the best iterate"
    # torch-native paths
    v = torch.tensor(v0, dtype=torch.float32, requires_grad=True)
    if opts.method == "torch":
        opt = torch.optim.LBFGS([v], lr=1.0, max_iter=opts.max_iter, history_size=opts.history,
                                tolerance_change=opts.ftol, tolerance_grad=opts.gtol, line_search_fn="strong_wolfe")

        def closure():
            val, g = win.fun(v.detach().double().numpy())
            v.grad = torch.from_numpy(g).float()
            check(win.best[1])
            return torch.tensor(val)

        try:
            opt.step(closure)
        except _Stopped:
            return best_or(v0), win.nfev, True, reason[0]
        n_iter = opt.state[opt._params[0]].get("n_iter", 0)
        return v.detach().double().numpy(), int(n_iter), True, "torch L-BFGS finished"
    opt = torch.optim.Adam([v], lr=opts.adam_lr)
    it = 0
    try:
        while it < opts.max_iter * 5:
            _, g = win.fun(v.detach().double().numpy())
            v.grad = torch.from_numpy(g).float()
            opt.step()
            it += 1
            check(v.detach().double().numpy())
    except _Stopped:
        return best_or(v0), it, True, reason[0]
    return v.detach().double().numpy(), it, True, "adam finished"


def window_starts(free: np.ndarray, window: int, overlap: int) -> list[int]:
    """Start frames of the windows that cover every free frame, stepping by window - overlap;
    past a stretch of fixed frames the next window starts at the next free frame."""
    idx = np.nonzero(free)[0]
    if len(idx) == 0:
        return []
    starts, s = [], int(idx[0])
    step = window - overlap
    while True:
        starts.append(s)
        if s + window > idx[-1]:
            break
        s += step
        nxt = idx[idx >= s]
        s = int(nxt[0]) if len(nxt) and nxt[0] > s + window else s
    return starts


def solve(objective: MAPObjective, problem: Problem, options: SolverOptions = SolverOptions()) -> MAPResult:
    """Solve the MAP problem window by window; see the module docstring.

    numpy's BLAS runs on one thread meanwhile: the optimisers' vector updates are far too
    small to share, and on a busy machine its spinning threads cost L-BFGS-B about
    20 ms per iteration (60 times its own work)."""
    with threadpool_limits(1, user_api="blas"):
        return _solve(objective, problem, options)


def _solve(objective: MAPObjective, problem: Problem, opts: SolverOptions) -> MAPResult:
    prior, spec = objective.prior, objective.spec
    norm = prior.normalizer
    x = problem.x0.clone().float()
    n, d = x.shape
    free = np.asarray(problem.free, bool)
    if d != spec.dim or free.shape != (n,):
        raise ValueError(f"the problem has x0 of shape {tuple(x.shape)} and free of shape {free.shape}; the prior "
                         f"needs x0 (N, {spec.dim}) and free (N,)")
    known = ~torch.isnan(x).any(-1).numpy()
    rf = prior.receptive_field
    p = spec.pose_dim
    temperature = opts.temperature_for(prior)
    starts = window_starts(free, opts.window, opts.overlap)
    t_total = time.perf_counter()
    timings = {"pso": 0.0, "lbfgs": 0.0, "prior": 0.0, "rollout": 0.0, "objective": 0.0}
    terms_start: dict[str, float] = {}
    terms_end: dict[str, float] = {}
    nit = nfev = 0
    messages: list[str] = []
    warns: list[str] = []
    windows: list[dict] = []
    success = True
    committed = 0                      # the root state is known up to frame `committed`
    root_state = problem.start         # state before frame `committed`
    lead_n = 2
    stopped = False
    for w_i, s in enumerate(starts):
        e = min(s + opts.window, n)
        frames = np.arange(s, e)
        # advance the root state up to the frame before the lead frames
        lead_from = max(s - lead_n, 0)
        if lead_from > committed:
            root_state = advance(root_state, norm.denormalize(x[committed:lead_from].double()), spec)
            committed = lead_from
        lead_raw = norm.denormalize(x[committed:s].double()).float()
        context = x[max(0, s - rf):s]
        free_local = free[s:e]
        win = _Window(objective, x[s:e], frames, free_local, context, lead_raw, root_state,
                      with_noise=objective.noise_term is not None)
        if win.size == 0:
            continue
        # new frames: a rollout of the prior, steered by the particle swarm when enabled
        unknown = np.nonzero(~known[s:e])[0]
        info: dict = {"frames": (int(s), int(e))}
        pso_evals = 0
        if len(unknown):
            first = int(unknown[0])
            ctx = x[max(0, s + first - rf):s + first]
            if len(ctx) == 0:
                raise ValueError("the first frame to synthesise has no context: give at least one known frame before it")
            fill = torch.from_numpy(~known[s + first:e])
            gen = torch.Generator().manual_seed(opts.seed * 100003 + w_i)
            base = torch.randn(e - s - first, p, generator=gen)
            t0 = time.perf_counter()
            if opts.pso is not None:
                roll, info["fun_pso"], pso_evals = _pso_rollout(win, prior, ctx, first, fill, base, opts.pso,
                                                                temperature, opts.seed * 7919 + w_i)
                timings["pso"] += time.perf_counter() - t0
            else:
                roll = prior.sample(ctx, e - s - first, temperature=temperature, noise=base)
                timings["rollout"] += time.perf_counter() - t0
            win.x[first:] = torch.where(fill[:, None], roll, win.x[first:])
            x[s:e] = win.x
            known[s + first:e] = True
        win.rebase()
        v0 = win.pack()
        t0 = time.perf_counter()

        def stop(v: np.ndarray) -> str | None:
            if opts.callback is not None:
                try:
                    if opts.callback({"window": w_i, "frames": (int(s), int(e)), "x": v, "best": win.best[0]}):
                        return "stopped by callback"
                except StopSolve:
                    return "stopped by callback"
            if opts.time_budget is not None and time.perf_counter() - t0 >= opts.time_budget:
                return "time budget reached"
            return None

        try:
            v, it, ok, msg = _local_solve(win, v0, opts, stop)
        except NonFiniteTermError as err:
            v = win.best[1] if win.best[1] is not None else v0
            it, ok, msg = 0, False, str(err)
            warns.append(f"window {w_i} (frames {s}-{e - 1}): {err}; kept the best iterate")
        timings["lbfgs"] += time.perf_counter() - t0
        # the optimisers start with v0, so the first evaluation holds the starting values
        start_vals = win.first_terms if win.first_terms is not None else win.values(v0)
        if win.best[1] is not None:   # keep the best point evaluated (where the optimiser ends, normally)
            f_end = win.seen.get(hash(v.tobytes()), math.inf)
            if f_end > win.best[0] + 1e-6 * abs(win.best[0]) and not msg.startswith("term "):
                warns.append(f"window {w_i}: the optimiser ended above its best iterate; kept the best")
            v, end_vals = win.best[1], win.best_terms
        else:
            end_vals = win.values(v)
        for k, val in start_vals.items():
            terms_start[k] = terms_start.get(k, 0.0) + val
        info["fun_start"] = sum(start_vals.values())
        stopped = msg == "stopped by callback"
        timings["prior"] += win.prior_seconds
        timings["objective"] += win.objective_seconds
        nit += it
        nfev += win.nfev + pso_evals
        success &= ok
        if not ok:
            messages.append(f"window {w_i}: {msg}")
        # write the window back, with contacts predicted by the prior
        with torch.no_grad():
            xw, _ = win.unpack(torch.from_numpy(v).float())
            _, probs = prior.nll_and_contacts(xw, context)
        xw[:, p:] = torch.where(torch.from_numpy(free_local)[:, None], (probs > 0.5).float(), xw[:, p:])
        x[s:e] = xw
        for k, val in end_vals.items():
            terms_end[k] = terms_end.get(k, 0.0) + val
        info.update(fun=sum(end_vals.values()), nit=it, nfev=win.nfev, message=msg)
        windows.append(info)
        if opts.progress:
            log.info("window %d/%d frames %d-%d: %.1f -> %.1f", w_i + 1, len(starts), s, e - 1,
                     info["fun_start"], info["fun"])
        if stopped:
            messages.append("stopped by callback")
            break
    timings["total"] = time.perf_counter() - t_total
    seam = seam_report(objective, x, problem.start, [w["frames"][0] for w in windows])
    return MAPResult(
        x=x, fun=sum(terms_end.values()), fun_start=sum(terms_start.values()), terms_start=terms_start,
        terms=terms_end, nit=nit, nfev=nfev, success=success and not stopped,
        message="; ".join(messages) if messages else "converged in every window",
        warnings=warns, timings=timings, windows=windows, seam=seam,
    )


@torch.no_grad()
def seam_report(objective: MAPObjective, x: Tensor, start: RootStart, boundaries: list[int]) -> dict[str, float]:
    """Largest mean joint acceleration (m/s^2) at window boundaries against inner frames'.

    Decodes ``SEAM_CHUNK`` frames at a time, so its memory does not grow with the length."""
    if len(boundaries) < 2:
        return {}
    norm, spec = objective.prior.normalizer, objective.spec
    n = len(x)
    acc = np.empty(max(n - 2, 0))
    state = start
    for a in range(0, n - 2, SEAM_CHUNK):
        lo = max(a - 2, 0)            # two frames before the chunk give its first accelerations
        if lo > 0:
            state = advance(state, norm.denormalize(x[prev_lo:lo].double()), spec)
        prev_lo = lo
        b = min(a + SEAM_CHUNK, n - 2)
        raw = norm.denormalize(x[lo:b + 2].double())
        pos = decode_positions(raw, spec, objective.skeleton, state if lo > 0 else start)
        a_chunk = ((pos[2:] - 2 * pos[1:-1] + pos[:-2]) * spec.fps ** 2).norm(dim=-1).mean(-1).numpy()
        acc[a:b] = a_chunk[a - lo:]
    at = np.zeros(len(acc), bool)
    for b in boundaries[1:]:
        at[max(b - 2, 0):min(b + 1, len(acc))] = True
    if at.all() or not at.any():
        return {}
    return {"boundary_max_acc": float(acc[at].max()), "inner_max_acc": float(acc[~at].max()),
            "inner_p99_acc": float(np.percentile(acc[~at], 99)),
            "ratio": float(acc[at].max() / max(acc[~at].max(), 1e-9))}
