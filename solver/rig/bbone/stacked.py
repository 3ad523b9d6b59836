"""The B-Bone curve of a stack of bones at once: the same math as :mod:`.reference`, every branch on a
setting taken once per stack and every constant of the rest pose computed once.

Arrays are laid out component first, bone last -- vectors (3, L, g), matrices (3, 3, L, g), per joint (3,
a, L, g) with a = segments + 1 and L the flattened leading dimensions -- so that numpy works on long
contiguous runs (it is slow on short trailing axes). Functions that numpy evaluates slowly on complex
numbers (sqrt, sin, cos, exp, log) are :mod:`solver.rig.analytic`'s, exact for complex-step arrays.
"""

from __future__ import annotations

import numpy as np

from .. import analytic
from .bbone_stack import BBoneStack, interpolate_joints, segment_fractions
from .reference import MAX_SEGMENTS, UNIFORM_SCALE_EPSILON, vec_roll_to_mat3

_Y_AXIS = np.array([0.0, 1.0, 0.0])
# Bézier weights of (h1, h2, c3) in the curve's point (columns 0-2) and tangent (3-5) at parameter t,
# as polynomials in (1, t, t², t³); the curve's controls are 0, h1, c3 + h2, c3 = (0, length, 0).
_BEZIER = np.array(
    [
        [0.0, 0.0, 0.0, 1.0, 0.0, 0.0],
        [3.0, 0.0, 0.0, -4.0, 2.0, 2.0],
        [-6.0, 3.0, 3.0, 3.0, -3.0, -2.0],
        [3.0, -3.0, -2.0, 0.0, 0.0, 0.0],
    ]
)
# The steps of the 32-step polyline that measures the curve's length, as weights of (h1, h2, c3).
_STEPS = np.arange(MAX_SEGMENTS + 1) / MAX_SEGMENTS
_POLYLINE = np.diff(np.stack([_STEPS**0, _STEPS, _STEPS**2, _STEPS**3], -1) @ _BEZIER[:, :3], axis=0)
# ease_handle_axis at the ends: the first derivative at the start and end, then the second ones, as
# weights of (h1, h2, c3); and what a unit of easing adds to the tangent weights there.
_END_DERIVATIVES = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [-2.0, 1.0, 1.0], [-1.0, 2.0, 1.0]])
_EASE_TANGENT = np.array([[-2.0, 1.0, 1.0], [-1.0, 2.0, 1.0]])
_STEPS_AND_ENDS = np.concatenate([_POLYLINE, _END_DERIVATIVES])
# mat3_normalized_to_quat_fast's four branches (x, y, z, w), each giving the quaternion's (w, y) up to
# a common factor as an affine function of the matrix entries m[3 r + c]: rows w of the four branches,
# then y of the same.
_TWIST = np.zeros((8, 9))
for _row, _terms in enumerate(
    [
        {7: 1, 5: -1},
        {2: 1, 6: -1},
        {3: 1, 1: -1},
        {0: 1, 4: 1, 8: 1},
        {3: 1, 1: 1},
        {0: -1, 4: 1, 8: -1},
        {7: 1, 5: 1},
        {2: 1, 6: -1},
    ]
):
    for _entry, _sign in _terms.items():
        _TWIST[_row, _entry] = _sign
del _row, _terms, _entry, _sign
_TWIST_CONSTANT = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0])[:, None]
# Cofactors of a 3x3 block of a flattened 4x4 matrix: C[i, j] = A[i+1, j+1] A[i+2, j+2] - A[i+1, j+2]
# A[i+2, j+1] (indices mod 3), as four gathers of the 16 entries.
_COFACTOR = np.array(
    [
        [4 * ((i + a) % 3) + (j + b) % 3 for i in range(3) for j in range(3)]
        for a, b in ((1, 1), (2, 2), (1, 2), (2, 1))
    ]
)
# The same for the first row of a flattened 3x3 (entries 3 r + c): its determinant is
# Σ_j A[0, j] (F[0] F[1] - F[2] F[3])[j].
_DET3 = np.array([[3 * a + (j + b) % 3 for j in range(3)] for a, b in ((1, 1), (2, 2), (1, 2), (2, 1))])
_FRAME = np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 1.0]])[:, :, None, None, None]
_SIGNS = np.array([-1.0, 1.0])[:, None, None, None]


def _mm(A, B):
    """Component-first matrix products: (n, k, ...) @ (k, m, ...) -> (n, m, ...)."""
    if A.size * B.shape[1] <= 4096:
        return (A[:, :, None] * B[None]).sum(1)
    out = A[:, 0, None] * B[0]
    for j in range(1, A.shape[1]):
        out += A[:, j, None] * B[j]
    return out


def _inv3(P):
    """(3, 3, ...) the inverse of the 3x3 blocks of component-first 4x4 matrices (4, 4, ...)."""
    F = P.reshape(16, *P.shape[2:])[_COFACTOR]
    C = (F[0] * F[1] - F[2] * F[3]).reshape(3, 3, *P.shape[2:])
    det = (P[0, :3] * C[0]).sum(0)
    return C.swapaxes(0, 1) / det


def _frame_columns(n):
    """The x and z columns (3, 2, ...) of ``vec_roll_to_mat3(n, 0)`` for unit vectors n (3, ...) (its y
    column is n), or None when some n takes Blender's branches for n near -y: the caller then falls back
    on ``vec_roll_to_mat3``."""
    theta = 1.0 + n[1]
    if theta.real.min() <= 6.1e-3:
        return None
    ratio = n[::2] / theta  # (x, z) / theta
    stretched = n + _Y_AXIS.reshape(3, *(1,) * (n.ndim - 1))  # (x, theta, z)
    frame = _FRAME.reshape(3, 2, *(1,) * (n.ndim - 1))
    return frame - stretched[:, None] * ratio[None]


def _twist(M, shared: bool = False):
    """(...) ``_twist_y`` of component-first (3, 3, ...): the twist about y of ``mat3_to_quat(M)``. Each
    branch of ``mat3_normalized_to_quat_fast`` gives the quaternion's (w, y) up to a common factor, and
    the twist ``2 atan2(y, w)`` with w made positive is ``2 atan(y / w)``. ``shared`` as for
    :func:`~solver.rig.analytic.real_part`."""
    shape = M.shape[2:]
    cn2 = (M * M).sum(0)
    if analytic.real_part(cn2, shared).min() > 0:
        M = M * analytic.rsqrt(cn2, shared)
    else:
        ok = cn2.real > 0
        M = M * np.where(ok, analytic.rsqrt(np.where(ok, cn2, 1.0)), 1.0)
    m = analytic.real_part(M, shared)
    F = m.reshape(9, *m.shape[2:])[_DET3]
    det = (m[0] * (F[0] * F[1] - F[2] * F[3])).sum(0)
    if det.min() < 0:
        M = np.where(det < 0, -M, M)
        m = analytic.real_part(M, shared)
    pick = np.where(m[2, 2] < 0, np.where(m[0, 0] > m[1, 1], 0, 1), np.where(m[0, 0] < -m[1, 1], 2, 3))
    pick = np.broadcast_to(pick, shape).reshape(-1)
    wy = _TWIST @ M.reshape(9, -1) + _TWIST_CONSTANT  # (8, n)
    column = np.arange(pick.size)
    ratio = (wy[pick + 4, column] / wy[pick, column]).reshape(shape)
    if not np.iscomplexobj(ratio):
        return 2.0 * np.arctan(ratio)
    r = analytic.real_part(ratio, shared)
    return analytic.as_complex(2.0 * np.arctan(r), ratio.imag * (2.0 / (1.0 + r * r)))


def stack_state(st: BBoneStack, P, prev, nxt, prev_parent, next_parent, shared: bool = False):
    """The per-bone quantities the curve is built from (``BKE_pchan_bbone_spline_params_get`` and
    ``BKE_pchan_bbone_handles_compute``), from component-first posed matrices (4, 4, L, g): the handles
    ``H`` (3, 2, L, g) (the curve's controls are 0, H[:, 0], c3 + H[:, 1], c3 = (0, length, 0)),
    ``length`` (L, g), ``roll`` (2, ., g) in and out, the pose scale ``sc`` (3, L, g), and the scales in
    and out (3, ., g). ``shared`` as for :func:`~solver.rig.analytic.real_part`."""
    complex_ = any(np.iscomplexobj(m) for m in (P, prev, nxt, prev_parent, next_parent) if m is not None)
    sc, imat, length = _pose_frame(st, P, complex_, shared)
    columns, mats = _handle_columns(st, P, prev, nxt)
    nv = len(st.sides)
    roll = st.roll
    scale_in, scale_out = st.scale_in, st.scale_out
    if not nv:
        H = np.broadcast_to(_Y_AXIS[:, None, None, None], (3, 2, *P.shape[2:]))
        ease, curve = st.ease, st.curve
    else:
        Y = _mm(imat, np.concatenate(columns, axis=1))  # (3, nv + 3 rolled, L, g)
        H, unit = _handle_directions(st, Y[:, :nv], length, shared)
        if st.rolled:
            roll = roll + _handle_rolls(st, Y[:, nv:], unit, shared)
        scale_in, scale_out, ease, curve = _handle_scales(st, P, mats, prev_parent, next_parent, length)
    # cubic_tangent_factor_circle_v3, then the handles' lengths, ease and curve offsets
    d = (H[:, 0] * H[:, 1]).sum(0)
    if d.real.max() <= 1 - 1e-5 and d.real.min() >= -1 + 1e-5:
        factor = 0.5 / (1 + analytic.sqrt((1 + d) * 0.5, shared))
    else:
        inside = (d.real <= 1 - 1e-5) & (d.real >= -1 + 1e-5)
        factor = 0.5 / (1 + analytic.sqrt(np.where(inside, 1 + d, 1.0) * 0.5))
        factor = np.where(inside, factor, np.where(d.real > 1 - 1e-5, 0.25, 0.5))
    H = H * (ease * (factor * length * (1 / 0.75))) + curve * sc[:, None]
    return H, length, roll, sc, scale_in, scale_out


def _pose_frame(st: BBoneStack, P, complex_: bool, shared: bool):
    """(sc, imat, length): the pose scale the curve is built without (ones unless non-uniform, or complex)
    (3, L, g), the inverse of the unscaled pose's 3×3 block (3, 3, L, g), the curve's length (L, g)."""
    P3 = P[:3, :3]
    scale = analytic.sqrt((P3 * P3).sum(0), shared)  # column lengths
    if complex_:
        sc = scale
    else:
        uniform = (np.abs(scale[0] - scale[1]) <= UNIFORM_SCALE_EPSILON) & (
            np.abs(scale[1] - scale[2]) <= UNIFORM_SCALE_EPSILON
        )
        sc = np.where(uniform, 1.0, scale)
    # imat = inv(P3 / sc) = diag(sc) adj(P3) / det(P3)
    F = P.reshape(16, *P.shape[2:])[_COFACTOR]
    C = (F[0] * F[1] - F[2] * F[3]).reshape(3, 3, *P.shape[2:])
    imat = C.swapaxes(0, 1) * (sc / (P3[0] * C[0]).sum(0))[:, None]
    return sc, imat, st.length * sc[1]


def _own(side, M, P):
    """A handle's posed matrices ``M`` (4, 4, L, g) with each bone that has no handle there given its own
    pose ``P`` (masked out later)."""
    if not side.partial:
        return M
    M = M.copy()
    M[..., side.absent] = (P if np.iscomplexobj(M) else P.real)[..., side.absent]
    return M


def _handle_columns(st: BBoneStack, P, prev, nxt):
    """(columns, mats): in armature space, the vector from the curve's end to each handle's point by
    handle type (3, 1, L, g) per side, then the rotations of the handles whose roll is read (3, 3, L, g);
    and the handles' posed matrices by side."""
    head = P[:3, 3]
    columns, mats = [], {}
    if (x := st.start) is not None:
        Pp = mats["start"] = _own(x, prev, P)
        if x.kind == "RELATIVE":
            v = x.head_local - Pp[:3, 3]
        elif x.kind == "TANGENT":
            v = Pp[:3, 1] * -x.length
        else:
            v = Pp[:3, 3] - head
        columns.append(v[:, None])
    if (x := st.end) is not None:
        Pn = mats["end"] = _own(x, nxt, P)
        if x.kind == "RELATIVE":
            v = P[:3, 1] * st.length + Pn[:3, 3] - x.head_local
        elif x.kind == "TANGENT":
            v = P[:3, 1] * st.length + Pn[:3, 1] * x.length
        else:
            v = Pn[:3, 3] + Pn[:3, 1] * x.length - head
        columns.append(v[:, None])
    columns += [mats[x.side][:3, :3] for x in st.rolled]
    return columns, mats


def _handle_directions(st: BBoneStack, V, length, shared: bool):
    """(H, unit): the handles' unit directions in the bone's frame (3, 2, L, g), +y at an end without a
    handle, from their vectors ``V`` (3, sides, L, g) (a joined start's and a plain end's shortened by the
    curve's length first, a vector shorter than 1e-5 of the bone taken as +y); ``unit`` per side."""
    V[1] -= length * st.offset
    d2 = (V * V).sum(0)
    use = analytic.real_part(d2, shared) >= st.eps2
    if st.partial:
        use = use & st.present
    if use.all():
        unit = V * (analytic.rsqrt(d2, shared) * st.sign)
    else:
        unit = V * (analytic.rsqrt(np.where(use, d2, 1.0)) * st.sign)
        unit = np.where(use, unit, _Y_AXIS[:, None, None, None])
    if len(st.sides) == 2:
        return unit, unit
    row = np.broadcast_to(_Y_AXIS[:, None, None, None], unit.shape)
    H = np.concatenate([unit, row] if st.sides[0].side == "start" else [row, unit], axis=1)
    return H, unit


def _handle_rolls(st: BBoneStack, rotations, unit, shared: bool):
    """(2, L, g) the rolls the handles add in and out (``mat3_vec_to_roll``), from the rotations of the
    handles whose roll is read (3, 3 rolled, L, g) in the bone's frame."""
    index = [st.sides.index(x) for x in st.rolled]
    N = rotations.reshape(3, len(index), 3, *rotations.shape[2:]).swapaxes(1, 2)  # (3, 3, r, L, g)
    r = _roll_of(N, unit[:, index], shared)
    if st.partial:
        r = r * st.present[index]
    if len(index) == 1:
        pad = np.zeros_like(r)
        r = np.concatenate([r, pad] if st.rolled[0].side == "start" else [pad, r])
    return r


def _handle_scales(st: BBoneStack, P, mats, prev_parent, next_parent, length):
    """(scale_in, scale_out, ease, curve): the scales in and out, the ease and the curve offsets, times the
    handles' own scales where ``bbone_handle_use_scale_*`` / ``bbone_handle_use_ease_*`` read them."""
    scale_in, scale_out = st.scale_in, st.scale_out
    factors = [1.0, 1.0]  # ease and curve factors of the handles' own scales
    for x in st.sides:
        if not x.reads_scale:
            continue
        rest_inverse = x.rest_inverse
        if x.has_parent:
            parent = prev_parent if x.side == "start" else next_parent
            rest_inverse = _mm(rest_inverse, _inv3(_own(x, parent, P)))
        handle_scale = analytic.sqrt((lambda A: (A * A).sum(0))(_mm(rest_inverse, mats[x.side][:3, :3])))
        scaled = x.use_scale * handle_scale + (1 - x.use_scale)
        if x.side == "start":
            scale_in = scale_in * scaled
        else:
            scale_out = scale_out * scaled
        factors[x.side == "end"] = x.use_ease * handle_scale[1] + (1 - x.use_ease)
    if not st.reads_scale:
        return scale_in, scale_out, st.ease, st.curve
    E = np.stack(np.broadcast_arrays(*factors, length)[:2])
    return scale_in, scale_out, st.ease * E, st.curve * E


def _roll_of(N, h, shared: bool = False):
    """(...) ``mat3_vec_to_roll(N, h)`` for component-first N (3, 3, ...) and unit h (3, ...)."""
    columns = _frame_columns(h)
    if columns is None:
        B = vec_roll_to_mat3(np.moveaxis(h, 0, -1), np.zeros(h.shape[1:]))
        return _twist(_mm(np.moveaxis(np.linalg.inv(B), (-2, -1), (0, 1)), N))
    return _twist(_mm(np.stack([columns[:, 0], h, columns[:, 1]]), N), shared)


def stack_joints(st: BBoneStack, H, length, roll, sc, scale_in, scale_out, shared: bool = False):
    """(3, 4, a, L, g) per joint ``[R diag(sc σ) | p]``: the joint's rotation R with its x / z scale σ
    and the pose scale, and its position p, in bone space times sc (Blender's ``bbone_pose_mats`` are
    ``diag(1 / sc)`` of this). ``shared``: axis L is a complex-step direction axis along which the real
    parts agree, so branches and real functions are taken on its first entry."""
    s, a = st.segments, st.segments + 1
    batch = length.shape
    n = length.size
    dtype = H.dtype
    h1, h2 = H[:, 0], H[:, 1]
    controls = np.concatenate([H.swapaxes(0, 1), (length * _Y_AXIS[:, None, None])[None]])  # h1, h2, c3
    # equalize_cubic_bezier (the polyline's steps) and ease_handle_axis (the derivatives at the ends)
    both = (_STEPS_AND_ENDS @ controls.reshape(3, -1)).reshape(MAX_SEGMENTS + 4, 3, *batch)
    sq = (both * both).sum(1)
    padded = np.empty((MAX_SEGMENTS + 1, *batch), dtype)
    padded[0] = 0.0
    np.cumsum(
        analytic.sqrt(sq[:MAX_SEGMENTS], shared), axis=0, out=padded[1:]
    )  # the polyline's length so far
    fractions = segment_fractions(scale_in[1], scale_out[1], s) if st.reads_scale else st.fractions
    dist = padded[-1] * fractions  # (s - 1, L, g)
    count = (
        analytic.real_part(padded, shared)[1:MAX_SEGMENTS, None] <= analytic.real_part(dist, shared)[None]
    ).sum(0)
    index = (np.broadcast_to(count, dist.shape) * n + np.arange(n).reshape(batch)).reshape(-1)
    lower = padded.reshape(-1)[index].reshape(dist.shape)
    upper = padded.reshape(-1)[index + n].reshape(dist.shape)
    powers = st.powers(batch, dtype)  # (4, a, L, g): 1, t, t², t³ with t = 0 and 1 at the ends
    t = powers[1, 1:s]
    np.multiply(count + (dist - lower) / (upper - lower), 1.0 / MAX_SEGMENTS, out=t)
    np.multiply(t, t, out=powers[2, 1:s])
    np.multiply(powers[2, 1:s], t, out=powers[3, 1:s])
    weights = (_BEZIER.T @ powers.reshape(4, -1)).reshape(2, 3, a, *batch)  # point, tangent; h1, h2, c3
    first, second = (
        analytic.real_part(sq[MAX_SEGMENTS : MAX_SEGMENTS + 2], shared),
        analytic.real_part(sq[MAX_SEGMENTS + 2 :], shared),
    )
    short = first < 0.01 * second
    if short.any():
        ratio = sq[MAX_SEGMENTS : MAX_SEGMENTS + 2] / np.where(short, sq[MAX_SEGMENTS + 2 :], 1.0)
        positive = short & (ratio.real > 0)
        k = np.where(short, 0.1 - np.where(positive, analytic.sqrt(np.where(positive, ratio, 1.0)), 0.0), 0.0)
        weights[1][:, [0, s]] += _EASE_TANGENT.T[:, :, None, None] * k
    vectors = weights[:, 0, None] * h1[:, None] + weights[:, 1, None] * h2[:, None]  # (2, 3, a, L, g)
    vectors[:, 1] += weights[:, 2] * length
    point, tangent = vectors[0], vectors[1]
    # make_bbone_spline_matrix: vec_roll_to_mat3 of the tangent and the interpolated roll, the scales
    roll = (st.blend @ roll.reshape(2, -1)).reshape(a, *roll.shape[1:])  # (a, ., g)
    scale_xz = interpolate_joints(st.blend, scale_in[::2], scale_out[::2]) if st.reads_scale else st.scale_xz
    scale_xz = scale_xz * sc[::2, None]  # (2, a, L, g)
    out = np.empty((3, 4, a, *batch), np.result_type(tangent, roll, scale_xz))
    t2 = (tangent * tangent).sum(0)
    normal = tangent * analytic.rsqrt(t2, shared)
    theta = 1.0 + normal[1]
    if analytic.real_part(t2, shared).min() <= 1e-35 or analytic.real_part(theta, shared).min() <= 6.1e-3:
        columns = None  # vec_roll_to_mat3's branches for a tangent near -y
    elif normal.size > 3000:
        # With B = vec_roll_to_mat3(n, 0), whose x and z columns are e_x - x/θ (x, θ, z) and e_z - z/θ
        # (x, θ, z) (θ = 1 + y), the x and z columns of B Ry(roll) are (c, 0, -s) - α (x, θ, z) and
        # (s, 0, c) - β (x, θ, z), with (α, β) the (x/θ, z/θ) rotated by the roll.
        cs = analytic.cos_sin(roll, shared)  # (2, a, ., g): cos, sin
        turned = cs[::-1] * _SIGNS  # -sin, cos
        ratio = normal[::2] / theta
        ab = (cs * ratio[0] + turned * ratio[1]) * -scale_xz
        np.multiply((normal + _Y_AXIS[:, None, None, None])[:, None], ab, out=out[:, 0:3:2])
        out[0, 0:3:2] += cs * scale_xz
        out[2, 0:3:2] += turned * scale_xz
        np.multiply(normal, sc[1], out=out[:, 1])
        out[:, 3] = point
        return out
    else:
        columns = _frame_columns(normal)
    if columns is None:
        R = vec_roll_to_mat3(np.moveaxis(tangent, 0, -1), np.broadcast_to(roll, tangent.shape[1:]))
        R = np.moveaxis(R, (-2, -1), (0, 1))
        out[:, 0:3:2] = R[:, 0:3:2] * scale_xz
        out[:, 1] = R[:, 1] * sc[1]
    else:
        cs = analytic.cos_sin(roll, shared)  # (2, a, ., g): cos, sin
        # the x and z columns of B Ry(roll): (c B0 - s B2, s B0 + c B2), each times its scale
        rotated = columns[:, :1] * cs + columns[:, 1:] * (cs[::-1] * _SIGNS)
        np.multiply(rotated, scale_xz, out=out[:, 0:3:2])
        np.multiply(normal, sc[1], out=out[:, 1])
    out[:, 3] = point
    return out


def assemble(P, sc, joints, unbend):
    """(3, 4, a, L, g) ``diag(1 / sc) joints unbend`` in the pose: ``P diag(1/sc) joints unbend``."""
    G = (joints[:, :3, None] * unbend[None, :3]).sum(1)  # (3, 4, a, L, g)
    G[:, 3] += joints[:, 3]
    U = P[:3, :3] / sc
    M = (U[:, :, None, None] * G[None]).sum(1)
    M[:, 3] += P[:3, 3, None]
    return M
