"""The B-Bone curve of one bone, ported function by function from Blender's ``armature.cc``
(``BKE_pchan_bbone_spline_setup`` and the helpers it calls): the rest shape of every B-Bone, the
segment matrices :func:`spline_matrices` gives, and the reference the stacked evaluation is tested
against."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ...errors import SolverError
from .. import analytic
from ..math_rotation import axis_angle_normalized_to_mat3

if TYPE_CHECKING:
    from .model import BBone, BBoneHandle

#: polyline that measures the curve's length.
MAX_SEGMENTS = 32
#: Blender's threshold (``BKE_pchan_bbone_spline_params_get``) above which a pose scale is non-uniform.
UNIFORM_SCALE_EPSILON = 1e-6


def _normalize(v, eps: float = 1e-35):
    """Blender's ``normalize_v3``: (unit vector, length); a vector with ``|v|² <= 1e-35`` becomes zero."""
    d2 = np.sum(v * v, axis=-1)
    ok = d2.real > eps
    d = np.sqrt(np.where(ok, d2, 1.0))
    unit = np.where(ok[..., None], v / d[..., None], 0.0)
    return unit, np.where(ok, d, 0.0)


def vec_roll_to_mat3(vec, roll):
    """(..., 3, 3) ``vec_roll_to_mat3``: the rotation taking +y to ``vec``'s direction, then rolled."""
    nor, _ = _normalize(vec)
    x, y, z = nor[..., 0], nor[..., 1], nor[..., 2]
    safe, critical = 6.1e-3, 2.5e-4
    theta = 1 + y
    theta_alt = x * x + z * z
    regular = (theta.real > safe) | (theta_alt.real > critical * critical)
    theta = np.where(theta.real <= safe, theta_alt * 0.5 + theta_alt * theta_alt * 0.125, theta)
    theta = np.where(regular, theta, 1.0)
    B = np.zeros((*nor.shape[:-1], 3, 3), dtype=nor.dtype)
    B[..., 1, 0], B[..., 0, 1] = -x, x
    B[..., 1, 1], B[..., 2, 1], B[..., 1, 2] = y, z, -z
    B[..., 0, 0] = 1 - x * x / theta
    B[..., 2, 2] = 1 - z * z / theta
    B[..., 0, 2] = B[..., 2, 0] = -x * z / theta
    B = np.where(regular[..., None, None], B, np.diag([-1.0, -1.0, 1.0]))
    return axis_angle_normalized_to_mat3(nor, np.sin(roll), np.cos(roll)) @ B


def _twist_y(M):
    """``quat_split_swing_and_twist(mat3_to_quat(M), 1)``: the twist angle of M about its y axis."""
    cols = analytic.norm(M, axis=-2)
    M = np.where((cols.real > 0)[..., None, :], M / np.where(cols.real > 0, cols, 1.0)[..., None, :], M)
    det = np.linalg.det(M)
    M = np.where(~np.isfinite(det.real)[..., None, None], np.eye(3), M)
    M = np.where((det.real < 0)[..., None, None], -M, M)
    m = {(r, c): M[..., r, c] for r in range(3) for c in range(3)}

    def branch(trace, flip):
        trace = np.where(trace.real > 0, trace, 1.0)
        s = 2 * np.sqrt(trace)
        return np.where(flip, -s, s)

    # mat3_normalized_to_quat_fast, keeping (w, y) up to one positive factor.
    sx = branch(1 + m[0, 0] - m[1, 1] - m[2, 2], m[2, 1].real < m[1, 2].real)
    sy = branch(1 - m[0, 0] + m[1, 1] - m[2, 2], m[0, 2].real < m[2, 0].real)
    sz = branch(1 - m[0, 0] - m[1, 1] + m[2, 2], m[1, 0].real < m[0, 1].real)
    sw = branch(1 + m[0, 0] + m[1, 1] + m[2, 2], np.zeros(sx.shape, bool))
    candidates = [
        ((m[2, 1] - m[1, 2]) / sx, (m[1, 0] + m[0, 1]) / sx),
        ((m[0, 2] - m[2, 0]) / sy, sy / 4),
        ((m[1, 0] - m[0, 1]) / sz, (m[2, 1] + m[1, 2]) / sz),
        (sw / 4, (m[0, 2] - m[2, 0]) / sw),
    ]
    negative_z = m[2, 2].real < 0
    pick = np.where(
        negative_z, np.where(m[0, 0].real > m[1, 1].real, 0, 1), np.where(m[0, 0].real < -m[1, 1].real, 2, 3)
    )
    w = np.choose(pick, [c[0] for c in candidates])
    y = np.choose(pick, [c[1] for c in candidates])
    flip = w.real < 0
    return 2 * analytic.atan2(np.where(flip, -y, y), np.where(flip, -w, w))


def _mat3_vec_to_roll(mat, vec):
    """``mat3_vec_to_roll``: the roll that, with ``vec``, gives the orientation closest to ``mat``."""
    vecmat = vec_roll_to_mat3(vec, np.zeros(vec.shape[:-1]))
    return _twist_y(np.linalg.inv(vecmat) @ mat)


def _circle_factor(t1, t2):
    """``cubic_tangent_factor_circle_v3`` for unit tangents, in the closed form
    ``1 / (2 (1 + cos(acos(t1·t2) / 2)))`` of Blender's ``(1 - cos a) / (2 sin² a)``."""
    d = np.sum(t1 * t2, axis=-1)
    eps = 1e-5
    inside = (d.real <= 1 - eps) & (d.real >= -1 + eps)
    c = np.sqrt((1 + np.where(inside, d, 0.0)) / 2)
    value = 1 / (2 * (1 + c))
    return np.where(inside, value, np.where(d.real > 1 - eps, 0.25, 0.5))


def _apply(M, p):
    """Affine matrices (..., 4, 4) applied to points (..., 3)."""
    return np.einsum("...ij,...j->...i", M[..., :3, :3], p) + M[..., :3, 3]


def _handle_scale(handle: BBoneHandle, pose, parent_pose):
    """(..., 3) ``mat4_to_size(BKE_armature_mat_pose_to_bone(handle, handle.pose_mat))`` for a handle
    whose parent (if any) it inherits fully: the column lengths of ``inv(rotscale) @ pose``."""
    rotscale = (
        handle.matrix_local[:3, :3]
        if handle.parent is None
        else (parent_pose[..., :3, :3] @ handle.parent_offset[:3, :3])
    )
    return analytic.norm(np.linalg.inv(rotscale) @ pose[..., :3, :3], axis=-2)


def checked_pose(what: str, bb: BBone, value):
    if value is None:
        raise SolverError(f"B-Bone {bb.name!r} needs the posed matrix of {what}")
    M = np.asarray(value)
    if M.shape[-2:] != (4, 4):
        raise SolverError(
            f"B-Bone {bb.name!r}: the posed matrix of {what} must have shape (..., 4, 4), got {M.shape}"
        )
    if not np.issubdtype(M.dtype, np.number) or not np.all(np.isfinite(M)):
        raise SolverError(f"B-Bone {bb.name!r}: the posed matrix of {what} must be finite")
    return M if np.iscomplexobj(M) else M.astype(np.float64)


def checked_inputs(bb: BBone, pose, prev_pose, next_pose, prev_parent_pose, next_parent_pose):
    """The matrices the curve needs, checked and broadcast to one batch shape (None where not needed)."""
    need = {"pose": pose}
    names = {"pose": f"the bone {bb.name!r}"}
    if bb.start is not None:
        need["prev"], names["prev"] = prev_pose, f"its start handle {bb.start.name!r}"
    if bb.end is not None:
        need["next"], names["next"] = next_pose, f"its end handle {bb.end.name!r}"
    for side, key, value in (
        ("start", "prev_parent", prev_parent_pose),
        ("end", "next_parent", next_parent_pose),
    ):
        handle = getattr(bb, side)
        if bb.reads_handle_scale(side) and handle.parent is not None:
            need[key] = value
            names[key] = f"{handle.parent!r}, the parent of its {side} handle {handle.name!r}"
    mats = {k: checked_pose(names[k], bb, v) for k, v in need.items()}
    batch = np.broadcast_shapes(*(m.shape[:-2] for m in mats.values()))
    return {k: np.broadcast_to(m, (*batch, 4, 4)) for k, m in mats.items()}, batch


def curve_joints(bb: BBone, rest: bool, mats=None, batch=()):
    """(..., segments + 1, 4, 4) the segment joint matrices in bone space (``BKE_pchan_bbone_spline_setup``
    with ``for_deform``): Blender's ``bbone_rest_mats`` (``rest``) or ``bbone_pose_mats``."""
    dtype = np.result_type(*(mats.values() if mats else ()), np.float64)
    one = np.ones(batch)
    sc, imat, head, tail = _pose_frame(bb, rest, mats, batch, dtype)
    ends = _handle_ends(bb, rest, mats, batch, imat, head, tail)
    shape = _shape_params(bb, rest, one, ends.prev_scale, ends.next_scale)
    h1, h2, roll1, roll2, length = _handles_compute(bb, sc, ends, shape, dtype, batch, one)
    return _spline_compute(bb.segments, h1, h2, roll1, roll2, length, shape.scale_in, shape.scale_out, sc)


def _pose_frame(bb: BBone, rest: bool, mats, batch, dtype):
    """(sc, imat, head, tail) of ``BKE_pchan_bbone_spline_params_get``: the pose scale the curve is built
    without (ones unless non-uniform, or complex), the inverse of the unscaled bone matrix, the bone's
    head and tail."""
    L = bb.length
    if rest:
        sc = np.ones((*batch, 3))
        imat = np.linalg.inv(bb.matrix_local)
        head, tail = bb.head_local, bb.tail_local
    else:
        P = mats["pose"]
        scale = analytic.norm(P[..., :3, :3], axis=-2)
        if np.iscomplexobj(P):
            do_scale = np.ones(batch, bool)
        else:
            do_scale = (np.abs(scale[..., 0] - scale[..., 1]) > UNIFORM_SCALE_EPSILON) | (
                np.abs(scale[..., 1] - scale[..., 2]) > UNIFORM_SCALE_EPSILON
            )
        sc = np.where(do_scale[..., None], scale, 1.0)
        unscaled = P.astype(dtype, copy=True)
        unscaled[..., :3, :3] = P[..., :3, :3] / sc[..., None, :]
        imat = np.linalg.inv(unscaled)
        head = P[..., :3, 3]
        tail = head + P[..., :3, 1] * L

    return sc, imat, head, tail


@dataclass
class _HandleEnds:
    """Where the handles put the curve's ends, in the unscaled bone's frame (``BBoneSplineParameters``'s
    ``prev_h``, ``next_h``, ``prev_mat``, ``next_mat``), and the handles' own scales (``prev_scale``,
    ``next_scale``; ones unless read)."""

    prev_h: np.ndarray | None
    prev_mat: np.ndarray | None
    prev_scale: np.ndarray
    next_h: np.ndarray | None
    next_mat: np.ndarray | None
    next_scale: np.ndarray


def _handle_ends(bb: BBone, rest: bool, mats, batch, imat, head, tail) -> _HandleEnds:
    """The handles' part of ``BKE_pchan_bbone_spline_params_get``, by handle type."""
    L = bb.length
    start, end = bb.start, bb.end

    def posed(key, handle):
        M = mats[key]
        h = M[..., :3, 3]
        return M, h, h + M[..., :3, 1] * handle.length

    prev_joins = bb.start_joins()
    prev_scale = np.ones((*batch, 3))
    next_scale = np.ones((*batch, 3))
    prev_h = prev_mat = next_h = next_mat = None
    if start is not None:
        kind = bb.handle_type_start
        if not rest:
            Pp, pp_head, pp_tail = posed("prev", start)
        if kind == "RELATIVE":
            prev_h = np.zeros((*batch, 3)) if rest else _apply(imat, head - (pp_head - start.head_local))
        elif kind == "TANGENT":
            h1 = bb.head_local - (start.tail_local - start.head_local) if rest else head - (pp_tail - pp_head)
            prev_h = _apply(imat, h1)
        else:
            prev_h = _apply(imat, start.head_local if rest else pp_head)
        if not prev_joins:
            prev_mat = imat[..., :3, :3] @ (start.matrix_local if rest else Pp)[..., :3, :3]
            if not rest and bb.reads_handle_scale("start"):
                prev_scale = _handle_scale(start, Pp, mats.get("prev_parent"))
    if end is not None:
        kind = bb.handle_type_end
        if not rest:
            Pn, pn_head, pn_tail = posed("next", end)
        if kind == "RELATIVE":
            next_h = (
                np.broadcast_to(np.array([0.0, L, 0.0]), (*batch, 3))
                if rest
                else _apply(imat, tail + (pn_head - end.head_local))
            )
        elif kind == "TANGENT":
            h2 = bb.tail_local + (end.tail_local - end.head_local) if rest else tail + (pn_tail - pn_head)
            next_h = _apply(imat, h2)
        else:
            next_h = _apply(imat, end.tail_local if rest else pn_tail)
        next_mat = imat[..., :3, :3] @ (end.matrix_local if rest else Pn)[..., :3, :3]
        if not rest and bb.reads_handle_scale("end"):
            next_scale = _handle_scale(end, Pn, mats.get("next_parent"))

    return _HandleEnds(prev_h, prev_mat, prev_scale, next_h, next_mat, next_scale)


@dataclass
class _ShapeParams:
    """``BBoneSplineParameters``' ease, roll, scale and curve in and out, bone and pose levels combined."""

    ease1: np.ndarray
    ease2: np.ndarray
    roll1: np.ndarray
    roll2: np.ndarray
    scale_in: np.ndarray
    scale_out: np.ndarray
    curve_in: np.ndarray
    curve_out: np.ndarray


def _shape_params(bb: BBone, rest: bool, one, prev_scale, next_scale) -> _ShapeParams:
    """The ease, roll, scale and curve part of ``BKE_pchan_bbone_spline_params_get`` (the rest shape uses
    the bone-level values alone)."""
    start = bb.start
    pose_level = 0.0 if rest else 1.0
    ease1 = (bb.bone_ease_in + pose_level * bb.pose_ease_in) * one
    ease2 = (bb.bone_ease_out + pose_level * bb.pose_ease_out) * one
    roll1 = bb.bone_roll_in + pose_level * bb.pose_roll_in
    roll2 = bb.bone_roll_out + pose_level * bb.pose_roll_out
    if bb.use_endroll_as_inroll and start is not None:
        roll1 += start.bone_roll_out + pose_level * start.pose_roll_out
    scale_in = bb.bone_scale_in * (1.0 if rest else bb.pose_scale_in) * one[..., None]
    scale_out = bb.bone_scale_out * (1.0 if rest else bb.pose_scale_out) * one[..., None]
    curve_in = (
        np.array([bb.bone_curve_in_x, bb.bone_curve_in_z])
        + pose_level * np.array([bb.pose_curve_in_x, bb.pose_curve_in_z]) * one[..., None]
    )
    curve_out = (
        np.array([bb.bone_curve_out_x, bb.bone_curve_out_z])
        + pose_level * np.array([bb.pose_curve_out_x, bb.pose_curve_out_z]) * one[..., None]
    )
    if bb.use_scale_easing:
        ease1 = ease1 * scale_in[..., 1]
        curve_in = curve_in * scale_in[..., 1:2]
        ease2 = ease2 * scale_out[..., 1]
        curve_out = curve_out * scale_out[..., 1:2]
    use = np.array(bb.handle_use_scale_start, float)
    scale_in = scale_in * (use * prev_scale + (1 - use))
    if bb.handle_use_ease_start:
        ease1 = ease1 * prev_scale[..., 1]
        curve_in = curve_in * prev_scale[..., 1:2]
    use = np.array(bb.handle_use_scale_end, float)
    scale_out = scale_out * (use * next_scale + (1 - use))
    if bb.handle_use_ease_end:
        ease2 = ease2 * next_scale[..., 1]
        curve_out = curve_out * next_scale[..., 1:2]

    return _ShapeParams(ease1, ease2, roll1, roll2, scale_in, scale_out, curve_in, curve_out)


def _handles_compute(bb: BBone, sc, ends: _HandleEnds, shape: _ShapeParams, dtype, batch, one):
    """``BKE_pchan_bbone_handles_compute``: the curve's inner controls h1, h2 (..., 3) with ease and
    offsets, the rolls in and out (the handles' rolls added), and the curve's length."""
    L = bb.length
    start, end = bb.start, bb.end
    prev_joins, next_joins = bb.start_joins(), bb.end_joins()
    prev_h, prev_mat, next_h, next_mat = ends.prev_h, ends.prev_mat, ends.next_h, ends.next_mat
    ease1, ease2, roll1, roll2 = shape.ease1, shape.ease2, shape.roll1, shape.roll2
    curve_in, curve_out = shape.curve_in, shape.curve_out
    length = L * sc[..., 1]
    epsilon = 1e-5 * L
    r1 = r2 = 0.0
    y_axis = np.broadcast_to(np.array([0.0, 1.0, 0.0]), (*batch, 3))
    if start is not None:
        h1 = prev_h.astype(dtype, copy=True)
        if prev_joins:
            h1[..., 1] -= length
        h1, n = _normalize(h1)
        h1 = -np.where((n.real < epsilon)[..., None], -y_axis, h1)
        if not prev_joins:
            r1 = _mat3_vec_to_roll(prev_mat, h1)
    else:
        h1 = y_axis
    if end is not None:
        h2 = next_h.astype(dtype, copy=True)
        if not next_joins:
            h2[..., 1] -= length
        h2, n = _normalize(h2)
        h2 = np.where((n.real < epsilon)[..., None], y_axis, h2)
        r2 = _mat3_vec_to_roll(next_mat, h2)
    else:
        h2 = y_axis
    circle = length * _circle_factor(h1, h2) / 0.75
    h1 = h1 * (ease1 * circle)[..., None]
    h2 = h2 * (-ease2 * circle)[..., None]
    roll1 = r1 + roll1 * one
    roll2 = r2 + roll2 * one
    h1 = h1 + np.stack([curve_in[..., 0] * sc[..., 0], 0 * one, curve_in[..., 1] * sc[..., 2]], axis=-1)
    h2 = h2 + np.stack([curve_out[..., 0] * sc[..., 0], 0 * one, curve_out[..., 1] * sc[..., 2]], axis=-1)

    return h1, h2, roll1, roll2, length


def _spline_compute(segs: int, h1, h2, roll1, roll2, length, scale_in, scale_out, sc):
    """``BKE_pchan_bbone_spline_compute`` (``for_deform``) and ``make_bbone_spline_matrix``: the joints
    of the Bézier curve 0, h1, c3 + h2, c3 (c3 = (0, length, 0)) spaced by the segment scales."""
    one = np.ones(length.shape)
    c3 = np.stack([0 * length, length, 0 * length], axis=-1)
    controls = np.stack([np.zeros_like(c3), h1 * one[..., None], c3 + h2, c3], axis=-2)  # (..., 4, 3)
    log_in = np.log(np.where(scale_in[..., 1].real < 1e-4, 1e-4, scale_in[..., 1]))
    log_out = np.log(np.where(scale_out[..., 1].real < 1e-4, 1e-4, scale_out[..., 1]))
    fac = np.arange(segs) / (segs - 1)
    segment_scales = np.exp(fac * log_out[..., None] + (1 - fac) * log_in[..., None])
    t = _equalize(controls, segment_scales)

    deriv1 = np.diff(controls, axis=-2)
    deriv2 = np.diff(deriv1, axis=-2)
    first = _ease_axis(deriv1[..., 0, :], deriv2[..., 0, :])
    last = _ease_axis(deriv1[..., 2, :], -deriv2[..., 1, :])
    pos, tangent = _bezier(controls, t[..., 1:segs])
    pos = np.concatenate([controls[..., :1, :], pos, controls[..., 3:, :]], axis=-2)
    axis = np.concatenate([first[..., None, :], tangent, last[..., None, :]], axis=-2)
    f = np.arange(segs + 1) / segs
    roll = f * roll2[..., None] + (1 - f) * roll1[..., None]
    scale_x = f * scale_out[..., 0:1] + (1 - f) * scale_in[..., 0:1]
    scale_z = f * scale_out[..., 2:3] + (1 - f) * scale_in[..., 2:3]

    R = vec_roll_to_mat3(axis, roll)
    out = np.zeros((*R.shape[:-2], 4, 4), dtype=np.result_type(R, pos))
    out[..., :3, :3] = R / sc[..., None, :, None] * sc[..., None, None, :]  # S^-1 R S
    out[..., :3, 3] = pos / sc[..., None, :]
    out[..., 3, 3] = 1.0
    out[..., :, 0] *= scale_x[..., None]
    out[..., :, 2] *= scale_z[..., None]
    return out


def _bezier(controls, t):
    """``evaluate_cubic_bezier`` at parameters t (..., k): positions and (unnormalized) tangents."""
    t = t[..., None]
    c = [controls[..., None, i, :] for i in range(4)]
    a = [c[i] + t * (c[i + 1] - c[i]) for i in range(3)]
    b = [a[i] + t * (a[i + 1] - a[i]) for i in range(2)]
    tangent = b[1] - b[0]
    return b[0] + tangent * t, tangent


def _ease_axis(d1, d2):
    """``ease_handle_axis``: fade from the first to the second derivative when the handle is short."""
    gap = 0.1
    len2 = np.sum(d2 * d2, axis=-1)
    len1 = np.sum(d1 * d1, axis=-1)
    nonzero = len2.real != 0
    ratio = len1 / np.where(nonzero, len2, 1.0)
    use = nonzero & (ratio.real < gap * gap)
    root = np.sqrt(np.where(use & (ratio.real > 0), ratio, 1.0))
    root = np.where(use & (ratio.real > 0), root, 0.0)
    return d1 + np.where(use[..., None], d2 * (gap - root)[..., None], 0.0)


def _equalize(controls, segment_scales):
    """(..., segments + 1) ``equalize_cubic_bezier``: Bézier parameters of points spaced along the
    curve's length (measured on a 32-step polyline) in proportion to the segment scales."""
    temp = MAX_SEGMENTS
    segs = segment_scales.shape[-1]
    coords, _ = _bezier(controls, np.arange(temp + 1) / temp)
    pdist = np.concatenate(
        [
            np.zeros((*coords.shape[:-2], 1)),
            np.cumsum(analytic.norm(np.diff(coords, axis=-2), axis=-1), axis=-1),
        ],
        axis=-1,
    )
    step = pdist[..., -1] / np.sum(segment_scales, axis=-1)
    dist = np.cumsum(segment_scales * step[..., None], axis=-1)  # (..., segs): dist at points 1..segs
    nr = 1 + np.sum(pdist[..., None, 1:temp].real <= dist[..., :, None].real, axis=-1)
    upper = np.take_along_axis(pdist, nr, axis=-1)
    lower = np.take_along_axis(pdist, nr - 1, axis=-1)
    fac = (upper - dist) / (upper - lower)
    t = (nr - fac) / temp
    zeros = np.zeros((*t.shape[:-1], 1), dtype=t.dtype)
    return np.concatenate([zeros, t[..., : segs - 1], zeros + 1.0], axis=-1)


def spline_matrices(
    bbone: BBone,
    pose=None,
    prev_pose=None,
    next_pose=None,
    prev_parent_pose=None,
    next_parent_pose=None,
    *,
    rest: bool = False,
) -> np.ndarray:
    """The B-Bone's segment joint matrices in bone space, as ``PoseBone.bbone_segment_matrix(i, rest)``.

    Parameters
    ----------
    bbone : BBone
        A bone with ``segments > 1``.
    pose : (..., 4, 4) float or complex
        The bone's posed matrix (``PoseBone.matrix``), armature space; ignored with ``rest``.
    prev_pose, next_pose : (..., 4, 4) float or complex
        The posed matrices of the start / end handle bones (:attr:`~solver.rig.bbone.BBone.handle_names`);
        required when the handle exists.
    prev_parent_pose, next_parent_pose : (..., 4, 4) float or complex
        The posed matrices of the handles' parents (:attr:`~solver.rig.bbone.BBone.handle_parent_names`);
        required when named there.
    rest : bool
        The rest shape (Blender's ``bbone_rest_mats``) instead of the posed one (``bbone_pose_mats``).

    Returns
    -------
    (..., segments + 1, 4, 4)
        Joint ``i`` of the curve, from head (0) to tail (``segments``), in the bone's (posed or rest)
        space; ``(segments + 1, 4, 4)`` with ``rest``.
    """
    if bbone.segments == 1:
        raise SolverError(f"bone {bbone.name!r} is not a B-Bone (bbone_segments is 1)")
    if rest:
        return bbone.rest_joints.copy()
    mats, batch = checked_inputs(bbone, pose, prev_pose, next_pose, prev_parent_pose, next_parent_pose)
    return curve_joints(bbone, False, mats, batch)


def deform_matrices_reference(
    bbone: BBone, pose, prev_pose=None, next_pose=None, prev_parent_pose=None, next_parent_pose=None
) -> np.ndarray:
    """:func:`~solver.rig.bbone.deform_matrices` computed bone by bone (:func:`curve_joints`): the reference
    the stacked evaluation is tested against."""
    mats, batch = checked_inputs(bbone, pose, prev_pose, next_pose, prev_parent_pose, next_parent_pose)
    spline = curve_joints(bbone, False, mats, batch)
    return mats["pose"][..., None, :, :] @ spline @ bbone.unbend
