"""A Blender armature as the solver's :class:`solver.rig.controls.Armature`: every bone's rest data, evaluated
pose and channels, constraints, B-Bone, locks, limits, and what its drivers and IK chains read.

Read from the *evaluated* armature (animation, drivers and constraints applied), so that whatever the
solve does not change is exactly what Blender shows.
"""

from __future__ import annotations

import re

import bpy
import numpy as np

from solver import SolverError
from solver.rig import Armature, DriverInput, PoseBone
from solver.rotations import EULER_ORDERS

from .bbones import read_bbone
from .constraints import read_bone, read_constraints
from .errors import BridgeError

_BONE_PATH = re.compile(r'^pose\.bones\["((?:[^"\\]|\\.)*)"\]')
_KEY_PATH = re.compile(r'^key_blocks\["((?:[^"\\]|\\.)*)"\]')
#: Pose bone properties whose values a driver may read without depending on the bone's pose.
_CHANNELS = ("location", "rotation_euler", "rotation_quaternion", "rotation_axis_angle", "scale")


def read_armature(armature: bpy.types.Object, depsgraph=None) -> Armature:
    """Every bone of ``armature`` as the solver models it (see :mod:`solver.rig.controls`).

    Raises
    ------
    BridgeError
        If the armature cannot be read (its data naming a bone that is not there).
    """
    depsgraph = depsgraph or bpy.context.evaluated_depsgraph_get()
    evaluated = armature.evaluated_get(depsgraph)
    drivers = _driver_inputs(armature)
    moved_by, aimed_at = _ik_chains(evaluated)
    pose_bones = []
    for pose_bone in evaluated.pose.bones:
        name = pose_bone.name
        bone = pose_bone.bone
        mode = pose_bone.rotation_mode
        rotation = {"QUATERNION": pose_bone.rotation_quaternion, "AXIS_ANGLE": pose_bone.rotation_axis_angle}
        lower, upper = _limits(pose_bone) if mode in EULER_ORDERS else (None, None)
        try:
            pose_bones.append(
                PoseBone(
                    bone=read_bone(pose_bone),
                    matrix=np.array(pose_bone.matrix, dtype=np.float64),
                    location=np.array(pose_bone.location, dtype=np.float64),
                    rotation=np.array(rotation.get(mode, pose_bone.rotation_euler), dtype=np.float64),
                    scale=np.array(pose_bone.scale, dtype=np.float64),
                    constraints=read_constraints(evaluated, pose_bone),
                    bbone=read_bbone(evaluated, name)
                    if bone.use_deform and bone.bbone_segments > 1
                    else None,
                    deform=bone.use_deform,
                    lock_location=tuple(pose_bone.lock_location),
                    lock_rotation=_rotation_locks(pose_bone),
                    lower=lower,
                    upper=upper,
                    drivers=tuple(drivers.get(name, ())),
                    moved_by_ik=tuple(sorted(moved_by.get(name, ()))),
                    ik_targets=tuple(sorted(aimed_at.get(name, ()))),
                )
            )
        except SolverError as err:
            raise BridgeError(f"'{armature.name}' bone '{name}': {err}", armature.name) from err
    try:
        return Armature(pose_bones, np.array(armature.matrix_world), armature.name)
    except SolverError as err:
        raise BridgeError(str(err), armature.name) from err


def _rotation_locks(pose_bone) -> tuple[bool, bool, bool]:
    """Locked rotation axes; a quaternion or axis-angle bone with its W (angle) locked turns not at all."""
    locks = tuple(bool(x) for x in pose_bone.lock_rotation)
    if (
        pose_bone.rotation_mode not in EULER_ORDERS
        and pose_bone.lock_rotations_4d
        and pose_bone.lock_rotation_w
    ):
        return (True, True, True)
    return locks


def _limits(pose_bone) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Rotation limits (radians) of an Euler bone from its IK limits and its local Limit Rotation
    constraints at full influence; None when nothing limits it."""
    lower, upper = np.full(3, -np.inf), np.full(3, np.inf)
    for c, axis in enumerate("xyz"):
        if getattr(pose_bone, f"use_ik_limit_{axis}"):
            lower[c] = getattr(pose_bone, f"ik_min_{axis}")
            upper[c] = getattr(pose_bone, f"ik_max_{axis}")
        for con in pose_bone.constraints:
            if (
                con.type == "LIMIT_ROTATION"
                and con.enabled
                and con.influence == 1
                and con.owner_space == "LOCAL"
                and con.euler_order in {"AUTO", pose_bone.rotation_mode}
                and getattr(con, f"use_limit_{axis}")
            ):
                lower[c] = max(lower[c], getattr(con, f"min_{axis}"))
                upper[c] = min(upper[c], getattr(con, f"max_{axis}"))
    if np.all(np.isinf(lower)) and np.all(np.isinf(upper)):
        return None, None
    return lower, upper


def _driver_inputs(armature: bpy.types.Object) -> dict[str, list[DriverInput]]:
    """Per bone whose channels or constraints are driven, what of the armature's bones the drivers read."""
    found: dict[str, list[DriverInput]] = {}
    data = armature.animation_data
    for fcurve in data.drivers if data else ():
        match = _BONE_PATH.match(fcurve.data_path)
        if not match or fcurve.mute:
            continue
        owner = match.group(1)
        for variable in fcurve.driver.variables:
            for target in variable.targets[: 2 if variable.type in {"ROTATION_DIFF", "LOC_DIFF"} else 1]:
                read = _driver_target(armature, variable.type, target)
                if read is not None:
                    found.setdefault(owner, []).append(read)
    return found


def driven_keys(mesh: bpy.types.Object, armature: bpy.types.Object) -> dict[str, tuple[str, ...]]:
    """The mesh's shape keys whose (unmuted) drivers read ``armature``'s bones: key name -> bones read."""
    keys = getattr(mesh.data, "shape_keys", None)
    data = keys.animation_data if keys is not None else None
    found: dict[str, set[str]] = {}
    for fcurve in data.drivers if data else ():
        match = _KEY_PATH.match(fcurve.data_path)
        block = keys.key_blocks.get(match.group(1)) if match else None
        if block is None or block.mute or fcurve.mute:
            continue
        for variable in fcurve.driver.variables:
            for target in variable.targets[: 2 if variable.type in {"ROTATION_DIFF", "LOC_DIFF"} else 1]:
                read = _driver_target(armature, variable.type, target)
                if read is not None:
                    found.setdefault(match.group(1), set()).add(read.bone)
    return {key: tuple(sorted(bones)) for key, bones in found.items()}


def _driver_target(armature, kind: str, target) -> DriverInput | None:
    if target.id != armature and getattr(target.id, "data", None) != armature.data:
        return None  # another object's values: input the solve does not change
    if kind == "SINGLE_PROP":
        match = _BONE_PATH.match(target.data_path)
        if match is None:
            return None
        prop = target.data_path[match.end() :].lstrip(".").split(".")[0].split("[")[0]
        return DriverInput(match.group(1), "channel") if prop in _CHANNELS else None
    if not target.bone_target:
        return None
    if kind == "TRANSFORMS" and target.transform_space == "TRANSFORM_SPACE":
        return DriverInput(target.bone_target, "channel")
    return DriverInput(target.bone_target, "pose")


def _ik_chains(armature) -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    """Per bone in the chain of an active IK or Spline IK constraint: the constraints' owners, and the
    bones they aim at (target and pole)."""
    moved_by: dict[str, set[str]] = {}
    aimed_at: dict[str, set[str]] = {}
    for pose_bone in armature.pose.bones:
        for con in pose_bone.constraints:
            if con.type not in {"IK", "SPLINE_IK"} or not con.enabled or con.influence <= 0:
                continue
            count = con.chain_count
            bone, chain = pose_bone, []
            while bone is not None and (count == 0 or len(chain) < count):
                chain.append(bone.name)
                bone = bone.parent
            targets = {getattr(con, "subtarget", ""), getattr(con, "pole_subtarget", "")} - {""}
            for name in chain:
                moved_by.setdefault(name, set()).add(pose_bone.name)
                aimed_at.setdefault(name, set()).update(targets)
    return moved_by, aimed_at
