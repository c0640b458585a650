"""The variables of one window and the window objective over them (``Window``).

The local optimisers see a flat vector; ``Window`` maps it to normalised features of
the window's frames (valid rotations at every iterate, preconditioned so that all
variables share the prior's units) and evaluates the objective with its gradient,
remembering the best point it has seen.
"""
from __future__ import annotations

import math
import time

import numpy as np
import torch
from torch import Tensor

from .. import rotations as R
from ..features import RootStart, decode
from ..objective import MAPObjective, NonFiniteTermError

#: Cosine components over a window added to the per-frame variables (see ``Window``;
#: ``SolverOptions.basis``).
BASIS_SIZE = 8


def dct_basis(n: int, k: int) -> Tensor:
    """(k, n) the first ``k`` DCT-II cosines over ``n`` samples (unnormalised)."""
    t = torch.arange(n, dtype=torch.float32)
    rows = [torch.cos(math.pi * (t + 0.5) * j / n) for j in range(k)]
    return torch.stack(rows)


def _coarse_basis(n: int, k: int, power: float = 1.0) -> Tensor:
    """(n, k) orthonormal cosine columns, column j scaled by (n / (pi (j + 1/2)))^power.

    The prior scores each frame against the one before it, so its curvature along the
    j-th cosine over n frames is about (pi j / n)^2 times that of a single frame: with
    ``power`` 1 a step on a column moves the slow directions as far as the per-frame
    variables move the fast ones (a diagonal preconditioner in the cosine basis). The
    root displacement and yaw channels integrate into positions, where task terms make
    the slow directions stiff again; they take ``power`` 1/2 (with 1 the first L-BFGS
    step can throw the root a metre when the start is already on target)."""
    b = dct_basis(n, k).T
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


class Window:
    """One window's optimisation: frames ``frames`` of the sequence, starting from ``x``
    (their normalised features), after ``context`` (the prior's history) and
    ``lead_raw`` (the last solved frames, unnormalised, decoded from ``start``).

    Variables per free frame: the root's offset in world space (ground position and
    heading, so that one variable moves one frame: offsets to the root's per-frame
    steps would move every later frame, and a millimetre fidelity acting through that
    sum makes condition numbers near 1e6), an offset to the root height, and a rotation
    vector per joint applied on the right of the frame's starting rotation, so every
    iterate holds valid rotations (never a 6D vector off the rotation manifold the prior
    was trained on). The root offsets are scaled by the normaliser's std of the root
    steps and rotation vectors are whitened (see ``_tangent_whitening``), so that all
    variables share the normalised units the prior scores. The rotation offsets are
    the sum of a per-frame part and a few scaled cosine components over the window (see
    ``_coarse_basis``): a step on those moves many frames together, which the prior's
    stiff coupling between neighbouring frames otherwise makes L-BFGS do very slowly.
    Contact weights (``MAPObjective.contact_weights``) and the prior's predicted log-std
    are fixed at the start (``rebase``), so the objective is smooth during a local solve
    and cannot be lowered by making frames less certain.

    Zero variables stand for the frames at the last ``rebase``; ``fun`` keeps the best
    point evaluated (``best``, with its terms) and the terms of the first (``first_terms``).
    """

    def __init__(self, objective: MAPObjective, x: Tensor, frames: np.ndarray, free_local: np.ndarray,
                 context: Tensor, lead_raw: Tensor, start: RootStart, basis: int = BASIS_SIZE):
        self.obj = objective
        self.x = x.clone()
        self.frames = frames
        self.free_np = free_local
        self.free = torch.from_numpy(free_local)
        self.all_free = bool(free_local.all())
        self.context = objective.prior.cache_context(context)   # scored after many times
        self.lead_raw = lead_raw
        self.start = start
        self.p = objective.spec.pose_dim
        self.n_rot = len(objective.spec.joints)
        self.k = 4 + 3 * self.n_rot
        self.n_free = int(free_local.sum())
        self.n_basis = min(basis, self.n_free)
        self.basis = _coarse_basis(self.n_free, self.n_basis) if self.n_free else torch.zeros(0, 0)
        # root offsets live in world space, where a slow cosine is no cheaper for the task
        # terms than a per-frame step: plain orthonormal columns, no preconditioning scale
        self.basis_root = _coarse_basis(self.n_free, self.n_basis, 0.0) if self.n_free else torch.zeros(0, 0)
        self.n_vars = (self.n_basis + self.n_free) * self.k
        norm = objective.prior.normalizer
        self._mean6 = norm.mean[4:self.p].float()
        self._std6 = norm.std[4:self.p].float()
        self._std_root = norm.std[:3].float()
        std = norm.std.double()
        # metres of ground offset and radians of heading per variable unit
        self._root_scale = torch.stack((0.5 * (std[0] + std[1]),) * 2 + (std[2],)).float()
        self.nfev = 0
        self.prior_seconds = 0.0       # decoding windows and scoring them under the prior
        self.objective_seconds = 0.0   # objective and gradient evaluations, all included
        self.best: tuple[float, np.ndarray | None] = (math.inf, None)
        self.best_terms: dict[str, float] = {}
        self.first_terms: dict[str, float] | None = None
        self.seen: dict[int, float] = {}   # objective of every evaluated point, by hash
        self._base_rot: Tensor | None = None
        self._whiten: Tensor | None = None
        self.contacts: Tensor | None = None
        self.log_std: Tensor | None = None

    # --- variables <-> window tensors -------------------------------------------------
    def rebase(self, known_contacts: Tensor | None = None) -> None:
        """Take the current window frames as the point that zero variables stand for, and
        fix the contact weights (``MAPObjective.contact_weights`` there, except where
        ``known_contacts (T, C)`` holds a value: the weights an earlier window fixed for an
        overlapping frame, so that a foot is not planted in one window and free in the
        next) and, with the objective's ``hold_prior_spread``, the prior's predicted log-std there."""
        norm = self.obj.prior.normalizer
        raw = norm.denormalize(self.x[self.free].double())
        base = R.sixd_to_matrix(raw[:, 4:self.p].reshape(self.n_free, self.n_rot, 6))
        self._base_rot = base.float()
        self._whiten = _tangent_whitening(base, norm.std[4:self.p].double().reshape(self.n_rot, 6)).float()
        self._height0 = self.x[self.free, 3]
        self._tail = self.x[self.free, self.p:]
        # the base root in world space, and the frame before the window
        lead = self.lead_raw.double()
        raw_all = torch.cat((lead, norm.denormalize(self.x.double())))
        yaw_all = self.start.yaw + torch.cumsum(raw_all[:, 2], 0)
        _, root_all = decode(raw_all, self.obj.spec, self.start)
        n_lead = len(lead)
        self._xz0 = root_all[n_lead:, [0, 2]].float()
        self._yaw0 = yaw_all[n_lead:].float()
        self._prev_xz = (root_all[n_lead - 1, [0, 2]] if n_lead else
                         torch.tensor([self.start.x, self.start.z], dtype=torch.float64)).float()
        self._prev_yaw = (yaw_all[n_lead - 1] if n_lead else torch.tensor(self.start.yaw, dtype=torch.float64)).float()
        self._steps0 = self._root_steps(self._xz0, self._yaw0)
        with torch.no_grad():
            self.contacts, self.log_std = None, None
            st = self.obj.window_state(self.x, self.frames, self.context, self.lead_raw, self.start)
            self.contacts = self.obj.contact_weights(st)
            if known_contacts is not None:
                self.contacts = torch.where(torch.isnan(known_contacts), self.contacts, known_contacts.to(self.contacts))
            if self.obj.hold_prior_spread:
                _, self.log_std, _ = self.obj.prior.gaussian(self.x, self.context)
        self.best = (math.inf, None)
        self.best_terms, self.first_terms, self.seen = {}, None, {}

    def pack(self) -> np.ndarray:
        """The variables of the current base: all zeros."""
        return np.zeros(self.n_vars)

    def _root_steps(self, xz: Tensor, yaw: Tensor) -> Tensor:
        """Raw root step features (..., T, 3) (ground step in the previous frame's heading
        frame, heading change) of world ground positions ``xz (..., T, 2)`` and headings
        ``yaw (..., T)`` after the frame before the window: the inverse of
        ``features.decode``'s integration."""
        prev_xz = torch.cat((self._prev_xz.expand(*xz.shape[:-2], 1, 2), xz[..., :-1, :]), dim=-2)
        prev_yaw = torch.cat((self._prev_yaw.expand(*yaw.shape[:-1], 1), yaw[..., :-1]), dim=-1)
        d = xz - prev_xz
        c, s = torch.cos(prev_yaw), torch.sin(prev_yaw)
        return torch.stack((c * d[..., 0] - s * d[..., 1], s * d[..., 0] + c * d[..., 1], yaw - prev_yaw), dim=-1)

    def unpack(self, v: Tensor) -> Tensor:
        """Window features (..., T, D) of variables ``v (..., size)``."""
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
        # root: world offsets of the free frames, turned into the steps of every window frame
        off = u[..., :3] * self._root_scale
        if not self.all_free:
            full = off.new_zeros(*lead, len(self.frames), 3)
            full[..., self.free, :] = off
            off = full
        steps = self._root_steps(self._xz0 + off[..., :2], self._yaw0 + off[..., 2])
        root = self.x[:, :3] + (steps - self._steps0) / self._std_root
        rows = torch.cat(((self._height0 + u[..., 3])[..., None], six, self._tail.expand(*lead, *self._tail.shape)),
                         dim=-1)
        if self.all_free:
            return torch.cat((root, rows), dim=-1)
        x = self.x.expand(*lead, *self.x.shape).clone()
        x[..., :3] = root
        x[..., self.free, 3:] = rows
        return x

    def state(self, v: Tensor):
        """The objective's decoded window state at variables ``v``."""
        x = self.unpack(v)
        t0 = time.perf_counter()
        st = self.obj.window_state(x, self.frames, self.context, self.lead_raw, self.start, self.contacts,
                                   self.log_std)
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
        """Objective and gradient at ``v_np`` (what the optimisers call); records the point."""
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
