"""The parts the editing tasks are built from, on a real clip: clamped rollouts, root
features, noise estimation and per-joint filtering, limb IK, in-betweening metrics."""
from __future__ import annotations


import numpy as np
import pytest
import torch

from motionopt import bvh
from motionopt import rotations as R
from motionopt.features import decode, encode, to_model_motion
from motionopt.metrics import l2p, l2q, npss
from motionopt.smoothing import butterworth, constant, denoising_family, least_risk, savitzky_golay
from problems.common import TermSigmas, clamped_rollout, planted_contacts, root_features, standard_terms
from problems.denoise import estimate_noise, low_pass
from problems.edit import reach
from problems.inbetween import velocity_handoff

from priorkit import assert_kept_the_best_sound_start, cmu_clips, tiny_prior
from clips import CMU_120, DATA



@pytest.fixture(scope="module")
def walk():
    prior = tiny_prior()
    clip = next(p for p in sorted(DATA.glob("cmu-*.bvh")))
    return prior, to_model_motion(bvh.load(clip), prior.spec)


def test_root_features_are_what_decoding_integrates(walk):
    prior, m = walk
    raw, start = encode(m, prior.spec)
    yaw = start.yaw + np.cumsum(raw[:, 2].numpy())
    f = root_features(m.root[:, [0, 2]], yaw)
    assert np.allclose(f, raw[1:, :3].numpy(), atol=1e-6)


def test_clamped_rollout_holds_the_clamped_channels_and_decodes_onto_the_path(walk):
    prior, m = walk
    raw, start = encode(m, prior.spec)
    x = prior.normalizer.normalize(raw).float()
    n = 12
    pts = np.cumsum(np.full((n + 1, 2), 0.03), axis=0) + m.root[19, [0, 2]]
    yaw = np.linspace(0.0, 0.5, n + 1)
    clamp = torch.from_numpy(root_features(pts, yaw))
    new = clamped_rollout(prior, x[:20], clamp, slice(0, 3), 0.5, torch.Generator().manual_seed(0))
    back = prior.normalizer.denormalize(new.double())
    assert torch.allclose(back[:, :3], clamp, atol=1e-5)
    _, root = decode(back, prior.spec, type(start)(0.0, pts[0, 0], pts[0, 1], start.ground))
    assert np.allclose(root[:, [0, 2]].numpy(), pts[1:], atol=1e-4)


def noisy(m, s: float, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    q = torch.from_numpy(m.rotations)
    turn = R.axis_angle_to_quat(torch.randn(q.shape[:-1] + (3,), generator=g, dtype=q.dtype) * s)
    return m.with_frames(R.quat_multiply(q, turn).numpy(), m.root.copy(), m.translations)


@pytest.mark.parametrize("s", [0.01, 0.04])
def test_noise_level_is_recovered_from_the_clip_alone(walk, s):
    _, m = walk
    est, _ = estimate_noise(noisy(m, s))
    assert abs(est - s) < 0.25 * s


def test_per_joint_low_pass_brings_a_noisy_clip_nearer_the_clean_one(walk):
    _, m = walk
    nz = noisy(m, 0.03)
    clean, before = m.positions(), nz.positions()
    smoothed, chosen = low_pass(nz, None, *estimate_noise(nz))
    err = lambda p: np.linalg.norm(p - clean, axis=-1).mean()  # noqa: E731
    assert err(smoothed.positions()) < 0.7 * err(before)
    assert set(chosen) == {*m.skeleton.names, "root"}


def test_risk_picks_more_smoothing_for_more_noise():
    t = np.arange(120) / 30.0
    signal = np.sin(2 * np.pi * 1.5 * t)[:, None, None]
    rng = np.random.default_rng(0)
    family = denoising_family(30.0)
    (low,) = least_risk(signal + 0.02 * rng.standard_normal(signal.shape), 0.02, family)
    (high,) = least_risk(signal + 0.3 * rng.standard_normal(signal.shape), 0.3, family)
    assert high.trace(120) < low.trace(120)


def test_a_joint_that_does_not_move_is_held_at_its_mean_and_a_moving_one_is_not():
    """Noise alone (Bandai's static ground joint, noised) picks the constant, whose risk
    counts one degree of freedom; a 1.5 Hz movement under the same noise never does."""
    rng = np.random.default_rng(1)
    t = np.arange(120) / 30.0
    family = denoising_family(30.0)
    still = 0.3 + 0.02 * rng.standard_normal((120, 1, 3))
    moving = np.sin(2 * np.pi * 1.5 * t)[:, None, None] + 0.02 * rng.standard_normal((120, 1, 3))
    (a,), (b,) = least_risk(still, 0.02, family), least_risk(moving, 0.02, family)
    assert a.label == constant().label != b.label
    assert np.allclose(a.apply(still[:, 0]), still[:, 0].mean(axis=0))


@pytest.mark.parametrize("smoother", [butterworth(4.0, 30.0), savitzky_golay(11, 3), constant()],
                         ids=lambda s: s.label)
@pytest.mark.parametrize("n", [40, 700])
def test_smoother_trace_matches_its_matrix(smoother, n):
    """The trace from a short matrix equals the full one, also for clips longer than it."""
    assert smoother.trace(n) == pytest.approx(np.trace(smoother.apply(np.eye(n))), rel=1e-9)


def test_reach_meets_a_target_with_the_limb_above_the_joint(walk):
    prior, m = walk
    j = m.skeleton.index(prior.spec.joints[8])  # a hand or wrist: three joints below the spine
    f = 10
    target = m.positions()[f, j] + np.array([0.05, 0.1, 0.0])
    turns = reach(m.skeleton, m.rotations[f], m.root[f], j, target)
    q = R.quat_multiply(torch.from_numpy(m.rotations[f]), R.axis_angle_to_quat(torch.from_numpy(turns)))
    moved = m.with_frames(np.repeat(q.numpy()[None], m.num_frames, 0), m.root.copy(), None).positions()[f]
    assert np.linalg.norm(moved[j] - target) < 1e-3
    untouched = [k for k in range(m.skeleton.num_joints) if not np.any(turns[k])]
    assert 0 in untouched and np.count_nonzero(np.abs(turns).sum(1)) <= 3


def test_inbetweening_metrics_are_zero_on_the_truth_and_grow_with_the_error():
    g = torch.Generator().manual_seed(0)
    pos = torch.randn(2, 15, 5, 3, generator=g)
    q = R.quat_normalize(torch.randn(2, 15, 5, 4, generator=g))
    assert float(l2p(pos, pos).max()) == 0.0
    assert float(l2q(-q, q).max()) < 1e-6  # q and -q are the same rotation
    assert float(l2p(pos + 0.1, pos).mean()) < float(l2p(pos + 0.2, pos).mean())
    seq = torch.sin(torch.linspace(0, 6, 30))[None, :, None].expand(1, 30, 4)
    assert float(npss(seq, seq)) < 1e-6
    jitter = seq + 0.3 * torch.randn(1, 30, 4, generator=g)
    assert float(npss(jitter, seq)) > 0.01


def test_velocity_handoff_continues_the_kept_joint_velocities_then_leaves_the_prior_alone(walk):
    """Frame 1 of a gap is the last kept frames' constant-velocity step; after the hand-off
    the synthesised rotations are untouched."""
    _, m = walk
    a, k = 20, 30
    before = m.rotations[a - 2:a]
    synth = m.rotations[a + 5:a + 5 + k]  # a jump away from the kept frames
    q = velocity_handoff(synth, before, m.fps, seconds=0.25)
    step = R.quat_multiply(R.quat_conjugate(torch.from_numpy(before[0])), torch.from_numpy(before[1]))
    expected = R.quat_multiply(torch.from_numpy(before[1]), step).numpy()
    assert np.allclose(np.abs((q[0] * expected).sum(-1)), 1.0, atol=1e-6)
    after = int(np.ceil(0.25 * m.fps)) + 1
    assert np.allclose(np.abs((q[after:] * synth[after:]).sum(-1)), 1.0)
    assert not np.allclose(np.abs((q[1:after - 1] * synth[1:after - 1]).sum(-1)), 1.0)


def test_denoise_cleans_every_joint_at_the_files_rate():
    """A 120 fps clip with fingers comes back at 120 fps with every joint cleaned: the
    joints the prior does not model (fingers, eyes) are filtered too, not copied noisy."""
    from motionopt.noise import capture_noise
    from priors.checkpoint import CHECKPOINT_DIR, load_prior_cached
    from problems.denoise import Denoise

    clean = bvh.load(DATA / CMU_120)
    noisy = capture_noise(clean, np.radians(2.0), 0.01, seed=0)
    out = Denoise(noisy, load_prior_cached(CHECKPOINT_DIR / "cmu-ccnet.pt")).solve().motion
    assert out.fps == clean.fps and out.num_frames == clean.num_frames and out.skeleton.names == clean.skeleton.names
    prior_joints = set(load_prior_cached(CHECKPOINT_DIR / "cmu-ccnet.pt").spec.joints)
    others = [j for j, n in enumerate(clean.skeleton.names) if n not in prior_joints]
    assert len(others) > 10
    p, pn, po = clean.positions(), noisy.positions(), out.positions()

    def err(a: np.ndarray, joints) -> float:
        return float(np.linalg.norm(a[:, joints] - p[:, joints], axis=-1).mean())

    assert err(po, others) < 0.6 * err(pn, others)
    every = list(range(clean.skeleton.num_joints))
    assert err(po, every) < 0.6 * err(pn, every)


def test_a_change_from_the_prior_carries_over_to_the_files_skeleton_and_rate():
    from motionopt import rotations as R
    from problems.denoise import with_change

    clip = bvh.load(DATA / CMU_120)
    prior = tiny_prior()
    model = to_model_motion(clip, prior.spec)
    assert np.allclose(with_change(clip, model, model).rotations, clip.rotations, atol=1e-6)
    raised = model.with_frames(model.rotations, model.root + np.array([0.0, 0.1, 0.0]))
    moved = with_change(clip, model, raised)
    assert np.allclose(moved.positions() - clip.positions(), [0.0, 0.1, 0.0], atol=1e-4)
    knee = model.skeleton.names.index("lShin")
    bend = R.axis_angle_to_quat(torch.tensor([0.3, 0.0, 0.0], dtype=torch.float64)).numpy()
    rot = model.rotations.copy()
    rot[:, knee] = R.quat_multiply(torch.from_numpy(rot[:, knee]), torch.from_numpy(bend).expand(len(rot), 4)).numpy()
    bent = with_change(clip, model, model.with_frames(rot, model.root))
    j = clip.skeleton.names.index("lShin")
    turn = R.quat_multiply(R.quat_conjugate(torch.from_numpy(clip.rotations[:, j])), torch.from_numpy(bent.rotations[:, j]))
    assert np.allclose(np.abs(turn.numpy()), np.abs(bend), atol=1e-5)


def test_the_hips_under_a_ground_joint_keep_the_files_position():
    """A Bandai file's hips hang under the ground joint joint_Root: the solve's turns carry
    over, its move of the hips does not (it ended further from the clean clip than the filter's)."""
    from priors.checkpoint import CHECKPOINT_DIR, load_prior_cached
    from problems.denoise import with_change

    from clips import shared_excerpt
    clip = shared_excerpt("bandai/dataset-1_walk-left_feminine_001.bvh", 0, 60)
    prior = load_prior_cached(CHECKPOINT_DIR / "bandai-locomotion-ccnet.pt")
    model = to_model_motion(clip, prior.spec)
    assert clip.skeleton.names[0] == "joint_Root" and model.skeleton.names[0] == "Hips"
    raised = model.with_frames(model.rotations, model.root + np.array([0.0, 0.1, 0.0]))
    assert np.allclose(with_change(clip, model, raised).positions(), clip.positions(), atol=1e-6)


def test_denoise_by_default_solves_under_the_prior_and_beats_the_filter_it_starts_from():
    """The default denoising runs the MAP solve from the per-joint filter: on a real walk
    the prior never saw, with 3 cm of rotation noise it ends nearer the clean clip than the filter alone
    (--no-refine), with less foot sliding, and its report shows the solve."""
    from motionopt.metrics import foot_skating
    from motionopt.noise import position_noise
    from priors.checkpoint import CHECKPOINT_DIR, load_prior_cached
    from problems.denoise import Denoise

    from clips import shared_excerpt
    prior = load_prior_cached(CHECKPOINT_DIR / "bandai-locomotion-ccnet.pt")   # a clip it never saw
    clean = to_model_motion(shared_excerpt("bandai/dataset-1_walk-left_feminine_001.bvh", 0, 90), prior.spec)
    noisy, _ = position_noise(clean, 0.03, seed=1)
    ours, filtered = Denoise(noisy, prior).solve(), Denoise(noisy, prior, refine=False).solve()
    assert filtered.solver is None and ours.solver is not None and "solver" in ours.report()

    def err(m) -> float:
        return float(np.linalg.norm(m.positions() - clean.positions(), axis=-1).mean())

    def skate(m) -> float:
        return float(foot_skating(torch.from_numpy(m.positions()), prior.spec.fps, prior.spec.contact_indices()))

    assert err(ours.model_motion) < 0.97 * err(filtered.model_motion)
    assert skate(ours.model_motion) < skate(filtered.model_motion)


def test_a_glitch_turns_one_joint_about_its_main_axis_for_the_frames_asked(walk):
    from motionopt.noise import glitch, main_axis

    _, m = walk
    knee = 5
    g = glitch(m, knee, 10, 8, 30.0)
    angle = R.quat_angle(torch.from_numpy(m.rotations), torch.from_numpy(g.rotations)).numpy()
    assert np.allclose(angle[10:18, knee], np.radians(30.0), atol=1e-5)
    angle[10:18, knee] = 0.0
    assert np.abs(angle).max() < 1e-5 and np.array_equal(g.root, m.root)
    # a joint swung about one axis: that axis is its main one
    axis = np.array([0.6, 0.0, 0.8])
    swing = np.sin(np.linspace(0, 6, m.num_frames))[:, None] * axis
    q = m.rotations.copy()
    q[:, knee] = R.axis_angle_to_quat(torch.from_numpy(swing)).numpy()
    assert abs(np.dot(main_axis(m.with_frames(q, m.root, m.translations), knee), axis)) > 0.999
    with pytest.raises(ValueError, match="outside"):
        glitch(m, knee, m.num_frames - 2, 8)


def test_a_closed_loop_or_a_path_walked_twice_is_joined_at_its_start():
    """A loop that ends where it starts passes the seed's end twice; it is walked from
    its start, so the whole loop is synthesised (not one frame, as when the nearest point
    was taken at the loop's end)."""
    from problems.path_follow import arc_length_of_nearest

    square = np.array([[0, 0], [3, 0], [3, 3], [0, 3], [0, 0]], float)
    assert arc_length_of_nearest(square, np.array([0.02, -0.01])) == pytest.approx(0.02)
    twice = np.concatenate((square, square[1:]))
    assert arc_length_of_nearest(twice, np.array([0.0, 0.0])) == pytest.approx(0.0)
    # a path that starts away from the seed is still joined where it passes nearest
    assert arc_length_of_nearest(square, np.array([3.5, 1.5])) == pytest.approx(4.5)


def test_denoising_a_120_fps_capture_ends_nearer_the_clean_one_than_its_filter():
    """A 120 fps file: the MAP solve at the prior's 30 fps holds to the file low-passed below
    that rate (``fidelity_target``), not to one noisy frame in four, so every joint of the
    file at 120 fps ends nearer the clean capture than the filter it starts from."""
    from motionopt.noise import position_noise
    from priors.checkpoint import CHECKPOINT_DIR, load_prior_cached
    from problems.denoise import Denoise

    from clips import shared_excerpt
    prior = load_prior_cached(CHECKPOINT_DIR / "cmu-ccnet.pt")            # indian/14 is held out of it
    clean = shared_excerpt("cmu/indian/14.bvh", 0, 360)
    noisy, _ = position_noise(clean, 0.03, seed=0)
    ours, filtered = Denoise(noisy, prior).solve(), Denoise(noisy, prior, refine=False).solve()
    assert ours.motion.fps == 120 and ours.settings["fidelity_noise_scale"] < 0.5

    def err(m) -> float:
        return float(np.linalg.norm(m.positions() - clean.positions(), axis=-1).mean())

    assert err(ours.motion) < 0.99 * err(filtered.motion) < 0.5 * err(noisy)   # plain resampling: 1.45 times


def test_the_support_terms_frames_are_named_and_checked():
    with pytest.raises(ValueError, match="support_where must be one of all, planted, expected"):
        TermSigmas(support=0.005, support_where="floor")
    with pytest.raises(ValueError, match="needs the solve's start"):
        standard_terms(None, tiny_prior(), TermSigmas(support=0.005, support_where="expected"))


def test_the_foot_ik_plants_only_feet_near_their_planted_height():
    """A foot the prior calls planted while it swings 10 cm up is left free; one near the
    floor keeps the prior's probability, and one near the floor and still is planted
    whatever the prior says."""
    t = 40
    pos = np.zeros((t, 2, 3))
    pos[:, 0, 0], pos[:, 0, 1] = np.arange(t) * 0.1, 0.10   # joint 0 swings 10 cm up at 3 m/s
    pos[:, 1, 0] = np.where(np.arange(t) < 20, 0.0, np.arange(t) * 0.1)  # joint 1 still, then sliding 3 m/s
    pos[:, 1, 1] = 0.01
    prob = np.full((t, 2), 0.7)
    contacts = planted_contacts(prob, pos, [0, 1], np.zeros(2), height=0.05, fps=30.0, slow=1.0)
    assert np.all(contacts[:, 0] == 0.0)
    assert np.all(contacts[:19, 1] == 1.0) and np.allclose(contacts[21:, 1], 0.7)


def test_completion_solves_from_several_rollouts_and_keeps_the_lowest_objective():
    """Prefix completion starts its solve from COMPLETION_ROLLOUT_STARTS rollouts of
    different noise and keeps the lowest objective among the results with the fewest
    seconds outside the range of human motion: never above the solve from the first
    rollout alone unless that one has more, and the prefix is the input's."""
    from problems.inbetween import COMPLETION_ROLLOUT_STARTS, complete

    prior = tiny_prior()
    clip = bvh.load(cmu_clips()[0])[:120]
    one = complete(clip, 60, 150, prior, rollout_starts=1).solve()
    many = complete(clip, 60, 150, prior).solve()
    assert len(many.solver.starts_fun) == COMPLETION_ROLLOUT_STARTS > 1
    assert many.solver.starts_fun[0] == pytest.approx(one.solver.fun)
    assert_kept_the_best_sound_start(many.solver)
    faults = many.solver.starts_faults
    assert many.solver.fun <= one.solver.fun or min(faults) < faults[0]
    assert np.array_equal(many.motion.rotations[:60], clip.rotations[:60])
    assert len(set(np.round(many.solver.starts_fun, 3))) == COMPLETION_ROLLOUT_STARTS  # the rollouts differ
    with pytest.raises(ValueError, match="rollout_starts"):
        complete(clip, 60, 150, prior, rollout_starts=0)

