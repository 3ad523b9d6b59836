"""Rotations exactly as Blender defines them: Euler angles in its six orders, quaternions, axis-angle.

Conventions (those of Blender's ``mathutils`` and of pose bones' rotation modes):

* Matrices act on column vectors: ``v' = R @ v``; rotations are right-handed (a positive angle turns
  counter-clockwise looking down the axis towards the origin).
* An Euler rotation has three angles ``(x, y, z)`` (Blender's ``rotation_euler``, always stored in that
  component order) and an order string naming which axis is applied first: order ``"ABC"`` means
  ``R = R_C(c) @ R_B(b) @ R_A(a)``, e.g. ``"XYZ"`` (Blender's default) is ``Rz(z) @ Ry(y) @ Rx(x)``.
  Each elementary rotation is about an axis of the fixed (parent) frame.
* Quaternions are ``(w, x, y, z)`` (Blender's ``rotation_quaternion``); they are normalized before use,
  as Blender does for pose bones.
* Axis-angle is ``(angle, x, y, z)`` (Blender's ``rotation_axis_angle``); the axis is normalized.

Every function accepts float64 or complex128 arrays (complex-step differentiation, see
:mod:`solver.rig.analytic`): choices between solutions are made on real parts only.

Conversions to matrices are exact to rounding; conversions from matrices return the representative
Blender would: quaternions with ``w >= 0``, Euler angles in ``[-π, π]`` with the middle angle in
``[-π/2, π/2]``, or, given ``compatible`` angles, the equivalent set closest to them (as
``Matrix.to_euler(order, compatible)`` does, so that keyed curves do not jump by 2π).
"""

from __future__ import annotations

import numpy as np

from geodesics import quaternions

from .errors import SolverError
from .rig import analytic

#: Blender's Euler rotation modes.
EULER_ORDERS = ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX")

#: Below this, the middle Euler angle is taken to be at ±π/2 (gimbal lock).
GIMBAL_EPSILON = 1e-12


def _array(x) -> np.ndarray:
    """``x`` as float64, or as complex128 when it carries a complex step."""
    x = np.asarray(x)
    return x.astype(np.complex128 if np.iscomplexobj(x) else np.float64, copy=False)


def _norm(v, axis: int = -1, keepdims: bool = False):
    """Euclidean norm: numpy's on real arrays (unchanged results), :func:`analytic.norm` on complex ones."""
    if np.iscomplexobj(v):
        return analytic.norm(v, axis=axis, keepdims=keepdims)
    return np.linalg.norm(v, axis=axis, keepdims=keepdims)


def order_axes(order: str) -> tuple[int, int, int]:
    """Indices (0 = x, 1 = y, 2 = z) of the first, second and third applied axes of an Euler order."""
    if order not in EULER_ORDERS:
        raise SolverError(f"unknown Euler order {order!r}; use one of {', '.join(EULER_ORDERS)}")
    return tuple("XYZ".index(c) for c in order)  # type: ignore[return-value]


def axis_rotation(angle, axis: int) -> np.ndarray:
    """(..., 3, 3) rotation matrices by ``angle`` (...,) about coordinate axis ``axis`` (0, 1 or 2)."""
    angle = _array(angle)
    c, s = np.cos(angle), np.sin(angle)
    R = np.zeros((*angle.shape, 3, 3), dtype=angle.dtype)
    i1, i2 = (axis + 1) % 3, (axis + 2) % 3
    R[..., axis, axis] = 1.0
    R[..., i1, i1] = c
    R[..., i2, i2] = c
    R[..., i2, i1] = s
    R[..., i1, i2] = -s
    return R


def euler_to_matrix(angles, order: str = "XYZ") -> np.ndarray:
    """(..., 3, 3) rotation matrices of Euler angles (..., 3) ``(x, y, z)`` in the given order."""
    a = _array(angles)
    i, j, k = order_axes(order)
    return axis_rotation(a[..., k], k) @ axis_rotation(a[..., j], j) @ axis_rotation(a[..., i], i)


def matrix_to_euler(R, order: str = "XYZ", compatible=None) -> np.ndarray:
    """(..., 3) Euler angles ``(x, y, z)`` of rotation matrices (..., 3, 3) in the given order.

    Parameters
    ----------
    R : (..., 3, 3) array_like
        Rotation matrices (orthonormal, determinant +1).
    order : str
        One of :data:`EULER_ORDERS`.
    compatible : (..., 3) array_like, optional
        Reference angles: of the two Euler solutions and their 2π shifts, the one closest to these is
        returned (the sum of absolute differences is minimized).
    """
    M = _array(R)
    i, j, k = order_axes(order)
    s = 1.0 if (j - i) % 3 == 1 else -1.0
    if np.iscomplexobj(M):
        cos_b = analytic.norm(np.stack([M[..., i, i], M[..., j, i]], -1))
    else:
        cos_b = np.hypot(M[..., i, i], M[..., j, i])
    b = analytic.atan2(-s * M[..., k, i], cos_b)
    a = analytic.atan2(s * M[..., k, j], M[..., k, k])
    c = analytic.atan2(s * M[..., j, i], M[..., i, i])
    locked = cos_b.real < GIMBAL_EPSILON
    if np.any(locked):
        # Only a + c (or a - c) is defined: put all of it in the first angle.
        rest = np.swapaxes(axis_rotation(b, j), -1, -2) @ M
        i1, i2 = (i + 1) % 3, (i + 2) % 3
        a = np.where(locked, analytic.atan2(rest[..., i2, i1], rest[..., i1, i1]), a)
        c = np.where(locked, 0.0, c)
    first = np.zeros(M.shape[:-1], dtype=M.dtype)
    first[..., i], first[..., j], first[..., k] = a, b, c
    if compatible is None:
        return first
    # The other solution: (a + π, π - b, c + π).
    second = np.zeros_like(first)
    second[..., i], second[..., j], second[..., k] = a + np.pi, np.pi - b, c + np.pi
    ref = np.broadcast_to(np.asarray(compatible, dtype=np.float64), first.shape)
    best = []
    for candidate in (first, second):
        shifted = candidate + 2 * np.pi * np.round((ref - candidate.real) / (2 * np.pi))
        best.append(shifted)
    cost = [np.abs(x.real - ref).sum(-1) for x in best]
    return np.where((cost[1] < cost[0])[..., None], best[1], best[0])


def quaternion_to_matrix(q) -> np.ndarray:
    """(..., 3, 3) rotation matrices of quaternions (..., 4) ``(w, x, y, z)`` (normalized first)."""
    q = _array(q)
    norm = _norm(q, axis=-1, keepdims=True)
    if np.any(norm.real == 0) or not np.all(np.isfinite(q)):
        raise SolverError("quaternions must be finite and nonzero")
    return quaternions.to_matrix(q / norm)


def matrix_to_quaternion(R) -> np.ndarray:
    """(..., 4) unit quaternions ``(w, x, y, z)`` with ``w >= 0`` of rotation matrices (..., 3, 3)."""
    return quaternions.from_matrix(_array(R))


def axis_angle_to_matrix(axis_angle) -> np.ndarray:
    """(..., 3, 3) rotation matrices of ``(angle, x, y, z)`` (..., 4) (Blender's axis-angle mode)."""
    aa = _array(axis_angle)
    angle, axis = aa[..., 0], aa[..., 1:]
    norm = _norm(axis, axis=-1, keepdims=True)
    if np.any(norm.real == 0) or not np.all(np.isfinite(aa)):
        raise SolverError("axis-angle rotations need a finite angle and a finite nonzero axis")
    half = 0.5 * angle[..., None]
    q = np.concatenate([np.cos(half), np.sin(half) * axis / norm], -1)
    return quaternion_to_matrix(q)


def matrix_to_axis_angle(R) -> np.ndarray:
    """(..., 4) ``(angle, x, y, z)`` with angle in ``[0, π]`` of rotation matrices (..., 3, 3).

    The identity gives angle 0 about +y (Blender's default axis).
    """
    return quaternion_to_axis_angle(matrix_to_quaternion(R))


def quaternion_to_axis_angle(q) -> np.ndarray:
    """(..., 4) ``(angle, x, y, z)`` of quaternions (..., 4) (normalized first), as Blender's
    ``Quaternion.to_axis_angle``: the angle in ``[0, 2π]`` (``[0, π]`` for ``w >= 0``), so that a curve of
    quaternions kept continuous in sign stays continuous; the identity gives angle 0 about +y."""
    q = _array(q)
    q = q / _norm(q, axis=-1, keepdims=True)
    sin_half = _norm(q[..., 1:], axis=-1, keepdims=True)
    angle = 2 * analytic.atan2(sin_half[..., 0], q[..., 0])
    axis = np.divide(q[..., 1:], sin_half, out=np.zeros_like(q[..., 1:]), where=sin_half.real > 0)
    axis[sin_half[..., 0].real == 0] = (0.0, 1.0, 0.0)
    return np.concatenate([angle[..., None], axis], -1)
