"""What goes into the MAP solver and what comes out: the problem, the result, and the
exception a callback raises to stop a run."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from torch import Tensor

from ..features import RootStart


class StopSolve(Exception):
    """Raised by a callback (or returned True) to stop the run; the best iterate is kept."""


@dataclass
class Problem:
    """The sequence to solve: ``x0 (N, D)`` normalised features (NaN rows where nothing
    is known yet: those frames are rolled out from the prior), ``free (N,)`` frames the
    solver may change, and the root state before frame 0."""

    x0: Tensor
    free: np.ndarray
    start: RootStart


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
    #: With several starts (``solve_from``): each start's final objective, in order; ``x`` is the lowest's
    #: among the starts of fewest ``starts_faults``.
    starts_fun: list[float] = field(default_factory=list)
    #: With several starts and a ``faults`` count (``solve_from``): each start's result's faults, in order.
    starts_faults: list[int] = field(default_factory=list)

    def __getitem__(self, key: str):
        return getattr(self, key)
