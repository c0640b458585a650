"""Foot-contact cleanup on real clips whose planted feet were made to slide."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
import torch

from motionopt import bvh, metrics
from motionopt import rotations as R
from motionopt.features import contact_labels, default_spec, estimate_ground, to_model_motion
from motionopt.footik import Leg, clean_contacts, find_legs
from motionopt.kinematics import fk
from motionopt.motion import Motion
from clips import CMU_120, DATA, shared_excerpt, slide

#: Real capture with planted feet (mocap's own feet barely slide; generated motion's do):
#: 2 s of a Bandai walk and 2 s of CMU martial arts (standing, then one step).
REAL = {"bandai-walk": ("bandai/dataset-1_walk_normal_001.bvh", 30, 90), "cmu-step": ("cmu/martial/03.bvh", 336, 576)}
DRIFT = np.array([0.3, 0.0, 0.1])  # m/s: the root drifts at 0.32 m/s, so planted feet slide


@dataclass
class Case:
    clean: Motion
    slid: Motion
    cleaned: Motion
    joints: list[str]
    contacts: np.ndarray
    heights: np.ndarray

    @property
    def idx(self) -> list[int]:
        return [self.clean.skeleton.index(n) for n in self.joints]


@pytest.fixture(scope="module", params=list(REAL))
def case(request) -> Case:
    motion = shared_excerpt(*REAL[request.param])
    spec = default_spec(motion.skeleton)
    clean = to_model_motion(motion, spec)
    idx = [clean.skeleton.index(n) for n in spec.contact_joints]
    pos = clean.positions()
    contacts = contact_labels(pos, idx, clean.fps, estimate_ground(pos, idx), spec.contact_height,
                              spec.contact_speed)
    slid = slide(clean, DRIFT)
    heights = metrics.rest_heights(torch.from_numpy(slid.positions()), idx).numpy()
    return Case(clean, slid, clean_contacts(slid, list(spec.contact_joints), contacts), list(spec.contact_joints),
                contacts, heights)


def positions(m: Motion) -> torch.Tensor:
    return torch.from_numpy(m.positions())


def side_steps(case: Case):
    """For each leg: its contact labels (T, M) and the frame steps on which it is labelled at both ends."""
    for leg in find_legs(case.clean.skeleton, case.joints):
        on = case.contacts[:, list(leg.columns)] > 0.5
        yield leg, on, on.any(1)[1:] & on.any(1)[:-1]


def test_skating_drops_below_a_third_of_the_slid_clip(case):
    skate = {k: [float(metrics.foot_skating(positions(getattr(case, k)), case.clean.fps, case.idx, threshold=th))
                 for th in (0.01, 0.03)] for k in ("clean", "slid", "cleaned")}
    assert skate["slid"][0] > skate["clean"][0] + 0.2, skate
    # joints within 1 cm of their planted height: these are the contact frames
    assert skate["cleaned"][0] < 0.3 * skate["slid"][0], skate
    # within 3 cm the metric also counts swing frames near the floor, which no label covers
    # (Bandai's low steps: 0.33 m/s on the clean clip), so only ask for less than before
    assert skate["cleaned"][1] < skate["slid"][1], skate


def test_the_labelled_point_of_a_planted_foot_stays_still(case):
    speed = metrics.joint_speed(positions(case.cleaned)[:, case.idx] * torch.tensor([1.0, 0.0, 1.0]),
                                case.clean.fps).numpy()
    speed0 = metrics.joint_speed(positions(case.slid)[:, case.idx] * torch.tensor([1.0, 0.0, 1.0]),
                                 case.clean.fps).numpy()
    for leg, on, _ in side_steps(case):
        cols = list(leg.columns)
        both = on[1:] & on[:-1]  # joints labelled at both ends of a step
        steps = both.any(axis=1)
        still = np.where(both, speed[:, cols], np.inf).min(axis=1)[steps]
        before = np.where(both, speed0[:, cols], np.inf).min(axis=1)[steps]
        assert len(still) > 5 and np.median(before) > 0.2
        assert still.max() < 1e-6


def test_planted_feet_stand_on_their_plane(case):
    y = positions(case.cleaned)[:, case.idx, 1].numpy() - case.heights
    assert (y[case.contacts > 0.5] > -1e-9).all()  # nothing below its planted height
    for leg, on, _ in side_steps(case):
        lowest = y[on.any(axis=1)][:, list(leg.columns)].min(axis=1)
        assert (lowest > -1e-9).all()
        # on the plane, but for a few frames where the leg could not reach it and the foot was lifted
        assert np.mean(lowest < 1e-9) > 0.6 and lowest.max() < 0.03


def test_frames_away_from_contacts_and_other_joints_are_unchanged(case):
    blend = 3
    sk = case.clean.skeleton
    changed = set()
    far_frames = 0
    for leg, on, _ in side_steps(case):
        labelled = np.flatnonzero(on.any(1))
        dist = np.abs(np.arange(len(on))[:, None] - labelled[None, :]).min(axis=1)
        far = dist > blend
        far_frames += far.sum()
        chain = [leg.hip, leg.knee, leg.ankle]
        assert np.array_equal(case.cleaned.rotations[far][:, chain], case.slid.rotations[far][:, chain])
        changed.update(chain)
    assert far_frames > 5
    others = [j for j in range(sk.num_joints) if j not in changed]
    assert np.array_equal(case.cleaned.rotations[:, others], case.slid.rotations[:, others])
    assert np.array_equal(case.cleaned.root, case.slid.root)


def test_bones_keep_their_lengths_and_feet_their_orientation(case):
    sk = case.clean.skeleton
    pos, grot = fk(sk.parents, torch.from_numpy(case.cleaned.rotations), torch.from_numpy(case.cleaned.root),
                   torch.from_numpy(sk.offsets), return_global_rotations=True)
    _, grot0 = fk(sk.parents, torch.from_numpy(case.slid.rotations), torch.from_numpy(case.slid.root),
                  torch.from_numpy(sk.offsets), return_global_rotations=True)
    bones = (pos[:, 1:] - pos[:, sk.parents[1:]]).norm(dim=-1)
    assert torch.allclose(bones, torch.from_numpy(np.linalg.norm(sk.offsets[1:], axis=-1)).expand_as(bones),
                          atol=1e-9)
    assert np.allclose(np.linalg.norm(case.cleaned.rotations, axis=-1), 1.0, atol=1e-12)
    # ankles and toes turn with the foot as they did: only their place changes
    assert R.quat_angle(grot[:, case.idx], grot0[:, case.idx]).max() < 1e-9


def test_no_pop_at_segment_ends(case):
    def acceleration(m: Motion) -> np.ndarray:
        p = m.positions()
        return np.linalg.norm(p[2:] - 2 * p[1:-1] + p[:-2], axis=-1) * m.fps ** 2

    assert acceleration(case.cleaned).max() < 2.0 * acceleration(case.clean).max()


def test_knee_bends_about_its_own_hinge(case):
    """The knee's change is a turn about the hip-knee-ankle plane's normal, and that normal
    stays where it was in the thigh's frame."""
    sk = case.clean.skeleton

    def hinges(m: Motion) -> dict[int, torch.Tensor]:
        p, grot = fk(sk.parents, torch.from_numpy(m.rotations), torch.from_numpy(m.root),
                     torch.from_numpy(sk.offsets), return_global_rotations=True)
        return {leg.knee: R.quat_apply(R.quat_conjugate(grot[:, leg.hip]),
                                       torch.cross(p[:, leg.ankle] - p[:, leg.hip], p[:, leg.knee] - p[:, leg.hip],
                                                   dim=-1))
                for leg in find_legs(sk, case.joints)}

    before, after = hinges(case.slid), hinges(case.cleaned)
    for knee, hinge in before.items():
        turn = R.quat_multiply(torch.from_numpy(case.cleaned.rotations[:, knee]),
                               R.quat_conjugate(torch.from_numpy(case.slid.rotations[:, knee])))
        axis = R.quat_to_axis_angle(turn)
        moved = axis.norm(dim=-1) > 1e-4
        assert moved.sum() > 5
        unit = hinge / hinge.norm(dim=-1, keepdim=True)
        assert torch.cross(axis[moved], unit[moved], dim=-1).norm(dim=-1).max() < 1e-9
        assert (after[knee] / after[knee].norm(dim=-1, keepdim=True) - unit).norm(dim=-1).max() < 1e-9


def test_no_leg_is_stretched_beyond_the_limit(case):
    sk = case.clean.skeleton
    out = clean_contacts(case.slid, case.joints, case.contacts, max_stretch=0.9)
    p, p0 = positions(out), positions(case.slid)
    for leg in find_legs(sk, case.joints):
        full = np.linalg.norm(sk.offsets[leg.knee]) + np.linalg.norm(sk.offsets[leg.ankle])
        reach = (p[:, leg.ankle] - p[:, leg.hip]).norm(dim=-1)
        reach0 = (p0[:, leg.ankle] - p0[:, leg.hip]).norm(dim=-1)
        assert (reach <= torch.clamp(reach0, min=0.9 * full) + 1e-9).all()


def straightened(frames: slice) -> tuple[Motion, list[str], Leg]:
    """The CMU excerpt, slid, with the left knee straight over ``frames``; its contact
    joints and its left leg."""
    motion = bvh.load(DATA / CMU_120)
    spec = default_spec(motion.skeleton)
    clean = to_model_motion(motion, spec)
    sk = clean.skeleton
    (leg,) = [g for g in find_legs(sk, list(spec.contact_joints)) if sk.names[g.ankle] == "lFoot"]
    rot = clean.rotations.copy()
    shin = torch.from_numpy(sk.offsets[leg.ankle] / np.linalg.norm(sk.offsets[leg.ankle]))
    thigh = torch.from_numpy(sk.offsets[leg.knee] / np.linalg.norm(sk.offsets[leg.knee]))
    q = torch.cat((1 + (shin * thigh).sum(-1, keepdim=True), torch.cross(shin, thigh, dim=-1)))
    rot[frames, leg.knee] = R.quat_normalize(q).numpy()
    return slide(clean.with_frames(rot, clean.root), DRIFT), list(spec.contact_joints), leg


def test_a_straight_leg_bends_the_way_its_knee_does():
    straight, joints, leg = straightened(slice(30, 40))  # the left foot is planted there
    out = clean_contacts(straight, joints, np.ones((straight.num_frames, 2)))
    p = positions(out)
    assert torch.isfinite(p).all()
    # bent where it had to reach closer, and forward: the same side as the knee bends elsewhere
    normal = torch.cross(p[:, leg.ankle] - p[:, leg.hip], p[:, leg.knee] - p[:, leg.hip], dim=-1)
    ref = normal[:30].mean(0)
    bent = normal[30:40].norm(dim=-1) > 1e-4
    assert bent.any()
    assert ((normal[30:40][bent] * ref).sum(-1) > 0).all()


def test_a_leg_straight_throughout_is_refused_when_it_must_bend():
    straight, joints, _ = straightened(slice(None))
    with pytest.raises(ValueError, match="straight in every frame"):
        clean_contacts(straight, joints, np.ones((straight.num_frames, 2)))


@pytest.mark.parametrize("joints, contacts, error", [
    (["lFoot", "rFoot"], np.ones((60, 3)), "contacts must be"),
    (["lFoot", "nose"], np.ones((60, 2)), "not in the skeleton"),
    (["lFoot", "abdomen"], np.ones((60, 2)), "needs a knee and a hip"),
    (["lHand", "neck"], np.ones((60, 2)), "share joints"),
])
def test_errors_say_what_to_pass(joints, contacts, error):
    motion = bvh.load(DATA / CMU_120)
    clean = to_model_motion(motion, default_spec(motion.skeleton))
    with pytest.raises((ValueError, KeyError), match=error):
        clean_contacts(clean, joints, contacts)


@pytest.mark.parametrize("max_rise", [0.03, 0.0])
def test_a_foot_far_out_of_reach_slides_instead_of_kicking_up(case, max_rise):
    """A body that runs on at 3 m/s leaves its planted feet a stride behind: the leg may
    lift such a foot by ``max_rise`` at most, not up towards the hip."""
    fast = slide(case.clean, np.array([3.0, 0.0, 0.0]))
    cleaned = clean_contacts(fast, case.joints, case.contacts, max_rise=max_rise)
    rise = positions(cleaned)[:, case.idx, 1] - positions(fast)[:, case.idx, 1]
    below = torch.relu(torch.from_numpy(metrics.rest_heights(positions(fast), case.idx).numpy())
                       - positions(fast)[:, case.idx, 1])  # the plane lifts a foot below it anyway
    assert float((rise - below).max()) <= max_rise + 0.005
    with pytest.raises(ValueError, match="max_rise"):
        clean_contacts(fast, case.joints, case.contacts, max_rise=-0.01)
