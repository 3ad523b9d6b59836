"""How Blender places bones: their channels, their parents' poses and the inherit flags, and the spaces
constraints work in — ported from Blender's ``armature.cc``, ``constraint.cc`` and ``math_matrix.cc``.

Conventions:

* Matrices are ``(..., 4, 4)`` affine matrices acting on column vectors (numpy ``M[row, col]``), in the
  armature object's space unless a function says otherwise; Blender's C arrays ``mat[i][j]`` are column
  ``i``, row ``j``, so Blender's ``mat[1]`` (a bone's Y axis) is ``M[..., :3, 1]`` here.
* A bone's *rest* matrix is Blender's ``arm_mat`` (``Bone.matrix_local``); its *pose* matrix is
  ``pose_mat`` (``PoseBone.matrix``); its *local* (channel) matrix is ``chan_mat`` (``PoseBone.matrix_basis``
  once location, rotation and scale are composed).
* Every function takes float64 or complex128 arrays with arbitrary leading batch dimensions and is
  analytic in them (complex-step differentiation, see :mod:`.analytic`): the branches Blender takes on
  values (degenerate vectors, thresholds) are taken on real parts. Bone data are plain settings.

Stacks. Bones whose discrete settings agree (:func:`bone_key`) are placed at once by a
:class:`BoneStack`, their rest data being arrays over a stack axis ``g``. Stacked code works on arrays in
the *stack layout* ``(g, K, 4, 4)``: the stack axis first, then the batch (complex-step directions)
flattened to one axis ``K``, or ``K = 1`` for what does not vary over the batch (per-bone constants are
``(g, 1, ...)``). Then a product with a per-bone constant is one BLAS product per bone of all its ``K``
matrices (:func:`matmul`) instead of ``g K`` small ones, and when the batch is complex-step directions
sharing one value (:class:`SharedValues`) so is a product of two varying matrices. Inverses are in closed
form (:func:`inverse_affine`), polar decompositions take an SVD of the values and carry derivatives in
closed form (:func:`polar`). :func:`to_stack` and :func:`from_stack` convert from and to the public layout
``(..., g, 4, 4)``. The armature's world matrix is a :class:`World`, analysed once.

Blender computes in float32; these ports compute in float64 and agree with it to float32 rounding.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..errors import SolverError
from ..rotations import EULER_ORDERS, euler_to_matrix
from . import analytic

#: Blender's ``Bone.inherit_scale`` modes.
INHERIT_SCALE_MODES = ("FULL", "FIX_SHEAR", "ALIGNED", "AVERAGE", "NONE", "NONE_LEGACY")
#: Constraint spaces (``owner_space``/``target_space``) modelled by :func:`convert_space`.
SPACES = ("WORLD", "CUSTOM", "POSE", "LOCAL_WITH_PARENT", "LOCAL", "LOCAL_OWNER_ORIENT")
#: Pose-bone rotation modes: the Euler orders, ``QUATERNION`` and ``AXIS_ANGLE``.
ROTATION_MODES = (*EULER_ORDERS, "QUATERNION", "AXIS_ANGLE")

#: Blender's ``FLT_EPSILON``.
FLT_EPSILON = 1.1920929e-07


def _frozen(value, shape) -> np.ndarray:
    array = np.array(value, dtype=np.float64).reshape(shape)
    array.setflags(write=False)
    return array


@dataclass(frozen=True, eq=False)
class Bone:
    """The rest data of one bone that posing needs (Blender's ``Bone`` plus its pose bone's rotation mode).

    Attributes
    ----------
    name : str
        The bone's name.
    matrix_local : (4, 4) ndarray
        Rest matrix in armature space (Blender's ``arm_mat``, ``Bone.matrix_local``).
    length : float
        Rest length (``Bone.length``).
    parent : str or None
        The parent bone's name.
    matrix : (3, 3) ndarray
        Rest orientation relative to the parent (Blender's ``bone_mat``, ``Bone.matrix``).
    head : (3,) ndarray
        Head relative to the parent's tail, in the parent's rest frame (Blender's ``Bone.head``).
    use_connect, use_inherit_rotation, use_local_location : bool
        Blender's flags of the same names.
    inherit_scale : str
        One of :data:`INHERIT_SCALE_MODES`.
    rotation_mode : str
        The pose bone's rotation mode (one of :data:`ROTATION_MODES`); constraints decompose Euler
        angles in it (``XYZ`` for quaternion and axis-angle bones).
    bbone_segments : int
        B-Bone segments (1: a plain bone).
    head_radius, tail_radius, envelope_distance : float
        Envelope of the bone (``Bone.head_radius`` ...), used by Armature constraints with envelopes.
    use_envelope_multiply : bool
        ``Bone.use_envelope_multiply``.
    """

    name: str
    matrix_local: np.ndarray
    length: float
    parent: str | None = None
    matrix: np.ndarray | None = None
    head: np.ndarray | None = None
    use_connect: bool = False
    use_inherit_rotation: bool = True
    inherit_scale: str = "FULL"
    use_local_location: bool = True
    rotation_mode: str = "QUATERNION"
    bbone_segments: int = 1
    head_radius: float = 0.1
    tail_radius: float = 0.1
    envelope_distance: float = 0.25
    use_envelope_multiply: bool = False

    def __post_init__(self):
        arm = _frozen(self.matrix_local, (4, 4))
        object.__setattr__(self, "matrix_local", arm)
        object.__setattr__(self, "length", float(self.length))
        if self.inherit_scale not in INHERIT_SCALE_MODES:
            raise SolverError(f"bone {self.name!r}: unknown inherit_scale {self.inherit_scale!r}")
        if self.rotation_mode not in ROTATION_MODES:
            raise SolverError(f"bone {self.name!r}: unknown rotation mode {self.rotation_mode!r}")
        if self.matrix is not None:
            object.__setattr__(self, "matrix", _frozen(self.matrix, (3, 3)))
        if self.head is not None:
            object.__setattr__(self, "head", _frozen(self.head, (3,)))

    @property
    def head_local(self) -> np.ndarray:
        """(3,) rest head in armature space (Blender's ``arm_head``)."""
        return self.matrix_local[:3, 3]

    @property
    def tail_local(self) -> np.ndarray:
        """(3,) rest tail in armature space (Blender's ``arm_tail``)."""
        return self.matrix_local[:3, 3] + self.length * self.matrix_local[:3, 1]

    @property
    def euler_order(self) -> str:
        """The Euler order constraints use for this bone (Blender's ``cob->rotOrder``)."""
        return self.rotation_mode if self.rotation_mode in EULER_ORDERS else "XYZ"

    def offset(self, parent: Bone) -> np.ndarray:
        """(4, 4) the bone's rest frame in its parent's (``BKE_bone_offset_matrix_get``): ``bone_mat``, at
        ``head`` plus the parent's length along Y (from the rest matrices when ``matrix``/``head`` are
        unset)."""
        if self.matrix is None or self.head is None:
            return np.linalg.inv(parent.matrix_local) @ self.matrix_local
        offs = np.eye(4)
        offs[:3, :3] = self.matrix
        offs[:3, 3] = self.head
        offs[1, 3] += parent.length
        return offs


# ----------------------------------------------------------------------------------------------------
# Small vector and matrix helpers (math_vector.cc, math_matrix.cc), analytic and batched.

# Index tables: cyclic successors for cross products and 3×3 cofactors.
_NEXT = np.array([1, 2, 0])
_AFTER = np.array([2, 0, 1])
_CROSS_A = np.array([_NEXT, _AFTER])  # a[next], a[after]
_CROSS_B = np.array([_AFTER, _NEXT])  # b[after], b[next]
# cof[i, j] = A[i+1, j+1] A[i+2, j+2] - A[i+1, j+2] A[i+2, j+1]  (indices mod 3): two gathers of
# (2, 3, 3) entries, multiplied, the second product subtracted from the first.
_R1, _R2 = np.broadcast_to(_NEXT[:, None], (3, 3)), np.broadcast_to(_AFTER[:, None], (3, 3))
_C1, _C2 = np.broadcast_to(_NEXT[None, :], (3, 3)), np.broadcast_to(_AFTER[None, :], (3, 3))
_COF_ROWS_1, _COF_COLS_1 = np.array([_R1, _R1]), np.array([_C1, _C2])
_COF_ROWS_2, _COF_COLS_2 = np.array([_R2, _R2]), np.array([_C2, _C1])
# Skew-symmetric [w]x from w: entry (i, j) is SKEW_SIGN[i, j] * w[SKEW_INDEX[i, j]].
_SKEW_INDEX = np.array([[0, 2, 1], [2, 0, 0], [1, 0, 0]])
_SKEW_SIGN = np.array([[0.0, -1.0, 1.0], [1.0, 0.0, -1.0], [-1.0, 1.0, 0.0]])
_EYE3 = np.eye(3)
_EYE3.setflags(write=False)
_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])
_ZERO3 = np.zeros(3)
_ONES3 = np.ones(3)


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


def normalize(v):
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
    return _ONES3 @ (A * A)


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
    out[..., 3, :] = _LAST_ROW
    return out


def cbrt_abs(x):
    """(...) ``cbrtf(fabsf(x))`` of ``x`` (...), analytic away from 0 (0 gives 0)."""
    x = np.asarray(x)
    a = np.where(x.real < 0, -x, x)
    ok = a.real > 0
    return np.where(ok, np.exp(np.log(np.where(ok, a, 1.0)) / 3.0), 0.0)


def matrix_to_size(M):
    """(..., 3) ``mat4_to_size``: lengths of the three axes (columns)."""
    return np.sqrt(column_norms_squared(np.asarray(M)[..., :3, :3]))


def size_fix_shear(M):
    """(..., 3) ``mat4_to_size_fix_shear``: axis lengths rescaled to the matrix's true volume."""
    size = matrix_to_size(M)
    volume = np.prod(size, axis=-1)
    ok = volume.real != 0
    ratio = det3(M) / np.where(ok, volume, 1.0)
    return np.where(ok[..., None], size * cbrt_abs(ratio)[..., None], size)


def rescale(M, scale):
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


def normalize_axes(M):
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


def orthogonalize_stable(M, axis: int = 1, unit: bool = False):
    """(..., 4, 4) ``orthogonalize_m4_stable``: a copy of ``M`` (..., 4, 4) without its shear around one
    axis.

    The other two axes are projected off the primary one, then turned symmetrically away from each other
    until perpendicular (only when their angle's cosine is within ``(1e-4, 1 - FLT_EPSILON)``), rescaled
    to keep area unless ``unit``; with ``unit`` all three axes come out unit length.
    """
    M = np.asarray(M)
    if axis == 1 and M.ndim >= 3:
        out = _orthogonalize_y(M, unit)
        if out is not None:
            return out
    return _orthogonalize_stable(M, axis, unit)


def _orthogonalize_y(M, unit):
    """:func:`orthogonalize_stable` about Y when no axis vanishes and X, Z come out perpendicular within
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


def _orthogonalize_stable(M, axis, unit):
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
    n2, l2 = normalize(v2)
    n3, l3 = normalize(v3)
    cos = dot(n2, n3)
    abs_cos = np.abs(cos.real)
    fix = (abs_cos > 1e-4) & (abs_cos < 1.0 - FLT_EPSILON)
    if np.any(fix):
        c = np.where(fix, cos, 0.5)
        angle = analytic.acos(c)
        target = angle + (np.pi / 2 - angle) / 2
        m2 = n2 - n3 * c[..., None]
        m2 = m2 * (np.sin(target) / analytic.norm(m2))[..., None] + n3 * np.cos(target)[..., None]
        m3, _ = normalize(cross(cross(m2, n3), m2))
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


def decompose(M):
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


def compose(location, rotation, size):
    """``loc_rot_size_to_mat4``: (..., 4, 4) from location (..., 3), rotation (..., 3, 3), size (..., 3)."""
    location, rotation, size = (np.asarray(x) for x in (location, rotation, size))
    shape = np.broadcast_shapes(location.shape[:-1], rotation.shape[:-2], size.shape[:-1])
    M = np.empty((*shape, 4, 4), dtype=_dtype(location, rotation, size))
    M[..., :3, :3] = rotation * size[..., None, :]
    M[..., :3, 3] = location
    M[..., 3, :] = _LAST_ROW
    return M


def _affine(rotscale3, location):
    rotscale3, location = np.asarray(rotscale3), np.asarray(location)
    shape = np.broadcast_shapes(rotscale3.shape[:-2], location.shape[:-1])
    M = np.empty((*shape, 4, 4), dtype=_dtype(rotscale3, location))
    M[..., :3, :3] = rotscale3
    M[..., :3, 3] = location
    M[..., 3, :] = _LAST_ROW
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


def transform_point(M, p):
    """(..., 3) ``mul_v3_m4v3``: the point ``p`` (..., 3) transformed by ``M`` (..., 4, 4)."""
    M, p = np.asarray(M), np.asarray(p)
    return (M[..., :3, :3] @ p[..., :, None])[..., 0] + M[..., :3, 3]


# ----------------------------------------------------------------------------------------------------
# Products in the stack layout.


def matmul(A, B):
    """``A @ B`` for stack-layout arrays ``(g, K, n, n)`` (``K`` may be 1 on either side), fast.

    numpy multiplies a batch of small matrices one by one; when one side is constant over the batch
    (``K == 1``), the product is instead one matrix product per bone, of the other side's ``K`` rows
    stacked: ``(g, K n, n) @ (g, n, n)`` for a constant right side, through transposes for a constant
    left side; a 2-D side (the same matrix for every bone) makes it one product in all. Any other shapes
    fall back to ``np.matmul``.
    """
    sa, sb = A.shape, B.shape
    if len(sb) == 2:
        if len(sa) == 2:
            return A @ B
        return (A.reshape(-1, sa[-1]) @ B).reshape(*sa[:-1], sb[-1])
    if len(sa) == 2:
        Bt = B.swapaxes(-1, -2)
        out = Bt.reshape(-1, sb[-2]) @ A.T
        return out.reshape(*sb[:-2], sb[-1], sa[0]).swapaxes(-1, -2)
    if len(sa) != 4 or len(sb) != 4 or sa[0] != sb[0]:
        return A @ B
    ka, kb = sa[1], sb[1]
    if kb == 1 and ka > 1:
        g, n, m, p = sa[0], sa[2], sa[3], sb[3]
        return (A.reshape(g, ka * n, m) @ B.reshape(g, m, p)).reshape(g, ka, n, p)
    if ka == 1 and kb > 1:
        g, n, m, p = sa[0], sa[2], sa[3], sb[3]
        Bt = B.swapaxes(-1, -2).reshape(g, kb * p, m)
        out = Bt @ A.reshape(g, n, m).swapaxes(-1, -2)
        return out.reshape(g, kb, p, n).swapaxes(-1, -2)
    if _SHARED[0] and ka > 1 and ka == kb and A.dtype == B.dtype == np.complex128:
        # Complex-step directions sharing their values: (Va + i Ta)(Vb + i Tb) = Va Vb + i (Va Tb + Ta Vb)
        # to far below rounding, i.e. Va B + A Vb - Va Vb: two products with a constant side.
        Va, Vb = A.real[:, :1], B.real[:, :1]
        return matmul(Va, B) + matmul(A, Vb) - Va @ Vb
    return A @ B


#: Whether the complex stack-layout arrays being evaluated are complex-step directions that share their
#: values (set by :class:`SharedValues`).
_SHARED = [False]


class SharedValues:
    """Context: complex stack-layout arrays (g, K, ...) in the block share their real parts across ``K``
    (complex-step directions of one value), which :func:`matmul` exploits."""

    def __init__(self, on: bool):
        self.on = on

    def __enter__(self):
        self.previous = _SHARED[0]
        _SHARED[0] = self.on

    def __exit__(self, *exc):
        _SHARED[0] = self.previous


def to_stack(A, lead: tuple[int, ...]) -> np.ndarray | None:
    """``A`` (..., g, r, c) or (g, r, c) in the stack layout (g, K, r, c): ``K = prod(lead)`` or 1 when
    ``A`` has no batch dimensions of its own. A view when ``A``'s memory is stack-major already."""
    if A is None:
        return None
    shape = A.shape
    nd = len(shape)
    if nd == 3:
        return A.reshape(shape[0], 1, shape[1], shape[2])
    own = shape[:-3]
    if own != lead:
        if math.prod(own) == 1:
            return A.reshape(shape[-3], 1, shape[-2], shape[-1])
        A = np.broadcast_to(A, (*lead, *shape[-3:]))
    A = A.transpose(nd - 3, *range(nd - 3), nd - 2, nd - 1)
    return A.reshape(shape[-3], -1, shape[-2], shape[-1])


def from_stack(A, lead: tuple[int, ...]) -> np.ndarray:
    """Stack-layout ``A`` (g, K, r, c) back to (*lead, g, r, c) (a view when ``K`` is the batch)."""
    g, k, r, c = A.shape
    size = math.prod(lead)
    if k != size:
        A = np.broadcast_to(A, (g, size, r, c)).copy()
    n = len(lead)
    if n == 0:
        return A.reshape(g, r, c)
    if n == 1:
        return A.swapaxes(0, 1)
    return A.reshape(g, *lead, r, c).transpose(*range(1, n + 1), 0, n + 1, n + 2)


def shared(A) -> bool:
    """Whether a complex stack-layout array (g, K, ...) carries the same value (real part) in every batch
    entry, as complex-step directions do (up to second-order terms far below rounding)."""
    if not np.iscomplexobj(A) or A.shape[1] == 1:
        return False
    real = A.real
    return bool(np.abs(real - real[:, :1]).max() <= 1e-40)


# ----------------------------------------------------------------------------------------------------
# Channels.


def channel_matrix(location, rotation, scale):
    """(..., 4, 4) a pose bone's local matrix (``BKE_pchan_to_mat4``): ``T(location) R diag(scale)``.

    Parameters
    ----------
    location : (..., 3) array_like
    rotation : (..., 3, 3) array_like
        From :func:`rotation_matrix`.
    scale : (..., 3) array_like

    Blender drops the location of connected bones; :func:`solver.rig.constraints.pose_bone` does that.
    """
    rotation, scale = np.asarray(rotation), np.asarray(scale)
    return _affine(rotation * scale[..., None, :], location)


def rotation_matrix(mode: str, rotation) -> np.ndarray:
    """(..., 3, 3) the rotation of a pose bone's stored rotation in its mode (``BKE_pchan_rot_to_mat3``).

    Parameters
    ----------
    mode : str
        An Euler order (``rotation`` is ``rotation_euler`` (..., 3)), ``QUATERNION`` (``(w, x, y, z)``
        (..., 4), normalized first; a zero quaternion is Blender's ``(0, 1, 0, 0)``) or ``AXIS_ANGLE``
        (``(angle, x, y, z)`` (..., 4); a zero axis is no rotation).
    """
    r = np.asarray(rotation)
    if mode in EULER_ORDERS:
        return euler_to_matrix(r, mode)
    if mode == "QUATERNION":
        n = analytic.norm(r)
        zero = n.real == 0
        q = np.where(zero[..., None], np.array([0.0, 1.0, 0.0, 0.0]), r / np.where(zero, 1.0, n)[..., None])
        return quaternion_to_matrix(q)
    if mode == "AXIS_ANGLE":
        axis, length = normalize(r[..., 1:])
        R = axis_angle_matrix(axis, np.sin(r[..., 0]), np.cos(r[..., 0]))
        return np.where((length.real == 0)[..., None, None], np.eye(3), R)
    raise SolverError(f"unknown rotation mode {mode!r}; use one of {', '.join(ROTATION_MODES)}")


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


def quaternion_to_matrix(q) -> np.ndarray:
    """(..., 3, 3) ``quat_to_mat3`` of ``(w, x, y, z)`` (..., 4) as given (not normalized, as Blender)."""
    q = np.asarray(q)
    outer = (q[..., :, None] * q[..., None, :]).reshape(*q.shape[:-1], 16)
    return (outer @ _QUAD.T).reshape(*q.shape[:-1], 3, 3) + _EYE3


def axis_angle_matrix(axis, sin, cos) -> np.ndarray:
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


def matrix_to_quaternion(R) -> np.ndarray:
    """(..., 4) ``mat3_to_quat`` of matrices ``R`` (..., 3, 3) (or the 3×3 blocks of (..., 4, 4)): axes
    normalized, a negative determinant negated, then ``mat3_normalized_to_quat_fast`` (Mike Day's method,
    ``w >= 0``)."""
    R = np.asarray(R)[..., :3, :3]
    units, _ = normalize(np.swapaxes(R, -1, -2))
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


# ----------------------------------------------------------------------------------------------------
# The armature object's world matrix.


@dataclass(frozen=True, eq=False)
class World:
    """The armature object's ``matrix_world`` with what the constraint solver precomputes of it.

    Attributes
    ----------
    matrix, inverse : (4, 4) ndarray
    identity : bool
        The world matrix is the identity (world and pose space coincide).
    similarity : bool
        A uniform scale times a rotation (of either handedness) plus a translation: constraints that
        only compare lengths read the same in world and pose space.
    proper : bool
        A similarity with a positive determinant: constraints that also turn by cross products read the
        same in world and pose space.
    """

    matrix: np.ndarray
    inverse: np.ndarray
    identity: bool
    similarity: bool
    proper: bool

    @classmethod
    def of(cls, matrix) -> World:
        """The world matrix (4, 4) as a :class:`World` (a World is returned as is)."""
        if isinstance(matrix, World):
            return matrix
        M = _frozen(matrix, (4, 4))
        if not np.all(np.isfinite(M)) or np.any(M[3] != _LAST_ROW):
            raise SolverError("the armature's world matrix must be a finite affine matrix")
        gram = M[:3, :3].T @ M[:3, :3]
        scale = gram.trace() / 3.0
        similarity = bool(scale > 0 and np.abs(gram - scale * np.eye(3)).max() <= 1e-12 * scale)
        proper = similarity and np.linalg.det(M[:3, :3]) > 0
        inverse = _frozen(np.linalg.inv(M), (4, 4))
        identity = bool(np.array_equal(M, np.eye(4)))
        return cls(M, inverse, identity, similarity, bool(proper))


# ----------------------------------------------------------------------------------------------------
# Parenting, for one bone or a stack of them.


def bone_key(bone: Bone, parent: Bone | None) -> tuple:
    """The discrete settings of a bone's placement: bones (and their parents) with equal keys can be
    posed in one :class:`BoneStack`.

    A root bone: ``("root", use_local_location)``; a child: ``("child", use_connect, use_inherit_rotation,
    inherit_scale, use_local_location)``. Rest matrices, lengths and offsets are continuous (arrays of
    the stack).
    """
    if parent is None:
        return ("root", bool(bone.use_local_location))
    return (
        "child",
        bool(bone.use_connect),
        bool(bone.use_inherit_rotation),
        bone.inherit_scale,
        bool(bone.use_local_location),
    )


def _constant(arrays) -> np.ndarray:
    """Per-bone constants stacked as (g, 1, ...), read-only."""
    out = np.ascontiguousarray(np.stack([np.asarray(a, dtype=np.float64) for a in arrays])[:, None])
    out.setflags(write=False)
    return out


class BoneStack:
    """The rest data of ``g`` bones with one :func:`bone_key`, as arrays over the stack axis.

    Build it with :meth:`of`. Arrays are in the stack layout: per-bone constants ``(g, 1, ...)``.

    Attributes
    ----------
    names : tuple of str
    key : tuple
        The common :func:`bone_key`.
    bones : tuple of Bone
    size : int
        ``g``.
    root, connect, inherit_rotation, local_location : bool
    inherit_scale : str
    full : bool
        Plain parenting: the parent's pose times the offset (inherited rotation, ``FULL`` scale).
    offset : (g, 1, 4, 4)
        ``BKE_bone_offset_matrix_get`` of each bone in its parent (a root bone's rest matrix).
    head_column : (g, 1, 4, 1)
        The offsets' translations as homogeneous columns (where connected heads go).
    rest, rest_inverse : (g, 1, 4, 4)
        The bones' rest matrices (``arm_mat``) and their inverses.
    parent_rest : (g, 1, 4, 4) or None
        The parents' rest matrices.
    length : (g, 1)
        Rest lengths.
    """

    def __init__(self, names, key, bones, offset, rest, parent_rest, length):
        self.names, self.key, self.bones = names, key, bones
        self.size = len(names)
        self.root = key[0] == "root"
        self.connect = not self.root and key[1]
        self.inherit_rotation = self.root or key[2]
        self.inherit_scale = "FULL" if self.root else key[3]
        self.local_location = key[-1]
        self.full = not self.root and self.inherit_rotation and self.inherit_scale == "FULL"
        self.offset = offset
        self.offset_translation = offset[..., :3, 3]
        self.head_column = _constant(offset[:, 0, :, 3:])
        self.rest = rest
        self.rest_inverse = _constant(np.linalg.inv(rest[:, 0]))
        self.parent_rest = parent_rest
        self.length = length

    @classmethod
    def of(cls, bones, parents) -> BoneStack:
        """The stack of ``bones`` (sequence of :class:`Bone`) under ``parents`` (their parents' Bones, or
        None for roots), which must all have one :func:`bone_key`."""
        bones, parents = tuple(bones), tuple(parents)
        if not bones or len(bones) != len(parents):
            raise SolverError("a bone stack needs one parent (or None) per bone, and at least one bone")
        keys = {bone_key(b, p) for b, p in zip(bones, parents, strict=True)}
        if len(keys) != 1:
            raise SolverError(
                f"bones {', '.join(b.name for b in bones[:4])} differ in their parenting settings "
                f"({len(keys)} kinds); stack them by bone_key"
            )
        key = keys.pop()
        root = key[0] == "root"
        offsets = [b.matrix_local if root else b.offset(p) for b, p in zip(bones, parents, strict=True)]
        return cls(
            names=tuple(b.name for b in bones),
            key=key,
            bones=bones,
            offset=_constant(offsets),
            rest=_constant([b.matrix_local for b in bones]),
            parent_rest=None if root else _constant([p.matrix_local for p in parents]),
            length=_constant([b.length for b in bones]),
        )

    def parenting(self, parent_pose) -> Parenting:
        """The parent transforms of the stack under the parents' poses (stack layout (g, K, 4, 4);
        ignored for roots)."""
        return Parenting(self, parent_pose)


class Parenting:
    """``BoneParentTransform`` of a stack of bones (stack layout), with its inverse on demand.

    ``rotscale`` and ``loc`` (g, K, 4, 4) and ``post`` (g, K, 3) or None (no post scale) as Blender's
    ``BKE_bone_parent_transform_calc_from_matrices``; :meth:`to_pose` and :meth:`to_local` are
    ``BKE_armature_mat_bone_to_pose`` and ``BKE_armature_mat_pose_to_bone``.
    """

    def __init__(self, stack: BoneStack, parent_pose):
        self.stack = stack
        self._parent_pose = parent_pose
        self._transform = None
        self._rotscale_inverse = None
        self._loc_inverse = None

    @property
    def parent_pose(self):
        """(g, K, 4, 4) the parents' pose matrices (not needed for roots)."""
        if self._parent_pose is None and not self.stack.root:
            raise SolverError(f"bones {', '.join(self.stack.names[:4])} need their parents' poses")
        return self._parent_pose

    def _calc(self):
        if self._transform is None:
            self._transform = _parent_transform(self.stack, self.parent_pose)
        return self._transform

    @property
    def rotscale(self):
        """(g, K, 4, 4) the rotation and scale transform."""
        return self._calc()[0]

    @property
    def loc(self):
        """(g, K, 4, 4) the location transform, or None when it is ``rotscale`` itself."""
        return self._calc()[1]

    @property
    def post(self):
        """(g, K, 3) the post scale, or None for none."""
        return self._calc()[2]

    @property
    def rotscale_inverse(self):
        """(g, K, 4, 4) the inverse of :attr:`rotscale`."""
        if self._rotscale_inverse is None:
            self._rotscale_inverse = inverse_affine(self.rotscale)
        return self._rotscale_inverse

    @property
    def loc_inverse(self):
        """(g, K, 4, 4) the inverse of :attr:`loc`, or None when that is None."""
        if self._loc_inverse is None and self.loc is not None:
            self._loc_inverse = inverse_affine(self.loc)
        return self._loc_inverse

    def head(self):
        """(g, K, 3) where a connected bone's head goes: the translation its pose matrix gets from
        channels without translation."""
        s = self.stack
        if s.root:
            return s.offset_translation
        if s.full:
            return matmul(self.parent_pose, s.head_column)[..., :3, 0]
        return (self.rotscale if self.loc is None else self.loc)[..., :3, 3]

    def to_pose(self, local, connect: bool = False):
        """``BKE_armature_mat_bone_to_pose`` of local matrices (g, K, 4, 4), or of the identity (None);
        ``connect`` drops their translations first (Blender's connected bones)."""
        s = self.stack
        if local is not None and connect:
            local = with_translation(local, _ZERO3)
        if s.full and s.local_location:
            P = self.parent_pose
            if local is None:
                return matmul(P, s.offset)
            if local.shape[1] == 1:
                return matmul(P, s.offset @ local)
            return matmul(self.rotscale, local)
        if s.root:
            offs = s.offset
            if local is None:
                return offs.copy()
            out = matmul(offs, local)
            if not s.local_location:
                out = with_translation(out, local[..., :3, 3] + s.offset_translation)
            return out
        out = self.rotscale if local is None else matmul(self.rotscale, local)
        if self.loc is not None:
            t = self.loc[..., :3, 3] if local is None else transform_point(self.loc, local[..., :3, 3])
            out = with_translation(out, t)
        elif local is None:
            out = out.copy()
        if self.post is not None:
            out = rescale(out, self.post)
        return out

    def to_local(self, pose):
        """``BKE_armature_mat_pose_to_bone`` of pose matrices (g, K, 4, 4)."""
        s = self.stack
        if s.root:
            out = matmul(s.rest_inverse, pose)
            if not s.local_location:
                out = with_translation(out, pose[..., :3, 3] - s.offset_translation)
            return out
        out = matmul(self.rotscale_inverse, pose)
        if self.loc is not None:
            out = with_translation(out, transform_point(self.loc_inverse, pose[..., :3, 3]))
        if self.post is not None:
            ok = self.post.real != 0
            out = rescale(out, np.where(ok, 1.0 / np.where(ok, self.post, 1.0), 0.0))
        return out


def _parent_transform(stack: BoneStack, P):
    """(rotscale, loc or None, post or None) of ``BKE_bone_parent_transform_calc_from_matrices`` for a
    stack; loc None means loc = rotscale, post None means no post-scale."""
    offs = stack.offset
    if stack.root:
        rotscale = offs
        if stack.local_location:
            return rotscale, None, None
        loc = np.broadcast_to(np.eye(4), offs.shape).copy()
        loc[..., :3, 3] = offs[..., :3, 3]
        return rotscale, loc, None
    mode = stack.inherit_scale
    use_rotation = stack.inherit_rotation
    full = use_rotation and mode == "FULL"
    post = None
    if full:
        rotscale = matmul(P, offs)
    else:
        if use_rotation:
            tmat = P
            if mode in ("NONE", "AVERAGE"):
                tmat = orthogonalize_stable(tmat, 1, unit=True)
            elif mode == "ALIGNED":
                tmat, post = normalize_axes(orthogonalize_stable(tmat, 1, unit=False))
            elif mode == "NONE_LEGACY":
                tmat, _ = normalize_axes(tmat)
        else:
            tmat = stack.parent_rest
            if mode == "FULL":
                tmat = rescale(tmat, matrix_to_size(P))
            elif mode == "FIX_SHEAR":
                tmat = rescale(tmat, size_fix_shear(P))
            elif mode == "ALIGNED":
                post = size_fix_shear(P)
        if mode == "AVERAGE":
            factor = cbrt_abs(det3(P))
            tmat = rescale(tmat, np.broadcast_to(factor[..., None], (*factor.shape, 3)))
        rotscale = matmul(tmat, offs)
        if mode == "FIX_SHEAR":
            rotscale = orthogonalize_stable(rotscale, 1, unit=False)
    if not stack.local_location:
        loc = _affine(P[..., :3, :3], transform_point(P, stack.offset_translation))
    elif not full:
        loc = matmul(P, offs)
    else:
        loc = None
    return rotscale, loc, post


# ----------------------------------------------------------------------------------------------------
# One bone at a time (the stacks with g = 1).


def _single(*arrays):
    """(lead, arrays (..., 4, 4) as stack layout (1, K, 4, 4))."""
    present = [np.asarray(a) for a in arrays if a is not None]
    lead = np.broadcast_shapes(*(a.shape[:-2] for a in present)) if present else ()
    return lead, [None if a is None else to_stack(np.asarray(a)[..., None, :, :], lead) for a in arrays]


def _unsingle(A, lead) -> np.ndarray:
    return np.asarray(from_stack(A, lead))[..., 0, :, :]


@dataclass(frozen=True)
class ParentTransform:
    """Blender's ``BoneParentTransform``: how a bone's local matrix becomes its pose matrix.

    ``rotscale`` and ``loc`` are (..., 4, 4), ``post_scale`` (..., 3), for a batch (...) of parent poses.
    """

    rotscale: np.ndarray
    loc: np.ndarray
    post_scale: np.ndarray

    def apply(self, matrix) -> np.ndarray:
        """(..., 4, 4) ``BKE_bone_parent_transform_apply``: local matrices ``matrix`` (..., 4, 4) as pose
        matrices (the batch dimensions broadcast with the transform's)."""
        matrix = np.asarray(matrix)
        out = self.rotscale @ matrix
        out = with_translation(out, transform_point(self.loc, matrix[..., :3, 3]))
        return rescale(out, self.post_scale)

    def inverted(self) -> ParentTransform:
        """``BKE_bone_parent_transform_invert`` (a zero post-scale inverts to zero)."""
        ok = self.post_scale.real != 0
        post = np.where(ok, 1.0 / np.where(ok, self.post_scale, 1.0), 0.0)
        return ParentTransform(inverse_affine(self.rotscale), inverse_affine(self.loc), post)


def parent_transform(bone: Bone, parent: Bone | None, parent_pose=None) -> ParentTransform:
    """``BKE_bone_parent_transform_calc_from_pchan`` / ``_from_matrices``: the inherit flags applied to the
    parent's pose matrix (..., 4, 4).

    Parameters
    ----------
    bone : Bone
    parent : Bone or None
        The parent's rest data (None for a root bone).
    parent_pose : (..., 4, 4) array_like
        The parent's pose matrix (ignored for a root bone).
    """
    stack = BoneStack.of([bone], [parent])
    lead, (P,) = _single(None if parent is None else parent_pose)
    rotscale, loc, post = _parent_transform(stack, P)
    rotscale = _unsingle(rotscale, lead)
    loc = rotscale if loc is None else _unsingle(loc, lead)
    k = math.prod(lead)
    post = np.ones((*lead, 3)) if post is None else np.broadcast_to(post[0], (k, 3)).reshape(*lead, 3)
    return ParentTransform(rotscale, loc, post)


def bone_to_pose(bone: Bone, parent: Bone | None, parent_pose, local) -> np.ndarray:
    """(..., 4, 4) ``BKE_armature_mat_bone_to_pose``: a local matrix ``local`` (..., 4, 4) as a pose matrix,
    under the parent's pose matrix ``parent_pose`` (..., 4, 4) (ignored for a root bone); the batch
    dimensions broadcast."""
    stack = BoneStack.of([bone], [parent])
    lead, (P, L) = _single(None if parent is None else parent_pose, local)
    return _unsingle(stack.parenting(P).to_pose(L), lead)


def pose_to_bone(bone: Bone, parent: Bone | None, parent_pose, pose) -> np.ndarray:
    """(..., 4, 4) ``BKE_armature_mat_pose_to_bone``: a pose matrix ``pose`` (..., 4, 4) as a local matrix,
    under the parent's pose matrix ``parent_pose`` (..., 4, 4) (ignored for a root bone); the batch
    dimensions broadcast."""
    stack = BoneStack.of([bone], [parent])
    lead, (P, M) = _single(None if parent is None else parent_pose, pose)
    return _unsingle(stack.parenting(P).to_local(M), lead)


class Spaces:
    """``BKE_constraint_mat_convertspace`` for a stack of pose bones (stack layout).

    Parameters
    ----------
    parenting : Parenting
        The bones' parent transforms.
    world : World
    diff : ((g, 1, 4, 4), (g, 1, 4, 4)), optional
        For ``LOCAL_OWNER_ORIENT``: the bones' rest orientations in their constraint owner's rest frame
        (translation dropped) and its inverse (:func:`owner_orientation`); None for the identity (the
        bones are the owners).
    custom : (g, K, 4, 4), optional
        The world matrices of the ``CUSTOM`` space.
    """

    def __init__(self, parenting: Parenting, world: World, diff=None, custom=None):
        self.parenting = parenting
        self.stack = parenting.stack
        self.world = world
        self.diff = diff
        self.custom = custom

    @cached_property
    def _custom_inverse(self):
        return inverse_affine(self.custom)

    def _world_times(self, M):
        return M if self.world.identity else matmul(self.world.matrix, M)

    def _world_inverse_times(self, M):
        return M if self.world.identity else matmul(self.world.inverse, M)

    def convert(self, M, from_space: str, to_space: str):
        """(g, K, 4, 4) ``M`` from one space to another (both in :data:`SPACES`)."""
        for space in (from_space, to_space):
            if space not in SPACES:
                raise SolverError(f"bone {self.stack.names[0]!r}: unknown constraint space {space!r}")
        if "CUSTOM" in (from_space, to_space) and self.custom is None:
            raise SolverError(f"bone {self.stack.names[0]!r}: the CUSTOM space needs its matrix")
        while from_space != to_space:
            M, from_space = self._step(M, from_space, to_space)
        return M

    def _step(self, M, from_space, to_space):
        """One step of ``BKE_constraint_mat_convertspace``'s state machine: (matrix, its new space)."""
        if from_space == "WORLD":
            if to_space == "CUSTOM":
                return matmul(self._custom_inverse, M), "CUSTOM"
            return self._world_inverse_times(M), "POSE"
        if from_space == "POSE":
            if to_space in ("LOCAL", "LOCAL_OWNER_ORIENT"):
                return self.parenting.to_local(M), "LOCAL"
            if to_space == "LOCAL_WITH_PARENT":
                return matmul(self.stack.rest_inverse, M), "LOCAL_WITH_PARENT"
            return self._world_times(M), "WORLD"
        if from_space == "LOCAL":
            if to_space == "LOCAL_OWNER_ORIENT":
                if self.diff is not None:
                    M = matmul(matmul(self.diff[0], M), self.diff[1])
                return M, "LOCAL_OWNER_ORIENT"
            return self.parenting.to_pose(M), "POSE"
        if from_space == "LOCAL_OWNER_ORIENT":
            if self.diff is not None:
                M = matmul(matmul(self.diff[1], M), self.diff[0])
            return M, "LOCAL"
        if from_space == "LOCAL_WITH_PARENT":
            return matmul(self.stack.rest, M), "POSE"
        # CUSTOM
        return matmul(self.custom, M), "WORLD"


def owner_orientation(rests, owner_rests=None):
    """(diff, inverse), each (g, 1, 4, 4): ``LOCAL_OWNER_ORIENT``'s change of frame, the rest matrices
    ``rests`` (g, 4, 4) seen from the owners' ``owner_rests`` (g, 4, 4) (or as they are when None), their
    translations dropped."""
    diff = np.array(rests, dtype=np.float64).reshape(-1, 4, 4)
    if owner_rests is not None:
        diff = np.linalg.inv(np.asarray(owner_rests, dtype=np.float64).reshape(-1, 4, 4)) @ diff
    diff[..., :3, 3] = 0.0
    return _constant(diff), _constant(np.linalg.inv(diff))


def convert_space(
    matrix,
    from_space: str,
    to_space: str,
    bone: Bone,
    parent: Bone | None,
    parent_pose,
    world,
    *,
    owner: Bone | None = None,
    custom=None,
) -> np.ndarray:
    """(..., 4, 4) ``BKE_constraint_mat_convertspace`` for a pose bone: ``matrix`` from one space to another.

    Parameters
    ----------
    matrix : (..., 4, 4) array_like
    from_space, to_space : str
        One of :data:`SPACES`.
    bone, parent, parent_pose
        The bone whose spaces these are, its parent's rest data and pose matrix (for ``LOCAL``).
    world : (4, 4) array_like or World
        The armature object's ``matrix_world``.
    owner : Bone, optional
        The constraint's owner, whose rest orientation ``LOCAL_OWNER_ORIENT`` uses (default: ``bone``).
    custom : (..., 4, 4) array_like, optional
        The world matrix of the ``CUSTOM`` space.
    """
    stack = BoneStack.of([bone], [parent])
    lead, (M, P, C) = _single(matrix, None if parent is None else parent_pose, custom)
    diff = owner_orientation([bone.matrix_local], None if owner is None else [owner.matrix_local])
    spaces = Spaces(stack.parenting(P), World.of(world), diff, C)
    return _unsingle(spaces.convert(M, from_space, to_space), lead)


# ----------------------------------------------------------------------------------------------------
# Influence blending.


#: Newton steps of the polar factor converge quadratically; past this many the matrix is singular enough
#: to be left to an SVD.
POLAR_STEPS = 12


def _orthogonal_factor(A: np.ndarray) -> np.ndarray:
    """(..., 3, 3) the orthogonal factor U of real matrices ``A = U P`` (the same as ``W Vᵀ`` of their SVD),
    by Higham's scaled Newton iteration ``U ← (γ U + U⁻ᵀ / γ) / 2`` on closed-form 3×3 inverses: LAPACK on
    thousands of tiny matrices is slower, and threads it."""
    U = A
    for _ in range(POLAR_STEPS):
        inverse_t = inverse3(U).swapaxes(-1, -2)
        gamma = np.sqrt(np.sqrt(np.sum(inverse_t * inverse_t, axis=(-2, -1)) / np.sum(U * U, axis=(-2, -1))))
        nxt = 0.5 * (gamma[..., None, None] * U + inverse_t / gamma[..., None, None])
        done = np.abs(nxt - U).max(initial=0.0) <= 1e-15 * max(np.abs(nxt).max(initial=0.0), 1.0)
        U = nxt
        if done:
            return U
    W, _, Vt = np.linalg.svd(A)
    return W @ Vt


def polar(A, shared_batch: bool = False):
    """Right polar decomposition ``A = U P`` of (..., 3, 3) matrices (``mat3_polar_decompose``).

    Blender takes it from an SVD; this iterates to the same factor (:func:`_orthogonal_factor`) from the real
    parts. The derivative carried by a complex
    step is exact: with ``Ω = Uᵀ dU`` (antisymmetric, its vector ``ω``) and ``X = Uᵀ dA``, ``X - Xᵀ = Ω P +
    P Ω``, i.e. ``(tr P - P) ω = vee(X - Xᵀ)``, and ``dP = X - Ω P``. ``U`` is orthogonal with the sign
    of ``det A``.

    Parameters
    ----------
    A : (..., 3, 3) array_like
    shared_batch : bool
        ``A`` is in the stack layout (g, K, 3, 3) and every batch entry has the same real part
        (:func:`shared`): the SVD is taken once per bone.

    Returns
    -------
    U, P : (..., 3, 3) ndarray
    """
    A = np.asarray(A)
    complex_ = A.dtype == np.complex128
    real = A.real if complex_ else A
    value = real[:, :1] if shared_batch else real
    Ur = _orthogonal_factor(value)
    Urt = Ur.swapaxes(-1, -2)
    Pr = Urt @ value
    if not complex_:
        return Ur, Pr
    X = matmul(Urt, A.imag) if shared_batch else Urt @ A.imag
    x = X[..., _AFTER, _NEXT] - X[..., _NEXT, _AFTER]  # vee(X - Xᵀ): (X21 - X12, X02 - X20, X10 - X01)
    trace = Pr[..., 0, 0] + Pr[..., 1, 1] + Pr[..., 2, 2]
    Minv = inverse3(trace[..., None, None] * _EYE3 - Pr)
    if shared_batch:
        g, k = x.shape[:2]
        w = (x.reshape(g, k, 3) @ Minv.reshape(g, 3, 3).swapaxes(-1, -2)).reshape(g, k, 3)
        Omega = skew(w)
        return Ur + 1j * matmul(Ur, Omega), Pr + 1j * (X - matmul(Omega, Pr))
    w = (Minv @ x[..., :, None])[..., 0]
    Omega = skew(w)
    return Ur + 1j * (Ur @ Omega), Pr + 1j * (X - Omega @ Pr)


def _acos(c):
    """``saacos`` of cosines strictly inside (-1, 1), analytic (see :func:`analytic.acos`)."""
    if c.dtype != np.complex128:
        return np.arccos(c)
    r = c.real
    return np.arccos(r) - 1j * (c.imag / np.sqrt(1.0 - r * r))


def slerp(a, b, t):
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


def rotation_quaternion(U) -> np.ndarray:
    """(..., 4) ``mat3_normalized_to_quat_fast`` of rotation matrices (..., 3, 3) (orthonormal, proper:
    no normalization, no sign fix, as :func:`matrix_to_quaternion` would leave them).

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
        return matrix_to_quaternion(U)
    s = 2.0 * np.sqrt(traces[..., case])
    if case < 3:
        a, b = _QCASE_TEST[case]
        r = m.real
        s = np.where(r[..., a] < r[..., b], -s, s)
    return (m @ _QLIN[case] + _QCONST[case]) / s[..., None]


def _flip_negative(U, P, shared_batch):
    """U and P negated where U is a reflection (``interp_m4_m4m4`` turns those into rotations)."""
    value = U.real[:, :1] if shared_batch else U.real
    negative = det3(value) < 0
    if negative.any():
        U = np.where(negative[..., None, None], -U, U)
        P = np.where(negative[..., None, None], -P, P)
    return U, P


def interpolate(a, b, t, stacked: bool = False) -> np.ndarray:
    """(..., 4, 4) ``interp_m4_m4m4``: Blender's blend of a constraint's result by its influence.

    Locations are interpolated linearly; the 3×3 parts are polar-decomposed (``A = U P``), a negative
    ``U`` flipped together with ``P``, the rotations slerped as quaternions and the stretches ``P``
    interpolated linearly; ``R = U(t) P(t)``.

    Parameters
    ----------
    a, b : (..., 4, 4) array_like
        The matrices at ``t = 0`` and ``t = 1``.
    t : float or (...) array_like
    stacked : bool
        ``a`` and ``b`` are in the stack layout (g, K, 4, 4): when their batch entries share their values
        (complex-step directions, :class:`SharedValues`), the polar decompositions take one SVD per
        bone.
    """
    a, b = np.asarray(a), np.asarray(b)
    t = np.asarray(t)
    if a.shape != b.shape:
        a, b = np.broadcast_arrays(a, b)
    la = a[..., :3, 3]
    location = la + (b[..., :3, 3] - la) * t[..., None]
    if stacked and a.ndim == 4:
        n = a.shape[0]
        both = np.concatenate([a[..., :3, :3], b[..., :3, :3]], 0)
        share = _SHARED[0] and both.dtype == np.complex128 and both.shape[1] > 1
    else:
        n = 1
        both = np.stack([a[..., :3, :3], b[..., :3, :3]])
        share = False
    U, P = _flip_negative(*polar(both, shared_batch=share), share)
    q = rotation_quaternion(U)
    Pa, Pb = P[:n], P[n:]
    if not stacked or a.ndim != 4:
        Pa, Pb, qa, qb = Pa[0], Pb[0], q[0], q[1]
    else:
        qa, qb = q[:n], q[n:]
    Ut = quaternion_to_matrix(slerp(qa, qb, t))
    R = Ut @ (Pa + (Pb - Pa) * t[..., None, None])
    return _affine(R, location)
