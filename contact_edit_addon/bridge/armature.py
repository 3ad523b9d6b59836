"""A hand mesh and the armature that deforms it, as a :class:`solver.SkinnedMesh` posed through the
armature's controls, and poses back.

Whatever rig deforms the hand (a plain armature of deform bones, or a production rig such as Rigify whose
deform bones follow mechanism bones and controls through constraints, with B-Bones), the solver poses
what Blender's Armature modifier deforms, exactly: :mod:`solver.rig.controls` models the part of the rig
between the controls and the deform bones, and everything else is read from Blender's evaluated pose.
The Armature modifier itself must be plain linear blend skinning by vertex groups (vertices whose deform
weights sum to at most 0.0001 stay in place); anything else is refused by name.

Everything the solver sees is in the armature object's space; the hand mesh and the object's contacts
are carried there by the objects' world matrices.
"""

from __future__ import annotations

from dataclasses import dataclass

import bpy
import numpy as np
from mathutils import Euler, Matrix, Quaternion
from scipy import sparse

from geodesics import SurfacePoints
from solver import SkinnedMesh, SolverError
from solver.retarget import Skeleton
from solver.rig import Armature, ControlRig, Plan
from solver.rotations import euler_to_matrix, matrix_to_quaternion, quaternion_to_axis_angle

from .errors import BridgeError
from .mesh import cached_trimesh, deformed_vertices, shaped_vertices, uneven_scale, vertex_group_weights
from .rigs import driven_keys, read_armature

#: Blender's Armature modifier leaves a vertex in place when its deform weights sum to no more than this.
MIN_TOTAL_WEIGHT = 1e-4


@dataclass(frozen=True)
class PosedHand:
    """A hand and its armature as the solver sees them.

    Attributes
    ----------
    hand, armature : str
        Object names (names, not references, so that undo cannot leave them dangling).
    skin : SkinnedMesh
        The hand's rest mesh in armature space, bound to the :class:`~solver.rig.controls.ControlRig` that
        poses it through the armature's controls.
    hand_to_armature : (4, 4)
        Hand object space to armature space (Blender's ``premat`` of the Armature modifier).
    """

    hand: str
    armature: str
    skin: SkinnedMesh
    hand_to_armature: np.ndarray

    @property
    def rig(self) -> ControlRig:
        return self.skin.rig

    @property
    def plan(self) -> Plan:
        return self.skin.rig.plan

    @property
    def start(self) -> np.ndarray:
        """(d,) the DOFs of the pose the armature had when this was read."""
        return self.skin.rig.start

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
    if problems:
        raise BridgeError(
            f"contact IK models plain linear blend skinning, but on '{hand.name}' the Armature modifier "
            f"'{modifier.name}': {'; '.join(problems)}",
            hand.name,
        )
    return modifier


@dataclass(frozen=True)
class HandRig:
    """What deforms a hand mesh: its armature read as the solver models it, the deform bones weighting the
    mesh (the weight columns), and their normalized weights."""

    armature: bpy.types.Object
    model: Armature
    deform: tuple[str, ...]
    weights: sparse.csr_matrix
    hand_to_armature: np.ndarray
    #: The hand's shape keys whose drivers read the armature's bones: key name -> the bones read.
    driven_keys: dict[str, tuple[str, ...]]


def hand_rig(hand: bpy.types.Object) -> HandRig:
    """Read the armature deforming ``hand`` and the hand's deform weights.

    Raises BridgeError for an Armature modifier the solver does not reproduce, an armature scaled
    unevenly, or a mesh no deform bone weights.
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
    used = np.unique(raw.indices)
    deform = tuple(bones[int(i)].name for i in used)
    W = raw[:, used].tocsr()
    total = np.asarray(W.sum(axis=1)).ravel()
    W = sparse.csr_matrix(
        sparse.diags(np.where(total > MIN_TOTAL_WEIGHT, 1.0 / np.maximum(total, 1e-300), 0.0)) @ W
    )
    return HandRig(armature, read_armature(armature), deform, W, to_armature, driven_keys(hand, armature))


def hand_skeleton(hand: bpy.types.Object) -> Skeleton:
    """The deform bones of the armature deforming ``hand``, in the hand mesh's space, each parented to its
    nearest deform ancestor (Rigify's finger bones hang from mechanism bones), with the hand's weights."""
    rig = hand_rig(hand)
    bones = rig.armature.data.bones
    index = {name: i for i, name in enumerate(rig.deform)}
    parents = []
    for name in rig.deform:
        parent = rig.model.deform_parent(name)
        while parent is not None and parent not in index:  # a deform bone that weights none of this mesh
            parent = rig.model.deform_parent(parent)
        parents.append(-1 if parent is None else index[parent])
    to_mesh = np.linalg.inv(rig.hand_to_armature)
    M = np.array([to_mesh @ np.array(bones[name].matrix_local) for name in rig.deform])
    scale = np.linalg.norm(M[:, :3, 0], axis=1)  # uniform (hand_rig checks)
    M[:, :3, :3] /= scale[:, None, None]
    lengths = np.array([bones[name].length for name in rig.deform]) * scale
    return Skeleton(rig.deform, np.array(parents, np.int64), M, lengths, rig.weights)


def contact_bones(rig: HandRig, faces: np.ndarray, points: SurfacePoints | None) -> list[str]:
    """The deform bones that weight the contact points most (every weighted bone when there are none)."""
    if points is None or len(points) == 0:
        return list(rig.deform)
    corners = np.unique(faces[points.faces].ravel())
    strongest = np.asarray(rig.weights[corners].argmax(axis=1)).ravel()
    weighted = np.asarray(rig.weights[corners].sum(axis=1)).ravel() > 0
    return [rig.deform[i] for i in np.unique(strongest[weighted])]


def bone_direction(obj: bpy.types.Object, faces: np.ndarray, points: SurfacePoints, deformed: bool = False):
    """(3,) in ``obj``'s space: the length axis (head to tail) of the deform bone that weights the
    ``points`` (on the triangles ``faces``) most, at rest or, when ``deformed``, as posed; None for a mesh
    no armature deforms the way contact IK models, or no deform bone weights there."""
    try:
        armature = armature_modifier(obj).object
        to_armature = _hand_to_armature(obj, armature)
    except BridgeError:
        return None
    corners = np.unique(faces[points.faces].ravel())
    weight = np.asarray(_deform_weights(obj, armature)[corners].sum(axis=0)).ravel()
    if not weight.any():
        return None
    name = armature.data.bones[int(np.argmax(weight))].name
    bone = armature.pose.bones[name].matrix if deformed else armature.data.bones[name].matrix_local
    return np.linalg.solve(to_armature[:3, :3], np.array(bone)[:3, 1])


def hand_plan(
    rig: HandRig, faces: np.ndarray, points: SurfacePoints | None = None, hand_root: str = ""
) -> Plan:
    """What a solve of the hand would pose and what blocks it (:meth:`solver.rig.controls.Armature.plan`).

    ``hand_root`` names the wrist bone; empty finds it from the bones under the contact ``points``.
    """
    try:
        plan = rig.model.plan(
            rig.deform,
            contact_bones=contact_bones(rig, faces, points),
            hand_root=hand_root or None,
        )
    except SolverError as err:
        raise BridgeError(f"'{rig.armature.name}': {err}") from err
    posed = {*plan.controls, *([plan.root] if plan.root else [])}
    posed |= rig.model.downstream(posed)
    driven = {key: sorted(posed.intersection(bones)) for key, bones in rig.driven_keys.items()}
    driven = {key: bones for key, bones in driven.items() if bones}
    if driven:
        what = "; ".join(f"'{key}' by {', '.join(bones[:3])}" for key, bones in driven.items())
        raise BridgeError(
            f"shape keys of the hand are driven by bones the solve moves ({what}), which contact IK does "
            "not model; mute those keys' drivers (or the keys) while solving",
        )
    return plan


def posed_hand(
    hand: bpy.types.Object, faces: np.ndarray, points: SurfacePoints | None = None, hand_root: str = ""
) -> PosedHand:
    """The hand's skinned rest mesh and the rig that poses it through the armature's controls.

    Parameters
    ----------
    hand : a mesh object with an Armature modifier
    faces : (m, 3) int
        The triangles of the hand's contact set (its :class:`geodesics.TriMesh`), so that the set's
        surface points (face, barycentric) name the same skin points on the skinned mesh.
    points : SurfacePoints, optional
        The contact points, to find the wrist from the bones under them.
    hand_root : str
        The wrist bone; empty finds it.

    Raises
    ------
    BridgeError
        For anything the solver cannot reproduce exactly, naming the bones, constraints or settings.
    """
    rig = hand_rig(hand)
    plan = hand_plan(rig, faces, points, hand_root)
    try:
        control_rig = ControlRig(plan)
        M = rig.hand_to_armature
        rest = shaped_vertices(hand) @ M[:3, :3].T + M[:3, 3]
        skin = SkinnedMesh(cached_trimesh(rest, faces), control_rig, rig.weights)
    except SolverError as err:
        raise BridgeError(str(err), hand.name) from err
    return PosedHand(hand.name, rig.armature.name, skin, M)


def _hand_to_armature(hand: bpy.types.Object, armature: bpy.types.Object) -> np.ndarray:
    if hand.parent == armature and hand.parent_type == "BONE":
        raise BridgeError(
            f"'{hand.name}' is parented to the bone '{hand.parent_bone}', so posing moves the mesh twice; "
            "parent it to the armature object instead",
            hand.name,
        )
    A = np.array(armature.matrix_world)
    scale = uneven_scale(armature)
    if scale is not None:
        raise BridgeError(
            f"the armature '{armature.name}' has non-uniform scale ({scale}), which distorts its bones; "
            "apply its scale (Ctrl+A, Scale) first",
            hand.name,
        )
    M = np.linalg.inv(A) @ np.array(hand.matrix_world)
    if np.linalg.det(M[:3, :3]) < 0:
        raise BridgeError(
            f"'{hand.name}' is placed mirrored against its armature '{armature.name}' (a negative scale on "
            "one and not the other), which turns its skin inside out for the armature; apply the mesh's "
            "scale (Ctrl+A, Scale) first",
            hand.name,
        )
    return M


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


def apply_pose(posed: PosedHand, theta, frame: int | None = None) -> None:
    """Pose the armature's controls by θ in their own rotation modes (the root control by the hand root's
    rigid motion), keying them at ``frame`` if given. A control θ leaves where it was read gets back the
    exact values it was read with, so that a cancelled solve restores them bit for bit."""
    armature = posed.armature_object()
    theta = posed.rig.check_theta(theta)
    channels = pose_channels(posed, theta[None])
    for name, path, values in channels:
        setattr(armature.pose.bones[name], path, values[0])
    if frame is not None:
        for name, path, _ in channels:
            armature.pose.bones[name].keyframe_insert(path, frame=frame, group=name)


def pose_channels(posed: PosedHand, thetas) -> list[tuple[str, str, np.ndarray]]:
    """The channel values :func:`apply_pose` gives the armature's controls, for many poses at once.

    Parameters
    ----------
    posed : PosedHand
    thetas : (F, d)
        One pose per row (finite, one value per DOF: the caller checks).

    Returns
    -------
    list of (bone, path, values)
        Per keyed channel, root control first: the pose bone's name, the property (``location``, or the
        :func:`rotation_path` of its rotation mode) and its values (F, 3 or 4). The root's locked location
        channels keep the values read. Rotations are continuous, so keys interpolate the short way: the
        first row's with the pose bones' current values (as :func:`set_bone_rotation`), each later row's
        with the row before (Euler angles nearest, quaternion signs kept). A control that a row leaves
        where it was read gets the exact values it was read with (on later rows, up to a quaternion's sign).
    """
    armature = posed.armature_object()
    rig = posed.rig
    thetas = np.asarray(thetas, np.float64).reshape(-1, rig.n_dofs)
    n = len(thetas)
    same = (thetas == rig.start).reshape(n, -1, 3).all(axis=2)  # per row: location, root rotation, controls
    channels: list[tuple[str, str, np.ndarray]] = []
    root = rig.plan.root
    if root is not None:
        pose_bone = _pose_bone(armature, root)
        read = rig.armature[root]
        keep = same[:, 0] & same[:, 1]
        locations = np.tile(read.location, (n, 1))
        rotations = np.zeros((n, 4))  # rows kept as read take the values read instead
        for f in np.flatnonzero(~keep):  # Blender converts pose space to the bone's channels
            M = rig.root_transform(thetas[f]) @ read.matrix
            local = armature.convert_space(
                pose_bone=pose_bone, matrix=Matrix(M), from_space="POSE", to_space="LOCAL"
            )
            location, rotation, _ = local.decompose()
            locations[f] = np.where(rig.locked[:3], read.location, location)
            rotations[f] = rotation
        channels.append((root, "location", locations))
        channels.append(_rotation_channel(pose_bone, rotations, keep, read.rotation))
    for b, name in enumerate(rig.names[1:], start=1):
        pose_bone = _pose_bone(armature, name)
        read = rig.armature[name]
        keep = same[:, b + 1]
        angles = thetas[:, 3 + 3 * b : 6 + 3 * b]
        if pose_bone.rotation_mode == rig.orders[b]:  # exactly the DOFs, no conversion
            values = np.where(keep[:, None], read.rotation, angles)
            channels.append((name, rotation_path(pose_bone.rotation_mode), values))
        else:
            rotations = matrix_to_quaternion(euler_to_matrix(angles, rig.orders[b]))
            channels.append(_rotation_channel(pose_bone, rotations, keep, read.rotation))
    return channels


def _pose_bone(armature: bpy.types.Object, name: str) -> bpy.types.PoseBone:
    pose_bone = armature.pose.bones.get(name)
    if pose_bone is None:
        raise BridgeError(f"the control '{name}' is gone from '{armature.name}'; read the hand again")
    return pose_bone


def _rotation_channel(
    pose_bone: bpy.types.PoseBone, rotations: np.ndarray, keep: np.ndarray, read
) -> tuple[str, str, np.ndarray]:
    """A pose bone's rotation channel over rows of quaternions (F, 4) in its own mode, continuous (see
    :func:`pose_channels`); rows ``keep`` get the values ``read`` instead."""
    mode = pose_bone.rotation_mode
    path = rotation_path(mode)
    current = np.array(getattr(pose_bone, path))
    n = len(rotations)
    if mode in ("QUATERNION", "AXIS_ANGLE"):
        kept = np.array(to_quaternion(mode, read)) if mode == "AXIS_ANGLE" else np.asarray(read)
        q = np.where(keep[:, None], kept, rotations)
        # Each row's sign flip relative to the row before, accumulated: a product of ±1 per row.
        flips = np.ones(n)
        flips[1:] = np.where(np.einsum("fi,fi->f", q[1:], q[:-1]) < 0, -1.0, 1.0)
        if mode == "QUATERNION" and not keep[0]:
            flips[0] = -1.0 if q[0] @ current < 0 else 1.0
        signs = np.cumprod(flips)[:, None]
        if mode == "QUATERNION":
            return pose_bone.name, path, q * signs
        values = quaternion_to_axis_angle(q * signs)
        return pose_bone.name, path, np.where(keep[:, None] & (signs > 0), read, values)
    values = np.empty((n, 3))
    previous = Euler(current, mode)
    for f in range(n):  # each nearest the one before: inherently sequential
        previous = Euler(read, mode) if keep[f] else Quaternion(rotations[f]).to_euler(mode, previous)
        values[f] = previous
    return pose_bone.name, path, values


def deviation(posed: PosedHand, theta) -> float:
    """The largest distance (armature space) between the skin Blender now shows and the solver's pose θ:
    near zero when the rig followed the solve exactly (the check after writing a pose back). Blender's
    skin is read where its Armature modifier puts the mesh's own vertices (before a Subdivision Surface
    after it refines them)."""
    hand = bpy.data.objects.get(posed.hand)
    shown = deformed_vertices(hand)
    M = posed.hand_to_armature
    shown = shown @ M[:3, :3].T + M[:3, 3]
    return float(np.abs(shown - posed.skin.posed_vertices(theta)).max())
