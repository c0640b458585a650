"""Rollouts chosen a second at a time: of several continuations of each second, the one
whose feet meet the floor best, continued from (the start the MAP solver refines)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from motionopt.features import RootStart, advance, decode_positions, planted_root_step
from motionopt.skeleton import Skeleton

from .common import clamped_rollout

#: Height (m) above its planted height within which a contact joint counts as on the
#: floor (as ``metrics.foot_skating`` counts it).
FLOOR_BAND = 0.03
#: What a frame with no foot on the floor costs in ``glide_cost``, in m/s of gliding.
AIRBORNE_COST = 1.0
#: What a foot raised above ``lift_limit`` costs in ``glide_cost``, in m/s per metre too
#: high (averaged over frames): a leg kicked up does not glide, so choosing by gliding alone
#: can favour a kick (of 8 whole 30 s rollouts, the least sliding hopped on one leg with the
#: other foot 85 cm up; held-out Bandai walks lift their feet 9-17 cm). In the held-out
#: paths checked, no candidate second reached the limit.
LIFT_COST = 10.0


#: Time constant (s) of ``SwayingPath``: sideways root motion slower than this is
#: taken out, faster (a walk's sway, one stride in about a second) kept.
SWAY_SECONDS = 0.3
#: Farthest (m) ``SwayingPath`` lets the root from the path: a walk's sway is 2-3 cm to
#: each side; a body turning on its planted feet (a seed that starts standing, facing
#: away from the path) stepped up to 13 cm off it.
MAX_SWAY = 0.03
#: Share of each planted sideways step ``SwayingPath`` takes in (an exponential mean):
#: the steps of sampled legs jitter from frame to frame.
STEP_SMOOTHING = 0.4
#: Speed (m/s) of the path below which ``SwayingPath`` takes sideways as the body's left-right.
MOVING = 0.2


@dataclass
class SwayingPath:
    """A ``Steer`` that walks a rollout along a path, with the hip sway of real walking.

    Each new frame t gets the path's yaw change and forward step (``path_raw[t]``,
    unnormalised root features (N, 3), ``root_features``), and sideways the step that
    keeps its planted feet still (``features.planted_root_step``; contact joints within
    the contact height of ``rest`` (C,), their heights above the ground when planted;
    the mean of theirs, which the smoothing suits: weighted to the lowest, as free
    rollouts are, one segment of 48 walked 3.2 cm from its path in bench/paths.py),
    smoothed (``STEP_SMOOTHING``) and high-passed: the running mean of those steps over
    ``SWAY_SECONDS`` is taken out, and the distance from the path decays over the same
    time and is at most ``MAX_SWAY``. A root clamped to the path moved sideways at
    1.5-3 cm/s (RMS, held-out Bandai walks along drawn paths) against 7-16 cm/s in the
    held-out walks themselves, and the stance foot slid under it.

    ``first`` is the path frame of the next rollout's frame 0; ``offset``, ``drift`` and
    ``step`` (per rollout: m from the path, the running mean sideways step and the
    smoothed one, m per frame) carry the sideways state from one rollout to the next
    (``continue_from``)."""

    prior: object
    path_raw: Tensor
    rest: Tensor
    first: int = 0
    offset: Tensor | None = None
    drift: Tensor | None = None
    step: Tensor | None = None

    def __call__(self, t: int, last: Tensor, drawn: Tensor) -> Tensor:
        norm, spec = self.prior.normalizer, self.prior.spec
        prev, raw = norm.denormalize(last.double()), norm.denormalize(drawn.double())
        path = self.path_raw[self.first + t].to(raw)
        raw[..., 2] = path[2]
        planted = planted_root_step(prev, raw, spec, self.prior.skeleton, self.rest.to(raw).expand(*raw.shape[:-1], -1),
                                    sharpness=math.inf)
        step = path[:2]
        length = float(step.norm())
        side = (torch.stack((step[1], -step[0])) / length if length * spec.fps > MOVING
                else torch.tensor([1.0, 0.0], dtype=raw.dtype))
        sideways = planted[..., :2] @ side
        if self.offset is None:
            self.offset, self.drift, self.step = (torch.zeros_like(sideways) for _ in range(3))
        self.step = self.step + STEP_SMOOTHING * (sideways - self.step)
        rate = 1.0 / (SWAY_SECONDS * spec.fps)
        self.drift = self.drift + rate * (self.step - self.drift)
        kept = (self.offset + self.step - self.drift - rate * self.offset).clamp(-MAX_SWAY, MAX_SWAY) - self.offset
        self.offset = self.offset + kept
        raw[..., :2] = step + kept[..., None] * side
        return norm.normalize(raw).to(drawn)

    def continue_from(self, rollout: int, frames: int, count: int) -> None:
        """Go on from rollout ``rollout``'s state after ``frames`` frames, for ``count`` rollouts."""
        self.first += frames
        self.offset = self.offset[rollout].expand(count).clone()
        self.drift = self.drift[rollout].expand(count).clone()
        self.step = self.step[rollout].expand(count).clone()


def lift_limit(feet: np.ndarray, planted_height: np.ndarray) -> float:
    """How high (m) above its planted height a contact joint may go in a rollout after
    context whose contact joints are at ``feet (T, C, 3)``: 1.5 times the most the context
    lifts one, plus 5 cm (the context shows the gait's own lift: 9-17 cm in held-out
    Bandai walks, 14-61 cm in its runs, its first second within a few cm of that)."""
    lift = float(np.max(feet[..., 1] - np.asarray(planted_height), initial=0.0))
    return 1.5 * lift + 0.05


def glide_cost(feet: torch.Tensor, planted_height: np.ndarray, fps: float, max_lift: float | None = None
               ) -> torch.Tensor:
    """How badly contact joints ``feet (..., T, C, 3)`` (world positions, frame 0 the one
    before) meet the floor, per leading index: the horizontal speed (m/s) of the joints
    within ``FLOOR_BAND`` of their planted height, summed over joints and averaged over
    frames, plus ``AIRBORNE_COST`` times the share of frames with no joint there (a foot
    that floats or a leg held up cannot hide its sliding by leaving the floor), plus
    ``LIFT_COST`` times how far the highest joint of each frame rises above ``max_lift``
    (m above its planted height; None: no limit), averaged over frames."""
    height = feet[..., 1:, :, 1] - torch.as_tensor(planted_height, dtype=feet.dtype)
    low = height < FLOOR_BAND
    speed = (feet[..., 1:, :, :] - feet[..., :-1, :, :])[..., [0, 2]].norm(dim=-1) * fps
    cost = (speed * low).sum(-1).mean(-1) + AIRBORNE_COST * (~low.any(-1)).to(feet.dtype).mean(-1)
    if max_lift is not None:
        cost = cost + LIFT_COST * torch.relu(height.max(-1).values - max_lift).mean(-1)
    return cost


def chosen_rollout(prior, history: torch.Tensor, state: RootStart, last_feet: np.ndarray, skeleton: Skeleton,
                   planted_height: np.ndarray, n_frames: int, candidates: int, temperature: float,
                   generator: torch.Generator, clamp_raw: torch.Tensor | None = None,
                   max_lift: float | None = None, sway: bool = False) -> torch.Tensor:
    """``n_frames`` new frames (n_frames, D), normalised, after ``history (T, D)``: rolled
    out a second at a time, each second the one of ``candidates`` continuations of the
    last with the least ``glide_cost``. ``state`` is the root state at history's last
    frame, ``last_feet (C, 3)`` its contact joints' world positions (on ``skeleton``, the
    prior's), ``planted_height (C,)`` their heights when planted. ``clamp_raw (n_frames, 3)``,
    when given, sets the root channels of the new frames (unnormalised; ``clamped_rollout``);
    otherwise the prior rolls out its own root, unplanted. With ``sway`` the root follows
    those channels with the sway of the legs (``SwayingPath``). ``max_lift``:
    ``glide_cost``'s (``lift_limit`` of the context).

    Chosen over whole rollouts, one bad second (a leg kicked up, a foot dragged) costs a
    second, not the clip: of 8 whole 30 s rollouts along a path the least sliding was one
    that hopped on one leg for a second at a time."""
    spec, norm = prior.spec, prior.normalizer
    chunk = max(int(round(spec.fps)), 1)
    cidx = spec.contact_indices()
    before = torch.as_tensor(last_feet, dtype=torch.float64).expand(candidates, 1, len(cidx), 3)
    steer = None
    if clamp_raw is not None and sway:
        rest = torch.as_tensor(np.asarray(planted_height) - state.ground)
        steer = SwayingPath(prior, clamp_raw.double(), rest)
    pieces = []
    for a in range(0, n_frames, chunk):
        ctx = history[-prior.receptive_field:].expand(candidates, -1, -1)
        k = min(chunk, n_frames - a)
        if clamp_raw is not None and steer is None:
            new = clamped_rollout(prior, ctx, clamp_raw[a:a + k], slice(0, 3), temperature, generator)
        else:
            new = prior.sample(ctx.float(), k, generator=generator, temperature=temperature, plant=False, steer=steer)
        raw = norm.denormalize(new.double())
        with torch.no_grad():
            feet = decode_positions(raw, spec, skeleton, state)[..., cidx, :]
        best = int(torch.argmin(glide_cost(torch.cat((before, feet), dim=1), planted_height, spec.fps, max_lift)))
        if steer is not None:
            steer.continue_from(best, k, candidates)
        state = advance(state, raw[best], spec)
        before = feet[best, -1:].expand(candidates, 1, len(cidx), 3)
        history = torch.cat((history, new[best]))
        pieces.append(new[best])
    return torch.cat(pieces)
