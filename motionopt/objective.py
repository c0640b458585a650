"""The MAP objective: a prior term and task terms.

Every term is an object with a name, a sigma in user units (metres, radians, m/s) and a
torch function of a decoded window (``WindowState``). Terms address frames by their
global index in the output, so the same term serves every sliding window. Energies
are negative log-likelihoods in nats: a Gaussian residual r with sigma s costs
``r^2 / (2 s^2)``, summed over frames.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import torch
from torch import Tensor

from .features import FeatureSpec, RootStart, decode_matrices
from .kinematics import fk_matrices
from .metrics import acceleration
from .prior import MotionPrior
from .rotations import quat_to_matrix
from .skeleton import Skeleton


class NonFiniteTermError(FloatingPointError):
    """A term evaluated to NaN or infinity; names the term."""

    def __init__(self, term: str, where: str = ""):
        self.term = term
        super().__init__(f"term {term!r} is not finite{(' ' + where) if where else ''}; "
                         "check its targets and sigma for NaN, infinity or zero")


@dataclass
class WindowState:
    """A decoded window of frames, batched over leading dims (e.g. PSO particles).

    ``frames`` are the global indices of the window's frames; arrays of motion hold
    ``lead`` extra frames before them (already solved context) so that velocities and
    accelerations are defined at the window's first frame.
    """

    frames: np.ndarray
    lead: int
    x: Tensor                 # (..., T, D) normalised features of the window frames
    rotations: Tensor         # (..., lead+T, J, 3, 3) local rotation matrices
    root: Tensor              # (..., lead+T, 3)
    positions: Tensor         # (..., lead+T, J, 3) world joint positions
    contacts: Tensor          # (..., T, C) contact probabilities predicted by the prior (no gradient)
    prior_nll: Tensor         # (..., T) per-frame NLL under the prior
    fps: float


class Term:
    """Base class: ``energy(state)`` returns (...,) nats for the batch of windows."""

    name: str = "term"

    def energy(self, state: WindowState) -> Tensor:
        raise NotImplementedError

    def active(self, frames: np.ndarray) -> bool:
        """Whether the term has anything to say about these frames (skip it otherwise)."""
        return True

    def window_tensors(self, frames: np.ndarray, dtype: torch.dtype) -> dict:
        """The term's targets and masks for ``frames`` as tensors, built by ``_window_tensors``
        once per window and dtype: a local solve evaluates the same window many times."""
        key = (frames.tobytes(), dtype)
        cached = self.__dict__.get("_window_cache")
        if cached is None or cached[0] != key:
            cached = (key, self._window_tensors(frames, dtype))
            self.__dict__["_window_cache"] = cached
        return cached[1]

    def _window_tensors(self, frames: np.ndarray, dtype: torch.dtype) -> dict:
        return {}


def _gaussian(residual_sq: Tensor, sigma: float | Tensor) -> Tensor:
    return residual_sq / (2.0 * sigma * sigma)


def _frame_mask(frames: np.ndarray, mask: np.ndarray | None) -> np.ndarray | None:
    """``mask`` (N,) at global ``frames``; frames past its end are off."""
    if mask is None:
        return None
    inside = frames < len(mask)
    m = np.zeros(len(frames), bool)
    m[inside] = mask[frames[inside]]
    return m


def _masked(e: Tensor, mask: Tensor | None) -> Tensor:
    return e if mask is None else e * mask


class FrameMasked:
    """Mixin of terms held to the global frames of their ``mask`` (N,) field (None: every
    frame): inactive in a window with none of them; ``_mask_tensor`` is a window's share."""

    mask: np.ndarray | None

    def active(self, frames: np.ndarray) -> bool:
        return self.mask is None or bool(_frame_mask(frames, self.mask).any())

    def _mask_tensor(self, frames: np.ndarray, dtype: torch.dtype) -> Tensor | None:
        m = _frame_mask(frames, self.mask)
        return None if m is None else torch.as_tensor(m, dtype=dtype)


def matrix_angle_sq(a: Tensor, b: Tensor) -> Tensor:
    """Smooth squared geodesic angle (radians^2) between rotation matrices (..., 3, 3):
    ||A - B||_F^2 / 2 = 2 (1 - cos angle), exact to second order and free of arccos's
    infinite slope at zero."""
    return 0.5 * (a - b).pow(2).sum((-1, -2))


@dataclass
class PriorTerm(Term):
    """Negative log-likelihood of the window under the prior, times ``weight``."""

    weight: float = 1.0
    name: str = "prior"

    def energy(self, state: WindowState) -> Tensor:
        return self.weight * state.prior_nll.sum(-1)


@dataclass
class PathTerm(FrameMasked, Term):
    """Root on the ground plane close to a polyline path.

    With ``targets`` (N, 2) per global frame (timed mode) each frame is pulled to its own
    point; without, to the nearest point of the polyline (the MAP path term of
    Wang et al. 2019, eq. 18). ``frames`` limits which global frames count. Within
    ``width`` metres of the path the root moves freely (the sway of a walk): only the
    distance beyond it costs.
    """

    path: np.ndarray
    sigma: float = 0.05
    targets: np.ndarray | None = None
    mask: np.ndarray | None = None
    name: str = "path"
    width: float = 0.0

    def __post_init__(self) -> None:
        self.path = np.asarray(self.path, dtype=np.float64)
        if self.path.ndim != 2 or self.path.shape[1] != 2 or len(self.path) < 2:
            raise ValueError(f"a path needs at least 2 points of (x, z); got shape {self.path.shape}")

    def _window_tensors(self, frames: np.ndarray, dtype: torch.dtype) -> dict:
        out = {"path": torch.as_tensor(self.path, dtype=dtype), "mask": self._mask_tensor(frames, dtype)}
        if self.targets is not None:
            out["target"] = torch.as_tensor(self.targets[np.minimum(frames, len(self.targets) - 1)], dtype=dtype)
        return out

    def energy(self, state: WindowState) -> Tensor:
        xz = state.root[..., state.lead:, [0, 2]]
        w = self.window_tensors(state.frames, xz.dtype)
        if self.targets is not None:
            d2 = (xz - w["target"]).pow(2).sum(-1)
        else:
            d2 = nearest_on_polyline_sq(xz, w["path"])
        if self.width > 0:
            d2 = torch.relu(torch.sqrt(d2 + 1e-12) - self.width).pow(2)
        return _gaussian(_masked(d2, w["mask"]), self.sigma).sum(-1)


def nearest_on_polyline_sq(points: Tensor, path: Tensor) -> Tensor:
    """Squared distance (...,) from points (..., 2) to the nearest point of a polyline (N, 2).

    The nearest segment is chosen without gradient and the distance to it recomputed
    differentiably: the same value and gradient as a minimum over all segments, with a
    backward pass over one segment per point instead of all of them."""
    a, ab = path[:-1], path[1:] - path[:-1]
    inv_len_sq = 1.0 / (ab * ab).sum(-1).clamp_min(1e-12)

    def dist_sq(p: Tensor, a: Tensor, ab: Tensor, inv: Tensor) -> Tensor:
        t = (((p - a) * ab).sum(-1) * inv).clamp(0.0, 1.0)
        return (p - a - t[..., None] * ab).pow(2).sum(-1)

    with torch.no_grad():
        seg = dist_sq(points.detach()[..., None, :], a, ab, inv_len_sq).argmin(-1)
    return dist_sq(points, a[seg], ab[seg], inv_len_sq[seg])


@dataclass
class PoseFidelityTerm(FrameMasked, Term):
    """Root position and local joint rotations close to a target motion.

    ``root`` (N, 3) and ``rotations`` (N, J, 4) quaternions are targets per global frame
    (either may be None); ``mask`` (N,) selects frames (e.g. only the noisy input's
    frames, or keyframes); ``joints`` selects which joints' rotations count (default all,
    the root's world rotation included).
    """

    root: np.ndarray | None
    rotations: np.ndarray | None
    sigma_root: float = 0.02
    sigma_angle: float = 0.05
    mask: np.ndarray | None = None
    joints: list[int] | None = None
    name: str = "fidelity"

    def __post_init__(self) -> None:
        if self.root is None and self.rotations is None:
            raise ValueError("a fidelity term needs root or rotation targets (or both)")

    def _window_tensors(self, frames: np.ndarray, dtype: torch.dtype) -> dict:
        n = len(self.root) if self.root is not None else len(self.rotations)
        idx = np.minimum(frames, n - 1)
        out = {"mask": self._mask_tensor(frames, dtype), "root": None, "rot": None}
        if self.root is not None:
            out["root"] = torch.as_tensor(np.asarray(self.root)[idx], dtype=dtype)
        if self.rotations is not None:
            q = np.asarray(self.rotations)[idx]
            if self.joints is not None:
                q = q[:, self.joints]
            out["rot"] = quat_to_matrix(torch.as_tensor(q, dtype=torch.float64)).to(dtype)
        return out

    def energy(self, state: WindowState) -> Tensor:
        w = self.window_tensors(state.frames, state.root.dtype)
        e = state.x.new_zeros(state.x.shape[:-1])
        if w["root"] is not None:
            e = e + _gaussian((state.root[..., state.lead:, :] - w["root"]).pow(2).sum(-1), self.sigma_root)
        if w["rot"] is not None:
            rot = state.rotations[..., state.lead:, :, :, :]
            if self.joints is not None:
                rot = rot[..., self.joints, :, :]
            e = e + _gaussian(matrix_angle_sq(rot, w["rot"]), self.sigma_angle).sum(-1)
        return _masked(e, w["mask"]).sum(-1)


@dataclass
class JointPositionTerm(Term):
    """World position targets for one joint at chosen global frames.

    ``targets`` maps a frame index to an (x, y, z) target in metres.
    """

    joint: int
    targets: dict[int, np.ndarray]
    sigma: float = 0.01
    name: str = "joint_position"

    def active(self, frames: np.ndarray) -> bool:
        return any(int(f) in self.targets for f in frames)

    def _window_tensors(self, frames: np.ndarray, dtype: torch.dtype) -> dict:
        local = [i for i, f in enumerate(frames) if int(f) in self.targets]
        tgt = np.stack([np.asarray(self.targets[int(frames[i])], float) for i in local]) if local else np.zeros((0, 3))
        return {"local": torch.as_tensor(local, dtype=torch.long), "target": torch.as_tensor(tgt, dtype=dtype)}

    def residuals(self, state: WindowState) -> Tensor:
        """(..., K, 3) position errors at the target frames inside the window."""
        w = self.window_tensors(state.frames, state.positions.dtype)
        p = state.positions[..., state.lead:, self.joint, :].index_select(-2, w["local"])
        return p - w["target"]

    def energy(self, state: WindowState) -> Tensor:
        return _gaussian(self.residuals(state).pow(2).sum(-1), self.sigma).sum(-1)


@dataclass
class FootTerm(Term):
    """Base of the terms on contact joints ``joints`` and their heights when planted
    ``planted_height (C,)`` (world y, m): the window's heights above those and ground speeds."""

    joints: list[int]
    planted_height: np.ndarray

    def _window_tensors(self, frames: np.ndarray, dtype: torch.dtype) -> dict:
        return {"planted": torch.as_tensor(np.asarray(self.planted_height), dtype=dtype)}

    def heights(self, state: WindowState) -> Tensor:
        """(..., T, C) height of each joint above its planted height in the window's frames."""
        y = state.positions[..., state.lead:, self.joints, 1]
        return y - self.window_tensors(state.frames, y.dtype)["planted"]

    def speed_sq(self, state: WindowState) -> Tensor:
        """(..., T, C) squared horizontal speed (m^2/s^2) of each joint in the window's
        frames, from the frame before (zero at the sequence's very first frame)."""
        p = state.positions[..., max(state.lead - 1, 0):, self.joints, :]
        step = (p[..., 1:, :, :] - p[..., :-1, :, :])[..., [0, 2]] * state.fps
        if state.lead == 0:  # the very first frame has no velocity
            step = torch.cat((torch.zeros_like(step[..., :1, :, :]), step), dim=-3)
        return step.pow(2).sum(-1)


@dataclass
class ContactTerm(FootTerm):
    """Planted feet do not slide and rest at their planted height: horizontal speed with
    sigma ``sigma_speed`` (m/s), height error with sigma ``sigma_height`` (m), on the
    joint-frames whose contact weight (``WindowState.contacts``) is above ``threshold``.

    A local solve takes the weights from ``labels`` at its start: the kinematics of the
    motion itself, not the prior's contact head, which fed a noisy iterate calls a third
    of the frames wrongly and brakes swinging feet."""

    sigma_speed: float = 0.05
    sigma_height: float = 0.02
    threshold: float = 0.5
    #: A joint counts as planted within this height (m) of its planted height, moving
    #: slower than ``label_speed`` (m/s) over ``label_frames`` frames (an average that
    #: capture noise does not flip).
    label_height: float = 0.05
    label_speed: float = 0.5
    label_frames: int = 5
    name: str = "contact"

    @torch.no_grad()
    def labels(self, state: WindowState) -> Tensor:
        """Contact weights (T, C), 0 or 1, of a single window from its own kinematics."""
        p = state.positions[..., self.joints, :]
        k = min(self.label_frames, p.shape[-3])
        pad = torch.cat((p[..., :1, :, :].expand(*p.shape[:-3], k // 2, *p.shape[-2:]), p,
                         p[..., -1:, :, :].expand(*p.shape[:-3], k - 1 - k // 2, *p.shape[-2:])), dim=-3)
        smooth = pad.unfold(-3, k, 1).mean(-1)                       # (..., lead+T, C, 3)
        step = (smooth[..., 1:, :, [0, 2]] - smooth[..., :-1, :, [0, 2]]).norm(dim=-1) * state.fps
        speed = torch.cat((step[..., :1, :], step), dim=-2)[..., state.lead:, :]
        return ((self.heights(state) < self.label_height) & (speed < self.label_speed)).to(p)

    def energy(self, state: WindowState) -> Tensor:
        height = self.heights(state)
        w = (state.contacts > self.threshold).to(height)
        e = w * (_gaussian(self.speed_sq(state), self.sigma_speed) + _gaussian(height.pow(2), self.sigma_height))
        return e.sum((-1, -2))


@dataclass
class SkatingTerm(FootTerm):
    """Feet near the floor do not glide: horizontal speed with sigma ``sigma_speed`` (m/s)
    of each contact joint, weighted by how near it is to its planted height, a logistic
    gate that is one below ``band`` metres above it and falls to zero over ``softness``.

    ``ContactTerm`` holds the feet its labels call planted; this term is for the rest, the
    swinging foot that skims the floor at walking speed (the foot skating a person sees and
    ``metrics.foot_skating`` counts). Being smooth in the height too, it can be lowered by
    lifting a swinging foot clear of the floor as much as by slowing it."""

    sigma_speed: float = 0.5
    band: float = 0.03
    softness: float = 0.005
    name: str = "skating"

    def __post_init__(self) -> None:
        if not (self.sigma_speed > 0 and self.band > 0 and self.softness > 0):
            raise ValueError(f"the skating term needs a positive sigma, band and softness; got {self.sigma_speed}, "
                             f"{self.band} and {self.softness}")

    def energy(self, state: WindowState) -> Tensor:
        gate = torch.sigmoid((self.band - self.heights(state)) / self.softness)
        return (gate * _gaussian(self.speed_sq(state), self.sigma_speed)).sum((-1, -2))


@dataclass
class SupportTerm(FrameMasked, FootTerm):
    """Some foot stands on the floor: the height of the lowest contact joint (a soft
    minimum over ``joints``, ``softness`` metres) above the floor, where positive, with
    sigma ``sigma`` (m). Beside ``SkatingTerm`` it keeps a body whose root is free
    (prefix completion) from rising so that no foot is near the floor to glide.

    With ``from_floor`` every joint is measured from one floor, the lowest planted
    height; without, each from its own planted height, so that an ankle at its planted
    height counts as support with the toes up. Path following needs the floor: from a
    standing start it stood on one heel with the toes 4-6 cm up for half a second (44 of
    48 segments of ``bench/paths.py`` pass, 47 from the floor). Prefix completion does
    not: runs held to the floor by their toes skated more (``bench/tasks.py`` 4b: 38 of 45
    seconds in range, 41 measured per joint)."""

    sigma: float = 0.03
    softness: float = 0.01
    #: (N,) the global frames the term holds (None: all), e.g. those where the prior
    #: expects a foot on the floor, so that a run's flight is left in the air.
    mask: np.ndarray | None = None
    #: Only in frames where some contact joint counts as planted (``WindowState.contacts``:
    #: the kinematics of the solve's start).
    planted_only: bool = False
    from_floor: bool = True
    name: str = "support"

    def __post_init__(self) -> None:
        if not (self.sigma > 0 and self.softness > 0):
            raise ValueError(f"the support term needs a positive sigma and softness; got {self.sigma} and "
                             f"{self.softness}")

    def energy(self, state: WindowState) -> Tensor:
        planted = self.window_tensors(state.frames, state.positions.dtype)["planted"]
        above_floor = self.heights(state) + (planted - planted.min() if self.from_floor else 0.0)
        lowest = -self.softness * torch.logsumexp(-above_floor / self.softness, dim=-1)
        e = _gaussian(torch.relu(lowest).pow(2), self.sigma)
        if self.planted_only:
            e = e * (state.contacts > 0.5).any(-1).to(e)
        return _masked(e, self.window_tensors(state.frames, e.dtype)["mask"]).sum(-1)

    def _window_tensors(self, frames: np.ndarray, dtype: torch.dtype) -> dict:
        return {**super()._window_tensors(frames, dtype), "mask": self._mask_tensor(frames, dtype)}


@dataclass
class FloorTerm(FootTerm):
    """No contact joint goes through the floor: each joint's depth below its planted
    height, where positive, with sigma ``sigma`` (m). ``SupportTerm`` pulls the lowest foot
    down to the floor and nothing else holds it above: with the support term alone, the
    path-following solve put the lowest foot more than 3 cm below the floor in up to 8%
    of the frames of held-out Bandai walks (10 s on a square)."""

    sigma: float = 0.01
    name: str = "floor"

    def __post_init__(self) -> None:
        if not self.sigma > 0:
            raise ValueError(f"the floor term needs a positive sigma; got {self.sigma}")

    def energy(self, state: WindowState) -> Tensor:
        return _gaussian(torch.relu(-self.heights(state)).pow(2), self.sigma).sum((-1, -2))


@dataclass
class SmoothnessTerm(Term):
    """Joint accelerations (m/s^2) small, with sigma ``sigma``: one for every joint, or
    one per joint of the model skeleton; uses the solved frames before the window so that
    the window's start is smooth too."""

    sigma: float | Sequence[float] = 30.0
    name: str = "smoothness"

    def energy(self, state: WindowState) -> Tensor:
        acc = acceleration(state.positions[..., max(state.lead - 2, 0):, :, :], state.fps)
        return _gaussian(acc.pow(2).sum(-1), torch.as_tensor(self.sigma, dtype=acc.dtype)).sum((-1, -2))


@dataclass
class MAPObjective:
    """Prior + task terms over normalised features of a model skeleton.

    ``prior_min_log_std`` floors the prior's predictive log-std (normalised units): the
    trained prior is very confident about the next frame, which makes the energy too
    stiff for task terms to move it; a floor of -2.5 keeps it natural but pliable.
    ``prior_min_std_raw`` also floors the std of the rotation features in their own
    units (6D entries, about radians): entries that barely vary in the training data (a
    knee's off-axis components) have normaliser stds of 1e-3, where the normalised floor
    alone makes the prior a thousand times stiffer than elsewhere, and a few centimetres
    of capture noise cost it 1e5 nats per frame; the solver then trades any amount of
    fidelity for them. 0.01 (about half a degree) keeps those entries tight but finite.

    ``hold_prior_spread``: each local solve holds the prior's predicted log-std where its
    window starts, so that the solver cannot lower the prior term by making frames less
    certain. Without it the prior term is the prior's own NLL at every iterate; that is
    what a solve that should make a motion likely under the prior as trained needs
    (``problems.settle``): held, the spread of the start misjudged the result, and
    settled held-out CMU variations scored 46 nats per frame less likely than their start.
    """

    prior: MotionPrior
    skeleton: Skeleton
    terms: list[Term] = field(default_factory=list)
    prior_weight: float = 1.0
    prior_min_log_std: float | None = -2.5
    prior_min_std_raw: float | None = 0.01
    hold_prior_spread: bool = True

    def __post_init__(self) -> None:
        self.spec: FeatureSpec = self.prior.spec
        self.prior_term = PriorTerm(self.prior_weight)
        self._offsets = torch.as_tensor(self.skeleton.offsets, dtype=torch.float32)
        self._floor = self._log_std_floor()

    def _log_std_floor(self) -> float | Tensor | None:
        """The predictive log-std floor per pose dimension (normalised units), or one number."""
        if not self.prior_min_std_raw:
            return self.prior_min_log_std
        std = self.prior.normalizer.std[:self.spec.pose_dim].double()
        floor = torch.full_like(std, -math.inf if self.prior_min_log_std is None else self.prior_min_log_std)
        floor[4:] = torch.maximum(floor[4:], torch.log(self.prior_min_std_raw / std[4:]))
        return floor.float()

    def all_terms(self) -> list[Term]:
        return [self.prior_term] + list(self.terms)

    def window_state(self, x: Tensor, frames: np.ndarray, context: Tensor, lead_raw: Tensor,
                     start: RootStart, contacts: Tensor | None = None, log_std: Tensor | None = None) -> WindowState:
        """Decode a (batch of) window(s) ``x (..., T, D)`` after ``context (C, D)``.

        ``lead_raw`` holds the last solved frames (unnormalised, (L, D)) before the
        window, decoded together with it from ``start`` (the state before them).
        ``contacts (T, C)``, when given, replaces the prior's contact prediction, and
        ``log_std (T, P)`` the prior's predicted log-std: a local solve fixes both where it
        starts, so that the contact term does not jump between iterates and the solver
        cannot lower the prior term by making frames less certain.
        """
        norm = self.prior.normalizer
        floor = self._floor.to(x.dtype) if isinstance(self._floor, Tensor) else self._floor
        nll, predicted = self.prior.nll_and_contacts(x, context, floor, log_std)
        if context.shape[-2] == 0:
            # the sequence's first frame has no history: the prior has nothing to say about it
            nll = torch.cat((torch.zeros_like(nll[..., :1]), nll[..., 1:]), dim=-1)
        raw = norm.denormalize(x)
        lead = lead_raw.to(raw).expand(*raw.shape[:-2], *lead_raw.shape)
        rot, root = decode_matrices(torch.cat((lead, raw), dim=-2), self.spec, start)
        pos = fk_matrices(self.skeleton.parents, rot, root, self._offsets.to(x.dtype))
        if contacts is None:
            contacts = predicted.detach()
        return WindowState(frames, lead_raw.shape[0], x, rot, root, pos, contacts, nll, self.spec.fps)

    def contact_weights(self, state: WindowState) -> Tensor:
        """Which contact joints count as planted (T, C) in a window: by the contact term's
        kinematic rule when the objective has one (``ContactTerm.labels``), else the
        prior's prediction."""
        for term in self.terms:
            if isinstance(term, ContactTerm):
                return term.labels(state)
        return state.contacts

    def energies(self, state: WindowState) -> dict[str, Tensor]:
        """Every active term's energy (...,) for the window."""
        out = {}
        for term in self.all_terms():
            if term.active(state.frames):
                out[term.name] = term.energy(state)
        return out
