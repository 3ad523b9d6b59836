"""The one place where Blender data becomes the libraries' numpy types and back: meshes and surface
points (:mod:`.mesh`), a hand's armature (read whole by :mod:`.rigs`, its constraints by :mod:`.constraints`,
its B-Bones by :mod:`.bbones`) and vertex groups as a skinned rig posed through its controls, and poses
(:mod:`.armature`). The puppet device's share (an armature and the numbers the device drives) lives with
the device, in :mod:`..device.bridge`.
"""

from .armature import (
    HandRig,
    PosedHand,
    apply_pose,
    armature_modifier,
    bone_direction,
    deviation,
    hand_plan,
    hand_rig,
    hand_skeleton,
    posed_hand,
    rotation_path,
    selected_bones,
    set_bone_rotation,
    to_quaternion,
)
from .errors import BridgeError
from .mesh import (
    after_armature,
    handedness,
    mesh_arrays,
    moved,
    moved_solid,
    object_to_world,
    points_from_hits,
    points_from_vertices,
    select_elements,
    selected_vertices,
    trimesh,
    uneven_scale,
    uniform_scale,
    world_to_object,
)

__all__ = [
    "BridgeError",
    "HandRig",
    "PosedHand",
    "after_armature",
    "apply_pose",
    "armature_modifier",
    "bone_direction",
    "deviation",
    "hand_plan",
    "hand_rig",
    "hand_skeleton",
    "handedness",
    "mesh_arrays",
    "moved",
    "moved_solid",
    "object_to_world",
    "points_from_hits",
    "points_from_vertices",
    "posed_hand",
    "rotation_path",
    "select_elements",
    "selected_bones",
    "selected_vertices",
    "set_bone_rotation",
    "to_quaternion",
    "trimesh",
    "uneven_scale",
    "uniform_scale",
    "world_to_object",
]
