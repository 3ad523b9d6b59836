"""The constraints that copy a target's transform: Copy Location, Copy Rotation, Copy Scale, Copy Transforms
(``loclike_evaluate``, ``rotlike_evaluate``, ``sizelike_evaluate``, ``translike_evaluate``).

Every ``*_evaluate`` function of this package takes the constraint stack, the owner matrix (in the owner
space) and the target matrices (in the target space), stack layout, and returns the new owner matrix.
"""

from __future__ import annotations

import numpy as np

from ...rotations import euler_to_matrix, order_axes
from ..math_matrix import (
    cbrt_abs,
    column_norms_squared,
    det3,
    loc_rot_size_to_mat4,
    mat4_to_loc_rot_size,
    mat4_to_size,
    mul_v3_m4v3,
    orthogonalize_m4_stable,
    rescale_m4,
    with_translation,
)
from ..math_rotation import EULER_HYPOT_EPSILON, compatible_eul, mat4_to_compatible_eulO, mat4_to_eulO
from ..stack import matmul


def loclike_evaluate(cs, cob, tars, ctx):
    """Copy Location (``loclike_evaluate``): the target's location, per axis, inverted or added as set."""
    T = tars[0]
    use = [cs.get(f"use_{c}") for c in "xyz"]
    invert = [cs.get(f"invert_{c}") for c in "xyz"]
    offset = cs.get("use_offset")
    if all(use) and not any(invert) and not offset:
        return with_translation(cob, T[..., :3, 3])
    loc = cob[..., :3, 3]
    sign = np.where(invert, -1.0, 1.0)
    copied = T[..., :3, 3] * sign + (loc if offset else 0.0)
    return with_translation(cob, np.where(use, copied, loc))


def _rotate_euler(eul, order, axis: int, angle):
    unit = np.zeros((*np.shape(angle), 3))
    unit = unit.astype(np.result_type(unit, angle))
    unit[..., axis] = angle
    total = euler_to_matrix(eul, order) @ euler_to_matrix(unit, order)
    return mat4_to_eulO(total, order)


def rotlike_evaluate(cs, cob, tars, ctx):
    """Copy Rotation (``rotlike_evaluate``): the target's rotation, as Euler angles per axis, mixed as set."""
    loc, oldrot, size = mat4_to_loc_rot_size(cob)
    order = cs.order
    mat = orthogonalize_m4_stable(tars[0], 1, unit=True)
    mix = cs.get("mix_mode")
    use = [cs.get(f"use_{c}") for c in "xyz"]
    invert = [cs.get(f"invert_{c}") for c in "xyz"]
    if mix == "REPLACE" and all(use) and not any(invert):
        newrot = _replaced_rotation(mat, order)
        if newrot is not None:
            return loc_rot_size_to_mat4(loc, newrot, size)
    obeul = mat4_to_eulO(cob, order)
    eul = mat4_to_compatible_eulO(mat, obeul, order)
    legacy = mix == "OFFSET"
    defeul = obeul if mix in ("OFFSET", "REPLACE") else np.zeros_like(obeul)
    shape = np.broadcast_shapes(eul.shape, obeul.shape)
    eul = np.array(np.broadcast_to(eul, shape), dtype=np.result_type(eul, obeul))
    for a in range(3):
        if not use[a]:
            eul[..., a] = np.broadcast_to(defeul, eul.shape)[..., a]
        else:
            if legacy:
                eul = _rotate_euler(eul, order, a, obeul[..., a])
            if invert[a]:
                eul[..., a] = -eul[..., a]
    if mix == "ADD":
        eul = eul + obeul
    eul = compatible_eul(eul, obeul)
    newrot = euler_to_matrix(eul, order)
    if mix == "BEFORE":
        newrot = newrot @ oldrot
    elif mix == "AFTER":
        newrot = oldrot @ newrot
    return loc_rot_size_to_mat4(loc, newrot, size)


def _replaced_rotation(mat, order):
    """The rotation Copy Rotation (Replace, every axis, no inversion) puts in, or None near gimbal lock.

    Blender turns the target's orthonormalized matrix into Euler angles and back. Away from gimbal lock
    both Euler solutions are ``mat3_normalized_to_eulo2``'s first one up to turns, which reads the
    matrix's entries through three normalized pairs: ``(cos, sin)`` of the three angles. The rotation is
    built from those pairs directly (no angles), which is that round trip, derivatives included, also
    where ``mat`` is not quite orthonormal.
    """
    i, j, k = order_axes(order)
    M = mat[..., :3, :3]

    def B(a, b):  # Blender's mat[a][b]
        return M[..., b, a]

    cy_sq = B(i, i) * B(i, i) + B(i, j) * B(i, j)
    if cy_sq.real.min() <= EULER_HYPOT_EPSILON**2 * 4:
        return None
    cy = np.sqrt(cy_sq)
    parity = -1.0 if order in ("XZY", "YXZ", "ZYX") else 1.0
    hi_sq = B(j, k) * B(j, k) + B(k, k) * B(k, k)
    if not hi_sq.real.min() > 0:
        return None
    h_i = np.sqrt(hi_sq)
    h_j = np.sqrt(B(i, k) * B(i, k) + cy_sq)
    pairs = [
        (i, B(k, k) / h_i, parity * B(j, k) / h_i),
        (j, cy / h_j, -parity * B(i, k) / h_j),
        (k, B(i, i) / cy, parity * B(i, j) / cy),
    ]
    Rs = [_axis_rotation(a, c, s) for a, c, s in pairs]
    return Rs[2] @ Rs[1] @ Rs[0]


# Elementary rotations about axis a: ONE[a] + cos COS[a] + sin SIN[a] (rotations.axis_rotation).
_AXIS_ONE = np.zeros((3, 3, 3))
_AXIS_COS = np.zeros((3, 3, 3))
_AXIS_SIN = np.zeros((3, 3, 3))
for _a in range(3):
    _i1, _i2 = (_a + 1) % 3, (_a + 2) % 3
    _AXIS_ONE[_a, _a, _a] = 1.0
    _AXIS_COS[_a, _i1, _i1] = _AXIS_COS[_a, _i2, _i2] = 1.0
    _AXIS_SIN[_a, _i2, _i1], _AXIS_SIN[_a, _i1, _i2] = 1.0, -1.0


def _axis_rotation(axis: int, cos, sin):
    """(..., 3, 3) the rotation about a coordinate axis by the angle of ``(cos, sin)`` (...)."""
    return _AXIS_ONE[axis] + cos[..., None, None] * _AXIS_COS[axis] + sin[..., None, None] * _AXIS_SIN[axis]


def _power(x, p):
    x = np.asarray(x)
    ok = x.real > 0
    return np.where(ok, np.exp(p * np.log(np.where(ok, x, 1.0))), 0.0)


def sizelike_evaluate(cs, cob, tars, ctx):
    """Copy Scale (``sizelike_evaluate``): the target's scale, per axis, raised, made uniform, offset or
    added."""
    T = tars[0]
    axes = [cs.get(f"use_{c}") for c in "xyz"]
    uniform = cs.get("use_make_uniform")
    power1 = cs.key[5][0]
    offset = cs.get("use_offset")
    if all(axes) and not uniform and power1 and not offset:
        target = column_norms_squared(T[..., :3, :3])
        owner = column_norms_squared(cob[..., :3, :3])
        if not owner.real.min() > 0:
            owner = np.where(owner.real != 0, owner, 1.0)
        return rescale_m4(cob, np.sqrt(target / owner))
    obsize = mat4_to_size(cob)
    if uniform:
        if all(axes):
            total = det3(T)
            total = np.where(total.real < 0, -total, total)
        else:
            size = mat4_to_size(T)
            total = np.ones(size.shape[:-1], dtype=size.dtype)
            for a in range(3):
                if axes[a]:
                    total = total * size[..., a]
        size = np.repeat(cbrt_abs(total)[..., None], 3, axis=-1)
    else:
        size = mat4_to_size(T)
    if not power1:
        size = _power(size, cs.get("power"))
    if offset:
        size = size + obsize - 1.0 if cs.get("use_add") else size * obsize
    ok = obsize.real != 0
    factor = np.where(ok, size / np.where(ok, obsize, 1.0), 1.0)
    factor = np.where(np.array(axes) | uniform, factor, 1.0)
    return rescale_m4(cob, factor)


def _aligned_scale(A, B):
    """``mul_m4_m4m4_aligned_scale``."""
    _la, ra, sa = mat4_to_loc_rot_size(A)
    lb, rb, sb = mat4_to_loc_rot_size(B)
    return loc_rot_size_to_mat4(mul_v3_m4v3(A, lb), ra @ rb, sa * sb)


def _split_channels(A, B):
    """``mul_m4_m4m4_split_channels``."""
    la, ra, sa = mat4_to_loc_rot_size(A)
    lb, rb, sb = mat4_to_loc_rot_size(B)
    return loc_rot_size_to_mat4(la + lb, ra @ rb, sa * sb)


def translike_evaluate(cs, cob, tars, ctx):
    """Copy Transforms (``translike_evaluate``): the target's matrix, replacing or mixed with the owner's."""
    T = tars[0]
    if cs.get("remove_target_shear"):
        T = orthogonalize_m4_stable(T, 1, unit=False)
    mix = cs.get("mix_mode")
    if mix == "REPLACE":
        return T
    if mix == "BEFORE_FULL":
        return matmul(T, cob)
    if mix == "AFTER_FULL":
        return matmul(cob, T)
    if mix == "BEFORE":
        return _aligned_scale(T, cob)
    if mix == "AFTER":
        return _aligned_scale(cob, T)
    if mix == "BEFORE_SPLIT":
        return _split_channels(T, cob)
    return _split_channels(cob, T)
