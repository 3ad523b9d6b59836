"""A hand mesh and the armature that deforms it, as a :class:`solver.SkinnedMesh`, and poses back.

What the solver models is exactly what Blender's Armature modifier does for directly posed bones:
linear blend skinning by vertex groups of deform bones (weights divided by their sum, vertices whose
weights sum to at most 0.0001 left in place), bones posed by their own location, rotation and limits.
Anything else that would make Blender's result differ from the solver's (B-Bones, Preserve Volume,
envelopes, modifiers or shape keys before the armature, constraints other than a local Limit Rotation,
drivers, bone scale) is reported by name rather than silently mis-posed.

Everything the solver sees is in the armature object's space; the hand mesh and the object's contacts
are carried there by the objects' world matrices.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import bpy
import numpy as np
from mathutils import Euler, Quaternion
from scipy import sparse

from geodesics import TriMesh
from solver import Rig, SkinnedMesh, SolverError
from solver.rotations import EULER_ORDERS

from .errors import BridgeError
from .mesh import vertex_group_weights

#: Blender's Armature modifier leaves a vertex in place when its deform weights sum to no more than this.
MIN_TOTAL_WEIGHT = 1e-4
#: Relative tolerance for an armature's scale to count as uniform.
UNIFORM_SCALE_TOLERANCE = 1e-5
_BONE_PATH = re.compile(r'^pose\.bones\["((?:[^"\\]|\\.)*)"\]')


@dataclass(frozen=True)
class PosedHand:
    """A hand and its armature as the solver sees them.

    Attributes
    ----------
    hand, armature : str
        Object names (names, not references, so that undo cannot leave them dangling).
    skin : SkinnedMesh
        The hand's rest mesh in armature space, bound to the rig of the bones that move it.
    hand_to_armature : (4, 4)
        Hand object space to armature space (Blender's ``premat`` of the Armature modifier).
    rotation_modes : tuple of str
        Each rig bone's Blender rotation mode (the rig's Euler order stands in for quaternion and
        axis-angle bones, whose poses are converted on the way in and out).
    """

    hand: str
    armature: str
    skin: SkinnedMesh
    hand_to_armature: np.ndarray
    rotation_modes: tuple[str, ...]

    @property
    def rig(self) -> Rig:
        return self.skin.rig

    def armature_object(self) -> bpy.types.Object:
        obj = bpy.data.objects.get(self.armature)
        if obj is None or obj.type != "ARMATURE":
            raise BridgeError(f"the armature '{self.armature}' is gone")
        return obj

    def to_hand(self, points) -> np.ndarray:
        """Armature-space positions (k, 3) in the hand's object space."""
        M = np.linalg.inv(self.hand_to_armature)
        return np.asarray(points, np.float64).reshape(-1, 3) @ M[:3, :3].T + M[:3, 3]


def armature_modifier(hand: bpy.types.Object) -> bpy.types.ArmatureModifier:
    """The one Armature modifier deforming ``hand``, checked to deform the way the solver models."""
    if hand is None or hand.type != "MESH":
        raise BridgeError(f"'{getattr(hand, 'name', None)}' is not a mesh object")
    found = [(i, m) for i, m in enumerate(hand.modifiers) if m.type == "ARMATURE" and m.show_viewport]
    if not found:
        raise BridgeError(
            f"'{hand.name}' has no Armature modifier, so there is no armature to pose; parent it to an "
            "armature (Ctrl+P, With Automatic Weights) or choose the skinned mesh as the hand",
            hand.name,
        )
    if len(found) > 1:
        raise BridgeError(
            f"'{hand.name}' has {len(found)} Armature modifiers; contact IK poses one", hand.name
        )
    index, modifier = found[0]
    if modifier.object is None or modifier.object.type != "ARMATURE":
        raise BridgeError(f"the Armature modifier '{modifier.name}' of '{hand.name}' has no armature set")
    before = [m.name for m in hand.modifiers[:index] if m.show_viewport]
    problems = []
    if before:
        problems.append(f"modifiers before it change the shape it deforms ({', '.join(before)})")
    if modifier.use_deform_preserve_volume:
        problems.append("Preserve Volume is on (dual quaternion skinning)")
    if modifier.use_bone_envelopes:
        problems.append("it deforms with bone envelopes")
    if not modifier.use_vertex_groups:
        problems.append("it does not use vertex groups")
    if modifier.vertex_group:
        problems.append(f"it is masked by the vertex group '{modifier.vertex_group}'")
    keys = hand.data.shape_keys
    if keys is not None and any(k.value != 0 and not k.mute for k in keys.key_blocks[1:]):
        problems.append("shape keys change the shape it deforms")
    if problems:
        raise BridgeError(
            f"contact IK models plain linear blend skinning, but on '{hand.name}' the Armature modifier "
            f"'{modifier.name}': {'; '.join(problems)}",
            hand.name,
        )
    return modifier


def posed_hand(hand: bpy.types.Object, faces: np.ndarray) -> PosedHand:
    """The hand's skinned rest mesh and rig, in armature space.

    Parameters
    ----------
    hand : a mesh object with an Armature modifier
    faces : (m, 3) int
        The triangles of the hand's contact set (its :class:`geodesics.TriMesh`), so that the set's
        surface points (face, barycentric) name the same skin points on the skinned mesh.

    Raises
    ------
    BridgeError
        For anything the solver cannot reproduce exactly, naming the bones, constraints or settings.
    """
    modifier = armature_modifier(hand)
    armature = modifier.object
    to_armature = _hand_to_armature(hand, armature)
    bones = armature.data.bones
    raw = _deform_weights(hand, armature)
    if raw.nnz == 0:
        raise BridgeError(
            f"no vertex of '{hand.name}' is weighted to a deform bone of '{armature.name}'; weight paint "
            "it, or parent it with automatic weights",
            hand.name,
        )
    weighted = [bones[i].name for i in np.unique(raw.indices)]
    names = _rig_bones(armature, weighted)
    column = {b.name: i for i, b in enumerate(bones)}
    W = raw[:, [column[n] for n in names]].tocsr()
    total = np.asarray(W.sum(axis=1)).ravel()
    W = sparse.diags(np.where(total > MIN_TOTAL_WEIGHT, 1.0 / np.maximum(total, 1e-300), 0.0)) @ W

    _check_supported(armature, names)
    lower, upper, locked, modes = _limits(armature, names)
    rig_bones = [bones[n] for n in names]
    parents = [-1] + [names.index(b.parent.name) for b in rig_bones[1:]]
    try:
        rig = Rig(
            names,
            parents,
            np.array([np.array(b.matrix_local) for b in rig_bones]),
            np.array([b.length for b in rig_bones]),
            lower=lower,
            upper=upper,
            locked=locked,
            rotation_modes=[m if m in EULER_ORDERS else "XYZ" for m in modes],
        )
        vertices = np.empty(3 * len(hand.data.vertices))
        hand.data.vertices.foreach_get("co", vertices)
        rest = vertices.reshape(-1, 3) @ to_armature[:3, :3].T + to_armature[:3, 3]
        skin = SkinnedMesh(TriMesh(rest, faces), rig, W)
    except SolverError as err:
        raise BridgeError(f"'{armature.name}' cannot be posed by contact IK: {err}", hand.name) from err
    return PosedHand(hand.name, armature.name, skin, to_armature, tuple(modes))


def _hand_to_armature(hand: bpy.types.Object, armature: bpy.types.Object) -> np.ndarray:
    if hand.parent == armature and hand.parent_type == "BONE":
        raise BridgeError(
            f"'{hand.name}' is parented to the bone '{hand.parent_bone}', so posing moves the mesh twice; "
            "parent it to the armature object instead",
            hand.name,
        )
    A = np.array(armature.matrix_world)
    columns = np.linalg.norm(A[:3, :3], axis=0)
    gram = A[:3, :3].T @ A[:3, :3]
    if np.abs(gram - np.diag(columns**2)).max() > UNIFORM_SCALE_TOLERANCE * columns.max() ** 2 or (
        np.ptp(columns) > UNIFORM_SCALE_TOLERANCE * columns.max()
    ):
        scale = ", ".join(f"{c:.4g}" for c in columns)
        raise BridgeError(
            f"the armature '{armature.name}' has non-uniform scale ({scale}), which distorts its bones; "
            "apply its scale (Ctrl+A, Scale) first",
            hand.name,
        )
    return np.linalg.inv(A) @ np.array(hand.matrix_world)


def _deform_weights(hand: bpy.types.Object, armature: bpy.types.Object) -> sparse.csr_matrix:
    """Raw weights (n_vertices, n_armature_bones) of the vertex groups named after deform bones."""
    bones = armature.data.bones
    groups = vertex_group_weights(hand).tocsc()
    columns = np.zeros((groups.shape[1], len(bones)))
    for group in hand.vertex_groups:
        bone = bones.get(group.name)
        if bone is not None and bone.use_deform:
            columns[group.index, bones.find(group.name)] = 1.0
    W = (groups @ sparse.csr_matrix(columns)).tocsr()
    W.data[W.data < 0] = 0.0  # Blender ignores negative weights
    W.eliminate_zeros()
    return W


def _rig_bones(armature: bpy.types.Object, weighted: list[str]) -> list[str]:
    """The weighted bones and their ancestors, parents first; they must share one root."""
    bones = armature.data.bones
    chains = {}
    for name in weighted:
        chain, bone = [], bones[name]
        while bone is not None:
            chain.append(bone.name)
            bone = bone.parent
        chains[name] = chain
    roots = sorted({chain[-1] for chain in chains.values()})
    if len(roots) > 1:
        raise BridgeError(
            f"the bones deforming the hand hang from {len(roots)} separate roots of '{armature.name}' "
            f"({', '.join(roots)}); contact IK needs them under one root bone"
        )
    depth = {name: len(chain) - 1 - k for chain in chains.values() for k, name in enumerate(chain)}
    order = {b.name: i for i, b in enumerate(bones)}
    return sorted(depth, key=lambda n: (depth[n], order[n]))


def _check_supported(armature: bpy.types.Object, names: list[str]) -> None:
    """Raise if anything would make Blender pose the rig's bones differently from the solver."""
    rig = set(names)
    found = []
    for name in names:
        bone, pose_bone = armature.data.bones[name], armature.pose.bones[name]
        if bone.bbone_segments > 1 and bone.use_deform:
            found.append(f"{name}: B-Bone segments")
        if bone.parent is not None and not bone.use_inherit_rotation:
            found.append(f"{name}: does not inherit rotation")
        if bone.parent is None and not bone.use_local_location:
            found.append(f"{name}: location not in local space")
        if any(abs(s - 1) > 1e-9 for s in pose_bone.scale):
            found.append(f"{name}: scaled (clear with Alt+S)")
        if bone.parent is not None and any(abs(x) > 1e-9 for x in pose_bone.location):
            found.append(f"{name}: moved off its parent (clear with Alt+G)")
        for constraint in pose_bone.constraints:
            if _active(constraint) and _limit_rotation_problem(constraint, pose_bone) is not None:
                found.append(f"{name}: {constraint.name} ({_limit_rotation_problem(constraint, pose_bone)})")
    for pose_bone in armature.pose.bones:
        for constraint in pose_bone.constraints:
            if _active(constraint) and constraint.type in {"IK", "SPLINE_IK"}:
                chain = _ik_chain(pose_bone, constraint)
                if rig & chain and pose_bone.name not in rig:
                    found.append(
                        f"{', '.join(sorted(rig & chain))}: moved by {pose_bone.name}'s {constraint.name}"
                    )
    drivers = armature.animation_data.drivers if armature.animation_data else ()
    for fcurve in drivers:
        match = _BONE_PATH.match(fcurve.data_path)
        if match and match.group(1) in rig and not fcurve.mute:
            found.append(f"{match.group(1)}: driven ({fcurve.data_path.split('.')[-1]})")
    if found:
        shown = "; ".join(found[:6]) + (f"; … ({len(found)} in all)" if len(found) > 6 else "")
        raise BridgeError(
            f"contact IK cannot reproduce how Blender poses these bones of '{armature.name}': {shown}. "
            "Mute or remove what is listed, or solve a rig without it"
        )


def _active(constraint) -> bool:
    return constraint.enabled and constraint.influence > 0


def _limit_rotation_problem(constraint, pose_bone) -> str | None:
    """Why a constraint is not a Limit Rotation the solver turns into bounds, or None if it is."""
    if constraint.type != "LIMIT_ROTATION":
        return constraint.type.replace("_", " ").title()
    if constraint.owner_space != "LOCAL":
        return "Limit Rotation outside local space"
    if constraint.influence != 1:
        return "Limit Rotation with partial influence"
    mode = pose_bone.rotation_mode if pose_bone.rotation_mode in EULER_ORDERS else "XYZ"
    if constraint.euler_order not in {"AUTO", mode}:
        return f"Limit Rotation in {constraint.euler_order} order on a {mode} bone"
    return None


def _ik_chain(pose_bone, constraint) -> set[str]:
    chain, bone, length = set(), pose_bone, constraint.chain_count
    while bone is not None and (length == 0 or len(chain) < length):
        chain.add(bone.name)
        bone = bone.parent
    return chain


def _limits(armature: bpy.types.Object, names: list[str]):
    """DOF bounds, locks and rotation modes of the rig's bones, from locks, IK limits and Limit
    Rotation constraints; unconstrained rotations get a full turn around their current value."""
    nd = 6 + 3 * (len(names) - 1)
    theta = current_pose(armature, names)
    lower = np.concatenate([np.full(3, -np.inf), np.minimum(-np.pi, theta[3:])])
    upper = np.concatenate([np.full(3, np.inf), np.maximum(np.pi, theta[3:])])
    locked = np.zeros(nd, bool)
    modes = []
    for b, name in enumerate(names):
        pose_bone = armature.pose.bones[name]
        modes.append(pose_bone.rotation_mode)
        rotation = 3 + 3 * b + np.arange(3)
        if b == 0:
            locked[:3] = pose_bone.lock_location
        locked[rotation] = np.array(pose_bone.lock_rotation) | np.array(
            [pose_bone.lock_ik_x, pose_bone.lock_ik_y, pose_bone.lock_ik_z]
        )
        for c, axis in enumerate("xyz"):
            d = rotation[c]
            if getattr(pose_bone, f"use_ik_limit_{axis}"):
                lower[d], upper[d] = (
                    getattr(pose_bone, f"ik_min_{axis}"),
                    getattr(pose_bone, f"ik_max_{axis}"),
                )
            for constraint in pose_bone.constraints:
                limited = constraint.type == "LIMIT_ROTATION" and getattr(constraint, f"use_limit_{axis}")
                if limited and _active(constraint):
                    lower[d] = max(lower[d], getattr(constraint, f"min_{axis}"))
                    upper[d] = min(upper[d], getattr(constraint, f"max_{axis}"))
    return lower, upper, locked, modes


def selected_bones(armature: bpy.types.Object) -> set[str]:
    """Names of the bones selected in Pose Mode (``PoseBone.select`` since Blender 5.0, ``Bone.select``
    before)."""
    return {b.name for b in armature.pose.bones if (b.select if hasattr(b, "select") else b.bone.select)}


def rotation_path(mode: str) -> str:
    """The pose bone property holding a rotation in ``mode``."""
    return {"QUATERNION": "rotation_quaternion", "AXIS_ANGLE": "rotation_axis_angle"}.get(
        mode, "rotation_euler"
    )


def to_quaternion(mode: str, values) -> Quaternion:
    """A rotation stored as Blender stores it in ``mode`` (quaternion, axis-angle or Euler angles)."""
    if mode == "QUATERNION":
        return Quaternion(values).normalized()
    if mode == "AXIS_ANGLE":
        return Quaternion(values[1:], values[0])
    return Euler(values, mode).to_quaternion()


def set_bone_rotation(pose_bone: bpy.types.PoseBone, rotation: Quaternion) -> None:
    """Give a pose bone a rotation in its own mode, continuous with its current value (Euler angles
    nearest the current ones, quaternion sign kept), so keys interpolate the short way."""
    mode = pose_bone.rotation_mode
    if mode == "QUATERNION":
        pose_bone.rotation_quaternion = (
            -rotation if rotation.dot(pose_bone.rotation_quaternion) < 0 else rotation
        )
    elif mode == "AXIS_ANGLE":
        axis, angle = rotation.to_axis_angle()
        pose_bone.rotation_axis_angle = (angle, *axis)
    else:
        pose_bone.rotation_euler = rotation.to_euler(mode, pose_bone.rotation_euler)


def current_pose(armature: bpy.types.Object, names) -> np.ndarray:
    """The DOF vector (root location, then each bone's Euler angles) of the bones' current pose."""
    theta = np.zeros(6 + 3 * (len(names) - 1))
    for b, name in enumerate(names):
        pose_bone = armature.pose.bones[name]
        if b == 0:
            theta[:3] = pose_bone.location
        mode = pose_bone.rotation_mode
        if mode in EULER_ORDERS:
            theta[3 + 3 * b : 6 + 3 * b] = pose_bone.rotation_euler
        else:
            theta[3 + 3 * b : 6 + 3 * b] = to_quaternion(
                mode, getattr(pose_bone, rotation_path(mode))
            ).to_euler("XYZ")
    return theta


def apply_pose(posed: PosedHand, theta, frame: int | None = None) -> None:
    """Pose the armature's bones by θ, keying location (root) and rotation at ``frame`` if given."""
    armature = posed.armature_object()
    theta = posed.rig.check_theta(theta)
    for b, name in enumerate(posed.rig.names):
        pose_bone = armature.pose.bones[name]
        angles = theta[3 + 3 * b : 6 + 3 * b]
        if posed.rotation_modes[b] in EULER_ORDERS:
            pose_bone.rotation_euler = angles  # exactly the DOFs, no conversion
        else:
            set_bone_rotation(pose_bone, Euler(angles, "XYZ").to_quaternion())
        if b == 0:
            pose_bone.location = theta[:3]
        if frame is not None:
            if b == 0:
                pose_bone.keyframe_insert("location", frame=frame, group=name)
            pose_bone.keyframe_insert(rotation_path(posed.rotation_modes[b]), frame=frame, group=name)
