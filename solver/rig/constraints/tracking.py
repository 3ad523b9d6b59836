"""The constraints that turn the owner towards a target: Damped Track, Stretch To, Track To, Locked Track
(``damptrack_evaluate``, ``stretchto_evaluate``, ``trackto_evaluate``, ``locktrack_evaluate``)."""

from __future__ import annotations

import numpy as np

from ...errors import SolverError
from .. import analytic
from ..math_matrix import (
    FLT_EPSILON,
    LAST_ROW,
    column_norms_squared,
    cross,
    det3,
    dot,
    inverse3,
    mat4_to_size,
    normalize_m3,
    normalize_m4_ex,
    normalize_v3,
    orthogonalize_m4_stable,
    rescale_m4,
    skew,
)
from ..math_rotation import axis_angle_normalized_to_mat3
from .model import TRACK_AXES

_TRACK_DIRECTIONS = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [-1, 0, 0], [0, -1, 0], [0, 0, -1]], float)


def damped_track(matrix, target_vector, track_axis: int):
    """``damptrack_do_transform``: turn ``matrix`` (..., 4, 4) by the smallest rotation that points its
    ``track_axis`` (index into :data:`TRACK_AXES`) along ``target_vector`` (..., 3); location kept.

    Blender turns about ``normalize_v3(a × b)`` by ``acos(a · b)`` (``asin`` when the turn is small); away
    from opposite directions this is the rotation ``(a · b) I + [a × b]× + (a × b)(a × b)ᵀ / (1 + a · b)``,
    computed so.
    """
    matrix = np.asarray(matrix)
    tarvec, tarlen = normalize_v3(target_vector)
    shape = np.broadcast_shapes(matrix.shape[:-2], tarvec.shape[:-1])
    M3 = matrix[..., :3, :3]
    sign = 1.0 if track_axis < 3 else -1.0
    raw = M3[..., :, track_axis % 3]
    obvec, oblen = normalize_v3(raw)
    cos = dot(obvec, tarvec) * sign
    if tarlen.real.min() > 0 and oblen.real.min() > 0 and cos.real.min() > -0.5:
        v = cross(obvec, tarvec) * sign
        outer = v[..., :, None] * (v / (1.0 + cos)[..., None])[..., None, :]
        R = cos[..., None, None] * np.eye(3) + skew(v) + outer
        out = np.array(np.broadcast_to(matrix, (*shape, 4, 4)), dtype=np.result_type(matrix, R))
        out[..., :3, :3] = R @ M3
        return out
    return _damped_track_general(np.broadcast_to(matrix, (*shape, 4, 4)), tarvec, tarlen, track_axis)


def _damped_track_general(matrix, tarvec, tarlen, track_axis):
    M3 = matrix[..., :3, :3]
    obvec, oblen = normalize_v3(M3 @ _TRACK_DIRECTIONS[track_axis])
    obvec = np.where((oblen.real == 0)[..., None], _TRACK_DIRECTIONS[track_axis], obvec)
    raxis = cross(obvec, tarvec)
    cos = dot(obvec, tarvec)
    rangle = analytic.acos(np.where(cos.real > 1, 1.0, np.where(cos.real < -1, -1.0, cos)))
    raxis, norm = normalize_v3(raxis)
    opposite = norm.real < FLT_EPSILON
    keep = (tarlen.real == 0) | (opposite & (np.abs(rangle.real) < np.pi - 0.01))
    if np.any(opposite & ~keep):
        other = normalize_v3(cross(obvec, M3 @ _TRACK_DIRECTIONS[(track_axis + 1) % 6]))
        raxis = np.where(opposite[..., None], other[0], raxis)
        rangle = np.where(opposite, np.pi, rangle)
        keep = keep | (opposite & (other[1].real == 0))
    small = ~opposite & (norm.real < 0.1)
    if np.any(small):
        asin = analytic.asin(np.where(small, norm, 0.0))
        rangle = np.where(small, np.where(rangle.real > np.pi / 2, np.pi - asin, asin), rangle)
    R = axis_angle_normalized_to_mat3(raxis, np.sin(rangle), np.cos(rangle))
    parallel = opposite & (cos.real > 0) & (tarlen.real > 0)
    if np.any(parallel):  # a turn below FLT_EPSILON: taken (continuously) rather than skipped
        v = cross(obvec, tarvec)
        outer = v[..., :, None] * (v / (1.0 + cos)[..., None])[..., None, :]
        turn = cos[..., None, None] * np.eye(3) + skew(v) + outer
        R = np.where(parallel[..., None, None], turn, R)
        keep = keep & ~parallel
    out = np.array(matrix, dtype=np.result_type(matrix, R))
    out[..., :3, :3] = R @ M3
    return np.where(keep[..., None, None], matrix, out)


def damptrack_evaluate(cs, cob, tars, ctx):
    """Damped Track (``damptrack_evaluate``): the smallest turn that points an axis at the target."""
    axis = TRACK_AXES.index(cs.get("track_axis"))
    return damped_track(cob, tars[0][..., :3, 3] - cob[..., :3, 3], axis)


def _interpf(target, origin, fac):
    return fac * target + (1.0 - fac) * origin


def _bulge_factors(cs, ratio):
    """(sx, sz) of Stretch To's volume preservation for ``rest / dist`` ratios ``ratio`` (None: 1)."""
    v = cs.values
    volume = cs.get("volume")
    if volume == "NO_VOLUME":
        return None, None
    bulge = ratio if cs.bulge_one else np.exp(v["bulge"] * np.log(ratio))
    smooth = v["bulge_smooth"]
    if cs.get("use_bulge_max"):
        bmax, rng = v["_bmax"], v["_bmax_range"]
        hard = np.where(bulge.real < bmax, bulge, bmax)
        soft = 1.0 + rng * analytic.atan2((bulge - 1.0) * v["_bmax_fac"], 1.0) / (np.pi / 2)
        bulge = np.where(bulge.real > 1.0, _interpf(soft, hard, smooth), bulge)
    if cs.get("use_bulge_min"):
        bmin, rng = v["_bmin"], v["_bmin_range"]
        hard = np.where(bulge.real > bmin, bulge, bmin)
        soft = 1.0 - rng * analytic.atan2((1.0 - bulge) * v["_bmin_fac"], 1.0) / (np.pi / 2)
        bulge = np.where(bulge.real < 1.0, _interpf(soft, hard, smooth), bulge)
    if volume == "VOLUME_XZX":
        sx = np.sqrt(bulge)
        return sx, sx
    if volume == "VOLUME_X":
        return bulge, None
    if volume == "VOLUME_Z":
        return None, bulge
    raise SolverError(f"Stretch To constraint {cs.names[0]!r}: unknown volume mode {volume!r}")


def _stretch_swing(cs, cob, T):
    """Stretch To with ``SWING_Y`` when nothing degenerates: Y turned onto the target by the smallest
    rotation, ``(a · b) I + [a × b]× + (a × b)(a × b)ᵀ / (1 + a · b)``, which on the X and Z axes (made
    perpendicular to Y, the shear removed) is ``w - (a + b)(b · w) / (1 + a · b)``; Y becomes the
    vector to the target over the rest length. None when an axis or the target vector vanishes, X and
    Z are sheared beyond 1e-4 or the turn is beyond 120°: then the general port runs."""
    A = cob[..., :3, :3]
    h = cob[..., :3, 3]
    Y = A[..., :, 1]
    YA = (Y[..., None, :] @ A)[..., 0, :]  # Y·X, Y·Y, Y·Z
    yy = YA[..., 1]
    d = T[..., :3, 3] - h
    dd = dot(d, d)
    if not (yy.real.min() > 0 and dd.real.min() > 0):
        return None
    XZ = A[..., :, ::2] - Y[..., :, None] * (YA[..., ::2] / yy[..., None])[..., None, :]
    n2 = column_norms_squared(XZ).real
    xz = dot(XZ[..., 0], XZ[..., 1]).real
    ylen, dist = np.sqrt(yy), np.sqrt(dd)
    c = dot(Y, d) / (ylen * dist)
    sheared = (xz * xz - 1e-8 * n2[..., 0] * n2[..., 1]).max() > 0
    if not (n2.min() > 1e-35 and c.real.min() > -0.5) or sheared:
        return None
    coef = (d[..., None, :] @ XZ) / (dist * (1.0 + c))[..., None, None]
    RXZ = XZ - (Y / ylen[..., None] + d / dist[..., None])[..., :, None] * coef
    rest = cs.values["rest_length"]
    sx, sz = _bulge_factors(cs, rest * ylen / dist)
    out = np.empty((*RXZ.shape[:-2], 4, 4), dtype=RXZ.dtype)
    out[..., 3, :] = LAST_ROW
    out[..., :3, 3] = h
    out[..., :3, 1] = d / rest[..., None]
    if sx is None and sz is None:
        out[..., :3, ::2] = RXZ
    else:
        out[..., :3, 0] = RXZ[..., 0] if sx is None else RXZ[..., 0] * sx[..., None]
        out[..., :3, 2] = RXZ[..., 1] if sz is None else RXZ[..., 1] * sz[..., None]
    return out


def stretchto_evaluate(cs, cob, tars, ctx):
    """Stretch To (``stretchto_evaluate``): Y turned onto the target and stretched to it, volume kept as
    set."""
    T = tars[0]
    plane = cs.get("keep_axis")
    if plane == "SWING_Y":
        out = _stretch_swing(cs, cob, T)
        if out is not None:
            return out
        cob = orthogonalize_m4_stable(cob, 1, unit=False)
    cob, size = normalize_m4_ex(cob)
    xx, zz = cob[..., :3, 0], cob[..., :3, 2]
    vec, dist = normalize_v3(T[..., :3, 3] - cob[..., :3, 3])
    dist = dist / size[..., 1]
    rest = cs.values["rest_length"]
    scale_y = dist / rest
    sx, sz = _bulge_factors(cs, rest / dist)
    one = np.ones_like(scale_y)
    factors = np.broadcast_arrays(one if sx is None else sx, scale_y, one if sz is None else sz)
    size = size * np.stack(factors, -1)
    if plane == "SWING_Y":
        cob = damped_track(cob, vec, 1)
    else:
        cob = np.array(np.broadcast_to(cob, (*vec.shape[:-1], 4, 4)), dtype=np.result_type(cob, vec))
        cob[..., :3, 1] = vec
        if plane == "PLANE_X":
            orth, _ = normalize_v3(cross(xx, vec))
            cob[..., :3, 2] = orth
            cob[..., :3, 0] = normalize_v3(cross(vec, orth))[0]
        else:
            orth, _ = normalize_v3(cross(zz, vec))
            cob[..., :3, 0] = -orth
            cob[..., :3, 2] = normalize_v3(cross(vec, orth))[0]
    return rescale_m4(cob, size)


def _basis_cross(n, m):
    d = n - m
    return 1 if d in (1, -2) else (-1 if d in (-1, 2) else 0)


def trackto_evaluate(cs, cob, tars, ctx):
    """Track To (``trackto_evaluate``): an axis pointed at the target, another kept up."""
    T = tars[0]
    axis = TRACK_AXES.index(cs.get("track_axis"))
    up = ("UP_X", "UP_Y", "UP_Z").index(cs.get("up_axis"))
    size = mat4_to_size(cob)
    shape = np.broadcast_shapes(np.shape(cob)[:-2], np.shape(T)[:-2])
    out = np.array(np.broadcast_to(cob, (*shape, 4, 4)), dtype=np.result_type(cob, T))
    out[..., :3, :3] = np.broadcast_to(size[..., None, :] * np.eye(3), (*shape, 3, 3))
    vec = out[..., :3, 3] - T[..., :3, 3]
    n, length = normalize_v3(vec)
    n = np.where((length.real == 0)[..., None], np.array([0.0, 0.0, 1.0]), n)
    if axis > 2:
        axis -= 3
    else:
        n = -n
    u = np.broadcast_to(T[..., :3, 2], n.shape) if cs.get("use_target_z") else np.array([0.0, 0.0, 1.0])
    nn = dot(n, n)
    proj = u - n * (dot(u, n) / np.where(nn.real != 0, nn, 1.0))[..., None]
    proj, plen = normalize_v3(proj)
    proj = np.where((plen.real == 0)[..., None], np.array([0.0, 1.0, 0.0]), proj)
    right, _ = normalize_v3(cross(proj, n))
    if axis == up:
        return out
    m = np.zeros((*n.shape[:-1], 3, 3), dtype=n.dtype)
    m[..., :, 3 - axis - up] = _basis_cross(axis, up) * right
    m[..., :, up] = proj
    m[..., :, axis] = n
    out[..., :3, :3] = m @ out[..., :3, :3]
    return out


def locktrack_evaluate(cs, cob, tars, ctx):
    """Locked Track (``locktrack_evaluate``): an axis pointed at the target, turning about a locked axis."""
    T = tars[0]
    track = TRACK_AXES.index(cs.get("track_axis"))
    lock = ("LOCK_X", "LOCK_Y", "LOCK_Z").index(cs.get("lock_axis"))
    sign = -1.0 if track > 2 else 1.0
    t = track % 3
    shape = np.broadcast_shapes(np.shape(cob)[:-2], np.shape(T)[:-2])
    cob = np.broadcast_to(cob, (*shape, 4, 4))
    if t == lock:
        return np.array(cob)
    vec = T[..., :3, 3] - cob[..., :3, 3]
    axis = cob[..., :3, lock]
    aa = dot(axis, axis)
    vec2 = axis * (dot(vec, axis) / np.where(aa.real != 0, aa, 1.0))[..., None]
    tot = np.zeros((*shape, 3, 3), dtype=np.result_type(cob, T))
    tot[..., :, t] = sign * normalize_v3(vec - vec2)[0]
    tot[..., :, lock] = normalize_v3(axis)[0]
    third = 3 - t - lock
    tot[..., :, third] = cross(tot[..., :, (third + 1) % 3], tot[..., :, (third + 2) % 3])
    unit = normalize_m3(cob)
    tot = tot @ inverse3(unit)
    tot = np.where(
        (det3(tot).real == 0)[..., None, None],
        np.eye(3),
        tot,
    )
    out = np.array(cob, dtype=tot.dtype)
    out[..., :3, :3] = tot @ cob[..., :3, :3]
    return out
