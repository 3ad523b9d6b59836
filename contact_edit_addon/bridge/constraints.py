"""Bones and their constraints read from Blender as :mod:`solver.rig.bones` / :mod:`solver.rig.constraints`
data.

Every setting the solver's port of Blender's constraint evaluation reads is copied from bpy here; what it
cannot model is recorded (``Constraint.refusal``) so that ``Constraint.unsupported()`` names it and the
caller can refuse the rig. Muted, invalid (target missing) and zero-influence constraints are left out,
as ``BKE_constraints_solve`` skips them (a constraint whose target is missing does nothing).
"""

from __future__ import annotations

import bpy
import numpy as np

from solver.rig import DEFAULTS, Bone, Constraint, Target
from solver.rotations import EULER_ORDERS

#: Constraint types whose targets are a list (``constraint.targets``) rather than ``target``/``subtarget``.
MULTI_TARGET = ("ARMATURE",)


def read_bone(item) -> Bone:
    """The rest data of a bpy ``Bone`` or ``PoseBone`` (a pose bone also gives its rotation mode)."""
    pose_bone = item if isinstance(item, bpy.types.PoseBone) else None
    bone = pose_bone.bone if pose_bone is not None else item
    return Bone(
        name=bone.name,
        matrix_local=np.array(bone.matrix_local, dtype=np.float64),
        length=bone.length,
        parent=bone.parent.name if bone.parent else None,
        matrix=np.array(bone.matrix, dtype=np.float64),
        head=np.array(bone.head, dtype=np.float64),
        use_connect=bone.use_connect,
        use_inherit_rotation=bone.use_inherit_rotation,
        inherit_scale=bone.inherit_scale,
        use_local_location=bone.use_local_location,
        rotation_mode=pose_bone.rotation_mode if pose_bone is not None else "QUATERNION",
        bbone_segments=bone.bbone_segments,
        head_radius=bone.head_radius,
        tail_radius=bone.tail_radius,
        envelope_distance=bone.envelope_distance,
        use_envelope_multiply=bone.use_envelope_multiply,
    )


def _value(value):
    if isinstance(value, str | bool | int | float):
        return value
    try:
        return np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        return value


def _settings(constraint) -> dict:
    keys = DEFAULTS.get(constraint.type, {})
    return {key: _value(getattr(constraint, key)) for key in keys if hasattr(constraint, key)}


def _object_target(armature_object, obj, subtarget: str, head_tail: float, use_bbone_shape: bool, weight=1.0):
    """(Target, refusal or None) for a target object and sub-target."""
    if obj == armature_object:
        bone = armature_object.data.bones.get(subtarget) if subtarget else None
        if bone is not None:
            return Target(
                subtarget=subtarget,
                head_tail=head_tail,
                use_bbone_shape=use_bbone_shape,
                weight=weight,
                bbone_segments=bone.bbone_segments,
            ), None
        return Target(matrix=np.array(obj.matrix_world), weight=weight), None
    if subtarget and obj.type == "ARMATURE":
        return None, f"it targets bone {subtarget!r} of another armature ({obj.name!r})"
    if subtarget and obj.type in ("MESH", "LATTICE"):
        return None, f"it targets vertex group {subtarget!r} of {obj.name!r}"
    order = obj.rotation_mode if obj.rotation_mode in EULER_ORDERS else "XYZ"
    return Target(matrix=np.array(obj.matrix_world), weight=weight, euler_order=order), None


def read_constraint(armature_object, constraint) -> Constraint | None:
    """One bpy constraint as a :class:`solver.rig.constraints.Constraint`, or None when Blender skips it."""
    if constraint.mute or not constraint.is_valid or constraint.influence <= 0:
        return None
    refusals = []
    targets = []
    head_tail = float(getattr(constraint, "head_tail", 0.0))
    use_bbone_shape = bool(getattr(constraint, "use_bbone_shape", False))
    if constraint.type in MULTI_TARGET:
        for t in constraint.targets:
            if t.target is None:
                return None  # Blender's armdef_evaluate gives up on an invalid target
            if t.target != armature_object:
                refusals.append(f"target {t.target.name!r} is not the bone's own armature")
                continue
            target, refusal = _object_target(armature_object, t.target, t.subtarget, 0.0, False, t.weight)
            if target is None:
                refusals.append(refusal)
            else:
                targets.append(target)
    elif hasattr(constraint, "target"):
        if constraint.target is None:
            return None  # no valid target: the constraint does nothing
        target, refusal = _object_target(
            armature_object,
            constraint.target,
            getattr(constraint, "subtarget", ""),
            head_tail,
            use_bbone_shape,
        )
        if target is None:
            refusals.append(refusal)
        else:
            targets.append(target)
    space_subtarget, space_matrix = "", None
    owner_space = getattr(constraint, "owner_space", "WORLD")
    target_space = getattr(constraint, "target_space", "WORLD")
    if "CUSTOM" in (owner_space, target_space) and getattr(constraint, "space_object", None) is not None:
        space = constraint.space_object
        sub = constraint.space_subtarget
        if space == armature_object and sub and sub in armature_object.data.bones:
            space_subtarget = sub
        elif sub and space.type in ("ARMATURE", "MESH", "LATTICE"):
            refusals.append(f"its custom space is {sub!r} of {space.name!r}")
        else:
            space_matrix = np.array(space.matrix_world)
    return Constraint(
        type=constraint.type,
        name=constraint.name,
        influence=float(constraint.influence),
        owner_space=owner_space,
        target_space=target_space,
        targets=tuple(targets),
        settings=_settings(constraint),
        space_subtarget=space_subtarget,
        space_matrix=space_matrix,
        refusal="; ".join(refusals) or None,
    )


def read_constraints(armature_object, pose_bone) -> tuple[Constraint, ...]:
    """The enabled constraints of a pose bone with influence > 0, in stack order (muted, invalid and
    zero-influence ones skipped, as Blender skips them)."""
    read = (read_constraint(armature_object, c) for c in pose_bone.constraints)
    return tuple(c for c in read if c is not None)
