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


def glide_cost(feet: torch.Tensor, planted_height: np.ndarray, fps: float) -> torch.Tensor:
    """How badly contact joints ``feet (..., T, C, 3)`` (world positions, frame 0 the one
    before) meet the floor, per leading index: the horizontal speed (m/s) of the joints
    within ``FLOOR_BAND`` of their planted height, summed over joints and averaged over
    frames, plus ``AIRBORNE_COST`` times the share of frames with no joint there (a foot
    that floats or a leg held up cannot hide its sliding by leaving the floor)."""
    height = feet[..., 1:, :, 1] - torch.as_tensor(planted_height, dtype=feet.dtype)
    low = height < FLOOR_BAND
    speed = (feet[..., 1:, :, :] - feet[..., :-1, :, :])[..., [0, 2]].norm(dim=-1) * fps
    glide = (speed * low).sum(-1).mean(-1)
    return glide + AIRBORNE_COST * (~low.any(-1)).to(feet.dtype).mean(-1)


def chosen_rollout(prior, history: torch.Tensor, state: RootStart, last_feet: np.ndarray, skeleton: Skeleton,
                   planted_height: np.ndarray, n_frames: int, candidates: int, temperature: float,
                   generator: torch.Generator, clamp_raw: torch.Tensor | None = None) -> torch.Tensor:
    """``n_frames`` new frames (n_frames, D), normalised, after ``history (T, D)``: rolled
    out a second at a time, each second the one of ``candidates`` continuations of the
    last with the least ``glide_cost``. ``state`` is the root state at history's last
    frame, ``last_feet (C, 3)`` its contact joints' world positions (on ``skeleton``, the
    prior's), ``planted_height (C,)`` their heights when planted. ``clamp_raw (n_frames, 3)``,
    when given, sets the root channels of the new frames (unnormalised; ``clamped_rollout``);
    otherwise the prior rolls out its own root, unplanted.

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
        best = int(torch.argmin(glide_cost(torch.cat((before, feet), dim=1), planted_height, spec.fps)))
        state = advance(state, raw[best], spec)
        before = feet[best, -1:].expand(candidates, 1, len(cidx), 3)
        history = torch.cat((history, new[best]))
        pieces.append(new[best])
    return torch.cat(pieces)
