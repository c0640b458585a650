"""Foot-contact cleanup: plant the feet where contact labels say, by analytic leg IK.

The post-process of Wang et al. (2019) and CCNet: after synthesis or denoising, inverse
kinematics zeroes the speed of the points in contact and puts them on the ground plane.
For each contact segment of each leg the foot is held still and the hip and knee
rotations are solved in closed form so the ankle gets there; the correction fades in and
out over a few frames at the segment ends so that nothing pops.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from . import rotations as R
from .kinematics import fk
from .metrics import rest_heights
from .motion import Motion
from .skeleton import Skeleton
from .smoothing import smoothstep

_STRAIGHT = 1e-3  # sine of the knee angle below which a leg counts as straight


@dataclass(frozen=True)
class Leg:
    """One leg: hip, knee and ankle joints, and the contact columns that plant it (the
    ankle's and those of contact joints below it, such as a toe)."""

    hip: int
    knee: int
    ankle: int
    columns: tuple[int, ...]
    joints: tuple[int, ...]


def find_legs(skeleton: Skeleton, contact_joints: list[str]) -> list[Leg]:
    """Group contact joints into legs. A contact joint below another one (a toe under its
    foot) plants the same leg; the topmost is the ankle, its parent the knee and its
    grandparent the hip, found from the hierarchy, not by name."""
    idx = [skeleton.index(n) for n in contact_joints]
    parents = skeleton.parents

    def ankle_of(j: int) -> int:
        top, p = j, int(parents[j])
        while p != -1:
            if p in idx:
                top = p
            p = int(parents[p])
        return top

    groups: dict[int, list[int]] = {}
    for c, j in enumerate(idx):
        groups.setdefault(ankle_of(j), []).append(c)
    legs = []
    for ankle, cols in groups.items():
        knee = int(parents[ankle])
        hip = int(parents[knee]) if knee > 0 else -1
        if hip <= 0:
            raise ValueError(f"contact joint {skeleton.names[ankle]!r} needs a knee and a hip below the root "
                             "(ankle, parent, grandparent, with the root above): pass ankle or toe joints")
        cols = sorted(cols, key=lambda c: idx[c] != ankle)  # the ankle's column first
        legs.append(Leg(hip, knee, ankle, tuple(cols), tuple(idx[c] for c in cols)))
    for a in legs:
        for b in legs:
            if a is not b and {a.hip, a.knee} & ({b.ankle, b.knee, b.hip} | set(_ancestors(parents, b.hip))):
                raise ValueError(f"the legs of {skeleton.names[a.ankle]!r} and {skeleton.names[b.ankle]!r} share "
                                 "joints: each contact joint must end its own hip-knee-ankle chain")
    return legs


def _ancestors(parents: np.ndarray, j: int) -> list[int]:
    out = []
    while parents[j] != -1:
        j = int(parents[j])
        out.append(j)
    return out


def clean_contacts(motion: Motion, contact_joints: list[str], contacts: np.ndarray,
                   planted_height: np.ndarray | None = None, blend_frames: int = 3,
                   max_stretch: float = 0.98, fill_gaps: int = 2, max_rise: float = 0.03) -> Motion:
    """The motion with each leg planted during its contact segments.

    Args:
        motion: a motion on a model skeleton (``features.to_model_motion``), metres, y up.
        contact_joints: names of the contact joints, e.g. ``spec.contact_joints``.
        contacts: (T, C) contact labels, one column per contact joint; values above 0.5
            count as contact (0/1 labels, or a prior's contact probabilities).
        planted_height: (C,) height (world y, metres) of each contact joint when planted;
            default: its 5th percentile over the clip (``metrics.rest_heights``).
        blend_frames: frames over which the correction fades in before and out after a
            segment (0: switch on and off at once).
        max_stretch: the IK never straightens a leg to more than this fraction of its
            full length, unless the input pose of that frame is straighter already.
        fill_gaps: breaks of at most this many frames inside a leg's contact are label
            flicker (a pivoting foot passing the speed threshold), not steps: they are
            filled, so the foot stays planted through them. 0 keeps the labels as given.
        max_rise: how far (m) a planted foot the leg cannot reach may be lifted towards it;
            further out of reach it slides instead.

    A leg is in contact on the frames where any of its contact joints (ankle, toe) is
    labelled. Within a contact segment the whole foot is moved by one translation per
    frame, so **its world orientation stays as it was** and toes follow; only its position
    is corrected. Vertically the foot moves just enough to put the lowest of its contact
    joints on its planted height (none below it, one on it). Horizontally it moves so that
    the labelled joint nearest its planted height keeps still from frame to frame (the
    ankle on a flat foot, the toe at heel-off), which leaves one point per segment to
    choose: where the foot stands. That is the mean over the segment (for an ankle-only
    leg, as on CMU, the ankle's mean position), or if the leg cannot reach it from the
    hip on every frame, the point nearest the mean that it can reach. Outside segments
    the correction of the nearest segment end fades out over ``blend_frames``
    (smoothstep); in a shorter gap the two ends are blended.

    The hip and knee rotations then bring the ankle to its target by analytic two-bone
    IK, which keeps the knee's hinge axis where it was in the thigh's frame (the pole
    comes from the input knee) and turns the knee only about it. A target out of reach
    is lifted until the leg reaches it, by at most ``max_rise``: a foot the leg cannot
    quite plant rises a little; one far out of reach (a contact the motion never made, a
    body that has walked on) slides towards the hip instead of kicking up. Only the local
    rotations of hips, knees and ankles change; frames outside the segments and their
    blends keep their input values exactly, and so do the root and the other joints.
    Per-frame joint translations, if any, are used as they are.
    """
    sk = motion.skeleton
    n_t, n_c = motion.num_frames, len(contact_joints)
    contacts = np.asarray(contacts)
    if contacts.shape != (n_t, n_c):
        raise ValueError(f"contacts must be (frames, contact joints) = ({n_t}, {n_c}), got {contacts.shape}")
    if blend_frames < 0 or fill_gaps < 0:
        raise ValueError(f"blend_frames and fill_gaps count frames, 0 or more; got {blend_frames} and {fill_gaps}")
    if max_rise < 0:
        raise ValueError(f"max_rise is a height in metres, 0 or more; got {max_rise}")
    if not 0 < max_stretch <= 1:
        raise ValueError(f"max_stretch is a fraction of the leg's length in (0, 1], got {max_stretch}")
    legs = find_legs(sk, list(contact_joints))
    rot = torch.from_numpy(motion.rotations)
    offsets = torch.from_numpy(sk.offsets)
    tr = None if motion.translations is None else torch.from_numpy(motion.translations)
    pos, grot = fk(sk.parents, rot, torch.from_numpy(motion.root), offsets, tr, return_global_rotations=True)
    cidx = [sk.index(n) for n in contact_joints]
    if planted_height is None:
        heights = rest_heights(pos, cidx).numpy()
    else:
        heights = np.asarray(planted_height, dtype=np.float64)
        if heights.shape != (n_c,):
            raise ValueError(f"planted_height must have one value per contact joint ({n_c}), got {heights.shape}")
    labels = contacts > 0.5
    out = rot.clone()
    pos_np = pos.numpy()
    for leg in legs:
        hip, knee, ankle = pos[:, leg.hip], pos[:, leg.knee], pos[:, leg.ankle]
        longest = torch.maximum(max_stretch * ((knee - hip).norm(dim=-1) + (ankle - knee).norm(dim=-1)),
                                (ankle - hip).norm(dim=-1))
        delta, active = _corrections(pos_np[:, list(leg.joints)], labels[:, list(leg.columns)],
                                     heights[list(leg.columns)], pos_np[:, leg.hip], longest.numpy(),
                                     blend_frames, fill_gaps)
        if not active.any():
            continue
        f = torch.from_numpy(np.flatnonzero(active))
        target = _within_reach(hip[f], ankle[f] + torch.from_numpy(delta[active]), longest[f], max_rise)
        hip_g, knee_g = _two_bone_ik(hip[f], knee[f], ankle[f], target, grot[f, leg.hip], grot[f, leg.knee],
                                     _bend_axis(pos, grot, leg, f), longest[f])
        parent_g = grot[f, int(sk.parents[leg.hip])]
        out[f, leg.hip] = R.quat_normalize(R.quat_multiply(R.quat_conjugate(parent_g), hip_g))
        out[f, leg.knee] = R.quat_normalize(R.quat_multiply(R.quat_conjugate(hip_g), knee_g))
        out[f, leg.ankle] = R.quat_normalize(R.quat_multiply(R.quat_conjugate(knee_g), grot[f, leg.ankle]))
    return motion.with_frames(out.numpy(), motion.root.copy(), motion.translations)


def _segments(on: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) of each run of True frames."""
    d = np.diff(np.concatenate(([0], on.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))


def _filled(on: np.ndarray, gap: int) -> np.ndarray:
    """``on`` with runs of at most ``gap`` False frames between True frames set True."""
    out = on.copy()
    runs = _segments(on)
    for (_, e), (s, _) in zip(runs[:-1], runs[1:]):
        if s - e <= gap:
            out[e:s] = True
    return out


def _corrections(p: np.ndarray, labels: np.ndarray, heights: np.ndarray, hip: np.ndarray, longest: np.ndarray,
                 blend: int, gap: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame translation (T, 3) of one foot, and the frames where it is non-zero or in
    contact. ``p`` (T, M, 3): the leg's contact joints (ankle first); ``labels`` (T, M);
    ``hip`` (T, 3) and ``longest`` (T,): where the leg hangs from and how far it reaches."""
    n_t = len(p)
    delta = np.zeros((n_t, 3))
    inside = _filled(labels.any(axis=1), gap)
    for s, e in _segments(inside):
        seg = p[s:e]
        rel = seg[..., 1] - heights  # height above the plane, per joint
        # the joint held still: the lowest labelled one, or the lowest in a filled gap
        lab = labels[s:e] | ~labels[s:e].any(axis=1, keepdims=True)
        anchor = np.where(lab, rel, np.inf).argmin(axis=1)
        step = seg[np.arange(1, e - s), anchor[1:]] - seg[np.arange(e - s - 1), anchor[1:]]
        drift = -np.concatenate((np.zeros((1, 3)), np.cumsum(step, axis=0)))[:, [0, 2]]
        delta[s:e, 1] = -rel.min(axis=1)
        # ankle target = ankle + drift + c: within reach of the hip wherever possible
        ankle = seg[:, 0] + delta[s:e]
        room = longest[s:e] ** 2 - (ankle[:, 1] - hip[s:e, 1]) ** 2
        center = hip[s:e][:, [0, 2]] - ankle[:, [0, 2]] - drift
        delta[s:e, 0::2] = drift + _plant(center, np.sqrt(np.clip(room, 0, None)), -drift.mean(axis=0))
    frames = np.arange(n_t)
    last = np.maximum.accumulate(np.where(inside, frames, -1))
    after = np.minimum.accumulate(np.where(inside, frames, n_t)[::-1])[::-1]
    a = np.where(last >= 0, smoothstep(1 - (frames - last) / (blend + 1)), 0.0)
    b = np.where(after < n_t, smoothstep(1 - (after - frames) / (blend + 1)), 0.0)
    outside = ~inside
    blended = a[:, None] * delta[np.maximum(last, 0)] + b[:, None] * delta[np.minimum(after, n_t - 1)]
    blended /= np.maximum(a + b, 1.0)[:, None]
    delta[outside] = blended[outside]
    return delta, inside | (a + b > 0)


def _plant(center: np.ndarray, radius: np.ndarray, start: np.ndarray, weight: float = 1e6) -> np.ndarray:
    """The point (2,) nearest ``start`` inside every disk (``center`` (N, 2), ``radius`` (N,));
    where the disks share no point, the one that leaves the least reach unmet (a millimetre
    out of reach weighs as a metre away from ``start``). Damped Newton on the convex cost
    ``|c - start|^2 + weight * sum(max(|c - center| - radius, 0)^2)``."""
    def terms(c: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        d = c - center
        dist = np.maximum(np.linalg.norm(d, axis=1), 1e-12)
        over = np.clip(dist - radius, 0, None)
        return float((c - start) @ (c - start) + weight * over @ over), d / dist[:, None], over, dist

    c = start
    cost, u, over, dist = terms(c)
    if not over.any():
        return start
    for _ in range(100):
        grad = 2 * (c - start) + 2 * weight * over @ u
        uu = u[:, :, None] * u[:, None, :]
        k = (over > 0)[:, None, None]
        hess = 2 * np.eye(2) + 2 * weight * (k * (uu + (over / dist)[:, None, None] * (np.eye(2) - uu))).sum(0)
        step = np.linalg.solve(hess, grad)
        t = 1.0
        while True:  # backtracking: the cost is convex, a descent step exists
            new = terms(c - t * step)
            if new[0] <= cost - 1e-4 * t * grad @ step or t < 1e-6:
                break
            t /= 2
        c = c - t * step
        cost, u, over, dist = new
        if np.linalg.norm(t * step) < 1e-10:
            break
    return c


def _within_reach(hip: Tensor, target: Tensor, longest: Tensor, max_rise: float) -> Tensor:
    """Targets (N, 3) within ``longest`` of the hip: raised as little as needed, by at most
    ``max_rise`` metres (a foot a little out of reach lifts rather than slides), and beyond
    that drawn in horizontally towards the hip (a foot far out of reach slides: lifted all
    the way, a planted point a stride behind a body that walked on raised the foot to hip
    height, a kick of 80 cm)."""
    off = target - hip
    flat = off[:, [0, 2]].norm(dim=-1)
    low = hip[:, 1] - torch.sqrt((longest ** 2 - flat ** 2).clamp_min(0))
    y = torch.where(flat < longest, torch.maximum(target[:, 1], low), hip[:, 1])
    y = torch.minimum(y, target[:, 1] + max_rise)
    reach = torch.sqrt((longest ** 2 - (y - hip[:, 1]) ** 2).clamp_min(0))
    scale = torch.minimum(torch.ones_like(flat), reach / flat.clamp_min(1e-12))
    out = target.clone()
    out[:, 1] = y
    out[:, 0] = hip[:, 0] + off[:, 0] * scale
    out[:, 2] = hip[:, 2] + off[:, 2] * scale
    return out


def _leg_normal(hip: Tensor, knee: Tensor, ankle: Tensor) -> tuple[Tensor, Tensor]:
    """Unit normal of the hip-knee-ankle plane (the knee's hinge axis) and whether it is
    defined (the leg is not straight)."""
    n = torch.cross(ankle - hip, knee - hip, dim=-1)
    scale = (ankle - hip).norm(dim=-1) * (knee - hip).norm(dim=-1)
    return _unit(n), n.norm(dim=-1) > _STRAIGHT * scale


def _bend_axis(pos: Tensor, grot: Tensor, leg: Leg, frames: Tensor) -> Tensor:
    """The knee's hinge axis (N, 3) in the world on ``frames``: the leg plane's normal, and
    where the leg is straight, the clip's mean normal in the thigh's frame (the way this
    knee bends elsewhere), made perpendicular to the leg."""
    hip, knee, ankle = pos[:, leg.hip], pos[:, leg.knee], pos[:, leg.ankle]
    normal, ok = _leg_normal(hip, knee, ankle)
    if ok[frames].all():
        return normal[frames]
    if not ok.any():
        raise ValueError("the leg is straight in every frame, so the knee's bending direction is unknown")
    thigh = R.quat_apply(R.quat_conjugate(grot[ok, leg.hip]), normal[ok]).mean(dim=0)
    fallback = R.quat_apply(grot[frames, leg.hip], thigh.expand(len(frames), 3))
    along = _unit(ankle[frames] - hip[frames])
    fallback = _unit(fallback - (fallback * along).sum(-1, keepdim=True) * along)
    return torch.where(ok[frames, None], normal[frames], fallback)


def _rotation_between(u: Tensor, v: Tensor) -> Tensor:
    """Shortest-arc rotations (..., 4) taking unit vectors ``u`` to ``v`` (not opposite)."""
    q = torch.cat((1 + (u * v).sum(-1, keepdim=True), torch.cross(u, v, dim=-1)), dim=-1)
    return R.quat_normalize(q)


def _unit(v: Tensor) -> Tensor:
    return v / v.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def _angle(u: Tensor, v: Tensor) -> Tensor:
    return torch.atan2(torch.cross(u, v, dim=-1).norm(dim=-1), (u * v).sum(-1))


def _two_bone_ik(hip: Tensor, knee: Tensor, ankle: Tensor, target: Tensor, hip_rot: Tensor, knee_rot: Tensor,
                 normal: Tensor, longest: Tensor) -> tuple[Tensor, Tensor]:
    """New world rotations (N, 4) of hip and knee that bring the ankle to ``target`` (N, 3),
    or as near as it gets on the line from the hip without reaching further than ``longest``.

    The knee turns about the leg plane's normal to give the hip-ankle distance, the hip
    turns about the same axis to keep the knee in place relative to that line, then the
    whole leg swings on the shortest arc onto the hip-target line.
    """
    l1 = (knee - hip).norm(dim=-1)
    l2 = (ankle - knee).norm(dim=-1)
    dist = (target - hip).norm(dim=-1).clamp(min=(l1 - l2).abs() * 1.0001 + 1e-9)
    dist = torch.minimum(dist, longest)
    hip_angle = _angle(ankle - hip, knee - hip)
    knee_angle = _angle(hip - knee, ankle - knee)
    hip_new = torch.acos(((l1 ** 2 + dist ** 2 - l2 ** 2) / (2 * l1 * dist)).clamp(-1, 1))
    knee_new = torch.acos(((l1 ** 2 + l2 ** 2 - dist ** 2) / (2 * l1 * l2)).clamp(-1, 1))
    turn_hip = R.axis_angle_to_quat(normal * (hip_new - hip_angle)[:, None])
    turn_knee = R.axis_angle_to_quat(normal * (hip_new - hip_angle + knee_new - knee_angle)[:, None])
    knee_moved = hip + R.quat_apply(turn_hip, knee - hip)
    ankle_moved = knee_moved + R.quat_apply(turn_knee, ankle - knee)
    swing = _rotation_between(_unit(ankle_moved - hip), _unit(target - hip))
    return (R.quat_multiply(swing, R.quat_multiply(turn_hip, hip_rot)),
            R.quat_multiply(swing, R.quat_multiply(turn_knee, knee_rot)))
