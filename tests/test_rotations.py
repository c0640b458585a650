"""Rotation conversions against scipy.spatial.transform, in float32 and float64."""
from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation, Slerp

from motionopt import rotations as R

ORDERS = ["".join(p) for p in itertools.permutations("XYZ")]
DTYPES = [torch.float32, torch.float64]
TOL = {torch.float32: 2e-5, torch.float64: 1e-10}


def random_rotations(n: int, seed: int) -> Rotation:
    return Rotation.random(n, random_state=seed)


def as_t(x: np.ndarray, dtype: torch.dtype) -> torch.Tensor:
    return torch.as_tensor(np.asarray(x), dtype=dtype)


def same_rotation(q: torch.Tensor, ref_wxyz: np.ndarray, tol: float) -> None:
    """Quaternions equal up to sign."""
    q = q.double().numpy()
    sign = np.sign((q * ref_wxyz).sum(-1, keepdims=True))
    np.testing.assert_allclose(q * sign, ref_wxyz, atol=tol)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("order", ORDERS)
def test_euler_to_quat_and_matrix_match_scipy(order, dtype):
    rng = np.random.default_rng(1)
    angles = rng.uniform(-math.pi, math.pi, size=(64, 3))
    ref = Rotation.from_euler(order, angles)
    same_rotation(R.euler_to_quat(as_t(angles, dtype), order), ref.as_quat(scalar_first=True), TOL[dtype] * 5)
    np.testing.assert_allclose(R.euler_to_matrix(as_t(angles, dtype), order).double().numpy(), ref.as_matrix(),
                               atol=TOL[dtype] * 5)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("order", ORDERS)
def test_matrix_to_euler_matches_scipy(order, dtype):
    rot = random_rotations(64, seed=2)
    ref = rot.as_euler(order)
    assert np.abs(np.cos(ref[:, 1])).min() > 1e-3  # away from gimbal lock, where angles are unique
    got = R.matrix_to_euler(as_t(rot.as_matrix(), dtype), order).double().numpy()
    np.testing.assert_allclose(got, ref, atol=TOL[dtype] * 50)
    got_q = R.quat_to_euler(as_t(rot.as_quat(scalar_first=True), dtype), order).double().numpy()
    np.testing.assert_allclose(got_q, ref, atol=TOL[dtype] * 50)


@pytest.mark.parametrize("dtype", DTYPES)
def test_quaternion_matrix_axis_angle_match_scipy(dtype):
    rot = random_rotations(200, seed=3)
    q = as_t(rot.as_quat(scalar_first=True), dtype)
    m = as_t(rot.as_matrix(), dtype)
    aa = as_t(rot.as_rotvec(), dtype)
    tol = TOL[dtype]
    np.testing.assert_allclose(R.quat_to_matrix(q).double().numpy(), rot.as_matrix(), atol=tol)
    same_rotation(R.matrix_to_quat(m), rot.as_quat(scalar_first=True), tol)
    same_rotation(R.axis_angle_to_quat(aa), rot.as_quat(scalar_first=True), tol)
    np.testing.assert_allclose(R.quat_to_axis_angle(q).double().numpy(), rot.as_rotvec(), atol=tol * 10)
    np.testing.assert_allclose(R.matrix_to_axis_angle(m).double().numpy(), rot.as_rotvec(), atol=tol * 10)
    np.testing.assert_allclose(R.axis_angle_to_matrix(aa).double().numpy(), rot.as_matrix(), atol=tol)
    assert (R.matrix_to_quat(m)[..., 0] >= 0).all()


@pytest.mark.parametrize("dtype", DTYPES)
def test_quaternion_algebra_matches_scipy(dtype):
    a, b = random_rotations(50, seed=4), random_rotations(50, seed=5)
    qa, qb = as_t(a.as_quat(scalar_first=True), dtype), as_t(b.as_quat(scalar_first=True), dtype)
    tol = TOL[dtype]
    same_rotation(R.quat_multiply(qa, qb), (a * b).as_quat(scalar_first=True), tol)
    same_rotation(R.quat_conjugate(qa), a.inv().as_quat(scalar_first=True), tol)
    v = np.random.default_rng(6).normal(size=(50, 3))
    np.testing.assert_allclose(R.quat_apply(qa, as_t(v, dtype)).double().numpy(), a.apply(v), atol=tol * 10)
    np.testing.assert_allclose(R.quat_angle(qa, qb).double().numpy(), (a.inv() * b).magnitude(), atol=tol * 10)


@pytest.mark.parametrize("dtype", DTYPES)
def test_sixd_round_trip_and_gram_schmidt(dtype):
    rot = random_rotations(100, seed=7)
    m = as_t(rot.as_matrix(), dtype)
    d6 = R.matrix_to_6d(m)
    assert d6.shape == (100, 6)
    np.testing.assert_allclose(R.sixd_to_matrix(d6).double().numpy(), rot.as_matrix(), atol=TOL[dtype])
    same_rotation(R.sixd_to_quat(R.quat_to_6d(as_t(rot.as_quat(scalar_first=True), dtype))),
                  rot.as_quat(scalar_first=True), TOL[dtype] * 5)
    # any 6D vector maps to a proper rotation
    noisy = d6 * 3.0 + as_t(np.random.default_rng(8).normal(size=(100, 6)), dtype)
    out = R.sixd_to_matrix(noisy).double()
    np.testing.assert_allclose((out.transpose(-1, -2) @ out).numpy(), np.broadcast_to(np.eye(3), (100, 3, 3)),
                               atol=TOL[dtype] * 10)
    np.testing.assert_allclose(torch.linalg.det(out).numpy(), 1.0, atol=TOL[dtype] * 10)


@pytest.mark.parametrize("dtype", DTYPES)
def test_slerp_matches_scipy(dtype):
    a, b = random_rotations(1, seed=9), random_rotations(1, seed=10)
    times = np.linspace(0, 1, 11)
    ref = Slerp([0, 1], Rotation.concatenate([a, b]))(times).as_quat(scalar_first=True)
    qa = as_t(np.repeat(a.as_quat(scalar_first=True), 11, 0), dtype)
    qb = as_t(np.repeat(b.as_quat(scalar_first=True), 11, 0), dtype)
    same_rotation(R.quat_slerp(qa, qb, as_t(times, dtype)), ref, TOL[dtype] * 5)
    # the shorter arc is taken whichever sign b has
    same_rotation(R.quat_slerp(qa, -qb, as_t(times, dtype)), ref, TOL[dtype] * 5)
    # identical rotations interpolate to themselves
    same_rotation(R.quat_slerp(qa, qa, 0.3), qa.double().numpy(), TOL[dtype])


CONVERSIONS = [
    ("euler_to_quat", lambda x: R.euler_to_quat(x, "ZXY"), (3,)),
    ("quat_to_euler", lambda x: R.quat_to_euler(R.quat_normalize(x), "YZX"), (4,)),
    ("quat_to_matrix", R.quat_to_matrix, (4,)),
    ("matrix_to_quat", lambda x: R.matrix_to_quat(R.quat_to_matrix(R.quat_normalize(x))), (4,)),
    ("axis_angle_to_quat", R.axis_angle_to_quat, (3,)),
    ("quat_to_axis_angle", lambda x: R.quat_to_axis_angle(R.quat_normalize(x)), (4,)),
    ("sixd_to_matrix", R.sixd_to_matrix, (6,)),
    ("quat_to_6d", lambda x: R.quat_to_6d(R.quat_normalize(x)), (4,)),
]


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("name,fn,tail", CONVERSIONS, ids=[c[0] for c in CONVERSIONS])
def test_batched_equals_unbatched(name, fn, tail, dtype):
    x = as_t(np.random.default_rng(11).normal(size=(2, 3, 5) + tail), dtype)
    batched = fn(x)
    single = torch.stack([fn(x[i, j, k]) for i in range(2) for j in range(3) for k in range(5)])
    torch.testing.assert_close(batched.reshape(single.shape), single, atol=TOL[dtype], rtol=0)
    # and over no leading dimension at all
    assert fn(x[0, 0, 0]).shape == batched.shape[3:]


@pytest.mark.parametrize("dtype", DTYPES)
def test_angles_near_zero_and_pi(dtype):
    axes = np.random.default_rng(12).normal(size=(6, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.array([0.0, 1e-9, 1e-5, 1e-3, math.pi - 1e-6, math.pi])
    rotvec = axes * angles[:, None]
    ref = Rotation.from_rotvec(rotvec)
    tol = TOL[dtype]
    q = R.axis_angle_to_quat(as_t(rotvec, dtype))
    same_rotation(q, ref.as_quat(scalar_first=True), tol)
    np.testing.assert_allclose(R.quat_to_matrix(q).double().numpy(), ref.as_matrix(), atol=tol * 5)
    q_ref = as_t(ref.as_quat(scalar_first=True), dtype)
    back = R.quat_to_axis_angle(q_ref).double().numpy()
    # near pi the axis sign is ambiguous: compare the rotations they describe
    np.testing.assert_allclose(Rotation.from_rotvec(back).as_matrix(), ref.as_matrix(), atol=tol * 20)
    np.testing.assert_allclose(np.linalg.norm(back, axis=1), angles, atol=tol * 20)
    same_rotation(R.matrix_to_quat(as_t(ref.as_matrix(), dtype)), ref.as_quat(scalar_first=True), tol * 20)


def test_small_angle_series_is_exact_to_float64_precision():
    """Angles on both sides of the switch to the Taylor series round-trip to 1e-12 relative."""
    angles = np.array([1e-7, 1e-5, 1.9e-4, 2.1e-4, 1e-2])
    aa = torch.as_tensor(np.array([0.6, -0.8, 0.0]) * angles[:, None])
    back = R.quat_to_axis_angle(R.axis_angle_to_quat(aa))
    np.testing.assert_allclose(back.numpy(), aa.numpy(), rtol=1e-12, atol=0)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("order", ORDERS)
def test_gimbal_lock_reconstructs_the_rotation(order, dtype):
    rng = np.random.default_rng(13)
    outer = rng.uniform(-math.pi, math.pi, size=(8, 2))
    rows = []
    for middle in (math.pi / 2, -math.pi / 2, math.pi / 2 - 1e-5, -math.pi / 2 + 1e-3):
        rows.append(np.stack((outer[:, 0], np.full(8, middle), outer[:, 1]), axis=1))
    angles = np.concatenate(rows)
    m = R.euler_to_matrix(as_t(angles, dtype), order)
    eul = R.matrix_to_euler(m, order)
    assert torch.isfinite(eul).all()
    assert (eul[:, 1].abs() <= math.pi / 2 + 1e-6).all()
    tol = 1e-3 if dtype == torch.float32 else 1e-7
    np.testing.assert_allclose(R.euler_to_matrix(eul, order).double().numpy(), m.double().numpy(), atol=tol)
    np.testing.assert_allclose(eul.double().numpy()[:, 1], angles[:, 1], atol=tol)


def test_euler_nearest_keeps_rotation_and_follows_reference():
    rng = np.random.default_rng(14)
    angles = torch.as_tensor(rng.uniform(-math.pi, math.pi, size=(100, 3)))
    # a reference that is another triple for the same rotation, shifted by whole turns
    alt = torch.stack((angles[:, 0] + math.pi, math.pi - angles[:, 1], angles[:, 2] + math.pi), -1)
    reference = alt + 2 * math.pi * torch.as_tensor(rng.integers(-2, 3, size=(100, 3)), dtype=torch.float64)
    got = R.euler_nearest(angles, reference + 1e-3)
    torch.testing.assert_close(got, reference, atol=1e-9, rtol=0)
    torch.testing.assert_close(R.euler_to_matrix(got, "ZXY"), R.euler_to_matrix(angles, "ZXY"))


def _grad_of(fn, x: torch.Tensor) -> torch.Tensor:
    x = x.clone().requires_grad_(True)
    fn(x).sum().backward()
    return x.grad


@pytest.mark.parametrize("dtype", DTYPES)
def test_gradients_are_finite_at_singular_points(dtype):
    zero = torch.zeros(1, 3, dtype=dtype)
    half_turn = torch.tensor([[0.0, 1.0, 0.0, 0.0]], dtype=dtype)  # angle pi, w = 0
    identity = R.quat_identity((1,), dtype=dtype)
    lock = torch.tensor([[0.3, math.pi / 2, -0.2]], dtype=dtype)
    cases = {
        "axis_angle_to_quat at 0": (R.axis_angle_to_quat, zero),
        "quat_to_axis_angle at 0": (R.quat_to_axis_angle, identity),
        "quat_to_axis_angle at pi": (R.quat_to_axis_angle, half_turn),
        "matrix_to_quat at pi": (R.matrix_to_quat, R.quat_to_matrix(half_turn)),
        "matrix_to_quat at 0": (R.matrix_to_quat, torch.eye(3, dtype=dtype)[None]),
        "matrix_to_euler at gimbal lock": (lambda m: R.matrix_to_euler(m, "ZXY"), R.euler_to_matrix(lock, "ZXY")),
        "slerp of equal quaternions": (lambda q: R.quat_slerp(q, identity, 0.4), identity),
        "quat_angle of equal quaternions": (lambda q: R.quat_angle(q, identity), identity),
        "sixd_to_matrix": (R.sixd_to_matrix, R.matrix_to_6d(torch.eye(3, dtype=dtype)[None])),
    }
    for name, (fn, x) in cases.items():
        g = _grad_of(fn, x)
        assert torch.isfinite(g).all(), f"{name}: gradient {g}"


GRADCHECK = [
    ("euler_to_quat", lambda x: R.euler_to_quat(x, "XZY"), (3,), 1.0),
    ("quat_to_euler", lambda x: R.quat_to_euler(R.quat_normalize(x), "ZXY"), (4,), 1.0),
    ("matrix_to_quat", lambda x: R.matrix_to_quat(R.axis_angle_to_matrix(x)), (3,), 1.0),
    ("axis_angle_to_quat small", R.axis_angle_to_quat, (3,), 1e-6),
    ("quat_to_axis_angle", lambda x: R.quat_to_axis_angle(R.quat_normalize(x)), (4,), 1.0),
    ("sixd_to_quat", R.sixd_to_quat, (6,), 1.0),
    ("quat_slerp", lambda x: R.quat_slerp(R.quat_normalize(x[..., :4]), R.quat_normalize(x[..., 4:]), 0.3),
     (8,), 1.0),
]


@pytest.mark.parametrize("name,fn,tail,scale", GRADCHECK, ids=[g[0] for g in GRADCHECK])
def test_gradcheck_float64(name, fn, tail, scale):
    x = torch.as_tensor(np.random.default_rng(15).normal(size=(4,) + tail) * scale)
    if name == "quat_to_axis_angle" or name == "quat_to_euler":
        x[:, 0] = x[:, 0].abs() + 0.5  # away from the w = 0 sign flip of the canonical form
    assert torch.autograd.gradcheck(fn, (x.requires_grad_(True),))


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="permutation"):
        R.euler_to_quat(torch.zeros(3), "XXY")
    with pytest.raises(ValueError, match=r"\(\.\.\., 4\)"):
        R.quat_to_matrix(torch.zeros(3))
    with pytest.raises(ValueError, match=r"\(\.\.\., 3, 3\)"):
        R.matrix_to_quat(torch.zeros(4, 4))
