"""Blender data for the puppet device: an armature as a :class:`tangible.Skeleton` with the channels its
bones had, sample poses read from an action, bone rotations and the numbers joints drive (shape keys,
properties), written and keyed in each bone's own rotation mode."""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import bpy
import numpy as np
from bpy_extras import anim_utils
from mathutils import Quaternion

from solver.rotations import EULER_ORDERS
from tangible import (
    Skeleton,
    area_weights,
)

from ..bridge.armature import rotation_path, set_bone_rotation, to_quaternion
from ..bridge.errors import BridgeError
from ..bridge.mesh import vertex_group_weights


@dataclass(frozen=True)
class BoneChannels:
    """Every bone's rotation channels as Blender stores them, to read sample poses against and to give
    back exactly on stop.

    Attributes
    ----------
    names : tuple of str
        In skeleton order.
    modes : tuple of str
        Each bone's rotation mode.
    quaternion, axis_angle : (b, 4) ndarray
    euler : (b, 3) ndarray
    rotations : (b, 4) ndarray
        The rotations those channels mean, quaternions (w, x, y, z).
    """

    names: tuple[str, ...]
    modes: tuple[str, ...]
    quaternion: np.ndarray
    euler: np.ndarray
    axis_angle: np.ndarray
    rotations: np.ndarray

    @classmethod
    def capture(cls, armature: bpy.types.Object, names) -> BoneChannels:
        bones = [armature.pose.bones[n] for n in names]
        modes = tuple(b.rotation_mode for b in bones)
        quaternion = np.array([tuple(b.rotation_quaternion) for b in bones]).reshape(-1, 4)
        euler = np.array([tuple(b.rotation_euler) for b in bones]).reshape(-1, 3)
        axis_angle = np.array([tuple(b.rotation_axis_angle) for b in bones]).reshape(-1, 4)
        rotations = np.array(
            [
                tuple(to_quaternion(m, {"QUATERNION": q, "AXIS_ANGLE": a}.get(m, e)))
                for m, q, e, a in zip(modes, quaternion, euler, axis_angle, strict=True)
            ]
        ).reshape(-1, 4)
        return cls(tuple(names), modes, quaternion, euler, axis_angle, rotations)

    def channel(self, b: int, path: str) -> np.ndarray:
        """Bone ``b``'s values of the rotation property ``path``."""
        return {"rotation_quaternion": self.quaternion, "rotation_axis_angle": self.axis_angle}.get(
            path, self.euler
        )[b]

    def restore(self, armature: bpy.types.Object, bones) -> None:
        """Give bones (indices) their captured rotation mode and channels back."""
        for b in bones:
            pose_bone = armature.pose.bones.get(self.names[b])
            if pose_bone is None:
                continue
            pose_bone.rotation_mode = self.modes[b]
            pose_bone.rotation_quaternion = self.quaternion[b]
            pose_bone.rotation_euler = self.euler[b]
            pose_bone.rotation_axis_angle = self.axis_angle[b]


@dataclass(frozen=True)
class ArmatureRig:
    """An armature as the device sees it: a :class:`tangible.Skeleton` (bones parents first) and the
    channels every bone had when it was captured."""

    armature: str
    skeleton: Skeleton
    start: BoneChannels
    index: dict[str, int] = field(repr=False)

    @classmethod
    def capture(cls, armature: bpy.types.Object, weights: bool = False) -> ArmatureRig:
        """The armature's bones; ``weights``: node weights from the skin it deforms (else bone lengths)."""
        bones = armature.data.bones
        if not bones:
            raise BridgeError(f"the armature '{armature.name}' has no bones to drive")
        depth = {b.name: len(b.parent_recursive) for b in bones}
        names = sorted(depth, key=depth.__getitem__)
        index = {n: i for i, n in enumerate(names)}
        rest = np.array([np.array(bones[n].matrix_local) for n in names], np.float64)
        # Blender's rest matrices are float32 and, for short bones, off orthonormal by up to ~1e-5: take
        # the nearest rotation (polar decomposition), which the skeleton requires.
        U, _, Vt = np.linalg.svd(rest[:, :3, :3])
        rest[:, :3, :3] = U @ Vt
        skeleton = Skeleton(
            names,
            [index[bones[n].parent.name] if bones[n].parent else -1 for n in names],
            rest,
            np.array([bones[n].length for n in names]),
            skin_area_weights(armature, index) if weights else None,
        )
        return cls(armature.name, skeleton, BoneChannels.capture(armature, names), index)

    @property
    def names(self) -> tuple[str, ...]:
        return self.skeleton.names

    def armature_object(self) -> bpy.types.Object:
        obj = bpy.data.objects.get(self.armature)
        if obj is None or obj.type != "ARMATURE":
            raise BridgeError(f"the armature '{self.armature}' is gone (deleted or renamed)")
        return obj

    def bone(self, name: str, where: str) -> int:
        if name not in self.index:
            raise BridgeError(f"{where}: '{self.armature}' has no bone called '{name}'")
        return self.index[name]


def skin_area_weights(armature: bpy.types.Object, index: dict[str, int]) -> np.ndarray | None:
    """Surface area each bone deforms directly (the paper's node weights), summed over the meshes the
    armature deforms; None if it deforms none."""
    total = np.zeros(len(index))
    for obj in bpy.data.objects:
        if obj.type != "MESH" or not any(
            m.type == "ARMATURE" and m.object == armature for m in obj.modifiers
        ):
            continue
        mesh = obj.data
        mesh.calc_loop_triangles()
        co = np.empty(3 * len(mesh.vertices))
        mesh.vertices.foreach_get("co", co)
        M = np.array(obj.matrix_world)
        vertices = co.reshape(-1, 3) @ M[:3, :3].T + M[:3, 3]
        triangles = np.empty(3 * len(mesh.loop_triangles), np.int32)
        mesh.loop_triangles.foreach_get("vertices", triangles)
        columns = np.zeros((len(obj.vertex_groups), len(index)))
        for group in obj.vertex_groups:
            if group.name in index:
                columns[group.index, index[group.name]] = 1.0
        weights = vertex_group_weights(obj) @ columns
        total += area_weights(vertices, triangles.reshape(-1, 3), weights)
    return total if total.sum() > 0 else None


def _channelbag(armature: bpy.types.Object, action: bpy.types.Action):
    """The channels ``action`` holds for ``armature``: its assigned slot, else the slot named after it,
    else its first object slot."""
    data = armature.animation_data
    if data is not None and data.action == action and data.action_slot is not None:
        return anim_utils.action_get_channelbag_for_slot(action, data.action_slot)
    slots = [s for s in action.slots if s.target_id_type in {"OBJECT", "UNSPECIFIED"}]
    slots.sort(key=lambda s: s.identifier != "OB" + armature.name)
    return anim_utils.action_get_channelbag_for_slot(action, slots[0]) if slots else None


def action_sample_poses(armature: bpy.types.Object, action: bpy.types.Action, rig: ArmatureRig) -> np.ndarray:
    """(s, b, 4) bone rotations at each frame where ``action`` keys a bone rotation: the sample poses.

    Each bone reads the rotation property of its own mode if keyed, else whichever one is; channels the
    action does not key keep the bone's captured value, as they would when the action plays.
    """
    bag = _channelbag(armature, action)
    curves = {(c.data_path, c.array_index): c for c in bag.fcurves} if bag is not None else {}
    paths = {f'pose.bones["{bpy.utils.escape_identifier(n)}"].': b for b, n in enumerate(rig.names)}
    frames = sorted(
        {
            k.co[0]
            for (path, _), curve in curves.items()
            if path.rpartition(".")[0] + "." in paths and path.rpartition(".")[2].startswith("rotation_")
            for k in curve.keyframe_points
        }
    )
    if not frames:
        raise BridgeError(
            f"the action '{action.name}' keys no bone rotations of '{armature.name}', so it holds no sample "
            "poses: key a few poses of the armature in it"
        )
    start = rig.start
    poses = np.broadcast_to(start.rotations, (len(frames), *start.rotations.shape)).copy()
    for prefix, b in paths.items():
        own = rotation_path(start.modes[b])
        for path in dict.fromkeys((own, "rotation_quaternion", "rotation_euler", "rotation_axis_angle")):
            values = np.tile(start.channel(b, path), (len(frames), 1))
            keyed = [
                (i, curves[prefix + path, i]) for i in range(values.shape[1]) if (prefix + path, i) in curves
            ]
            if keyed:
                break
        else:
            continue
        for i, curve in keyed:
            values[:, i] = [curve.evaluate(f) for f in frames]
        mode = {"rotation_quaternion": "QUATERNION", "rotation_axis_angle": "AXIS_ANGLE"}.get(
            path, start.modes[b] if start.modes[b] in EULER_ORDERS else "XYZ"
        )
        poses[:, b] = [tuple(to_quaternion(mode, v)) for v in values]
    return poses


def write_rotations(armature: bpy.types.Object, names, rotations: np.ndarray) -> None:
    """Pose bones ``names`` by local rotations (k, 4), each in its own rotation mode (Euler angles and
    quaternion signs kept continuous with the current values, so keys interpolate the short way)."""
    bones = armature.pose.bones
    for name, q in zip(names, rotations, strict=True):
        pose_bone = bones.get(name)
        if pose_bone is None:
            raise BridgeError(f"the bone '{name}' of '{armature.name}' is gone: stop and connect again")
        set_bone_rotation(pose_bone, Quaternion(q))


def key_rotations(armature: bpy.types.Object, names, frame: int) -> None:
    """Key the rotation of bones ``names`` at ``frame``, in each bone's rotation mode."""
    for name in names:
        pose_bone = armature.pose.bones[name]
        pose_bone.keyframe_insert(rotation_path(pose_bone.rotation_mode), frame=frame, group=name)


@dataclass(frozen=True)
class ScalarTarget:
    """A number a joint angle drives: a shape key's value, or a property reached by a data path from an
    object (``location[2]``, ``["open"]``, ``pose.bones["jaw"]["open"]``), looked up by name each time.
    """

    object: str
    kind: str
    path: str

    @property
    def key(self) -> str:
        return f"{self.object}/{self.kind}/{self.path}"

    def label(self) -> str:
        what = "shape key" if self.kind == "SHAPE_KEY" else "property"
        return f"{what} '{self.path}' of '{self.object}'"

    def _resolve(self):
        """(owner, attribute, index, custom): where the number lives."""
        obj = bpy.data.objects.get(self.object)
        if obj is None:
            raise BridgeError(f"the object '{self.object}' of {self.label()} is gone")
        if self.kind == "SHAPE_KEY":
            keys = obj.data.shape_keys if obj.type in {"MESH", "CURVE", "SURFACE", "LATTICE"} else None
            block = keys.key_blocks.get(self.path) if keys is not None else None
            if block is None:
                raise BridgeError(f"'{self.object}' has no shape key called '{self.path}'")
            return block, "value", -1, False
        path, index = self.path, -1
        custom = path.endswith('"]') and '["' in path
        if custom:
            cut = path.rfind('["')
            owner_path, attribute = path[:cut], path[cut:]
        else:
            indexed = re.fullmatch(r"(.*)\[(\d+)\]", path)
            if indexed:
                path, index = indexed.group(1), int(indexed.group(2))
            owner_path, _, attribute = path.rpartition(".")
        try:
            owner = obj.path_resolve(owner_path) if owner_path else obj
            value = owner.path_resolve(attribute) if custom else getattr(owner, attribute)
            if index >= 0:
                value = value[index]
        except (ValueError, AttributeError, TypeError, IndexError, KeyError):
            raise BridgeError(f"'{self.path}' is not a property of '{self.object}'") from None
        if isinstance(value, bool) or not isinstance(value, float | int):
            raise BridgeError(f"{self.label()} is not a number, so a joint cannot drive it")
        return owner, attribute, index, custom

    def check(self) -> None:
        """Raise a BridgeError unless the number can be found."""
        self._resolve()

    def get(self) -> float:
        owner, attribute, index, custom = self._resolve()
        value = owner.path_resolve(attribute) if custom else getattr(owner, attribute)
        return float(value[index] if index >= 0 else value)

    def set(self, value: float) -> None:
        owner, attribute, index, custom = self._resolve()
        if custom:
            owner[attribute[2:-2].replace('\\"', '"')] = value
        elif index >= 0:
            getattr(owner, attribute)[index] = value
        else:
            setattr(owner, attribute, value)

    def keyframe(self, frame: int) -> None:
        owner, attribute, index, _ = self._resolve()
        owner.keyframe_insert(attribute, index=index, frame=frame)


def scalar_target(binding) -> ScalarTarget | None:
    """The number a (non-bone) binding drives, None while it has no object."""
    if binding.object is None:
        return None
    path = binding.shape_key if binding.target == "SHAPE_KEY" else binding.data_path
    return ScalarTarget(binding.object.name, binding.target, path)
