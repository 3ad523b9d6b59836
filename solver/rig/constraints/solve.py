"""``BKE_pose_where_is_bone`` for a stack of bones: their pose matrices from their channels, through their
parents and their constraints (``BKE_constraints_solve``), with targets taken in the constraints' spaces."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ...errors import SolverError
from ..bones import BoneStack
from ..interpolation import interp_m4_m4m4
from ..math_matrix import inverse_affine, with_translation
from ..parenting import Parenting
from ..spaces import Spaces, World
from ..stack import SharedValues, from_stack, matmul, to_stack
from ..stack import shared as _shared
from .constraint_stack import LOCAL_SPACES, ConstraintStack, Slot
from .evaluate import EVALUATE, Context

_EYE4 = np.eye(4)
_EYE4.setflags(write=False)


def _at_head_tail(slot: Slot, pose):
    """The target bones' pose matrices moved ``head_tail`` along them (``constraint_target_to_mat4``)."""
    if slot.head_tail is None:
        return pose
    shift = (slot.head_tail * slot.length)[..., None] * pose[..., :3, 1]
    return with_translation(pose, pose[..., :3, 3] + shift)


def target_in_space(cs: ConstraintStack, slot: Slot, pose, parent_pose, world: World, custom, cache=None):
    """(g, K, 4, 4) a slot's target matrix in the constraint's target space (stack layout)."""
    space = cs.target_space
    if slot.kind == "object":
        if space == "CUSTOM":
            return matmul(inverse_affine(custom), slot.matrix)
        return slot.matrix
    T = _at_head_tail(slot, pose)
    if space == "POSE":
        return T
    if space == "WORLD":
        return T if world.identity else matmul(world.matrix, T)
    if space == "LOCAL_WITH_PARENT":
        return matmul(slot.rest_inverse, T)
    if space == "CUSTOM":
        W = T if world.identity else matmul(world.matrix, T)
        return matmul(inverse_affine(custom), W)
    parenting = cache.get(slot.names) if cache is not None else None
    if parenting is None:
        parenting = Parenting(slot.stack, parent_pose)
        if cache is not None:
            cache[slot.names] = parenting
    M = parenting.to_local(T)
    if space == "LOCAL_OWNER_ORIENT":
        M = matmul(matmul(slot.diff[0], M), slot.diff[1])
    return M


def _replace_start(constraint_stacks) -> int:
    """Index of the last constraint stack that replaces the owner's transform (0 if none)."""
    start = 0
    for i, cs in enumerate(constraint_stacks):
        if cs.replaces:
            start = i
    return start


def parent_needed(bone_stack: BoneStack, constraint_stacks: Sequence[ConstraintStack]) -> bool:
    """Whether :func:`stack_pose_bones` reads the parents' poses: not for roots, nor for unconnected
    bones whose transform a constraint replaces when no later constraint works in their local space."""
    if bone_stack.root:
        return False
    start = _replace_start(constraint_stacks)
    if not constraint_stacks or not constraint_stacks[start].replaces or bone_stack.connect:
        return True
    return any(cs.owner_space in LOCAL_SPACES and not cs.off for cs in constraint_stacks[start:])


def _blend(old, new, influence, world: World):
    """``interp_m4_m4m4`` of the world matrices before and after a constraint, in pose space."""
    if world.identity:
        return interp_m4_m4m4(old, new, influence, stacked=True)
    blended = interp_m4_m4m4(matmul(world.matrix, old), matmul(world.matrix, new), influence, stacked=True)
    return matmul(world.inverse, blended)


def solve_one(cs: ConstraintStack, cob, parenting: Parenting, poses, parent_poses, world: World, cache=None):
    """The owner's pose matrix (g, K, 4, 4) after one constraint stack (``BKE_constraints_solve``'s loop
    body, in pose space)."""
    if cs.off:
        return cob
    nslots = len(cs.slots)
    target_poses = list(poses[:nslots])
    ctx = Context(parenting.stack, world, cs.order, target_poses)
    evaluate = EVALUATE[cs.type]
    if cs.in_pose_space(world):
        tars = []
        for slot, pose in zip(cs.slots, target_poses, strict=True):
            if slot.kind == "object":
                tars.append(slot.matrix if world.identity else matmul(world.inverse, slot.matrix))
            else:
                tars.append(_at_head_tail(slot, pose))
        new = evaluate(cs, cob, tars, ctx)
        if cs.type == "CHILD_OF" and cs.owner_space == "POSE" and not world.identity:
            new = matmul(world.inverse, new)  # CONSTRAINT_SPACEONCE: the result is taken as a world matrix
    else:
        custom = None
        if cs.custom is not None:
            if cs.custom.kind == "bone":
                space = poses[nslots]
                custom = space if world.identity else matmul(world.matrix, space)
            else:
                custom = cs.custom.matrix
        spaces = Spaces(parenting, world, None, custom)
        M = spaces.convert(cob, "POSE", cs.owner_space)
        tars = [
            target_in_space(cs, slot, pose, parent, world, custom, cache)
            for slot, pose, parent in zip(cs.slots, target_poses, parent_poses[:nslots], strict=True)
        ]
        new = evaluate(cs, M, tars, ctx)
        if cs.type == "CHILD_OF":  # CONSTRAINT_SPACEONCE: the result is taken as a world matrix
            new = new if world.identity else matmul(world.inverse, new)
        else:
            new = spaces.convert(new, cs.owner_space, "POSE")
    if not cs.full:
        new = _blend(cob, new, cs.influence, world)
    return new


def _pose_stack(bone_stack, P, L, constraint_stacks, poses, parent_poses, world):
    """:func:`stack_pose_bones` in the stack layout. Constraints before the last one that replaces the
    whole transform are skipped, and so is the parenting then, but for the heads of connected bones."""
    parenting = Parenting(bone_stack, P)
    connect = bone_stack.connect
    if not constraint_stacks:
        return parenting.to_pose(L, connect=connect)
    start = _replace_start(constraint_stacks)
    if constraint_stacks[start].replaces:
        cob = None
        head = parenting.head() if connect else None
    else:
        cob = parenting.to_pose(L, connect=connect)
        head = cob[..., :3, 3] if connect else None
    cache = {}
    for cs, p, pp in zip(constraint_stacks[start:], poses[start:], parent_poses[start:], strict=True):
        cob = solve_one(cs, cob, parenting, p, pp, world, cache)
    if head is not None:
        cob = with_translation(cob, head)
    return cob


def _array(a):
    return a if a is None or type(a) is np.ndarray else np.asarray(a)


def stack_pose_bones(
    bone_stack: BoneStack,
    parent_poses,
    locals,
    constraint_stacks: Sequence[ConstraintStack] = (),
    target_poses: Sequence[Sequence] = (),
    target_parent_poses: Sequence[Sequence] | None = None,
    world=None,
    shared: bool | None = None,
) -> np.ndarray:
    """(..., g, 4, 4) ``BKE_pose_where_is_bone`` for a stack of ``g`` bones: their pose matrices from
    their local channel matrices, through their parents and their constraints.

    Parameters
    ----------
    bone_stack : BoneStack
        The bones (one :func:`solver.rig.bones.bone_key`).
    parent_poses : (..., g, 4, 4) array_like or None
        The parents' (final) pose matrices; None for root bones, or when :func:`parent_needed` says they
        are not read.
    locals : (..., g, 4, 4) array_like or None
        The channel matrices (:func:`solver.rig.bones.channel_matrix`), or None for identity channels; their
        translations are ignored for connected bones, as Blender does.
    constraint_stacks : sequence of ConstraintStack
        The bones' constraints, position by position (each stack holds the ``g`` constraints at one
        position of the bones' constraint stacks).
    target_poses : sequence of sequences of (..., g, 4, 4) array_like
        Per constraint stack, per entry of its :attr:`ConstraintStack.inputs`: the pose matrices of those
        bones (None for object targets).
    target_parent_poses : sequence of sequences, optional
        Likewise for :attr:`ConstraintStack.parent_inputs` (None where not needed).
    world : (4, 4) array_like or solver.rig.spaces.World, optional
        The armature object's ``matrix_world`` (default identity); pass a :class:`solver.rig.spaces.World`
        to precompute it once.
    shared : bool, optional
        Complex inputs are complex-step directions that share their values (real parts) across the
        leading dimensions, which makes products of varying matrices cheap; default: checked.

    Leading dimensions ``...`` (complex-step directions) broadcast; constants may be ``(g, 4, 4)``.
    Arrays whose memory is stack-major (``np.moveaxis(a, 0, -3)`` of a ``(g, ..., 4, 4)`` array) are used
    without copies, and the result is such a view; it may share memory with the inputs.
    """
    if world.__class__ is not World:
        world = World.of(_EYE4 if world is None else world)
    g = bone_stack.size
    n = len(constraint_stacks)
    if len(target_poses) != n:
        if target_poses or any(cs.inputs for cs in constraint_stacks):
            raise SolverError("stack_pose_bones needs the target poses of every constraint stack")
        target_poses = ((),) * n
    if target_parent_poses is None:
        target_parent_poses = [(None,) * len(cs.inputs) for cs in constraint_stacks]
    parent_poses, locals = _array(parent_poses), _array(locals)
    target_poses = [[_array(a) for a in tp] for tp in target_poses]
    target_parent_poses = [[_array(a) for a in tp] for tp in target_parent_poses]
    lead = None
    for group in ((parent_poses, locals), *target_poses, *target_parent_poses):
        for a in group:
            if a is None:
                continue
            shape = a.shape
            if shape[-3:] != (g, 4, 4):
                raise SolverError(
                    f"stack of bones {', '.join(bone_stack.names[:3])}: matrices must be (..., {g}, 4, 4), "
                    f"got {shape}"
                )
            own = shape[:-3]
            if lead is None or lead == ():
                lead = own
            elif own != lead and own != ():
                lead = np.broadcast_shapes(lead, own)
    lead = () if lead is None else lead
    P = None if parent_poses is None else to_stack(parent_poses, lead)
    L = None if locals is None else to_stack(locals, lead)
    poses = [[None if a is None else to_stack(a, lead) for a in tp] for tp in target_poses]
    parents = [[None if a is None else to_stack(a, lead) for a in tp] for tp in target_parent_poses]
    if shared is None:
        shared = all(
            a is None or a.dtype != np.complex128 or a.shape[1] == 1 or _shared(a)
            for a in (P, L, *(x for p in poses for x in p), *(x for p in parents for x in p))
        )
    with SharedValues(shared):
        out = _pose_stack(bone_stack, P, L, constraint_stacks, poses, parents, world)
    return from_stack(out, lead)
