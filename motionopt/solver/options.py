"""How to solve: the MAP solver's options (with its particle swarm's) and the latent
inversion's. Plain dataclasses, checked where a wrong value would only fail later."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from ..prior import MotionPrior
from .optimizers import OPTIMIZERS
from .window import BASIS_SIZE


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
    """How to solve. ``optimizer`` is the local optimizer, a key of ``OPTIMIZERS``: 'scipy'
    (L-BFGS-B), 'nlopt' (LD_LBFGS), 'torch' (torch.optim.LBFGS) or 'adam' (plain
    first-order baseline). ``time_budget`` (seconds per window) stops any of them when
    spent (for comparisons at equal time)."""

    window: int = 34
    overlap: int = 17
    optimizer: str = "scipy"
    # 30: bench/solver.py (throughput) puts it at about 43 new frames/s for path following
    # on this 2-core CPU with 1.1 cm path error; 40 gives about the same error at 35 frames/s.
    max_iter: int = 30
    ftol: float = 1e-7
    gtol: float = 1e-5
    #: L-BFGS memory (corrections kept).
    history: int = 10
    #: Cosine components over each window added to its per-frame variables
    #: (``window.Window``): steps that move many frames together.
    basis: int = BASIS_SIZE
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

    def temperature_for(self, prior: MotionPrior) -> float:
        """``temperature``, or the prior's calibrated one when it is None."""
        return prior.sample_temperature if self.temperature is None else self.temperature

    def __post_init__(self) -> None:
        if self.optimizer not in OPTIMIZERS:
            raise ValueError(f"unknown optimizer {self.optimizer!r}; choose one of {', '.join(OPTIMIZERS)}")
        if not 0 <= self.overlap < self.window:
            raise ValueError(f"overlap must be in [0, window): got window {self.window}, overlap {self.overlap}")
        if self.basis < 0 or self.history < 1:
            raise ValueError(f"basis must be 0 or more and history 1 or more: got {self.basis} and {self.history}")


@dataclass(frozen=True)
class InversionOptions:
    """How to invert a latent prior. ``refine_iters`` 0 means encoder only; ``pso_iters`` 0
    means no particle swarm (``pso_*``: its size, subspace and bounds, in standard
    deviations of single codes). ``position_sigma`` (metres) is the tasks' fidelity term's: how far
    a refined joint may sit from the input (``problems.latent.FidelityTerm``)."""

    overlap: int = 16
    refine_iters: int = 0
    reg_weight: float = 0.01
    pso_iters: int = 0
    pso_particles: int = 16
    pso_components: int = 8
    pso_bound: float = 2.0
    position_sigma: float = 0.02
    seed: int = 0
