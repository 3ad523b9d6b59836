"""Blender's rotation conversions (``math_rotation.cc``), batched and analytic, bit for bit as Blender's C.

Quaternions ``(w, x, y, z)`` are taken as given (Blender's C functions do not normalize them, unlike
``mathutils`` and :mod:`solver.rotations`, the user-facing conversions); Euler angles are ``(x, y, z)`` in
one of Blender's six orders (``eulO``). Matrix conventions and complex-step analyticity are those of
:mod:`.math_matrix`.
"""

from __future__ import annotations

import numpy as np

from ..rotations import EULER_ORDERS, euler_to_matrix, order_axes
from . import analytic
from .math_matrix import AFTER, NEXT, ONES3, det3, dot, loc_rot_size_to_mat4, normalize_m3, normalize_v3, skew

_EYE3 = np.eye(3)
_EYE3.setflags(write=False)
#: ``EULER_HYPOT_EPSILON`` of math_rotation.cc: below it the third Euler angle is taken as 0.
EULER_HYPOT_EPSILON = 0.0000375
#: Blender's ``rotOrders``: the axes (i, j, k) and the parity of each Euler order.
_ORDERS = {
    "XYZ": ((0, 1, 2), 0),
    "XZY": ((0, 2, 1), 1),
    "YXZ": ((1, 0, 2), 1),
    "YZX": ((1, 2, 0), 0),
    "ZXY": ((2, 0, 1), 0),
    "ZYX": ((2, 1, 0), 1),
}


# quat_to_mat3 as a quadratic form: R[i, j] = δ_ij + Σ_ab QUAD[i, j, a, b] q_a q_b (q scaled by √2).
_QUAD = np.zeros((3, 3, 4, 4))
for (_i, _j), _terms in {
    (0, 0): [(2, 2, -1), (3, 3, -1)],
    (1, 0): [(0, 3, 1), (1, 2, 1)],
    (2, 0): [(0, 2, -1), (1, 3, 1)],
    (0, 1): [(0, 3, -1), (1, 2, 1)],
    (1, 1): [(1, 1, -1), (3, 3, -1)],
    (2, 1): [(0, 1, 1), (2, 3, 1)],
    (0, 2): [(0, 2, 1), (1, 3, 1)],
    (1, 2): [(0, 1, -1), (2, 3, 1)],
    (2, 2): [(1, 1, -1), (2, 2, -1)],
}.items():
    for _a, _b, _s in _terms:
        _QUAD[_i, _j, _a, _b] = 2.0 * _s
_QUAD = _QUAD.reshape(9, 16)


def quat_to_mat3(q) -> np.ndarray:
    """(..., 3, 3) ``quat_to_mat3`` of ``(w, x, y, z)`` (..., 4) as given (not normalized, as Blender)."""
    q = np.asarray(q)
    outer = (q[..., :, None] * q[..., None, :]).reshape(*q.shape[:-1], 16)
    return (outer @ _QUAD.T).reshape(*q.shape[:-1], 3, 3) + _EYE3


def axis_angle_normalized_to_mat3(axis, sin, cos) -> np.ndarray:
    """(..., 3, 3) ``axis_angle_normalized_to_mat3_ex``: rotation about a unit ``axis`` (..., 3) by the
    angle of ``sin`` and ``cos`` (...)."""
    axis, sin, cos = np.asarray(axis), np.asarray(sin), np.asarray(cos)
    ico = 1.0 - cos
    outer = axis[..., :, None] * axis[..., None, :] * ico[..., None, None]
    return outer + skew(axis * sin[..., None]) + _EYE3 * cos[..., None, None]


# mat3_normalized_to_quat_fast, table-driven. Per case c (the branch Blender takes), the component c is
# s / 4 and each other component k is (m[a] + sign m[b]) / s over flattened 3×3 entries a, b (Blender's
# mat[i][j] is numpy m[..., i, j] of the transposed matrix: see matrix_to_quaternion).
_QCASE_SIGNS = np.array([[1, -1, -1], [-1, 1, -1], [-1, -1, 1], [1, 1, 1]], dtype=float)
_QCASE_TEST = np.array([(1 * 3 + 2, 2 * 3 + 1), (2 * 3 + 0, 0 * 3 + 2), (0 * 3 + 1, 1 * 3 + 0), (0, 0)])
_QCASE_A = np.array([[5, 5, 1, 6], [6, 1, 6, 5], [1, 6, 5, 5], [0, 5, 6, 1]])
_QCASE_B = np.array([[7, 7, 3, 2], [2, 3, 2, 7], [3, 2, 7, 7], [0, 7, 2, 3]])
_QCASE_SIGN = np.array([[-1, 0, 1, 1], [-1, 1, 0, 1], [-1, 1, 1, 0], [0, -1, -1, -1]], dtype=float)


def mat3_to_quat(R) -> np.ndarray:
    """(..., 4) ``mat3_to_quat`` of matrices ``R`` (..., 3, 3) (or the 3×3 blocks of (..., 4, 4)): axes
    normalized, a negative determinant negated, then ``mat3_normalized_to_quat_fast`` (Mike Day's method,
    ``w >= 0``)."""
    R = np.asarray(R)[..., :3, :3]
    units, _ = normalize_v3(np.swapaxes(R, -1, -2))
    m = units  # m[..., i, j] is Blender's mat[i][j]
    negative = det3(m).real < 0
    if negative.any():
        m = np.where(negative[..., None, None], -m, m)
    flat = m.reshape(*m.shape[:-2], 9)
    diag = flat[..., [0, 4, 8]]
    m00, m11, m22 = diag[..., 0].real, diag[..., 1].real, diag[..., 2].real
    case = np.where(m22 < 0, np.where(m00 > m11, 0, 1), np.where(m00 < -m11, 2, 3))
    trace = 1.0 + np.sum(diag * _QCASE_SIGNS[case], axis=-1)
    s = 2.0 * np.sqrt(trace)
    test = np.take_along_axis(flat, _QCASE_TEST[case], axis=-1).real
    s = np.where((case < 3) & (test[..., 0] < test[..., 1]), -s, s)
    a = np.take_along_axis(flat, _QCASE_A[case], axis=-1)
    b = np.take_along_axis(flat, _QCASE_B[case], axis=-1)
    q = (a + _QCASE_SIGN[case] * b) / s[..., None]
    onehot = np.arange(4) == np.where(case == 3, 0, case + 1)[..., None]
    q = np.where(onehot, 0.25 * s[..., None], q)
    length_sq = dot(q, q)
    renorm = np.abs(length_sq.real - 1.0) >= 0.0006
    if renorm.any():
        q = np.where(renorm[..., None], q / np.sqrt(length_sq)[..., None], q)
    return q


def _acos(c):
    """``saacos`` of cosines strictly inside (-1, 1), analytic (see :func:`analytic.acos`)."""
    if c.dtype != np.complex128:
        return np.arccos(c)
    r = c.real
    return np.arccos(r) - 1j * (c.imag / np.sqrt(1.0 - r * r))


def interp_qt_qtqt(a, b, t):
    """(..., 4) ``interp_qt_qtqt``: spherical interpolation from quaternions ``a`` to ``b`` (..., 4) by
    ``t`` (...) along the shorter arc (``a`` negated when ``a · b < 0``), linear when the quaternions are
    within ``1e-4`` of parallel, not renormalized."""
    a, b, t = np.asarray(a), np.asarray(b), np.asarray(t)
    cos = dot(a, b)
    if cos.size and cos.real.min() < 0:
        flip = cos.real < 0
        cos = np.where(flip, -cos, cos)
        a = np.where(flip[..., None], -a, a)
    if cos.size and cos.real.max() < 1.0 - 1e-4:
        omega = _acos(cos)
        inv_sin = 1.0 / np.sin(omega)
        w0 = np.sin((1.0 - t) * omega) * inv_sin
        w1 = np.sin(t * omega) * inv_sin
    else:
        spherical = np.abs(cos.real) < 1.0 - 1e-4
        omega = analytic.acos(np.where(spherical, cos, 0.0))
        sin = np.sin(omega)
        w0 = np.where(spherical, np.sin((1.0 - t) * omega) / sin, 1.0 - t)
        w1 = np.where(spherical, np.sin(t * omega) / sin, t)
    return w0[..., None] * a + w1[..., None] * b


# mat3_normalized_to_quat_fast of one case as a linear map: with m the rotation's entries flattened
# (Blender's mat[i][j] at 3 i + j), q s = m @ _QLIN[case] + _QCONST[case], s = ±2 sqrt(trace).
_QLIN = np.zeros((4, 9, 4))
_QCONST = np.zeros((4, 4))
for _c in range(4):
    _on = 0 if _c == 3 else _c + 1
    for _k in range(4):
        if _k == _on:
            _QLIN[_c, [0, 4, 8], _k] = _QCASE_SIGNS[_c]
            _QCONST[_c, _k] = 1.0
        else:
            _QLIN[_c, _QCASE_A[_c, _k], _k] += 1.0
            _QLIN[_c, _QCASE_B[_c, _k], _k] += _QCASE_SIGN[_c, _k]
_QTRACE = np.array([_QLIN[_c, :, 0 if _c == 3 else _c + 1] for _c in range(4)])  # (4, 9)
# Blender's mat[i][j] is U[j, i]: the entry of U's flattening at 3 j + i.
_TRANSPOSED9 = np.array([3 * (k % 3) + k // 3 for k in range(9)])


def mat3_normalized_to_quat_fast(U) -> np.ndarray:
    """(..., 4) ``mat3_normalized_to_quat_fast`` of rotation matrices (..., 3, 3) (orthonormal, proper:
    no normalization, no sign fix, as :func:`mat3_to_quat` would leave them).

    Blender picks one of four formulas per matrix by its diagonal; each gives the canonical quaternion
    (``w >= 0``) wherever its own trace is positive, so one formula whose trace is well above 0 for the
    whole batch serves all (the same values to rounding, the same derivatives).
    """
    U = np.asarray(U)
    m = U.reshape(*U.shape[:-2], 9)[..., _TRANSPOSED9]
    traces = m @ _QTRACE.T + 1.0
    lowest = traces.real.reshape(-1, 4).min(0)
    case = int(lowest.argmax()) if lowest.size else 3
    if not lowest.size or lowest[case] < 0.1:
        return mat3_to_quat(U)
    s = 2.0 * np.sqrt(traces[..., case])
    if case < 3:
        a, b = _QCASE_TEST[case]
        r = m.real
        s = np.where(r[..., a] < r[..., b], -s, s)
    return (m @ _QLIN[case] + _QCONST[case]) / s[..., None]


def _atan2(y, x):
    """:func:`analytic.atan2` of arrays of one dtype."""
    if y.dtype != np.complex128:
        return np.arctan2(y, x)
    yr, xr = y.real, x.real
    r2 = xr * xr + yr * yr
    if r2.min() > 0:
        return np.arctan2(yr, xr) + 1j * ((xr * y.imag - yr * x.imag) / r2)
    return analytic.atan2(y, x)


# Per Euler order: flat indices (3 b + a of Blender's mat[a][b], numpy M[..., b, a]) of the numerators
# B(j,k), B(i,k), B(i,j) and of the denominators B(k,k), B(i,i); where each slot's angle goes.
_EULER_TABLES = {}
for _order in EULER_ORDERS:
    _i, _j, _k = order_axes(_order)
    _slots = np.empty(3, dtype=int)
    _slots[[_i, _j, _k]] = [0, 1, 2]
    _EULER_TABLES[_order] = (
        np.array([3 * _k + _j, 3 * _k + _i, 3 * _j + _i]),
        np.array([3 * _k + _k, 3 * _i + _i]),
        np.concatenate([_slots, _slots + 3]),
        -1.0 if _order in ("XZY", "YXZ", "ZYX") else 1.0,
    )
_EULER_SIGNS = np.array([1.0, -1.0, 1.0, -1.0, -1.0, -1.0])


def _eulo2(M, order: str):
    """``mat3_normalized_to_eulo2``: the two Euler solutions (..., 3) of a normalized (..., 3, 3)."""
    numerators, denominators, slots, parity = _EULER_TABLES[order]
    i, j, _ = order_axes(order)
    flat = M.reshape(*M.shape[:-2], 9)
    cy = np.sqrt(flat[..., 3 * i + i] ** 2 + flat[..., 3 * j + i] ** 2)
    if not (cy.size and cy.real.min() > EULER_HYPOT_EPSILON):
        return _eulo2_general(M, order)
    y = flat[..., numerators]
    xd = flat[..., denominators]
    x = np.empty((*y.shape[:-1], 6), dtype=y.dtype)
    x[..., 0], x[..., 1], x[..., 2] = xd[..., 0], cy, xd[..., 1]
    x[..., 3:] = -x[..., :3]
    angles = _atan2(np.concatenate([y, y], -1) * _EULER_SIGNS, x)[..., slots]
    if parity < 0:
        angles = -angles
    return angles[..., :3], angles[..., 3:]


def _eulo2_general(M, order: str):
    i, j, k = order_axes(order)
    parity = order in ("XZY", "YXZ", "ZYX")

    def B(a, b):  # Blender's mat[a][b]
        return M[..., b, a]

    cy = analytic.norm(np.stack([B(i, i), B(i, j)], -1))
    ok = cy.real > EULER_HYPOT_EPSILON
    shape = (*M.shape[:-2], 3)
    e1 = np.zeros(shape, dtype=M.dtype)
    e2 = np.zeros(shape, dtype=M.dtype)
    e1[..., i] = np.where(ok, analytic.atan2(B(j, k), B(k, k)), analytic.atan2(-B(k, j), B(j, j)))
    e1[..., j] = analytic.atan2(-B(i, k), cy)
    e1[..., k] = np.where(ok, analytic.atan2(B(i, j), B(i, i)), 0.0)
    e2[..., i] = analytic.atan2(-B(j, k), -B(k, k))
    e2[..., j] = analytic.atan2(-B(i, k), -cy)
    e2[..., k] = analytic.atan2(-B(i, j), -B(i, i))
    e2 = np.where(ok[..., None], e2, e1)
    if parity:
        e1, e2 = -e1, -e2
    return e1, e2


def mat4_to_eulO(M, order: str):
    """(..., 3) ``mat4_to_eulO`` of ``M`` (..., 4, 4) or (..., 3, 3): axes normalized, the solution with
    the smaller ``Σ|angle|``."""
    return mat3_normalized_to_eulO(normalize_m3(M), order)


def mat3_normalized_to_eulO(M, order: str):
    """(..., 3) ``mat3_normalized_to_eulO`` of (..., 3, 3) taken as they are (``quat_to_eulO`` of a quaternion
    that is not of unit length gives what Blender gives): the solution with the smaller ``Σ|angle|``."""
    e1, e2 = _eulo2(np.asarray(M)[..., :3, :3], order)
    d1 = np.abs(e1.real) @ ONES3
    d2 = np.abs(e2.real) @ ONES3
    return np.where((d1 > d2)[..., None], e2, e1)


def compatible_eul(eul, old):
    """(..., 3) ``compatible_eul``: ``eul`` (..., 3) shifted by turns to be closest to ``old`` (..., 3) (the
    two broadcast)."""
    old = np.asarray(old)
    eul = np.asarray(eul)
    if eul.shape != old.shape:
        eul = np.broadcast_to(eul, np.broadcast_shapes(eul.shape, old.shape))
    two_pi = 2.0 * np.pi
    d = (eul - old).real
    up, down = d > np.pi, d < -np.pi
    if up.any() or down.any():
        shift = np.where(up, -np.floor(d / two_pi + 0.5), np.where(down, np.floor(-d / two_pi + 0.5), 0.0))
        eul = eul + shift * two_pi
        d = (eul - old).real
    a = np.abs(d)
    big = a > np.pi
    if big.any():
        small = a < np.pi / 2
        flip = big & small[..., NEXT] & small[..., AFTER]
        eul = eul + np.where(flip, np.where(d > 0, -two_pi, two_pi), 0.0)
    return eul if eul.flags.writeable else eul.copy()


def mat4_to_compatible_eulO(M, old, order: str):
    """(..., 3) ``mat4_to_compatible_eulO`` of ``M`` (..., 4, 4) or (..., 3, 3): the solution closest to
    ``old`` (..., 3)."""
    e1, e2 = _eulo2(normalize_m3(M), order)
    e1, e2 = compatible_eul(e1, old), compatible_eul(e2, old)
    old = np.asarray(old).real
    d1 = np.abs(e1.real - old) @ ONES3
    d2 = np.abs(e2.real - old) @ ONES3
    return np.where((d1 > d2)[..., None], e2, e1)


def quat_to_eulO(q, order: str = "XYZ") -> np.ndarray:
    """(..., 3) Blender's ``quat_to_eulO``: Euler angles of quaternions (..., 4) (not normalized first)."""
    return mat3_normalized_to_eulO(quat_to_mat3(np.asarray(q, dtype=np.float64)), order)


def eulO_to_quat(e, order: str = "XYZ") -> np.ndarray:
    """(..., 4) Blender's ``eulO_to_quat`` (and ``eul_to_quat`` for XYZ) of Euler angles (..., 3)."""
    e = np.asarray(e, dtype=np.float64)
    (i, j, k), parity = _ORDERS[order]
    ti = e[..., i] * 0.5
    tj = e[..., j] * (-0.5 if parity else 0.5)
    th = e[..., k] * 0.5
    ci, cj, ch = np.cos(ti), np.cos(tj), np.cos(th)
    si, sj, sh = np.sin(ti), np.sin(tj), np.sin(th)
    cc, cs, sc, ss = ci * ch, ci * sh, si * ch, si * sh
    a = np.empty((*e.shape[:-1], 3))
    a[..., i] = cj * sc - sj * cs
    a[..., j] = cj * ss + sj * cc
    a[..., k] = cj * cs - sj * sc
    q = np.concatenate([(cj * cc + sj * ss)[..., None], a], -1)
    if parity:
        q[..., j + 1] = -q[..., j + 1]
    return q


def axis_angle_to_quat(axis, angle) -> np.ndarray:
    """(..., 4) Blender's ``axis_angle_to_quat`` of ``axis`` (..., 3) and ``angle`` (...): a zero axis gives
    the identity."""
    axis = np.asarray(axis, dtype=np.float64)
    angle = np.asarray(angle, dtype=np.float64)
    length_sq = (axis * axis).sum(-1)
    ok = length_sq > 1.0e-35  # normalize_v3_v3's threshold
    unit = axis / np.sqrt(np.where(ok, length_sq, 1.0))[..., None]
    half = 0.5 * angle
    q = np.concatenate([np.cos(half)[..., None], unit * np.sin(half)[..., None]], -1)
    return np.where(ok[..., None], q, np.array([1.0, 0.0, 0.0, 0.0]))


def quat_to_axis_angle(q) -> tuple[np.ndarray, np.ndarray]:
    """Blender's ``quat_to_axis_angle`` of ``q`` (..., 4): ``(axis (..., 3), angle (...))``, angle in [0, 2π].

    Below a half-angle sine of 0.0005 the axis is not divided (so it is not unit length); a zero axis
    becomes +y.
    """
    q = np.asarray(q, dtype=np.float64)
    # Clipped: float32 rounds |w| <= 1 + ulp to 1 (Blender gives NaN for a stored |w| > 1, this does not).
    half = np.arccos(np.clip(q[..., 0], -1.0, 1.0))
    si = np.sin(half)
    si = np.where(np.abs(si) < 0.0005, 1.0, si)
    axis = q[..., 1:] / si[..., None]
    zero = np.all(axis == 0, axis=-1)
    axis = np.where(zero[..., None], np.array([0.0, 1.0, 0.0]), axis)
    return axis, 2.0 * half


def normalize_qt(q: np.ndarray) -> np.ndarray:
    """``normalize_qt``: a zero quaternion becomes (0, 1, 0, 0)."""
    length = np.sqrt((q * q).sum(-1))
    ok = length != 0
    return np.where(ok[..., None], q / np.where(ok, length, 1.0)[..., None], np.array([0.0, 1.0, 0.0, 0.0]))


def loc_eulO_size_to_mat4(loc, eul, size, order: str):
    """(..., 4, 4) ``loc_eulO_size_to_mat4``: location (..., 3), Euler angles (..., 3) in ``order``, size
    (..., 3)."""
    return loc_rot_size_to_mat4(loc, euler_to_matrix(eul, order), size)
