"""The causal-convolution prior: protocol, causality, gradients, sampling, checkpoints."""
from __future__ import annotations

import copy
import math

import pytest
import torch

from motionopt.features import floored_root_height, planted_root_step
from priors.checkpoint import CheckpointError, check_compatible, load_prior, read_checkpoint, save_prior
from motionopt.prior import ChannelClamp, MotionPrior
from priors.score import checked_features

from priorkit import cmu_clips, features, fresh_prior, tiny_prior


@pytest.fixture(scope="module")
def prior():
    return tiny_prior()


@pytest.fixture(scope="module")
def x(prior):
    """40 frames of a real clip, normalised for the prior."""
    return features(cmu_clips()[0])[:40]


def changed(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Per-frame: did the NLL change?"""
    return (a - b).abs() > 1e-6 * (1 + a.abs())


def test_conforms_to_protocol(prior, tmp_path):
    assert isinstance(prior, MotionPrior)
    save_prior(prior, tmp_path / "p.pt")
    assert isinstance(load_prior(tmp_path / "p.pt"), MotionPrior)


def test_nll_shapes_and_batching(prior, x):
    nll = prior.nll(x[5:], context=x[:5])
    assert nll.shape == (35,) and torch.isfinite(nll).all()
    batch = torch.stack((x, x.flip(0)))
    both = prior.nll(batch[:, 5:], context=batch[:, :5])
    assert torch.allclose(both[0], nll, atol=2e-4)
    assert torch.allclose(both[1], prior.nll(x.flip(0)[5:], context=x.flip(0)[:5]), atol=2e-4)
    # one context shared by a batch of continuations
    shared = prior.nll(batch[:, 5:], context=x[:5])
    assert torch.allclose(shared[0], nll, atol=2e-4)


@pytest.mark.parametrize("n_context", [0, 6])
def test_frame_t_does_not_change_earlier_frames(prior, x, n_context):
    ctx = x[:n_context] if n_context else None
    seq = x[n_context:]
    t = 12
    base = prior.nll(seq, context=ctx)
    edited = seq.clone()
    edited[t] += 0.5
    after = prior.nll(edited, context=ctx)
    ch = changed(base, after)
    assert not ch[:t].any()
    assert ch[t] and ch[t + 1:t + 4].all()  # the frame itself and the frames it predicts


def test_receptive_field_is_exact(prior, x):
    rf = prior.receptive_field
    assert rf == 8  # 1 + (2 - 1) * (1 + 2 + 4)
    s = 3
    edited = x.clone()
    edited[s] += 0.5
    ch = changed(prior.nll(x), prior.nll(edited))
    assert ch[s + rf] and not ch[s + rf + 1:].any()


def test_context_continues_the_sequence(prior, x):
    """With at least a receptive field of context, scoring the rest equals scoring the whole."""
    c = prior.receptive_field
    assert torch.allclose(prior.nll(x[c:], context=x[:c]), prior.nll(x)[c:], atol=1e-5)
    edited = x[:c].clone()
    edited[-1] += 0.5
    assert changed(prior.nll(x[c:], context=x[:c]), prior.nll(x[c:], context=edited))[0]


def test_a_given_log_std_replaces_the_predicted_one(prior, x):
    mean, log_std, _ = prior.gaussian(x[1:], x[:1])
    nll, _ = prior.nll_and_contacts(x[1:], x[:1], log_std=log_std)
    assert torch.allclose(nll, prior.nll(x[1:], x[:1]))
    wider, _ = prior.nll_and_contacts(x[1:], x[:1], log_std=log_std + 1.0)
    assert not torch.allclose(wider, nll)


def test_contacts_come_from_the_same_pass(prior, x):
    nll, contacts = prior.nll_and_contacts(x)
    assert torch.equal(nll, prior.nll(x))
    assert torch.equal(contacts, prior.predict_contacts(x))
    assert contacts.shape == (len(x), prior.spec.num_contacts)
    assert ((contacts >= 0) & (contacts <= 1)).all()


def test_nll_gradients_are_exact_in_float64(prior, x):
    p64 = copy.deepcopy(prior).double()
    xs, ctx = x[3:9].double().requires_grad_(), x[:3].double().requires_grad_()
    assert torch.autograd.gradcheck(lambda a, c: p64.nll(a, context=c).sum(), (xs, ctx), eps=1e-6, atol=1e-5,
                                     fast_mode=True)


def test_nll_gradient_flows_to_every_pose_dimension(prior, x):
    xs = x.clone().requires_grad_()
    prior.nll(xs).sum().backward()
    g = xs.grad
    assert torch.isfinite(g).all()
    p = prior.spec.pose_dim
    assert (g[:, :p].abs().sum(0) > 0).all()
    assert (g[:-1, p:].abs().sum() > 0)  # contact labels of earlier frames condition later ones


def test_training_lowers_the_nll_of_held_out_motion(prior):
    """A few steps already beat the untrained prior (which predicts "no change") on the
    typical frame with a history (the first frame's score is the marginal, not a prediction;
    a tiny prior trained on 2 s still has rare large misses, so the median)."""
    fresh = fresh_prior().eval()
    val = features(cmu_clips()[-1])
    with torch.no_grad():
        assert prior.nll(val)[1:].median() < fresh.nll(val)[1:].median() - 10


def test_sampling_is_seeded_and_follows_the_predicted_mean(prior, x):
    ctx = x[:10]
    a = prior.sample(ctx, 20, generator=torch.Generator().manual_seed(1))
    b = prior.sample(ctx, 20, generator=torch.Generator().manual_seed(1))
    c = prior.sample(ctx, 20, generator=torch.Generator().manual_seed(2))
    assert a.shape == (20, x.shape[-1]) and torch.isfinite(a).all()
    assert torch.equal(a, b) and not torch.equal(a, c)
    # temperature 0: the first new frame is the predicted mean, made a valid rotation set,
    # and with planting (the default) its root step then keeps planted contact joints still
    # and no contact joint goes below the ground
    first = prior.sample(ctx, 1, temperature=0.0, plant=False)[0]
    mean, _, logits = prior.gaussian(x[10:11], context=ctx)
    expected = prior.project(torch.cat((mean[0], (logits[0] > 0).float())))
    assert torch.allclose(first, expected, atol=1e-5)
    norm = prior.normalizer
    step = planted_root_step(norm.denormalize(ctx[-1:]), norm.denormalize(expected[None]), prior.spec, prior.skeleton)
    planted = norm.normalize(floored_root_height(step, prior.spec, prior.skeleton))[0]
    assert torch.allclose(prior.sample(ctx, 1, temperature=0.0)[0], planted, atol=1e-5)
    # batched contexts roll out independently
    two = prior.sample(torch.stack((ctx, ctx)), 5, temperature=0.0)
    assert two.shape == (2, 5, x.shape[-1]) and torch.allclose(two[0], two[1])


@pytest.mark.parametrize("absolute_root,absolute_height,direct", [(True, False, 3), (True, True, 4), (False, False, 0)])
def test_root_rates_are_predicted_directly_and_the_rest_as_changes(x, absolute_root, absolute_height, direct):
    """An untrained prior outputs zeros: its mean is then 0 (the data mean) where it
    predicts directly (the root rates; the height too in older checkpoints), and the
    previous frame where it predicts a change."""
    from dataclasses import replace

    fresh = fresh_prior()
    config = replace(fresh.config, absolute_root=absolute_root, absolute_height=absolute_height)
    untrained = type(fresh)(fresh.spec, fresh.normalizer, fresh.skeleton, config).eval()
    mean, _, _ = untrained.gaussian(x[1:], context=x[:1])
    assert torch.equal(mean[:, direct:], x[:-1, direct:fresh.spec.pose_dim])
    assert torch.equal(mean[:, :direct], torch.zeros_like(mean[:, :direct]))


def test_an_absolute_pose_prior_predicts_every_moving_dimension_directly(x):
    """Untrained (zero output), its mean is the data mean wherever the data moves, and the
    previous frame only where it never moves (held, as every prior holds them)."""
    from dataclasses import replace

    fresh = fresh_prior()
    untrained = type(fresh)(fresh.spec, fresh.normalizer, fresh.skeleton,
                            replace(fresh.config, absolute_pose=True)).eval()
    mean, _, _ = untrained.gaussian(x[1:], context=x[:1])
    moving = untrained.moving.bool()
    assert torch.equal(mean[:, moving], torch.zeros_like(mean[:, moving]))
    assert torch.equal(mean[:, ~moving], x[:-1, :fresh.spec.pose_dim][:, ~moving])
    assert 0 < int((~moving).sum()) < len(moving)


def test_absolute_joints_are_predicted_directly_and_the_rest_as_changes(x, tmp_path):
    """Untrained, the named joints' moving dimensions (the root's: its tilt) are predicted
    as the data mean and every other joint as its previous frame; the setting survives a
    checkpoint, and a name the prior does not model is refused with the names it does."""
    from dataclasses import replace

    fresh = fresh_prior()
    spec, s = fresh.spec, fresh.spec.slices()
    legs = tuple(j for j in spec.joints[1:] if j.startswith(("r", "l")))[:2]
    untrained = type(fresh)(fresh.spec, fresh.normalizer, fresh.skeleton,
                            replace(fresh.config, absolute_joints=(spec.joints[0],) + legs)).eval()
    mean, _, _ = untrained.gaussian(x[1:], context=x[:1])
    direct = torch.zeros(spec.pose_dim, dtype=torch.bool)
    direct[s["root_tilt"]] = True
    for name in legs:
        start = s["joint_rotations"].start + 6 * (spec.joints.index(name) - 1)
        direct[start:start + 6] = True
    direct &= untrained.moving.bool()
    rest = ~direct
    rest[:4] = False   # the root rates and height: predicted directly in every prior
    assert torch.equal(mean[:, direct], torch.zeros_like(mean[:, direct]))
    assert torch.equal(mean[:, rest], x[:-1, :spec.pose_dim][:, rest])
    save_prior(untrained, tmp_path / "legs.pt")
    assert load_prior(tmp_path / "legs.pt").config.absolute_joints == (spec.joints[0],) + legs
    with pytest.raises(ValueError, match="not among the prior's joints"):
        type(fresh)(fresh.spec, fresh.normalizer, fresh.skeleton, replace(fresh.config, absolute_joints=("tail",)))


def test_checkpoint_from_before_absolute_pose_predicts_changes(prior, tmp_path):
    path = tmp_path / "old.pt"
    save_prior(prior, path)
    data = read_checkpoint(path)
    del data["config"]["absolute_pose"]
    torch.save(data, path)
    assert load_prior(path).config.absolute_pose is False


def test_checkpoint_from_before_absolute_root_keeps_its_meaning(prior, x, tmp_path):
    from dataclasses import replace

    old = copy.deepcopy(prior)
    old.config = replace(prior.config, absolute_root=False)
    path = tmp_path / "old.pt"
    save_prior(old, path)
    data = read_checkpoint(path)
    del data["config"]["absolute_root"]
    del data["config"]["absolute_height"]
    torch.save(data, path)
    loaded = load_prior(path)
    assert loaded.config.absolute_root is False and loaded.config.absolute_height is False
    assert torch.equal(loaded.nll(x), old.nll(x)) and not torch.equal(loaded.nll(x), prior.nll(x))


def test_checkpoint_from_before_absolute_height_predicts_the_height_directly(prior, x, tmp_path):
    from dataclasses import replace

    old = copy.deepcopy(prior)
    old.config = replace(prior.config, absolute_root=True, absolute_height=True)
    path = tmp_path / "old.pt"
    save_prior(old, path)
    data = read_checkpoint(path)
    del data["config"]["absolute_height"]
    torch.save(data, path)
    assert load_prior(path).config.absolute_height is True


def test_checkpoint_round_trip_gives_identical_nll(prior, x, tmp_path):
    path = tmp_path / "tiny.pt"
    save_prior(prior, path)
    loaded = load_prior(path)
    assert torch.equal(loaded.nll(x), prior.nll(x))
    assert loaded.metadata == prior.metadata
    assert loaded.spec == prior.spec and loaded.config == prior.config
    assert loaded.skeleton.same_hierarchy(prior.skeleton)
    assert torch.allclose(torch.as_tensor(loaded.skeleton.offsets), torch.as_tensor(prior.skeleton.offsets))
    assert not any(p.requires_grad for p in loaded.parameters()) and not loaded.training


def test_wrong_feature_version_is_refused(prior, tmp_path):
    path = tmp_path / "old.pt"
    save_prior(prior, path)
    data = read_checkpoint(path)
    data["spec"]["version"] = 0
    torch.save(data, path)
    with pytest.raises(CheckpointError, match="feature version 0.*train-prior"):
        load_prior(path)


@pytest.mark.parametrize("content", [b"not a checkpoint", None])
def test_unreadable_or_missing_checkpoint_is_refused(tmp_path, content):
    path = tmp_path / "bad.pt"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(CheckpointError, match="not a motionopt checkpoint|does not exist"):
        load_prior(path)


def test_motion_of_another_skeleton_is_refused(prior):
    from motionopt import bvh

    legless = bvh.load(cmu_clips()[0]).remove_joints(["lThigh", "lShin", "lFoot"])
    with pytest.raises(CheckpointError, match="lacks lThigh, lShin, lFoot.*train-prior"):
        check_compatible(prior.spec, legless.skeleton)
    with pytest.raises(CheckpointError, match="lacks"):
        checked_features(prior, legless)


def test_a_refused_skeleton_is_pointed_to_the_shipped_prior_that_models_it():
    from motionopt import bvh
    from priors.checkpoint import CHECKPOINT_DIR, load_prior_cached

    bandai = CHECKPOINT_DIR / "bandai-locomotion-ccnet.pt"
    if not bandai.exists():
        pytest.skip("the shipped checkpoints are not here")
    spec = load_prior_cached(bandai).spec
    cmu = bvh.load(cmu_clips()[0]).skeleton
    with pytest.raises(CheckpointError, match="shipped cmu-ccnet.pt models this skeleton: pass --prior cmu-ccnet"):
        check_compatible(spec, cmu)
    with pytest.raises(CheckpointError, match="shipped cmu-latent.pt models this skeleton"):
        check_compatible(spec, cmu, kind="LatentPrior")
    with pytest.raises(CheckpointError, match="Use a prior trained on this skeleton"):
        check_compatible(spec, cmu, kind="LatentDensity")  # the latent prior as a MAP term: no shipped kind


def test_motion_with_the_same_names_but_another_hierarchy_is_refused(prior):
    from motionopt import bvh
    from motionopt.motion import Motion
    from motionopt.skeleton import Skeleton

    m = bvh.load(cmu_clips()[0])
    sk = m.skeleton
    parents = sk.parents.copy()
    parents[sk.index("lButtock")] = sk.index("abdomen")  # another rig's idea of the pelvis
    other = Skeleton(sk.names, parents, sk.offsets, sk.channels)
    with pytest.raises(CheckpointError, match="another hierarchy"):
        checked_features(prior, Motion(other, m.rotations, m.root, m.fps))


def test_std_floor_bounds_the_predicted_std_in_feature_units(x, tmp_path):
    """With ``std_floor`` no dimension is predicted more sharply than the floor in the
    features' own units, also after a checkpoint round trip; without it the trained tiny
    prior is sharper than that somewhere."""
    from dataclasses import replace

    from priors.ccnet import CCNetPrior

    trained = tiny_prior()
    floored = CCNetPrior(trained.spec, trained.normalizer, trained.skeleton, replace(trained.config, std_floor=0.01),
                         trained.metadata)
    floored.load_state_dict(trained.state_dict())
    save_prior(floored, tmp_path / "floored.pt")
    loaded = load_prior(tmp_path / "floored.pt")
    std = trained.normalizer.std[:trained.spec.pose_dim]
    moving = trained.moving.bool()

    def raw_std(p):
        return (torch.exp(p.gaussian(x[5:], x[:5])[1]) * std)[:, moving]

    assert float(raw_std(trained).min()) < 0.01
    assert float(raw_std(loaded).min()) >= 0.01 * (1 - 1e-5)


@pytest.mark.parametrize("n_context", [0, 1, 5, 25])
def test_a_cached_context_gives_the_same_predictions_as_the_context(prior, x, n_context):
    """The solver scores many iterates after one context: its cached share of the pass
    (``cache_context``) must predict exactly what the context itself does, batched too."""
    ctx, window = x[:n_context], x[n_context:n_context + 15]
    cached = prior.cache_context(ctx)
    assert cached.shape == ctx.shape
    for batch in (window, window.expand(3, *window.shape) + 0.1 * torch.randn(3, *window.shape)):
        for a, b in zip(prior.gaussian(batch, ctx), prior.gaussian(batch, cached)):
            assert torch.allclose(a, b, atol=1e-5)
    nll, _ = prior.nll_and_contacts(window, cached)
    assert torch.allclose(nll, prior.nll(window, ctx), atol=1e-4)


def test_a_rollout_step_predicts_what_a_pass_over_the_whole_history_does(prior, x):
    """``_advance`` carries each block's inputs from frame to frame: after 30 steps its
    prediction is the full teacher-forced pass's, which re-reads every frame."""
    past = prior._past(x[None, :5])
    last = x[None, 4]
    with torch.no_grad():
        full_mean, full_log_std, full_logits = prior._predict(x[None, :35])
        for t in range(4, 35):
            mean, log_std, logits, past = prior._advance(last, past)
            last = x[None, t + 1]
            assert torch.allclose(mean, full_mean[:, t], atol=1e-5)
            assert torch.allclose(log_std, full_log_std[:, t], atol=1e-5)
            assert torch.allclose(logits, full_logits[:, t], atol=1e-5)


def test_clamped_channels_are_set_in_every_new_frame_and_steer_the_rest(prior, x):
    ctx = x[:10]
    values = torch.linspace(-2, 2, 8)[:, None].expand(8, 10)
    free = prior.sample(ctx, 8, temperature=0.0, plant=False)
    clamped = prior.sample(ctx, 8, temperature=0.0, plant=False, steer=ChannelClamp(slice(0, 10), values))
    assert torch.equal(clamped[:, :10], values)
    # the first frame is drawn before any clamped frame is history; later ones know them
    assert torch.allclose(clamped[0, 10:], free[0, 10:], atol=1e-6)
    assert not torch.allclose(clamped[1:, 10:], free[1:, 10:], atol=1e-3)


def test_the_free_running_pass_scores_frames_after_the_models_own_draws(prior, x):
    """With one rollout frame nothing is drawn: the pass is the teacher-forced NLL of the
    last frame. With more, the frames after the draws score worse than after real ones
    (the tiny prior's draws wander), and the loss reports that pass."""
    prior.train()
    try:
        torch.manual_seed(0)
        w = torch.ones(2, x.shape[0] - 1)
        batch = torch.stack((x, x))
        one = prior._rollout_nll(batch, w, 1, 1.0, 0.0)
        tail = prior._frame_nll(x[None, -1:], *prior._predict(x[None, :-1])[:2])[:, -1:]
        assert float(one) == pytest.approx(float(tail.mean()), rel=1e-5)
        drawn = prior._rollout_nll(batch, w, 20, 1.0, 0.0)
        real = prior._frame_nll(x[None, 1:], *prior._predict(x[None, :-1])[:2])[0, -20:].mean()
        assert float(drawn) > float(real)
        loss, parts = prior.loss(batch, rollout_frames=20)
        loss.backward()
        assert math.isfinite(parts["nll_rollout"]) and parts["nll_rollout"] > parts["nll"]
    finally:
        prior.zero_grad(set_to_none=True)
        prior.eval()


def test_a_student_t_prior_scores_by_the_t_and_keeps_it_in_its_checkpoint(prior, x, tmp_path):
    """``tail_dof``: the per-frame NLL is the sum over moving dimensions of Student-t
    log-densities (torch's own) at the predicted mean and scale; a dimension far from its
    prediction costs the log of its square, less than the Gaussian's square; the field
    survives a checkpoint, and one from before it loads as Gaussian."""
    from dataclasses import replace

    t_prior = copy.copy(prior)
    t_prior.config = replace(prior.config, tail_dof=5.0)
    with torch.no_grad():
        mean, log_std, _ = prior.gaussian(x[1:], x[:1])
        got = t_prior.nll(x[1:], x[:1])
        moving = prior.moving.bool()
        want = -torch.distributions.StudentT(5.0, mean, log_std.exp()).log_prob(x[1:, :prior.spec.pose_dim])
        assert torch.allclose(got, want[:, moving].sum(-1), rtol=1e-4, atol=1e-3)
        far = x[1:].clone()
        far[:, int(torch.nonzero(moving)[0])] += 50.0
        gaussian_cost = prior.nll(far, x[:1]) - prior.nll(x[1:], x[:1])
        assert float((t_prior.nll(far, x[:1]) - got).min()) < float(gaussian_cost.min())
    path = tmp_path / "t.pt"
    save_prior(t_prior, path)
    assert load_prior(path).config.tail_dof == 5.0
    data = read_checkpoint(path)
    del data["config"]["tail_dof"]
    torch.save(data, path)
    assert load_prior(path).config.tail_dof == 0.0
