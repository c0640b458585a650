"""Solvers of motion under a learned prior: MAP optimisation over sliding windows
(autoregressive priors) and inversion into W+ codes (latent priors).

Rooms:

- ``options``: ``SolverOptions``, ``PSOOptions``, ``InversionOptions``;
- ``result``: ``Problem`` in, ``MAPResult`` out, ``StopSolve`` to stop a run;
- ``driver``: ``solve``, the windowed MAP driver, and ``solve_from`` several starts;
- ``layout``: where windows go (``free_window_starts``) and what each is conditioned on;
- ``window``: one window's variables and objective (``Window``);
- ``optimizers``: the local optimisers, ``OPTIMIZERS`` (``SolverOptions.optimizer`` -> function);
- ``swarm``: the particle swarm both solvers use;
- ``diagnostics``: ``seam_report`` and ``energies_at`` (term energies without optimising);
- ``inversion``: ``invert`` for latent priors (encoder, swarm, L-BFGS refinement).
"""
from .optimizers import OPTIMIZERS
from .diagnostics import energies_at, seam_report
from .driver import solve, solve_from
from .inversion import InversionResult, blend, clip_window_starts, invert, refine, regulariser
from .layout import free_window_starts
from .options import InversionOptions, PSOOptions, SolverOptions
from .result import MAPResult, Problem, StopSolve

__all__ = ["OPTIMIZERS", "InversionOptions", "InversionResult", "MAPResult", "PSOOptions", "Problem", "SolverOptions",
           "StopSolve", "blend", "clip_window_starts", "energies_at", "free_window_starts", "invert", "refine",
           "regulariser", "seam_report", "solve", "solve_from"]
