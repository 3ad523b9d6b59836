"""Blender's vector and matrix math (``math_vector.cc``, ``math_matrix.cc``), batched and analytic.

Each function ports the Blender function its docstring names, so that it reads beside Blender's source.

Conventions:

* Matrices are ``(..., 4, 4)`` affine matrices acting on column vectors (numpy ``M[row, col]``); Blender's C
  arrays ``mat[i][j]`` are column ``i``, row ``j``, so Blender's ``mat[1]`` (a bone's Y axis) is
  ``M[..., :3, 1]`` here.
* Every function takes float64 or complex128 arrays with arbitrary leading batch dimensions and is
  analytic in them (complex-step differentiation, see :mod:`.analytic`): the branches Blender takes on
  values (degenerate vectors, thresholds) are taken on real parts.

Blender computes in float32; these ports compute in float64 and agree with it to float32 rounding.
"""

from __future__ import annotations

import numpy as np

from . import analytic

#: Blender's ``FLT_EPSILON``.
FLT_EPSILON = 1.1920929e-07

#: Cyclic successors of the axes 0, 1, 2: ``NEXT[i] = i + 1``, ``AFTER[i] = i + 2`` (mod 3).
NEXT = np.array([1, 2, 0])
AFTER = np.array([2, 0, 1])
_CROSS_A = np.array([NEXT, AFTER])  # a[next], a[after]
_CROSS_B = np.array([AFTER, NEXT])  # b[after], b[next]
# cof[i, j] = A[i+1, j+1] A[i+2, j+2] - A[i+1, j+2] A[i+2, j+1]  (indices mod 3): two gathers of
# (2, 3, 3) entries, multiplied, the second product subtracted from the first.
_R1, _R2 = np.broadcast_to(NEXT[:, None], (3, 3)), np.broadcast_to(AFTER[:, None], (3, 3))
_C1, _C2 = np.broadcast_to(NEXT[None, :], (3, 3)), np.broadcast_to(AFTER[None, :], (3, 3))
_COF_ROWS_1, _COF_COLS_1 = np.array([_R1, _R1]), np.array([_C1, _C2])
_COF_ROWS_2, _COF_COLS_2 = np.array([_R2, _R2]), np.array([_C2, _C1])
# Skew-symmetric [w]x from w: entry (i, j) is SKEW_SIGN[i, j] * w[SKEW_INDEX[i, j]].
_SKEW_INDEX = np.array([[0, 2, 1], [2, 0, 0], [1, 0, 0]])
_SKEW_SIGN = np.array([[0.0, -1.0, 1.0], [1.0, 0.0, -1.0], [-1.0, 1.0, 0.0]])
_EYE3 = np.eye(3)
_EYE3.setflags(write=False)
#: The last row of an affine matrix.
LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])
_ZERO3 = np.zeros(3)
#: Sums over a last axis of three: ``x @ ONES3``.
ONES3 = np.ones(3)


def _dtype(*arrays):
    return np.complex128 if any(np.iscomplexobj(a) for a in arrays) else np.float64


def dot(a, b):
    """(...) ``a · b`` of ``a``, ``b`` (..., n) over the last axis (no conjugation)."""
    a, b = np.asarray(a), np.asarray(b)
    return (a[..., None, :] @ b[..., :, None])[..., 0, 0]


def cross(a, b):
    """(..., 3) ``a × b`` of ``a``, ``b`` (..., 3) (analytic in complex inputs)."""
    a, b = np.asarray(a), np.asarray(b)
    products = a[..., _CROSS_A] * b[..., _CROSS_B]
    return products[..., 0, :] - products[..., 1, :]


def skew(w):
    """(..., 3, 3) ``[w]×``, the matrix of ``v ↦ w × v``, of vectors (..., 3)."""
    return np.asarray(w)[..., _SKEW_INDEX] * _SKEW_SIGN


def normalize_v3(v):
    """``normalize_v3_v3``: (unit (..., 3), length (...)); vectors with ``|v|² <= 1e-35`` give zeros."""
    v = np.asarray(v)
    d = dot(v, v)
    if d.size and d.real.min() > 1e-35:
        length = np.sqrt(d)
        return v / length[..., None], length
    ok = d.real > 1e-35
    length = np.sqrt(np.where(ok, d, 1.0))
    unit = np.where(ok[..., None], v / length[..., None], 0.0)
    return unit, np.where(ok, length, 0.0)


def det3(M):
    """(...) determinant of the upper-left 3×3 block of (..., 3, 3) or (..., 4, 4) matrices
    (``mat4_to_volume_scale``)."""
    M = np.asarray(M)
    return dot(M[..., :3, 0], cross(M[..., :3, 1], M[..., :3, 2]))


def column_norms_squared(M):
    """(..., n) the squared lengths of the columns of the upper 3 rows of (..., 3 or 4, n) matrices."""
    A = np.asarray(M)[..., :3, :]
    return ONES3 @ (A * A)


def cofactors3(M):
    """(..., 3, 3) the cofactor matrix of the upper-left 3×3 block of ``M``: ``det(M) M⁻ᵀ``."""
    A = np.asarray(M)[..., :3, :3]
    products = A[..., _COF_ROWS_1, _COF_COLS_1] * A[..., _COF_ROWS_2, _COF_COLS_2]
    return products[..., 0, :, :] - products[..., 1, :, :]


def inverse3(M):
    """(..., 3, 3) the inverse of the upper-left 3×3 block of ``M`` (closed form, analytic)."""
    M = np.asarray(M)
    C = cofactors3(M)
    det = dot(M[..., :3, 0], C[..., :, 0])
    return C.swapaxes(-1, -2) / det[..., None, None]


def inverse_affine(M):
    """(..., 4, 4) the inverse of affine matrices (last row ``0 0 0 1``), in closed form: the 3×3 block
    inverted through its cofactors and determinant, the translation carried back."""
    M = np.asarray(M)
    R = inverse3(M)
    out = np.empty(M.shape, dtype=R.dtype)
    out[..., :3, :3] = R
    out[..., :3, 3:] = -(R @ M[..., :3, 3:])
    out[..., 3, :] = LAST_ROW
    return out


def cbrt_abs(x):
    """(...) ``cbrtf(fabsf(x))`` of ``x`` (...), analytic away from 0 (0 gives 0)."""
    x = np.asarray(x)
    a = np.where(x.real < 0, -x, x)
    ok = a.real > 0
    return np.where(ok, np.exp(np.log(np.where(ok, a, 1.0)) / 3.0), 0.0)


def mat4_to_size(M):
    """(..., 3) ``mat4_to_size``: lengths of the three axes (columns)."""
    return np.sqrt(column_norms_squared(np.asarray(M)[..., :3, :3]))


def mat4_to_size_fix_shear(M):
    """(..., 3) ``mat4_to_size_fix_shear``: axis lengths rescaled to the matrix's true volume."""
    size = mat4_to_size(M)
    volume = np.prod(size, axis=-1)
    ok = volume.real != 0
    ratio = det3(M) / np.where(ok, volume, 1.0)
    return np.where(ok[..., None], size * cbrt_abs(ratio)[..., None], size)


def rescale_m4(M, scale):
    """(..., 4, 4) ``rescale_m4``: a copy of ``M`` (..., 4, 4) (or (..., 3, 3)) with its three axes
    (columns) multiplied by ``scale`` (..., 3), the batch dimensions broadcast."""
    M, scale = np.asarray(M), np.asarray(scale)
    if M.shape[:-2] == scale.shape[:-1] and (M.dtype == scale.dtype or M.dtype == np.complex128):
        out = M.copy()
    else:
        shape = np.broadcast_shapes(M.shape, (*scale.shape[:-1], 1, 1))
        out = np.array(np.broadcast_to(M, shape), dtype=_dtype(M, scale))
    out[..., :3, :3] *= scale[..., None, :]
    return out


def normalize_m4_ex(M):
    """``normalize_m4_ex``: (a copy of ``M`` (..., 4, 4) with unit axes, axis lengths (..., 3)); axes
    with ``|axis|² <= 1e-35`` become zero with length 0."""
    M = np.asarray(M)
    A = M[..., :3, :3]
    d = column_norms_squared(A)
    out = M.copy() if M.dtype == np.complex128 else M.astype(np.float64)
    if d.size and d.real.min() > 1e-35:
        lengths = np.sqrt(d)
        out[..., :3, :3] = A / lengths[..., None, :]
        return out, lengths
    ok = d.real > 1e-35
    lengths = np.sqrt(np.where(ok, d, 1.0))
    out[..., :3, :3] = np.where(ok[..., None, :], A / lengths[..., None, :], 0.0)
    return out, np.where(ok, lengths, 0.0)


def orthogonalize_m4_stable(M, axis: int = 1, unit: bool = False):
    """(..., 4, 4) ``orthogonalize_m4_stable``: a copy of ``M`` (..., 4, 4) without its shear around one
    axis.

    The other two axes are projected off the primary one, then turned symmetrically away from each other
    until perpendicular (only when their angle's cosine is within ``(1e-4, 1 - FLT_EPSILON)``), rescaled
    to keep area unless ``unit``; with ``unit`` all three axes come out unit length.
    """
    M = np.asarray(M)
    if axis == 1 and M.ndim >= 3:
        out = _orthogonalize_m4_stable_y(M, unit)
        if out is not None:
            return out
    return _orthogonalize_m4_stable(M, axis, unit)


def _orthogonalize_m4_stable_y(M, unit):
    """:func:`orthogonalize_m4_stable` about Y when no axis vanishes and X, Z come out perpendicular within
    1e-4 (nothing to turn): projections only. None otherwise."""
    A = M[..., :3, :3]
    Y = A[..., :, 1]
    YA = (Y[..., None, :] @ A)[..., 0, :]  # Y·X, Y·Y, Y·Z
    yy = YA[..., 1]
    if not yy.real.min() > 0:
        return None
    XZ = A[..., :, ::2] - Y[..., :, None] * (YA[..., ::2] / yy[..., None])[..., None, :]
    n2 = column_norms_squared(XZ)
    xz = dot(XZ[..., 0], XZ[..., 1]).real
    nr = n2.real
    if not (nr.min() > 1e-35 and (xz * xz - 1e-8 * nr[..., 0] * nr[..., 1]).max() <= 0):
        return None
    out = M.copy() if M.dtype == np.complex128 else M.astype(np.float64)
    if unit:
        out[..., :3, 1] = Y / np.sqrt(yy)[..., None]
        out[..., :3, ::2] = XZ / np.sqrt(n2)[..., None, :]
    else:
        out[..., :3, ::2] = XZ
    return out


def _orthogonalize_m4_stable(M, axis, unit):
    M = np.array(M, dtype=_dtype(M))
    order = {0: (0, 1, 2), 1: (1, 0, 2), 2: (2, 0, 1)}[axis]
    v1, v2, v3 = (M[..., :3, i] for i in order)
    len_sq = dot(v1, v1)
    has = len_sq.real > 0
    safe = np.where(has, len_sq, 1.0)[..., None]
    v2 = np.where(has[..., None], v2 - v1 * (dot(v2, v1)[..., None] / safe), v2)
    v3 = np.where(has[..., None], v3 - v1 * (dot(v3, v1)[..., None] / safe), v3)
    if unit:
        v1 = np.where(has[..., None], v1 / np.sqrt(safe), v1)
    n2, l2 = normalize_v3(v2)
    n3, l3 = normalize_v3(v3)
    cos = dot(n2, n3)
    abs_cos = np.abs(cos.real)
    fix = (abs_cos > 1e-4) & (abs_cos < 1.0 - FLT_EPSILON)
    if np.any(fix):
        c = np.where(fix, cos, 0.5)
        angle = analytic.acos(c)
        target = angle + (np.pi / 2 - angle) / 2
        m2 = n2 - n3 * c[..., None]
        m2 = m2 * (np.sin(target) / analytic.norm(m2))[..., None] + n3 * np.cos(target)[..., None]
        m3, _ = normalize_v3(cross(cross(m2, n3), m2))
        if not unit:
            fac = np.sqrt(np.sin(angle))
            v2 = np.where(fix[..., None], m2 * (l2 * fac)[..., None], v2)
            v3 = np.where(fix[..., None], m3 * (l3 * fac)[..., None], v3)
        n2 = np.where(fix[..., None], m2, n2)
        n3 = np.where(fix[..., None], m3, n3)
    if unit:
        v2, v3 = n2, n3
    for i, v in zip(order, (v1, v2, v3), strict=False):
        M[..., :3, i] = v
    return M


def mat4_to_loc_rot_size(M):
    """``mat4_to_loc_rot_size`` of ``M`` (..., 4, 4): (location (..., 3), rotation (..., 3, 3), size
    (..., 3)); a negative determinant is given to the size (all three negated) so that the rotation stays
    proper."""
    M = np.asarray(M)
    A = M[..., :3, :3]
    d = column_norms_squared(A)
    if d.size and d.real.min() > 1e-35:
        size = np.sqrt(d)
        rot = A / size[..., None, :]
    else:
        ok = d.real > 1e-35
        size = np.sqrt(np.where(ok, d, 1.0))
        rot = np.where(ok[..., None, :], A / size[..., None, :], 0.0)
        size = np.where(ok, size, 0.0)
    negative = det3(rot).real < 0
    if negative.any():
        rot = np.where(negative[..., None, None], -rot, rot)
        size = np.where(negative[..., None], -size, size)
    return M[..., :3, 3], rot, size


def loc_rot_size_to_mat4(location, rotation, size):
    """``loc_rot_size_to_mat4``: (..., 4, 4) from location (..., 3), rotation (..., 3, 3), size (..., 3)."""
    location, rotation, size = (np.asarray(x) for x in (location, rotation, size))
    shape = np.broadcast_shapes(location.shape[:-1], rotation.shape[:-2], size.shape[:-1])
    M = np.empty((*shape, 4, 4), dtype=_dtype(location, rotation, size))
    M[..., :3, :3] = rotation * size[..., None, :]
    M[..., :3, 3] = location
    M[..., 3, :] = LAST_ROW
    return M


def affine(rotscale3, location):
    """(..., 4, 4) the affine matrices of 3×3 blocks (..., 3, 3) and translations (..., 3)."""
    rotscale3, location = np.asarray(rotscale3), np.asarray(location)
    shape = np.broadcast_shapes(rotscale3.shape[:-2], location.shape[:-1])
    M = np.empty((*shape, 4, 4), dtype=_dtype(rotscale3, location))
    M[..., :3, :3] = rotscale3
    M[..., :3, 3] = location
    M[..., 3, :] = LAST_ROW
    return M


def with_translation(M, location):
    """(..., 4, 4) a copy of ``M`` with its translation replaced by ``location`` (..., 3)."""
    if (location.ndim == 1 or M.shape[:-2] == location.shape[:-1]) and (
        M.dtype == location.dtype or M.dtype == np.complex128
    ):
        out = M.copy()
    else:
        shape = np.broadcast_shapes(M.shape, (*location.shape[:-1], 1, 1))
        out = np.array(np.broadcast_to(M, shape), dtype=_dtype(M, location))
    out[..., :3, 3] = location
    return out


def mul_v3_m4v3(M, p):
    """(..., 3) ``mul_v3_m4v3``: the point ``p`` (..., 3) transformed by ``M`` (..., 4, 4)."""
    M, p = np.asarray(M), np.asarray(p)
    return (M[..., :3, :3] @ p[..., :, None])[..., 0] + M[..., :3, 3]


def normalize_m3(M):
    """``normalize_m3`` on a copy: the 3×3 parts of (..., 4, 4) or (..., 3, 3) ``M`` with unit columns (zero
    columns stay zero)."""
    A = np.asarray(M)[..., :3, :3]
    d = column_norms_squared(A)
    if d.size and d.real.min() > 1e-35:
        return A / np.sqrt(d)[..., None, :]
    units, _ = normalize_v3(A.swapaxes(-1, -2))
    return units.swapaxes(-1, -2)


def orthogonalize_m4_y(M):
    """(..., 4, 4) ``orthogonalize_m4(M, 1)`` (the non-stable one, about Y) of (..., 4, 4) matrices."""
    M = np.array(M)
    size = mat4_to_size(M)
    R0, R1, R2 = (M[..., :3, i] for i in range(3))
    R1 = normalize_v3(R1)[0]
    first = dot(R1, R0).real < 1
    second = ~first & (dot(R0, R2).real < 1)
    a2 = normalize_v3(cross(R0, R1))[0]
    a0 = cross(R1, a2)
    b0 = normalize_v3(cross(R1, R2))[0]
    b2 = cross(b0, R1)
    vec = np.stack([R1[..., 1], R1[..., 2], R1[..., 0]], -1)
    c0 = normalize_v3(cross(R1, vec))[0]
    c2 = cross(c0, R1)
    new0 = np.where(first[..., None], a0, np.where(second[..., None], b0, c0))
    new2 = np.where(first[..., None], a2, np.where(second[..., None], b2, c2))
    M[..., :3, 0], M[..., :3, 1], M[..., :3, 2] = new0, R1, new2
    return rescale_m4(M, size)
