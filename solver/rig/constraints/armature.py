"""The Armature constraint (``armdef_evaluate``, ``constraint.cc``): the owner moved as a weighted blend of
its target bones' deformations, as the Armature modifier moves a vertex, with envelopes and Preserve
Volume (dual quaternions, ``math_rotation.cc``'s ``mat4_to_dquat``, ``add_weighted_dq_dq``,
``dquat_to_mat4``)."""

from __future__ import annotations

import numpy as np

from ..math_matrix import (
    dot,
    inverse_affine,
    mul_v3_m4v3,
    normalize_v3,
    orthogonalize_m4_stable,
    orthogonalize_m4_y,
    with_translation,
)
from ..math_rotation import mat3_to_quat, quat_to_mat3
from ..stack import matmul

_EYE4 = np.eye(4)
_EYE4.setflags(write=False)


def distfactor_to_bone(co, head, tail, rad_head, rad_tail, rdist):
    """(...) ``distfactor_to_bone``: envelope weight of point ``co`` (..., 3) for a bone ``head → tail``
    ((3,) or (..., 3); radii and distance: floats or arrays broadcasting against ``co``'s leading
    dimensions)."""
    co = np.asarray(co)
    rad_head, rad_tail, rdist = (np.asarray(x, dtype=np.float64) for x in (rad_head, rad_tail, rdist))
    bdelta, length = normalize_v3(np.asarray(tail) - np.asarray(head))
    pdelta = co - head
    a = dot(bdelta, pdelta)
    hsqr = dot(pdelta, pdelta)
    d_head = dot(co - head, co - head)
    d_tail = dot(co - tail, co - tail)
    mid = hsqr - a * a
    has = length.real != 0
    frac = np.where(has, a / np.where(has, length, 1.0), 0.0)
    rad_mid = np.where(has, frac * rad_tail + (1.0 - frac) * rad_head, rad_head + 0.0 * a)
    before, after = a.real < 0, a.real > length.real
    dist_sq = np.where(before, d_head, np.where(after, d_tail, mid))
    rad = np.where(before, rad_head, np.where(after, rad_tail, rad_mid))
    inside = dist_sq.real < (rad * rad).real
    lim = (rad + rdist) ** 2
    outside = dist_sq.real >= lim.real
    e = np.sqrt(np.where(dist_sq.real > 0, dist_sq, 1.0)) - rad
    safe = np.where(rdist == 0, 1.0, rdist)
    smooth = np.where(inside, 1.0, np.where(outside, 0.0, 1.0 - e * e / (safe * safe)))
    return np.where(rdist == 0, np.where(inside, 1.0, 0.0), smooth)


def mat4_to_dquat(basemat, mat):
    """``mat4_to_dquat`` (always taking its scaled branch, equal in value to the other): (quat (..., 4),
    trans (..., 4), scale (..., 4, 4))."""
    baseRS = matmul(mat, basemat)
    basequat = mat3_to_quat(orthogonalize_m4_y(baseRS))
    baseR = np.zeros(baseRS.shape, dtype=baseRS.dtype)
    baseR[..., :3, :3] = quat_to_mat3(basequat)
    baseR[..., :3, 3] = baseRS[..., :3, 3]
    baseR[..., 3, 3] = 1.0
    baseinv = inverse_affine(basemat)
    R = matmul(baseR, baseinv)
    S = matmul(inverse_affine(baseR), baseRS)
    scale = matmul(matmul(basemat, S), baseinv)
    q = mat3_to_quat(R)
    t = R[..., :3, 3]
    trans = np.stack(
        [
            -0.5 * (t[..., 0] * q[..., 1] + t[..., 1] * q[..., 2] + t[..., 2] * q[..., 3]),
            0.5 * (t[..., 0] * q[..., 0] + t[..., 1] * q[..., 3] - t[..., 2] * q[..., 2]),
            0.5 * (-t[..., 0] * q[..., 3] + t[..., 1] * q[..., 0] + t[..., 2] * q[..., 1]),
            0.5 * (t[..., 0] * q[..., 2] - t[..., 1] * q[..., 1] + t[..., 2] * q[..., 0]),
        ],
        -1,
    )
    return q, trans, scale


def _bone_dquat(world, slot, mat, wco):
    """One target bone's deformation ``mat`` (world space) as a dual quaternion (quat, trans, scale) about
    the owner's head ``wco``: ``armdef_accumulate_bone``'s Preserve Volume branch."""
    basemat = orthogonalize_m4_stable(matmul(world, slot.rest), 1, unit=True)
    q, trans, scale = mat4_to_dquat(basemat, mat)
    dst = mul_v3_m4v3(scale, wco) - wco
    trans = trans + 0.5 * np.stack(
        [
            -(q[..., 1] * dst[..., 0] + q[..., 2] * dst[..., 1] + q[..., 3] * dst[..., 2]),
            q[..., 0] * dst[..., 0] + q[..., 2] * dst[..., 2] - q[..., 3] * dst[..., 1],
            q[..., 0] * dst[..., 1] + q[..., 3] * dst[..., 0] - q[..., 1] * dst[..., 2],
            q[..., 0] * dst[..., 2] + q[..., 1] * dst[..., 1] - q[..., 2] * dst[..., 0],
        ],
        -1,
    )
    return q, trans, with_translation(scale, scale[..., :3, 3] - dst)


def _add_weighted_dquat(total, dquat, w):
    """``add_weighted_dq_dq``: the running sum ``total`` (quat, trans, scale) or None, plus ``w`` (...) times
    ``dquat``, the quaternion flipped to the sum's hemisphere."""
    q, trans, scale = dquat
    if total is None:
        return w[..., None] * q, w[..., None] * trans, w[..., None, None] * scale
    dq_quat, dq_trans, dq_scale = total
    flipped = dot(q, dq_quat).real < 0
    wq = np.where(flipped, -w, w)
    return (
        dq_quat + wq[..., None] * q,
        dq_trans + wq[..., None] * trans,
        dq_scale + w[..., None, None] * scale,
    )


def _dquat_to_mat4(total, weight, scale_weight, safe):
    """``normalize_dq`` then ``dquat_to_mat4`` of the weighted sum ``total`` (quat, trans, scale) of bones
    whose weights sum to ``weight`` (``scale_weight`` of them with a scale): the blended matrix."""
    dq_quat, dq_trans, dq_scale = total
    quat = dq_quat / safe[..., None]
    t = dq_trans / safe[..., None]
    add = weight - scale_weight
    scale = dq_scale + add[..., None, None] * np.eye(4)
    scale = scale / safe[..., None, None]
    length = np.sqrt(dot(quat, quat))
    inv = np.where(length.real != 0, 1.0 / np.where(length.real != 0, length, 1.0), 0.0)
    q0 = quat * inv[..., None]
    R = np.zeros((*q0.shape[:-1], 4, 4), dtype=q0.dtype)
    R[..., :3, :3] = quat_to_mat3(q0)
    R[..., 0, 3] = (
        2.0
        * (-t[..., 0] * q0[..., 1] + t[..., 1] * q0[..., 0] - t[..., 2] * q0[..., 3] + t[..., 3] * q0[..., 2])
        * inv
    )
    R[..., 1, 3] = (
        2.0
        * (-t[..., 0] * q0[..., 2] + t[..., 1] * q0[..., 3] + t[..., 2] * q0[..., 0] - t[..., 3] * q0[..., 1])
        * inv
    )
    R[..., 2, 3] = (
        2.0
        * (-t[..., 0] * q0[..., 3] - t[..., 1] * q0[..., 2] + t[..., 2] * q0[..., 1] + t[..., 3] * q0[..., 0])
        * inv
    )
    R[..., 3, 3] = 1.0
    return R @ scale


def armdef_evaluate(cs, cob, tars, ctx):
    """The Armature constraint (``armdef_evaluate``): the owner (in world space) times the blend of its
    target bones' deformations weighted by the constraint's weights (times their envelopes at the owner's
    head), as matrices or, with Preserve Volume, as dual quaternions."""
    world, iworld = ctx.world.matrix, ctx.world.inverse
    if cs.get("use_current_location"):
        wco = cob[..., :3, 3]
    else:
        wco = mul_v3_m4v3(world, ctx.owner.rest[..., :3, 3])
    preserve = cs.get("use_deform_preserve_volume")
    total = 0.0
    sum_mat = 0.0
    dquats = None
    dq_scale_weight = 0.0
    for slot, pose in zip(cs.slots, ctx.poses, strict=True):
        if not slot.positive:
            continue
        weight = slot.weight
        co = mul_v3_m4v3(iworld, wco)
        if slot.envelope:
            head, tail, rad_head, rad_tail, rdist = slot.envelope_data
            weight = weight * distfactor_to_bone(co, head, tail, rad_head, rad_tail, rdist)
        chan = matmul(pose, slot.rest_inverse)
        mat = matmul(matmul(world, chan), iworld)
        weight = np.asarray(weight)
        nonzero = weight.real != 0
        if preserve:
            w = np.where(nonzero, weight, 0.0)
            dquats = _add_weighted_dquat(dquats, _bone_dquat(world, slot, mat, wco), w)
            dq_scale_weight = dq_scale_weight + w
        else:
            sum_mat = sum_mat + mat * np.where(nonzero, weight, 0.0)[..., None, None]
        total = total + weight
    total = np.asarray(total)
    if not np.any(total.real > 0):
        return cob
    safe = np.where(total.real > 0, total, 1.0)
    if preserve:
        sum_mat = _dquat_to_mat4(dquats, total, dq_scale_weight, safe)
    else:
        sum_mat = sum_mat / safe[..., None, None]
    return np.where((total.real > 0)[..., None, None], sum_mat @ cob, cob)
