"""Rollouts chosen a second at a time: of several continuations of each second, the one
whose feet meet the floor best, continued from (the start the MAP solver refines)."""
from __future__ import annotations

import numpy as np
import torch

from motionopt.features import RootStart, advance, decode_positions
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
                   max_lift: float | None = None) -> torch.Tensor:
    """``n_frames`` new frames (n_frames, D), normalised, after ``history (T, D)``: rolled
    out a second at a time, each second the one of ``candidates`` continuations of the
    last with the least ``glide_cost``. ``state`` is the root state at history's last
    frame, ``last_feet (C, 3)`` its contact joints' world positions (on ``skeleton``, the
    prior's), ``planted_height (C,)`` their heights when planted. ``clamp_raw (n_frames, 3)``,
    when given, sets the root channels of the new frames (unnormalised; ``clamped_rollout``);
    otherwise the prior rolls out its own root, unplanted. ``max_lift``: ``glide_cost``'s
    (``lift_limit`` of the context).

    Chosen over whole rollouts, one bad second (a leg kicked up, a foot dragged) costs a
    second, not the clip: of 8 whole 30 s rollouts along a path the least sliding was one
    that hopped on one leg for a second at a time."""
    spec, norm = prior.spec, prior.normalizer
    chunk = max(int(round(spec.fps)), 1)
    cidx = spec.contact_indices()
    before = torch.as_tensor(last_feet, dtype=torch.float64).expand(candidates, 1, len(cidx), 3)
    pieces = []
    for a in range(0, n_frames, chunk):
        ctx = history[-prior.receptive_field:].expand(candidates, -1, -1)
        k = min(chunk, n_frames - a)
        if clamp_raw is None:
            new = prior.sample(ctx.float(), k, generator=generator, temperature=temperature, plant=False)
        else:
            new = clamped_rollout(prior, ctx, clamp_raw[a:a + k], slice(0, 3), temperature, generator)
        raw = norm.denormalize(new.double())
        with torch.no_grad():
            feet = decode_positions(raw, spec, skeleton, state)[..., cidx, :]
        best = int(torch.argmin(glide_cost(torch.cat((before, feet), dim=1), planted_height, spec.fps, max_lift)))
        state = advance(state, raw[best], spec)
        before = feet[best, -1:].expand(candidates, 1, len(cidx), 3)
        history = torch.cat((history, new[best]))
        pieces.append(new[best])
    return torch.cat(pieces)
