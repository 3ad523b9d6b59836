"""A Blender bone's B-Bone settings as a :class:`solver.rig.bbone.BBone`.

Everything a bone's B-Bone shape depends on except the evaluated pose is read here: the ``Bone``'s and
the ``PoseBone``'s B-Bone properties and the rest data of the handle bones Blender resolves for it
(``BKE_pchan_bbone_handles_get``: an ``AUTO`` start handle is the parent of a connected bone, an
``AUTO`` end handle the last connected child; other types use the custom handle bones). The caller adds
the posed matrices (``PoseBone.matrix``) of the bone, of the handles named by
:attr:`solver.rig.bbone.BBone.handle_names`, and of the handle parents named by
:attr:`~solver.rig.bbone.BBone.handle_parent_names`.
"""

from __future__ import annotations

import numpy as np

from solver import SolverError
from solver.rig import BBone, BBoneHandle

from .errors import BridgeError


def _matrix(m) -> np.ndarray:
    return np.array([list(row) for row in m], dtype=np.float64)


def _handle(armature_object, bone) -> BBoneHandle:
    pose_bone = armature_object.pose.bones[bone.name]
    parent = bone.parent
    offset = None
    if parent is not None:
        # BKE_bone_offset_matrix_get: bone_mat, translated to head + (0, parent length, 0).
        offset = np.eye(4)
        offset[:3, :3] = _matrix(bone.matrix)
        offset[:3, 3] = np.array(bone.head) + np.array([0.0, parent.length, 0.0])
    return BBoneHandle(
        name=bone.name,
        matrix_local=_matrix(bone.matrix_local),
        length=bone.length,
        head_local=tuple(bone.head_local),
        tail_local=tuple(bone.tail_local),
        segments=bone.bbone_segments,
        bone_roll_out=bone.bbone_rollout,
        pose_roll_out=pose_bone.bbone_rollout,
        parent=None if parent is None else parent.name,
        parent_offset=offset,
        inherit_scale=bone.inherit_scale,
        use_inherit_rotation=bool(bone.use_inherit_rotation),
    )


def handle_bones(bone):
    """The start and end handle bones Blender uses for ``bone`` (``bpy.types.Bone`` or ``None`` each)."""
    if bone.bbone_handle_type_start == "AUTO":
        start = bone.parent if bone.use_connect else None
    else:
        start = bone.bbone_custom_handle_start
    if bone.bbone_handle_type_end == "AUTO":
        connected = [child for child in bone.children if child.use_connect]
        end = connected[-1] if connected else None
    else:
        end = bone.bbone_custom_handle_end
    return start, end


def read_bbone(armature_object, bone_name: str) -> BBone:
    """The B-Bone constants of one bone of an armature object.

    Parameters
    ----------
    armature_object : bpy.types.Object
        An armature object (its ``data`` holds the bones, its ``pose`` the pose bones).
    bone_name : str

    Returns
    -------
    solver.rig.bbone.BBone
        Every field read from the ``Bone`` and ``PoseBone`` (the pose-level B-Bone values as they are
        now). Raises :class:`BridgeError` for a missing bone or a setting the solver rejects.
    """
    if armature_object is None or armature_object.type != "ARMATURE":
        raise BridgeError("B-Bones can only be read from an armature object")
    bone = armature_object.data.bones.get(bone_name)
    pose_bone = armature_object.pose.bones.get(bone_name) if armature_object.pose else None
    if bone is None or pose_bone is None:
        raise BridgeError(
            f"Armature {armature_object.name!r} has no bone {bone_name!r}", armature_object.name
        )
    start, end = handle_bones(bone)
    try:
        return BBone(
            name=bone.name,
            matrix_local=_matrix(bone.matrix_local),
            length=bone.length,
            head_local=tuple(bone.head_local),
            tail_local=tuple(bone.tail_local),
            segments=bone.bbone_segments,
            mapping_mode=bone.bbone_mapping_mode,
            handle_type_start=bone.bbone_handle_type_start,
            handle_type_end=bone.bbone_handle_type_end,
            start=None if start is None else _handle(armature_object, start),
            end=None if end is None else _handle(armature_object, end),
            bone_ease_in=bone.bbone_easein,
            bone_ease_out=bone.bbone_easeout,
            pose_ease_in=pose_bone.bbone_easein,
            pose_ease_out=pose_bone.bbone_easeout,
            bone_roll_in=bone.bbone_rollin,
            bone_roll_out=bone.bbone_rollout,
            pose_roll_in=pose_bone.bbone_rollin,
            pose_roll_out=pose_bone.bbone_rollout,
            bone_curve_in_x=bone.bbone_curveinx,
            bone_curve_in_z=bone.bbone_curveinz,
            bone_curve_out_x=bone.bbone_curveoutx,
            bone_curve_out_z=bone.bbone_curveoutz,
            pose_curve_in_x=pose_bone.bbone_curveinx,
            pose_curve_in_z=pose_bone.bbone_curveinz,
            pose_curve_out_x=pose_bone.bbone_curveoutx,
            pose_curve_out_z=pose_bone.bbone_curveoutz,
            bone_scale_in=tuple(bone.bbone_scalein),
            bone_scale_out=tuple(bone.bbone_scaleout),
            pose_scale_in=tuple(pose_bone.bbone_scalein),
            pose_scale_out=tuple(pose_bone.bbone_scaleout),
            use_endroll_as_inroll=bool(bone.use_endroll_as_inroll),
            use_scale_easing=bool(bone.use_scale_easing),
            handle_use_scale_start=tuple(bool(f) for f in bone.bbone_handle_use_scale_start),
            handle_use_scale_end=tuple(bool(f) for f in bone.bbone_handle_use_scale_end),
            handle_use_ease_start=bool(bone.bbone_handle_use_ease_start),
            handle_use_ease_end=bool(bone.bbone_handle_use_ease_end),
        )
    except SolverError as err:
        raise BridgeError(
            f"Bone {bone_name!r} of {armature_object.name!r}: {err}", armature_object.name
        ) from err
