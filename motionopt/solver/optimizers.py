"""The local optimisers that solve one window, as a table (``OPTIMIZERS``).

Every optimizer has the signature of ``LocalOptimizer``: it minimises ``win.fun`` from ``v0``
within the iteration and tolerance settings of ``opts`` (a ``SolverOptions``; the
optimizers read the fields of ``LocalSettings`` only), asks ``stop(v)`` after every
iteration (a reason it returns ends the run at the best iterate so far), and returns
``(v, iterations, success, message)``.
"""
from __future__ import annotations

from typing import Callable, Protocol

import numpy as np
import torch

from ..objective import NonFiniteTermError
from .window import Window


class LocalSettings(Protocol):
    """What the optimizers read of ``SolverOptions`` (which validates ``optimizer`` against
    ``OPTIMIZERS``, so this module cannot import it)."""

    max_iter: int
    ftol: float
    gtol: float
    history: int
    adam_lr: float


#: Asked after every iteration with the current variables: a reason to stop, or None.
Stop = Callable[[np.ndarray], "str | None"]
LocalOptimizer = Callable[[Window, np.ndarray, LocalSettings, Stop], tuple[np.ndarray, int, bool, str]]


class _Stopped(Exception):
    """Internal: the callback or the time budget ended a local solve."""


class _Guard:
    """Turns ``stop``'s reason into ``_Stopped`` (so it unwinds the optimiser) and keeps it."""

    def __init__(self, stop: Stop):
        self.stop = stop
        self.reason: str | None = None

    def check(self, v: np.ndarray) -> None:
        why = self.stop(v)
        if why:
            self.reason = why
            raise _Stopped


def _best_or(win: Window, v: np.ndarray) -> np.ndarray:
    return win.best[1] if win.best[1] is not None else v


def scipy_lbfgsb(win: Window, v0: np.ndarray, opts: LocalSettings, stop: Stop) -> tuple[np.ndarray, int, bool, str]:
    """scipy's L-BFGS-B (the default)."""
    from scipy.optimize import minimize

    guard, it = _Guard(stop), [0]

    def cb(intermediate_result):
        it[0] += 1
        guard.check(intermediate_result.x)

    try:
        r = minimize(win.fun, v0, jac=True, method="L-BFGS-B", callback=cb,
                     options={"maxiter": opts.max_iter, "ftol": opts.ftol, "gtol": opts.gtol,
                              "maxcor": opts.history})
    except _Stopped:
        return _best_or(win, v0), it[0], True, guard.reason
    # status 1 is the iteration limit, which windowed solving uses on purpose
    return r.x, int(r.nit), r.status in (0, 1), str(r.message)


def nlopt_lbfgs(win: Window, v0: np.ndarray, opts: LocalSettings, stop: Stop) -> tuple[np.ndarray, int, bool, str]:
    """nlopt's LD_LBFGS; ``max_iter`` bounds its evaluations (it reports no iterations)."""
    import nlopt

    it, reason = [0], []
    opt = nlopt.opt(nlopt.LD_LBFGS, len(v0))
    opt.set_vector_storage(opts.history)

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

    opt.set_maxeval(opts.max_iter)
    opt.set_min_objective(f)
    opt.set_ftol_rel(opts.ftol)
    try:
        v = opt.optimize(v0.copy())
        return v, it[0], True, f"nlopt result code {opt.last_optimize_result()}"
    except nlopt.ForcedStop:
        return _best_or(win, v0), it[0], True, reason[0] if reason else "stopped"
    except NonFiniteTermError:
        raise
    except (nlopt.RoundoffLimited, RuntimeError, ValueError) as e:
        return _best_or(win, v0), it[0], False, f"nlopt failed ({type(e).__name__}: {e}); kept the best iterate"


def torch_lbfgs(win: Window, v0: np.ndarray, opts: LocalSettings, stop: Stop) -> tuple[np.ndarray, int, bool, str]:
    """torch.optim.LBFGS with a strong Wolfe line search; when stopped, its count is of evaluations."""
    guard = _Guard(stop)
    v = torch.tensor(v0, dtype=torch.float32, requires_grad=True)
    opt = torch.optim.LBFGS([v], lr=1.0, max_iter=opts.max_iter, history_size=opts.history,
                            tolerance_change=opts.ftol, tolerance_grad=opts.gtol, line_search_fn="strong_wolfe")

    def closure():
        val, g = win.fun(v.detach().double().numpy())
        v.grad = torch.from_numpy(g).float()
        guard.check(win.best[1])
        return torch.tensor(val)

    try:
        opt.step(closure)
    except _Stopped:
        return _best_or(win, v0), win.nfev, True, guard.reason
    n_iter = opt.state[opt._params[0]].get("n_iter", 0)
    return v.detach().double().numpy(), int(n_iter), True, "torch L-BFGS finished"


def adam(win: Window, v0: np.ndarray, opts: LocalSettings, stop: Stop) -> tuple[np.ndarray, int, bool, str]:
    """Plain Adam (step ``adam_lr``) for ``5 * max_iter`` steps: a first-order baseline."""
    guard = _Guard(stop)
    v = torch.tensor(v0, dtype=torch.float32, requires_grad=True)
    opt = torch.optim.Adam([v], lr=opts.adam_lr)
    it = 0
    try:
        while it < opts.max_iter * 5:
            _, g = win.fun(v.detach().double().numpy())
            v.grad = torch.from_numpy(g).float()
            opt.step()
            it += 1
            guard.check(v.detach().double().numpy())
    except _Stopped:
        return _best_or(win, v0), it, True, guard.reason
    return v.detach().double().numpy(), it, True, "adam finished"


#: ``SolverOptions.optimizer`` -> local optimiser.
OPTIMIZERS: dict[str, LocalOptimizer] = {"scipy": scipy_lbfgsb, "nlopt": nlopt_lbfgs, "torch": torch_lbfgs, "adam": adam}
