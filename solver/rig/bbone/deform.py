"""The matrices the Armature modifier blends for a vertex weighted to a B-Bone (``bbone_deform_mats``), for a
stack of bones at once or one bone."""

from __future__ import annotations

import math

import numpy as np

from ...errors import SolverError
from .bbone_stack import BBoneStack
from .jacobian import stack_jacobian
from .model import BBone
from .reference import checked_inputs, checked_pose
from .stacked import assemble, stack_joints, stack_state

#: The fewest complex-step directions for which :func:`stack_deform_matrices` differentiates through the
#: per-bone state (below, it evaluates the curve on every direction).
JACOBIAN_MIN = 10


def checked_stack_pose(st: BBoneStack, what: str, value):
    if value is None:
        raise SolverError(f"B-Bone stack {st!r} needs the posed matrices of {what}")
    M = np.asarray(value)
    if M.ndim < 3 or M.shape[-3:] != (len(st), 4, 4):
        raise SolverError(
            f"B-Bone stack {st!r}: the posed matrices of {what} must have shape (..., {len(st)}, 4, 4), "
            f"got {M.shape}"
        )
    if not (np.issubdtype(M.dtype, np.floating) or np.issubdtype(M.dtype, np.complexfloating)):
        M = M.astype(np.float64)
    return M


def stack_deform_matrices(
    stack: BBoneStack, poses, starts=None, ends=None, start_parents=None, end_parents=None
) -> np.ndarray:
    """:func:`deform_matrices` of every bone of a stack at once.

    Parameters
    ----------
    stack : BBoneStack
    poses : (..., g, 4, 4) float or complex
        The bones' posed matrices (``PoseBone.matrix``) along the stack axis (:attr:`BBoneStack.names`).
    starts, ends : (..., g, 4, 4) or None
        The posed matrices of the start / end handle bones (:attr:`BBoneStack.handle_names`); ``None``
        when no bone of the stack has a handle there. The entries of bones without a handle are not
        used (:meth:`BBoneStack.gather` puts the bone's own pose there).
    start_parents, end_parents : (..., g, 4, 4) or None
        The posed matrices of the handles' parents (:attr:`BBoneStack.handle_parent_names`).

    Returns
    -------
    (..., g, segments + 1, 4, 4)
        :func:`deform_matrices` of each bone; the leading dimensions are those of the arguments,
        broadcast. A stack of plain bones (``segments == 1``) gives two copies, (..., g, 2, 4, 4).

    Notes
    -----
    Posed matrices are affine: their last rows are not read. Complex arguments whose real parts agree
    along the leading dimensions (the complex-step directions of one pose), at least ``JACOBIAN_MIN``
    of them, are differentiated through the per-bone state (see the module's "Stacks"); others are
    evaluated direction by direction. Both give the complex-step derivatives to rounding.
    """
    if not isinstance(stack, BBoneStack):
        raise SolverError(f"stack_deform_matrices needs a BBoneStack, got {type(stack).__name__}")
    st, g = stack, len(stack)
    mats = [checked_stack_pose(st, "the bones", poses)]
    if st.segments == 1:
        M = mats[0] @ st.inverse_rest
        return np.stack([M, M], axis=-3)
    for what, value, needed in (
        ("the start handles", starts, st.start),
        ("the end handles", ends, st.end),
        ("the start handles' parents", start_parents, st.start is not None and st.start.has_parent),
        ("the end handles' parents", end_parents, st.end is not None and st.end.has_parent),
    ):
        mats.append(checked_stack_pose(st, what, value) if needed else None)
    shapes = {m.shape[:-3] for m in mats if m is not None}
    batch = shapes.pop() if len(shapes) == 1 else np.broadcast_shapes(*shapes)
    size = math.prod(batch)

    def component_first(M):
        if M is None:
            return None
        if M.shape[:-3] != batch:
            M = np.broadcast_to(M, (*batch, g, 4, 4))
        return np.ascontiguousarray(M.reshape(size, g, 4, 4).transpose(2, 3, 0, 1))

    Pt = [component_first(M) for M in mats]
    complex_ = [M is not None and np.iscomplexobj(M) for M in Pt]
    if (
        size >= JACOBIAN_MIN
        and any(complex_)
        and all((M.real[:3] == M.real[:3, :, :1]).all() for M, c in zip(Pt, complex_, strict=True) if c)
    ):
        return stack_jacobian(st, Pt).reshape(*batch, g, st.segments + 1, 4, 4)
    H, length, roll, sc, scale_in, scale_out = stack_state(st, *Pt)
    joints = stack_joints(st, H, length, roll, sc, scale_in, scale_out)
    M = assemble(Pt[0], sc, joints, st.unbend)
    a = st.segments + 1
    out = np.empty((size, g, a, 4, 4), M.dtype)
    out[..., :3, :] = M.transpose(3, 4, 2, 0, 1)
    out[..., 3, :] = (0.0, 0.0, 0.0, 1.0)
    return out.reshape(*batch, g, a, 4, 4)


def deform_matrices(
    bbone: BBone, pose, prev_pose=None, next_pose=None, prev_parent_pose=None, next_parent_pose=None
) -> np.ndarray:
    """The matrices the Armature modifier blends for a vertex weighted to this bone (``bbone_deform_mats``).

    Parameters
    ----------
    bbone : BBone
    pose : (..., 4, 4) float or complex
        The bone's posed matrix (``PoseBone.matrix``), armature space.
    prev_pose, next_pose, prev_parent_pose, next_parent_pose : (..., 4, 4), optional
        As for :func:`~solver.rig.bbone.spline_matrices` (unused when ``segments == 1``).

    Returns
    -------
    (..., segments + 1, 4, 4)
        ``M[a] = pose @ spline[a] @ inv(rest_spline[a]) @ inv(matrix_local)`` (``BKE_pchan_bbone_segments_
        cache_compute``; Blender's array has an extra leading ``inv(matrix_local)``, left out here):
        each takes a rest-pose point in armature space to its posed position as joint ``a`` moves it.
        With ``segments == 1``, two copies of ``pose @ inv(matrix_local)`` (``(..., 2, 4, 4)``).
    """
    if bbone.segments == 1:
        P = checked_pose(f"the bone {bbone.name!r}", bbone, pose)
        M = P @ np.linalg.inv(bbone.matrix_local)
        return np.stack([M, M], axis=-3)
    mats, _ = checked_inputs(bbone, pose, prev_pose, next_pose, prev_parent_pose, next_parent_pose)
    keys = ("pose", "prev", "next", "prev_parent", "next_parent")
    args = [None if mats.get(k) is None else mats[k][..., None, :, :] for k in keys]
    return stack_deform_matrices(BBoneStack.of([bbone]), *args)[..., 0, :, :, :]
