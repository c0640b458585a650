"""Rotation conversions in torch, batched over any leading shape and differentiable.

Conventions, stated once:
- Quaternions are unit quaternions ``(..., 4)`` stored **w first**: ``(w, x, y, z)``.
- Rotation matrices ``(..., 3, 3)`` act on column vectors: ``v' = R @ v``.
- Axis-angle (exponential map) ``(..., 3)``: direction is the axis, norm the angle in radians.
- 6D ``(..., 6)``: the first two columns of the matrix, concatenated (Zhou et al. 2019).
- Euler angles ``(..., 3)`` in radians, in BVH convention: an order such as ``"ZXY"``
  means intrinsic rotations applied in that order, ``R = Rz(a0) @ Rx(a1) @ Ry(a2)``
  (the same as scipy's upper-case ``from_euler("ZXY", ...)``).

Functions are named ``source_to_target``; dtype and device follow the input.
"""
from __future__ import annotations

import math

import torch
from torch import Tensor

_AXIS_INDEX = {"X": 0, "Y": 1, "Z": 2}


def _check_last(x: Tensor, n: int, what: str) -> None:
    if x.shape[-1] != n:
        raise ValueError(f"{what} must have shape (..., {n}), got {tuple(x.shape)}")


def quat_identity(shape: tuple[int, ...] = (), dtype=torch.float64, device=None) -> Tensor:
    """Identity quaternions of the given leading shape."""
    q = torch.zeros(*shape, 4, dtype=dtype, device=device)
    q[..., 0] = 1.0
    return q


def quat_normalize(q: Tensor, eps: float = 1e-12) -> Tensor:
    """Scale quaternions to unit norm."""
    return q / q.norm(dim=-1, keepdim=True).clamp_min(eps)


def quat_conjugate(q: Tensor) -> Tensor:
    """Inverse of a unit quaternion."""
    return q * q.new_tensor([1.0, -1.0, -1.0, -1.0])


def quat_multiply(a: Tensor, b: Tensor) -> Tensor:
    """Hamilton product ``a * b`` (apply ``b`` first, then ``a``)."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        (
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ),
        dim=-1,
    )


def quat_apply(q: Tensor, v: Tensor) -> Tensor:
    """Rotate vectors ``v (..., 3)`` by unit quaternions ``q (..., 4)``."""
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * torch.cross(u, v, dim=-1)
    return v + w * t + torch.cross(u, t, dim=-1)


def quat_canonical(q: Tensor) -> Tensor:
    """Pick the sign with non-negative w (q and -q are the same rotation)."""
    return torch.where(q[..., :1] < 0, -q, q)


def quat_to_matrix(q: Tensor) -> Tensor:
    """Unit quaternions (..., 4) to rotation matrices (..., 3, 3)."""
    _check_last(q, 4, "quaternion")
    w, x, y, z = q.unbind(-1)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    m = torch.stack(
        (
            1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy),
            2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx),
            2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy),
        ),
        dim=-1,
    )
    return m.reshape(*q.shape[:-1], 3, 3)


def matrix_to_quat(m: Tensor) -> Tensor:
    """Rotation matrices (..., 3, 3) to unit quaternions (..., 4), w >= 0.

    Uses the largest of the four candidate denominators, which keeps the result and
    its gradient finite at every rotation, including angles near pi.
    """
    if m.shape[-2:] != (3, 3):
        raise ValueError(f"matrix must have shape (..., 3, 3), got {tuple(m.shape)}")
    m00, m01, m02 = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    m10, m11, m12 = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    m20, m21, m22 = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    four_sq = torch.stack(
        (1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22),
        dim=-1,
    )
    # sqrt with a floor: the branch we select always has four_sq >= 1, others are masked out.
    r = torch.sqrt(four_sq.clamp_min(1e-12))
    cand = torch.stack(
        (
            torch.stack((r[..., 0] ** 2, m21 - m12, m02 - m20, m10 - m01), -1) / (2 * r[..., 0:1]),
            torch.stack((m21 - m12, r[..., 1] ** 2, m10 + m01, m02 + m20), -1) / (2 * r[..., 1:2]),
            torch.stack((m02 - m20, m10 + m01, r[..., 2] ** 2, m12 + m21), -1) / (2 * r[..., 2:3]),
            torch.stack((m10 - m01, m20 + m02, m21 + m12, r[..., 3] ** 2), -1) / (2 * r[..., 3:4]),
        ),
        dim=-2,
    )
    best = four_sq.argmax(dim=-1)
    q = torch.gather(cand, -2, best[..., None, None].expand(*best.shape, 1, 4)).squeeze(-2)
    return quat_canonical(quat_normalize(q))


def axis_angle_to_quat(aa: Tensor) -> Tensor:
    """Axis-angle vectors (..., 3) to unit quaternions (..., 4); smooth at angle 0."""
    _check_last(aa, 3, "axis-angle")
    angle_sq = (aa * aa).sum(-1, keepdim=True)
    angle = torch.sqrt(angle_sq.clamp_min(1e-24))
    small = angle_sq < 1e-8
    # sin(a/2)/a, with its Taylor series near zero so the gradient stays exact.
    k_big = torch.sin(angle / 2) / angle
    k_small = 0.5 - angle_sq / 48.0
    k = torch.where(small, k_small, k_big)
    w_big = torch.cos(angle / 2)
    w_small = 1 - angle_sq / 8.0
    w = torch.where(small, w_small, w_big)
    return torch.cat((w, aa * k), dim=-1)


def quat_to_axis_angle(q: Tensor) -> Tensor:
    """Unit quaternions (..., 4) to axis-angle (..., 3) with angle in [0, pi]."""
    _check_last(q, 4, "quaternion")
    q = quat_canonical(q)
    w = q[..., :1]
    v = q[..., 1:]
    s_sq = (v * v).sum(-1, keepdim=True)
    s = torch.sqrt(s_sq.clamp_min(1e-24))
    angle = 2 * torch.atan2(s, w)
    small = s_sq < 1e-8
    # 2 atan2(s, w) / s -> 2 / w * (1 - s^2 / (3 w^2)) near zero; w is about 1 there, and
    # replaced by 1 elsewhere so that the unused branch has no infinite gradient at angle pi.
    w_safe = torch.where(small, w, torch.ones_like(w))
    k = torch.where(small, 2.0 / w_safe * (1 - s_sq / (3 * w_safe * w_safe)), angle / s)
    return v * k


def axis_angle_to_matrix(aa: Tensor) -> Tensor:
    """Axis-angle (..., 3) to rotation matrices (..., 3, 3)."""
    return quat_to_matrix(axis_angle_to_quat(aa))


def matrix_to_axis_angle(m: Tensor) -> Tensor:
    """Rotation matrices (..., 3, 3) to axis-angle (..., 3)."""
    return quat_to_axis_angle(matrix_to_quat(m))


def matrix_to_6d(m: Tensor) -> Tensor:
    """Rotation matrices (..., 3, 3) to the 6D representation (first two columns)."""
    return torch.cat((m[..., :, 0], m[..., :, 1]), dim=-1)


def sixd_to_matrix(d6: Tensor) -> Tensor:
    """6D vectors (..., 6) to rotation matrices by Gram-Schmidt; any input is valid."""
    _check_last(d6, 6, "6D rotation")
    a1, a2 = d6[..., :3], d6[..., 3:]
    b1 = a1 / a1.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    a2 = a2 - (b1 * a2).sum(-1, keepdim=True) * b1
    b2 = a2 / a2.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    b3 = torch.cross(b1, b2, dim=-1)
    return torch.stack((b1, b2, b3), dim=-1)


def quat_to_6d(q: Tensor) -> Tensor:
    """Unit quaternions (..., 4) to 6D (..., 6)."""
    return matrix_to_6d(quat_to_matrix(q))


def sixd_to_quat(d6: Tensor) -> Tensor:
    """6D (..., 6) to unit quaternions (..., 4)."""
    return matrix_to_quat(sixd_to_matrix(d6))


def _check_order(order: str) -> tuple[int, int, int]:
    order = order.upper()
    if len(order) != 3 or set(order) != {"X", "Y", "Z"}:
        raise ValueError(f"Euler order must be a permutation of 'XYZ' (as in BVH), got {order!r}")
    return tuple(_AXIS_INDEX[c] for c in order)  # type: ignore[return-value]


def _axis_quat(angle: Tensor, axis: int) -> Tensor:
    half = angle / 2
    zeros = torch.zeros_like(half)
    parts = [torch.cos(half), zeros, zeros, zeros]
    parts[axis + 1] = torch.sin(half)
    return torch.stack(parts, dim=-1)


def euler_to_quat(angles: Tensor, order: str) -> Tensor:
    """Intrinsic Euler angles (..., 3) in radians, BVH channel order, to quaternions."""
    _check_last(angles, 3, "Euler angles")
    axes = _check_order(order)
    q = _axis_quat(angles[..., 0], axes[0])
    for k in (1, 2):
        q = quat_multiply(q, _axis_quat(angles[..., k], axes[k]))
    return q


def euler_to_matrix(angles: Tensor, order: str) -> Tensor:
    """Intrinsic Euler angles (..., 3) to rotation matrices (..., 3, 3)."""
    return quat_to_matrix(euler_to_quat(angles, order))


def matrix_to_euler(m: Tensor, order: str) -> Tensor:
    """Rotation matrices to intrinsic Euler angles (..., 3), middle angle in [-pi/2, pi/2].

    At gimbal lock (middle angle +/- pi/2) only the sum or difference of the outer angles
    is defined: it all goes to the first angle and the third is 0.
    """
    i, j, k = _check_order(order)
    parity = 1.0 if (i, j, k) in ((0, 1, 2), (1, 2, 0), (2, 0, 1)) else -1.0
    cos_b = torch.sqrt((m[..., i, i] ** 2 + m[..., i, j] ** 2).clamp_min(1e-24))
    b = torch.atan2(parity * m[..., i, k], cos_b)
    # Below sqrt(machine eps) the regular formulas lose more accuracy than the lock formula.
    gimbal = cos_b < torch.finfo(m.dtype).eps ** 0.5

    def safe_atan2(y: Tensor, x: Tensor, use: Tensor) -> Tensor:
        # atan2 where ``use``, 0 elsewhere, with a finite gradient everywhere
        x = torch.where(use, x, torch.ones_like(x))
        return torch.where(use, torch.atan2(torch.where(use, y, torch.zeros_like(y)), x), torch.zeros_like(x))

    a_reg = safe_atan2(-parity * m[..., j, k], m[..., k, k], ~gimbal)
    c_reg = safe_atan2(-parity * m[..., i, j], m[..., i, i], ~gimbal)
    a_lock = safe_atan2(parity * m[..., k, j], m[..., j, j], gimbal)
    return torch.stack((a_reg + a_lock, b, c_reg), dim=-1)


def quat_to_euler(q: Tensor, order: str) -> Tensor:
    """Unit quaternions (..., 4) to intrinsic Euler angles (..., 3) in radians."""
    return matrix_to_euler(quat_to_matrix(q), order)


def euler_nearest(angles: Tensor, reference: Tensor) -> Tensor:
    """Of the equivalent Euler triples for the same rotation, the one nearest ``reference``.

    Every rotation has two Tait-Bryan solutions ``(a, b, c)`` and ``(a+pi, pi-b, c+pi)``,
    each defined modulo 2*pi per angle. Writers use this to keep animation curves
    continuous and to reproduce the angle ranges of a source file.
    """
    alt = torch.stack(
        (angles[..., 0] + math.pi, math.pi - angles[..., 1], angles[..., 2] + math.pi), dim=-1
    )
    two_pi = 2 * math.pi

    def wrap(x: Tensor) -> Tensor:
        return x - two_pi * torch.round((x - reference) / two_pi)

    first, second = wrap(angles), wrap(alt)
    d1 = ((first - reference) ** 2).sum(-1, keepdim=True)
    d2 = ((second - reference) ** 2).sum(-1, keepdim=True)
    return torch.where(d2 < d1, second, first)


def quat_slerp(a: Tensor, b: Tensor, t: Tensor | float) -> Tensor:
    """Spherical linear interpolation from ``a`` to ``b`` at fraction ``t`` (shortest arc).

    ``t`` is a number or has the leading shape of ``a``; differentiable everywhere
    (nearly equal rotations fall back to normalised linear interpolation).
    """
    t = torch.as_tensor(t, dtype=a.dtype, device=a.device)
    t = t[..., None] if t.dim() == a.dim() - 1 else t
    dot = (a * b).sum(-1, keepdim=True)
    b = torch.where(dot < 0, -b, b)
    dot = dot.abs()
    near = dot > 1 - 1e-6
    theta = torch.acos(torch.where(near, torch.zeros_like(dot), dot))
    sin_theta = torch.where(near, torch.ones_like(theta), torch.sin(theta))
    wa = torch.where(near, 1 - t, torch.sin((1 - t) * theta) / sin_theta)
    wb = torch.where(near, t, torch.sin(t * theta) / sin_theta)
    return quat_normalize(wa * a + wb * b)


def quat_angle(a: Tensor, b: Tensor) -> Tensor:
    """Geodesic angle in radians, in [0, pi], between unit quaternions (..., 4).

    Computed as ``2 atan2(|v|, |w|)`` of the relative rotation, which is accurate for
    small angles (unlike ``acos``) and has a finite gradient at angle 0.
    """
    d = quat_multiply(quat_conjugate(a), b)
    v_sq = (d[..., 1:] ** 2).sum(-1)
    zero = v_sq == 0
    v_norm = torch.where(zero, torch.zeros_like(v_sq), torch.sqrt(torch.where(zero, torch.ones_like(v_sq), v_sq)))
    return 2 * torch.atan2(v_norm, d[..., 0].abs())


def yaw_quat(angle: Tensor) -> Tensor:
    """Quaternions for rotations by ``angle`` about the vertical y axis."""
    return _axis_quat(angle, 1)
