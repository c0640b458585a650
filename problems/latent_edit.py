"""Semantic edits with the latent prior, in user terms (MoDi section 4.1, then a MAP solve).

MoDi edits a motion by moving its W+ code along an attribute's direction (the normal of
a linear classifier on codes, ``priors.semantic``). Here that step only starts the
edit: with codes that carry a motion's timing a few frames at a time, a step large
enough to show (several standard deviations of the codes) leaves the generator's range,
and one small enough to stay natural moved the hips by 1-5 cm and the hand by 1.5 cm
(bench/results/latent.txt before this solve). So the codes are then refined by L-BFGS
against three terms:

- the goal: the attribute's measure on each frame (or window) of the generated clip,
  pulled to the unedited generation's measure moved by ``strength`` units
  (``EditGoal``; the units are what a user sees: centimetres of hip height, degrees of
  arm lift, a factor of speed, a style classifier's probability);
- what the edit leaves alone: the rotations of the joints the attribute does not move
  (``EditGoal.free``), kept at the unedited generation's, and the feet: the
  path-following solve's skating and support terms (``feet_term``), without which a
  faster pace slid the feet at 3-4 times the input's speed on held-out Bandai walks;
- the latent prior: the inversion's regulariser, which keeps every code where the
  generator was trained (``motionopt.solver.regulariser``), so that the edited motion
  stays one the prior would make.

Every edit but the pace's keeps the input's slow root path and heading (``anchor_root``).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch
from torch import Tensor

from motionopt import attributes as A
from motionopt import rotations as R
from motionopt.codec import Codec
from motionopt.motion import Motion
from motionopt.objective import SkatingTerm, SupportTerm, WindowState
from motionopt.solver import InversionOptions, refine, regulariser
from priors.latent import LatentPrior
from priors.semantic import PACE, edit_codes
from priors.style import style_classifier_of

from .latent import LatentTaskResult, directions, generate_clip, invert_input, result_of

#: What one unit of strength does, per attribute (``goal_of``). Weakening a crouch stops
#: at the clip's highest hips: above them the feet left the floor (held-out walks at -2
#: unbounded: feet sliding 2-3 times the input's).
CROUCH_M_PER_UNIT = 0.03
ARM_DEGREES_PER_UNIT = 20.0
SPEED_FACTOR_PER_UNIT = 1.2
#: A style's unit: at 0.25, 17 of 19 Bandai styles raised the classifier's probability by
#: 0.3 at +2 against -2 on 4 held-out clips (musical +0.29, tired +0.26) with feet sliding up
#: to 3.1 times strength 0's; at 0.4, 19 of 19 (+0.38 to +0.92), sliding 1.04-2.12 times,
#: the root path moved up to 5.3 cm (bench/latent.py section 5's edit figures).
STYLE_PROBABILITY_PER_UNIT = 0.4
#: Weight of the unmoved joints' rotations (mean squared change in normalised units).
KEEP_WEIGHT = 10.0
#: Sigmas of the feet in the edit's solve (``feet_term``): speed (m/s) of a foot near
#: the floor, and height (m) of the lowest foot above the floor.
EDIT_SKATING_SIGMA = 0.3
EDIT_SUPPORT_SIGMA = 0.01
#: Weight of the latent prior's regulariser in the edit's solve (the inversion's is
#: lighter: there the input itself keeps the codes in place).
EDIT_REG_WEIGHT = 0.05
#: L-BFGS iterations of the edit's solve.
EDIT_ITERS = 40
#: Frames per window of the pace's measure (about half a second at 30 fps).
SPEED_WINDOW = 16


@dataclass
class EditGoal:
    """An attribute's edit in user terms: ``measure`` maps the generated clip's normalised
    features (T, D) and its joint positions (T, J, 3) (``Codec.positions``, decoded once
    per evaluation for the goal and the feet alike) to values (K,) (per frame or per
    window); strength s asks for
    ``target(unedited measure, s)`` within ``sigma``; ``free`` names the joints whose
    rotations may change (None: all of them)."""

    unit: str
    measure: Callable[[Tensor, Tensor], Tensor]
    target: Callable[[Tensor, float], Tensor]
    sigma: float
    free: set[str] | None = None
    #: The mean of a measure in words (e.g. "87.9 cm").
    show: Callable[[float], str] = "{:.3g}".format


def leg_joints(prior: LatentPrior) -> set[str]:
    """The joints between the root and the contact joints (hips to toes), contacts included."""
    names, parents = prior.skeleton.names, prior.skeleton.parents
    out = set()
    for j in prior.spec.contact_indices():
        while j > 0:
            out.add(names[j])
            j = int(parents[j])
    return out


def goal_of(prior: LatentPrior, attribute: str) -> EditGoal:
    """The edit goal of ``attribute`` (gral, root_speed, crouch or style:NAME)."""
    codec = Codec.of(prior)
    s = prior.spec.slices()
    fps = prior.spec.fps
    if attribute == "crouch":
        h = s["root_height"].start
        return EditGoal(f"hips {CROUCH_M_PER_UNIT * 100:g} cm lower per unit (never above their highest in the clip)",
                        lambda x, p: codec.raw(x)[:, h], lambda m0, k: (m0 - CROUCH_M_PER_UNIT * k).clamp(max=m0.max()),
                        0.01, leg_joints(prior), lambda v: f"hips {100 * v:.1f} cm high")
    if attribute == "gral":
        shoulder, elbow, wrist = A.right_arm(prior.skeleton.names, prior.skeleton.parents)

        def lift(x: Tensor, p: Tensor) -> Tensor:
            return (A.angle_from_down(p[:, elbow] - p[:, shoulder]) + A.angle_from_down(p[:, wrist] - p[:, elbow])) / 2

        step = math.radians(ARM_DEGREES_PER_UNIT)
        return EditGoal(f"right arm raised {ARM_DEGREES_PER_UNIT:g} degrees per unit", lift,
                        lambda m0, k: (m0 + step * k).clamp(0.0, math.pi), math.radians(3.0),
                        {prior.skeleton.names[j] for j in (shoulder, *prior.skeleton.descendants(shoulder))},
                        lambda v: f"right arm {math.degrees(v):.0f} degrees from down")
    if attribute == PACE:
        d = s["root_delta"]

        def speed(x: Tensor, p: Tensor) -> Tensor:
            v = codec.raw(x)[:, d].norm(dim=-1) * fps
            n = max(len(v) // SPEED_WINDOW, 1)
            return v[:n * SPEED_WINDOW].reshape(n, -1).mean(-1) if len(v) >= SPEED_WINDOW else v.mean()[None]

        return EditGoal(f"speed times {SPEED_FACTOR_PER_UNIT:g} per unit", speed,
                        lambda m0, k: m0 * SPEED_FACTOR_PER_UNIT ** k, 0.05, show=lambda v: f"{v:.2f} m/s")
    if attribute.startswith("style:"):
        classifier = style_classifier_of(prior.metadata)
        style = attribute.split(":", 1)[1]
        if classifier is None or style not in classifier.styles:
            raise ValueError(f"the prior has no classifier of style {style!r}")
        j = classifier.styles.index(style)
        w = prior.window

        def log_probability(x: Tensor, p: Tensor) -> Tensor:
            x = as_decoded(codec, x)
            starts = list(range(0, max(len(x) - w, 0) + 1, w // 2))
            win = torch.stack([x[a:a + w] for a in starts]) if len(x) >= w else x[None]
            return torch.log(classifier.probabilities(win)[:, j].clamp_min(1e-9))

        def target(m0: Tensor, k: float) -> Tensor:
            # within 0.001-0.95, but never against the edit's sign: a window already at 0.97
            # is not asked down to 0.95 by a positive strength
            p0 = m0.exp()
            goal = p0 + STYLE_PROBABILITY_PER_UNIT * k
            goal = torch.maximum(goal.clamp(max=0.95), p0) if k >= 0 else torch.minimum(goal.clamp(min=1e-3), p0)
            return torch.log(goal)

        return EditGoal(f"the style classifier's probability {STYLE_PROBABILITY_PER_UNIT:+g} per unit",
                        log_probability, target, 0.1, show=lambda v: f"probability {math.exp(v):.2f}")
    raise ValueError(f"no edit goal for attribute {attribute!r}")


def as_decoded(codec: Codec, x: Tensor) -> Tensor:
    """Features (T, D) as the decoded motion has them: every rotation's 6D pair made
    orthonormal (as decoding makes it), and the contact channels replaced by the labels
    the decoded motion gets (constants to the gradient). A goal scored on the raw output
    (a style classifier's window descriptors) was met through the parts decoding
    discards: on a held-out walk, probability 0.40 on the generator's features and 0.16
    on the written motion's."""
    s = codec.spec.slices()
    raw = codec.raw(x)
    rot = torch.cat((raw[:, s["root_tilt"]], raw[:, s["joint_rotations"]]), dim=-1).reshape(len(x), -1, 6)
    rot = R.matrix_to_6d(R.sixd_to_matrix(rot)).reshape(len(x), -1)
    c = s["contacts"]
    with torch.no_grad():
        labels = codec.raw(codec.features(codec.motion(x.detach().double())))[:, c].to(x)
    raw = torch.cat((raw[:, :s["root_tilt"].start], rot, labels, raw[:, c.stop:]), dim=-1)
    return codec.normalizer.normalize(raw)


def feet_term(prior: LatentPrior, p0: Tensor) -> Callable[[Tensor, Tensor], Tensor]:
    """Mean energy per frame of the path-following ``SkatingTerm`` and completion's
    ``SupportTerm`` (sigmas ``EDIT_SKATING_SIGMA``, ``EDIT_SUPPORT_SIGMA``) on a generated
    clip's features (T, D) and joint positions (T, J, 3), with the contact joints' planted
    heights those of the unedited clip's positions ``p0`` (5th percentile): an edit that
    speeds the root up or lowers the hips must move the feet with it, not slide them or
    lift them clear of the floor."""
    cidx = prior.spec.contact_indices()
    planted = torch.quantile(p0[:, cidx, 1].detach().double(), 0.05, dim=0).numpy()
    terms = [SkatingTerm(cidx, planted, sigma_speed=EDIT_SKATING_SIGMA), SupportTerm(cidx, planted, sigma=EDIT_SUPPORT_SIGMA)]
    fps = prior.spec.fps

    def energy(x: Tensor, p: Tensor) -> Tensor:
        state = WindowState(np.arange(len(x)), 0, x, p.new_zeros(0), p[:, 0], p, p.new_zeros(0), p.new_zeros(0), fps)
        return sum(t.energy(state) for t in terms) / len(x)

    return energy


def kept_dims(prior: LatentPrior, free: set[str] | None) -> Tensor:
    """Feature dimensions of the joint rotations an edit leaves alone (joints not in ``free``)."""
    if free is None:
        return torch.zeros(0, dtype=torch.long)
    first = prior.spec.slices()["joint_rotations"].start
    dims = [first + 6 * (j - 1) + k for j, name in enumerate(prior.spec.joints) if j > 0 and name not in free
            for k in range(6)]
    return torch.tensor(dims, dtype=torch.long)


def latent_edit(prior: LatentPrior, motion: Motion, attribute: str, strength: float,
                options: InversionOptions = InversionOptions(), iters: int = EDIT_ITERS) -> LatentTaskResult:
    """Strengthen (``strength`` > 0) or weaken an attribute of ``motion``: invert it, step
    along the attribute's direction, then refine the codes toward the goal in user terms
    (``goal_of``) while the joints the attribute does not move keep the unedited
    generation's rotations. ``iters`` 0 gives MoDi's plain step."""
    dirs = directions(prior)
    if attribute not in dirs:
        raise ValueError(f"unknown attribute {attribute!r}; this prior knows: {', '.join(sorted(dirs))}")
    t0 = time.perf_counter()
    prep, inv = invert_input(prior, motion, options)
    n = len(prep.x)
    codec = Codec.of(prior)

    def clip(codes: Tensor) -> tuple[Tensor, Tensor]:
        """The generated clip's features and joint positions."""
        x = generate_clip(prior, codes, inv, n)
        return x, codec.positions(x)

    codes = edit_codes(inv.wplus, dirs[attribute], strength)
    goal = None
    if iters and strength:
        goal = goal_of(prior, attribute)
        with torch.no_grad():
            x0, p0 = clip(inv.wplus)
            m0 = goal.measure(x0, p0)
            target = goal.target(m0, strength)
        keep = kept_dims(prior, goal.free)
        feet = feet_term(prior, p0)

        def energy(c: Tensor) -> Tensor:
            x, p = clip(c)
            e = ((goal.measure(x, p) - target) / goal.sigma).pow(2).mean() + feet(x, p)
            if len(keep):
                e = e + KEEP_WEIGHT * (x[:, keep] - x0[:, keep]).pow(2).mean()
            return e + EDIT_REG_WEIGHT * regulariser(prior, c)

        codes, _ = refine(codes, energy, iters)
    reached = {}
    with torch.no_grad():
        x, p = clip(codes)
        if goal is not None:
            unedited, asked, got = (float(v.mean()) for v in (m0, target, goal.measure(x, p)))
            reached = {"goal_unedited": unedited, "goal_target": asked, "goal_reached": got,
                       "goal_summary": f"{goal.unit}: {goal.show(unedited)} unedited, {goal.show(asked)} asked, "
                                       f"{goal.show(got)} reached (means over the clip)"}
    inv.timings["total"] = time.perf_counter() - t0
    keep_path = attribute != PACE
    metrics = {"attribute": attribute, "strength": strength, "classifier_accuracy": dirs[attribute].accuracy,
               "root_path_kept": keep_path, "unit": goal.unit if goal else "standard deviations of the codes", **reached}
    return result_of(prior, x, prep.start, motion, inv, metrics, n_frames=motion.num_frames,
                     anchor=(prep.model, np.ones(n, bool)) if keep_path else None, anchor_height=False)

