"""MAP objective terms: float64 gradients (gradcheck) through real poses, the nearest-point
path distance, window decoding against whole-clip decoding, and non-finite terms."""
from __future__ import annotations

import functools

import numpy as np
import pytest
import torch

from motionopt import bvh
from motionopt import rotations as R
from motionopt.features import RootStart, advance, decode, decode_positions, encode, to_model_motion
from motionopt.kinematics import fk_matrices
from motionopt.objective import (ContactTerm, FloorTerm, JointPositionTerm, MAPObjective, NonFiniteTermError, PathTerm,
                                 PoseFidelityTerm, SkatingTerm, SmoothnessTerm, SupportTerm, WindowState,
                                 nearest_on_polyline_sq)

from priorkit import cmu_clips, features, tiny_prior

LEAD, T = 2, 5          # solved frames before the window, window frames
FIRST = 10              # global index of the window's first frame


@functools.lru_cache(maxsize=None)
def clip_pose():
    """Real local rotations (as rotation vectors) and root positions of LEAD + T frames of a
    CMU excerpt, float64, with the model skeleton's parents and offsets."""
    prior = tiny_prior()
    x = features(cmu_clips()[0])[FIRST - LEAD:FIRST + T].double()
    raw = prior.normalizer.denormalize(x)
    quats, root = decode(raw, prior.spec)
    return R.quat_to_axis_angle(quats), root, prior.skeleton


def state_of(aa: torch.Tensor, root: torch.Tensor, contacts: torch.Tensor | None = None) -> WindowState:
    """A window state (float64) of rotation vectors (LEAD+T, J, 3) and root (LEAD+T, 3)."""
    _, _, sk = clip_pose()
    rot = R.axis_angle_to_matrix(aa)
    pos = fk_matrices(sk.parents, rot, root, torch.as_tensor(sk.offsets, dtype=aa.dtype))
    if contacts is None:
        contacts = torch.ones(T, 2, dtype=aa.dtype)
    return WindowState(np.arange(FIRST, FIRST + T), LEAD, torch.zeros(T, 4, dtype=aa.dtype), rot, root, pos,
                       contacts, torch.zeros(T, dtype=aa.dtype), 30.0)


def real_targets():
    """Targets near the clip: its own root path and poses, moved a little."""
    aa, root, sk = clip_pose()
    rng = np.random.default_rng(0)
    n = FIRST + T + 3
    root_t = np.zeros((n, 3))
    root_t[FIRST - LEAD:FIRST + T] = root.numpy() + rng.normal(0, 0.02, (LEAD + T, 3))
    rot_t = np.tile([1.0, 0, 0, 0], (n, aa.shape[1], 1))
    noisy = aa + torch.from_numpy(rng.normal(0, 0.05, aa.shape))
    rot_t[FIRST - LEAD:FIRST + T] = R.axis_angle_to_quat(noisy).numpy()
    return root_t, rot_t


def terms():
    aa, root, sk = clip_pose()
    root_t, rot_t = real_targets()
    xz = root[LEAD:, [0, 2]].numpy()
    # a bent path passing near (not through) the clip's root path, longer than the window
    path = np.stack([xz[0] + [0.03, -0.2], xz[2] + [-0.04, 0.01], xz[-1] + [0.05, 0.3]])
    timed = np.zeros((FIRST + T + 3, 2))
    timed[FIRST:FIRST + T] = xz + 0.05
    mask = np.zeros(FIRST + T + 3, bool)
    mask[FIRST + 1:FIRST + 4] = True
    keyframe = np.zeros(FIRST + T + 3, bool)
    keyframe[FIRST + 2] = True
    hand = sk.names.index("rHand")
    feet = [sk.names.index("rFoot"), sk.names.index("lFoot")]
    pos = fk_matrices(sk.parents, R.axis_angle_to_matrix(aa), root, torch.as_tensor(sk.offsets, dtype=aa.dtype))
    foot_heights = pos[LEAD:, feet, 1].mean(0).numpy()
    return {
        "path nearest-point": PathTerm(path, sigma=0.05),
        "path timed": PathTerm(path, sigma=0.3, targets=timed, mask=mask),
        "path with a free band": PathTerm(path, sigma=0.05, width=0.02),
        "pose fidelity": PoseFidelityTerm(root_t, rot_t, 0.02, 0.05, mask=mask),
        "pose fidelity, some joints": PoseFidelityTerm(None, rot_t, 0.02, 0.05, joints=[0, 3, 7]),
        "pose fidelity, one tight keyframe": PoseFidelityTerm(root_t, rot_t, 0.005, 0.01, mask=keyframe),
        "joint position": JointPositionTerm(hand, {FIRST + 1: np.array([0.1, 1.2, 0.3]),
                                                  FIRST + 4: np.array([0.0, 1.0, 0.2])}, sigma=0.01),
        "contact": ContactTerm([sk.names.index("rFoot"), sk.names.index("lFoot")], np.array([0.05, 0.06])),
        "smoothness": SmoothnessTerm(10.0),
        # planted heights at the feet's own mean height: the gate is neither 0 nor 1
        "skating": SkatingTerm(feet, foot_heights, softness=0.02),
        "support": SupportTerm(feet, foot_heights - 0.02),
        # planted heights above the feet's mean height: some frames are below the floor
        "floor": FloorTerm(feet, foot_heights + 0.01),
        "smoothness, one sigma per joint": SmoothnessTerm(list(np.linspace(4.0, 20.0, sk.num_joints))),
    }


def test_the_path_terms_free_band_costs_only_the_distance_beyond_it():
    """Within ``width`` of the path the root sways freely; 3 cm off with a 2 cm band costs
    what 1 cm off costs without one."""
    path = np.array([[0.0, 0.0], [0.0, 10.0]])

    def energy(term: PathTerm, off: float) -> float:
        root = torch.zeros(1, 3, dtype=torch.float64)
        root[0, 0], root[0, 2] = off, 5.0
        state = WindowState(np.arange(1), 0, torch.zeros(1, 4), torch.zeros(0), root, torch.zeros(1, 2, 3),
                            torch.zeros(1, 2), torch.zeros(1), 30.0)
        return float(term.energy(state))

    banded, plain = PathTerm(path, sigma=0.01, width=0.02), PathTerm(path, sigma=0.01)
    assert energy(banded, 0.015) == pytest.approx(0.0, abs=1e-9)
    assert energy(banded, -0.03) == pytest.approx(energy(plain, 0.01), rel=1e-4) == pytest.approx(0.5, rel=1e-4)


def test_per_joint_acceleration_sigmas_weigh_each_joint_alone():
    """The same sigma for every joint is the scalar term; a joint whose sigma doubles
    pays a quarter of its share."""
    aa, root, _ = clip_pose()
    state = state_of(aa, root, torch.zeros(5, 2, dtype=torch.float64))
    n = state.positions.shape[-2]
    scalar = SmoothnessTerm(10.0).energy(state)
    assert torch.allclose(SmoothnessTerm([10.0] * n).energy(state), scalar)
    alone = [SmoothnessTerm([10.0 if j == k else 1e9 for j in range(n)]).energy(state) for k in range(n)]
    assert torch.allclose(sum(alone), scalar)
    doubled = SmoothnessTerm([20.0 if j == 3 else 10.0 for j in range(n)]).energy(state)
    assert torch.allclose(doubled, scalar - 0.75 * alone[3])


@pytest.mark.parametrize("name", list(terms()))
def test_term_gradients_gradcheck_float64(name):
    term = terms()[name]
    aa, root, _ = clip_pose()
    contacts = torch.tensor([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0], [0.0, 0.0]], dtype=torch.float64)

    def energy(a, r):
        return term.energy(state_of(a, r, contacts))

    a = aa.clone().requires_grad_()
    r = root.clone().requires_grad_()
    assert energy(a, r).item() > 0
    assert torch.autograd.gradcheck(energy, (a, r), eps=1e-6, atol=1e-5, rtol=1e-4)


def test_terms_batch_like_single_windows():
    """A batch of windows (as the particle swarm evaluates) gives each window's own energy."""
    aa, root, _ = clip_pose()
    other = aa + 0.05
    batch = state_of(torch.stack((aa, other)), torch.stack((root, root + 0.1)))
    for name, term in terms().items():
        both = term.energy(batch)
        one = torch.stack((term.energy(state_of(aa, root)), term.energy(state_of(other, root + 0.1))))
        torch.testing.assert_close(both, one, msg=name)


def test_window_cache_follows_the_frames():
    """Targets cached for one window are not reused for another."""
    aa, root, _ = clip_pose()
    term = terms()["pose fidelity"]
    first = term.energy(state_of(aa, root))
    shifted = state_of(aa, root)
    shifted.frames = shifted.frames + 1
    fresh = terms()["pose fidelity"]
    torch.testing.assert_close(term.energy(shifted), fresh.energy(shifted))
    assert not torch.equal(term.energy(shifted), first)


def brute_force_nearest_sq(points: np.ndarray, path: np.ndarray) -> np.ndarray:
    best = np.full(len(points), np.inf)
    for a, b in zip(path[:-1], path[1:]):
        for i, p in enumerate(points):
            for t in np.linspace(0, 1, 2001):
                best[i] = min(best[i], float(((a + t * (b - a) - p) ** 2).sum()))
    return best


def test_nearest_on_polyline_matches_brute_force():
    rng = np.random.default_rng(3)
    path = np.cumsum(rng.normal(0, 1, (5, 2)), axis=0)
    points = rng.normal(0, 2, (12, 2))
    got = nearest_on_polyline_sq(torch.from_numpy(points), torch.from_numpy(path)).numpy()
    want = brute_force_nearest_sq(points, path)
    np.testing.assert_array_less(got, want + 1e-12)
    np.testing.assert_allclose(got, want, atol=1e-4)


def test_window_state_decodes_like_the_whole_clip():
    """Positions of a window decoded after its lead frames from an advanced root state equal
    the positions of the same frames decoded from the clip's start."""
    prior = tiny_prior()
    x = features(cmu_clips()[0])[:60]
    _, start = encode(to_model_motion(bvh.load(cmu_clips()[0]), prior.spec), prior.spec)
    norm = prior.normalizer
    s, e = 30, 50
    obj = MAPObjective(prior, prior.skeleton, [])
    state_before_lead = advance(start, norm.denormalize(x[:s - LEAD].double()), prior.spec)
    st = obj.window_state(x[s:e], np.arange(s, e), x[:s], norm.denormalize(x[s - LEAD:s].double()).float(),
                          state_before_lead)
    whole = decode_positions(norm.denormalize(x.double()), prior.spec, prior.skeleton, start)
    # float32 window against the float64 whole clip: 0.1 mm
    torch.testing.assert_close(st.positions.double(), whole[s - LEAD:e], atol=1e-4, rtol=0)
    assert st.prior_nll.shape == (e - s,) and torch.isfinite(st.prior_nll).all()


def test_non_finite_term_names_the_term():
    aa, root, _ = clip_pose()
    root_t, rot_t = real_targets()
    root_t[FIRST + 2, 1] = np.nan
    term = PoseFidelityTerm(root_t, None, name="bad_target")
    assert not torch.isfinite(term.energy(state_of(aa, root)))
    err = NonFiniteTermError("bad_target", "in frames 10-14")
    assert "'bad_target'" in str(err) and "10-14" in str(err) and err.term == "bad_target"


def test_fidelity_needs_a_target():
    with pytest.raises(ValueError, match="root or rotation"):
        PoseFidelityTerm(None, None)


def test_path_needs_two_points():
    with pytest.raises(ValueError, match="at least 2 points"):
        PathTerm(np.zeros((1, 2)))


def test_raw_floor_bounds_the_prior_on_near_constant_features():
    """Rotation noise on entries that barely vary in the data costs the prior far less with
    the floor in the features' own units, and still far more than clean motion."""
    prior = tiny_prior()
    x = features(cmu_clips()[0])[:40]
    std = prior.normalizer.std[:prior.spec.pose_dim]
    noisy = x.clone()
    gen = torch.Generator().manual_seed(0)
    noisy[:, 4:prior.spec.pose_dim] += 0.02 * torch.randn(40, prior.spec.pose_dim - 4, generator=gen) / std[4:].float()
    nll = {}
    for raw in (None, 0.01):
        obj = MAPObjective(prior, prior.skeleton, [], prior_min_std_raw=raw)
        for name, seq in (("clean", x), ("noisy", noisy)):
            st = obj.window_state(seq[10:], np.arange(10, 40), seq[:10], torch.zeros(0, x.shape[1]), RootStart())
            nll[name, raw] = float(st.prior_nll.detach().sum())
    assert nll["noisy", 0.01] - nll["clean", 0.01] < 0.1 * (nll["noisy", None] - nll["clean", None])
    assert nll["noisy", 0.01] - nll["clean", 0.01] > 30 * 20     # 20 nats per frame at least
    floor = MAPObjective(prior, prior.skeleton, [])._log_std_floor()
    torch.testing.assert_close(floor[4:], torch.log(0.01 / std[4:]).clamp_min(-2.5).float())
    assert torch.equal(floor[:4], torch.full((4,), -2.5))


def test_skating_term_costs_a_gliding_foot_on_the_floor_not_one_planted_or_clear_of_it():
    """One foot glides at 2 m/s: it costs about (2 / sigma)^2 / 2 per frame at its planted height,
    nothing held still there, and almost nothing 10 cm up, where it swings clear."""
    T_, fps = 6, 30.0
    term = SkatingTerm([0], np.array([0.05]), sigma_speed=0.5)

    def state(height: float, speed: float) -> WindowState:
        pos = torch.zeros(T_ + 1, 1, 3, dtype=torch.float64)
        pos[:, 0, 1] = height
        pos[:, 0, 0] = torch.arange(T_ + 1) * speed / fps
        return WindowState(np.arange(1, T_ + 1), 1, torch.zeros(T_, 4), torch.zeros(0), torch.zeros(0), pos,
                           torch.zeros(T_, 1), torch.zeros(T_), fps)

    gate = 1 / (1 + np.exp(-term.band / term.softness))    # at the planted height itself
    assert float(term.energy(state(0.05, 2.0))) == pytest.approx(gate * T_ * (2.0 / 0.5) ** 2 / 2, rel=1e-6)
    assert float(term.energy(state(0.05, 0.0))) == 0.0
    assert float(term.energy(state(0.15, 2.0))) < 1e-6 * T_ * 8



def two_feet(h0: float, h1: float) -> WindowState:
    """A window of frames 1-3 (one lead frame) whose two contact joints stand at heights
    ``h0`` and ``h1`` (m)."""
    pos = torch.zeros(4, 2, 3, dtype=torch.float64)
    pos[:, 0, 1], pos[:, 1, 1] = h0, h1
    return WindowState(np.arange(1, 4), 1, torch.zeros(3, 4), torch.zeros(0), torch.zeros(0), pos,
                       torch.zeros(3, 2), torch.zeros(3), 30.0)


def test_support_term_costs_only_frames_with_no_foot_on_the_floor():
    """Two feet: one on the floor costs (about) nothing whatever the other does; both 6 cm
    up cost (0.06 / sigma)^2 / 2 per frame, less the soft minimum's few millimetres."""
    term = SupportTerm([0, 1], np.array([0.05, 0.05]), sigma=0.03, softness=0.001)
    state = two_feet

    assert float(term.energy(state(0.05, 0.5))) < 1e-6
    assert float(term.energy(state(0.11, 0.11))) == pytest.approx(3 * 2.0, rel=0.05)
    with pytest.raises(ValueError, match="positive sigma"):
        SupportTerm([0], np.zeros(1), sigma=0.0)

    # planted_only: only the frames where the solve's start planted some foot
    gated = SupportTerm([0, 1], np.array([0.05, 0.05]), sigma=0.03, softness=0.001, planted_only=True)
    up = state(0.11, 0.11)
    assert float(gated.energy(up)) == 0.0                          # no foot planted at the start: a flight
    up.contacts[1, 0] = 1.0                                        # one frame planted its first foot
    assert float(gated.energy(up)) == pytest.approx(2.0, rel=0.05)
    # mask: only the global frames it names (the window holds frames 1-3)
    masked = SupportTerm([0, 1], np.array([0.05, 0.05]), sigma=0.03, softness=0.001,
                         mask=np.array([True, False, True, False, False]))
    assert float(masked.energy(state(0.11, 0.11))) == pytest.approx(2.0, rel=0.05)
    assert not SupportTerm([0], np.zeros(1), mask=np.array([True, False, False])).active(np.arange(1, 3))


def test_support_term_measures_every_joint_from_the_floor_not_its_own_planted_height():
    """An ankle (planted 8 cm up) at its planted height with the toe (planted on the floor)
    5 cm up is a heel stand, not support: it costs the toe's 5 cm. The toe on the floor
    with the ankle raised (heel-off) costs nothing. Measured per joint, the heel stand
    is support."""
    term = SupportTerm([0, 1], np.array([0.08, 0.0]), sigma=0.01, softness=0.001)
    state = two_feet    # (ankle, toe)

    assert float(term.energy(state(0.08, 0.05))) == pytest.approx(3 * (0.05 / 0.01) ** 2 / 2, rel=0.05)
    assert float(term.energy(state(0.15, 0.0))) < 1e-6
    per_joint = SupportTerm([0, 1], np.array([0.08, 0.0]), sigma=0.01, softness=0.001, from_floor=False)
    assert float(per_joint.energy(state(0.08, 0.05))) < 1e-6     # each joint from its own planted height


def test_floor_term_costs_each_joint_below_its_planted_height_and_nothing_above():
    """A joint 2 cm below its planted height costs (0.02 / sigma)^2 / 2 per frame, one at
    or above it nothing: a swinging foot may rise, none may go through the floor."""
    term = FloorTerm([0, 1], np.array([0.05, 0.10]), sigma=0.01)
    pos = torch.zeros(4, 2, 3, dtype=torch.float64)
    pos[:, 0, 1], pos[:, 1, 1] = 0.03, 0.30
    state = WindowState(np.arange(1, 4), 1, torch.zeros(3, 4), torch.zeros(0), torch.zeros(0), pos,
                        torch.zeros(3, 2), torch.zeros(3), 30.0)
    assert float(term.energy(state)) == pytest.approx(3 * 2.0)
    pos[:, 0, 1] = 0.05
    assert float(term.energy(state)) == 0.0
    with pytest.raises(ValueError, match="positive sigma"):
        FloorTerm([0], np.zeros(1), sigma=0.0)
