"""The procedural human hand on a Rigify human: the production rig most Blender animators pose.

Rigify ships with Blender. This builds what a user would: the human meta-rig, its right hand's bones moved
onto the procedural hand's (wrist, palm, three bones per finger and thumb), *Generate Rig*, and the hand
mesh parented to the generated rig *With Automatic Weights*. The result is a real Rigify rig — deform
bones following mechanism bones and controls through constraints, B-Bone fingers, IK/FK arm — skinning
the same mesh, with the same contact patches, as :func:`solver.hands.make_hand`, so the two can be
compared contact for contact.
"""

from __future__ import annotations

import addon_utils
import bpy
import numpy as np
from mathutils import Vector

from solver import hands

#: The meta-rig's bones of the right hand, by the procedural hand's bones they are moved onto.
FINGERS = ("index", "middle", "ring", "pinky")
#: How far along from the wrist to a finger's base its palm (metacarpal) bone starts.
PALM_START = 0.3


def available() -> bool:
    """Whether Rigify can be enabled in this Blender."""
    return any(m.__name__ == "rigify" for m in addon_utils.modules())


def rigify_hand(collection: bpy.types.Collection) -> tuple[bpy.types.Object, bpy.types.Object]:
    """A Rigify human whose right hand is the procedural human hand: (hand mesh object, generated rig).

    Enables the bundled Rigify add-on if it is off. Leaves Object Mode active with the rig active.
    """
    if not available():
        raise RuntimeError("Rigify is not part of this Blender; it ships with Blender's own builds")
    addon_utils.enable("rigify", default_set=True)
    kit = hands.make_hand("human")
    context = bpy.context
    if context.object is not None and context.object.mode != "OBJECT":
        bpy.ops.object.mode_set(mode="OBJECT")
    bpy.ops.object.armature_human_metarig_add()
    meta = context.object
    for obj in list(meta.users_collection):
        obj.objects.unlink(meta)
    collection.objects.link(meta)
    R, wrist = _fit(meta, kit)
    bpy.ops.pose.rigify_generate()
    rig = context.object
    meta.hide_set(True)
    V = kit.mesh.vertices @ R.T + wrist
    data = bpy.data.meshes.new("Hand")
    data.from_pydata(V.tolist(), [], kit.mesh.faces.tolist())
    data.shade_smooth()
    hand = bpy.data.objects.new("Hand", data)
    collection.objects.link(hand)
    bpy.ops.object.select_all(action="DESELECT")
    hand.select_set(True)
    rig.select_set(True)
    context.view_layer.objects.active = rig
    bpy.ops.object.parent_set(type="ARMATURE_AUTO")
    return hand, rig


def _fit(meta: bpy.types.Object, kit) -> tuple[np.ndarray, np.ndarray]:
    """Move the meta-rig's right hand bones onto the procedural hand's, placed at the meta-rig's right
    wrist with its fingers along the arm and its palm down; returns that placement (rotation, wrist)."""
    bpy.ops.object.mode_set(mode="EDIT")
    bones = meta.data.edit_bones
    wrist = np.array(bones["hand.R"].head)
    y = np.array((bones["hand.R"].tail - bones["hand.R"].head).normalized())
    z = np.array([0.0, 0.0, 1.0]) - y[2] * y
    z /= np.linalg.norm(z)
    R = np.stack([np.cross(y, z), y, z], axis=1)  # procedural +y (fingers) along the arm, -z (palm) down
    rig = kit.rig
    index = {name: i for i, name in enumerate(rig.names)}
    z_axes = rig.matrix_local[:, :3, 2]

    def place(point):
        return Vector(R @ point + wrist)

    def put(name, head, tail, b):
        bone = bones[name]
        bone.head, bone.tail = place(head), place(tail)
        bone.align_roll(Vector(R @ z_axes[b]))

    hand = index["hand"]
    put("hand.R", rig.heads[hand], rig.tails[hand], hand)
    for finger, palm in zip(FINGERS, ("palm.01.R", "palm.02.R", "palm.03.R", "palm.04.R"), strict=True):
        base = rig.heads[index[f"{finger}_1"]]
        bones[palm].use_connect = False
        put(palm, rig.heads[hand] + PALM_START * (base - rig.heads[hand]), base, hand)
        for k in (1, 2, 3):
            b = index[f"{finger}_{k}"]
            put(f"f_{finger}.0{k}.R", rig.heads[b], rig.tails[b], b)
    for k in (1, 2, 3):
        b = index[f"thumb_{k}"]
        put(f"thumb.0{k}.R", rig.heads[b], rig.tails[b], b)
    bpy.ops.object.mode_set(mode="OBJECT")
    return R, wrist
