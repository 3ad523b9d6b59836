"""One bone at a time: :func:`pose_bone`, :func:`solve` and :func:`target_matrix` as stacks of one bone,
each bone's targets given by name (:class:`~.model.TargetBone`)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ...errors import SolverError
from ..bones import Bone, BoneStack
from ..parenting import Parenting
from ..spaces import World
from ..stack import from_stack, to_stack
from .constraint_stack import ConstraintStack
from .model import Constraint, Target, TargetBone
from .solve import solve_one, stack_pose_bones, target_in_space


def _target_bones(targets: Mapping[str, TargetBone]) -> dict[str, Bone]:
    bones = {}
    for name, tb in targets.items():
        bones[name] = tb.bone
        if tb.parent is not None:
            bones.setdefault(tb.parent.name, tb.parent)
    return bones


def _single_inputs(cs: ConstraintStack, targets: Mapping[str, TargetBone], con: Constraint):
    poses, parents = [], []
    for names, parent_names in zip(cs.inputs, cs.parent_inputs, strict=True):
        if names is None:
            poses.append(None)
            parents.append(None)
            continue
        tb = _target_bone(targets, names[0], con)
        poses.append(np.asarray(tb.pose)[..., None, :, :])
        parents.append(None if parent_names is None else np.asarray(tb.parent_pose)[..., None, :, :])
    return poses, parents


def _target_bone(targets: Mapping[str, TargetBone], name: str, con: Constraint) -> TargetBone:
    try:
        return targets[name]
    except KeyError:
        raise SolverError(f"constraint {con.name!r} targets bone {name!r}, which was not given") from None


def _single_stacks(bone: Bone, constraints, targets: Mapping[str, TargetBone]):
    bones = _target_bones(targets)
    for con in constraints:
        for name in [t.subtarget for t in con.targets if t.subtarget] + (
            [con.space_subtarget] if con.space_subtarget else []
        ):
            if con.unsupported() is None:
                _target_bone(targets, name, con)
    stacks = [ConstraintStack.of([c], [bone], bones) for c in constraints]
    inputs = [_single_inputs(cs, targets, c) for cs, c in zip(stacks, constraints, strict=True)]
    return stacks, [p for p, _ in inputs], [q for _, q in inputs]


def target_matrix(
    con: Constraint, target: Target, owner: Bone, targets: Mapping[str, TargetBone], world, custom
):
    """(..., 4, 4) ``constraint_target_to_mat4``: a target's matrix in the constraint's target space.

    A bone target is taken at ``head_tail`` along the bone (``pose_head`` to ``pose_tail``, orientation
    of its pose matrix), put in world space by the armature's ``world`` matrix, then converted to the
    target space as the target bone's space (``LOCAL_OWNER_ORIENT`` uses the owner's rest orientation).
    The target bone's poses in ``targets`` (:class:`TargetBone`) and ``custom``, the ``CUSTOM`` space's world
    matrix (..., 4, 4) or None, give the leading dimensions ``...`` (broadcast).
    """
    world = World.of(world)
    single = Constraint(
        con.type,
        con.name,
        1.0,
        con.owner_space,
        con.target_space,
        (target,),
        con.settings,
        con.space_subtarget,
        con.space_matrix,
    )
    cs = ConstraintStack.of([single], [owner], _target_bones(targets))
    slot = cs.slots[0]
    arrays = [custom]
    if slot.kind == "bone":
        tb = _target_bone(targets, target.subtarget, con)
        arrays += [tb.pose, tb.parent_pose if slot.parent_names is not None else None]
    present = [np.asarray(a) for a in arrays if a is not None]
    lead = np.broadcast_shapes(*(a.shape[:-2] for a in present)) if present else ()
    C, *rest = [None if a is None else to_stack(np.asarray(a)[..., None, :, :], lead) for a in arrays]
    pose, parent = rest if rest else (None, None)
    return from_stack(target_in_space(cs, slot, pose, parent, world, C), lead)[..., 0, :, :]


def solve(bone: Bone, parent: Bone | None, parent_pose, pose, constraints, targets, world) -> np.ndarray:
    """(..., 4, 4) ``BKE_constraints_solve``: a pose matrix (..., 4, 4) after the constraints.

    Parameters are those of :func:`pose_bone`, with ``pose`` (..., 4, 4) the bone's pose matrix before
    constraints in place of ``local``; ``parent_pose`` (..., 4, 4) (None for a root bone) and the targets'
    poses broadcast against it.
    """
    stack = BoneStack.of([bone], [parent])
    world = World.of(world)
    stacks, poses, parents = _single_stacks(bone, constraints, targets)
    P = None if parent is None else np.asarray(parent_pose)[..., None, :, :]
    M = np.asarray(pose)[..., None, :, :]
    arrays = [P, M, *(x for p in poses for x in p), *(x for p in parents for x in p)]
    lead = np.broadcast_shapes(*(a.shape[:-3] for a in arrays if a is not None))
    parenting = Parenting(stack, to_stack(P, lead))
    cob = to_stack(M, lead)
    for cs, p, pp in zip(stacks, poses, parents, strict=True):
        p = [to_stack(a, lead) for a in p]
        pp = [to_stack(a, lead) for a in pp]
        cob = solve_one(cs, cob, parenting, p, pp, world)
    return from_stack(cob, lead)[..., 0, :, :]


def pose_bone(
    bone: Bone,
    parent: Bone | None,
    parent_pose,
    local,
    constraints,
    targets: Mapping[str, TargetBone],
    world,
) -> np.ndarray:
    """(..., 4, 4) ``BKE_pose_where_is_bone``: a bone's pose matrix from its local channel matrix.

    Parameters
    ----------
    bone : Bone
    parent : Bone or None
        The parent's rest data (None for a root bone).
    parent_pose : (..., 4, 4) array_like or None
        The parent's (final) pose matrix.
    local : (..., 4, 4) array_like
        The channel matrix (:func:`solver.rig.bones.channel_matrix`); its translation is ignored for a
        connected bone, as Blender does.
    constraints : sequence of Constraint
        The bone's enabled constraints, in stack order.
    targets : Mapping[str, TargetBone]
        Every bone the constraints target (and ``CUSTOM`` space bones), posed already.
    world : (4, 4) array_like
        The armature object's ``matrix_world``.
    """
    stack = BoneStack.of([bone], [parent])
    stacks, poses, parents = _single_stacks(bone, constraints, targets)
    P = None if parent is None else np.asarray(parent_pose)[..., None, :, :]
    out = stack_pose_bones(stack, P, np.asarray(local)[..., None, :, :], stacks, poses, parents, world)
    return np.asarray(out)[..., 0, :, :]
