"""The procedural hands and objects of :mod:`solver` as Blender objects (the demo scene, and the
viewport's Add menu, so that anyone can try contact editing without a rigged hand of their own).

A hand becomes an armature whose bones have exactly the rig's rest matrices, a mesh skinned to it by
vertex groups through an Armature modifier, and a local Limit Rotation constraint per joint carrying
the rig's anatomical limits, so Blender shows the same limits the solver obeys.
"""

from __future__ import annotations

import bpy
import numpy as np
from mathutils import Matrix, Vector

from geodesics import TriMesh
from solver import Hand, hands, objects, placement

#: What the Add menu offers: name -> (label, builder of a TriMesh in metres).
OBJECTS = {
    "mug": ("Mug", objects.mug),
    "sphere": ("Sphere", objects.sphere),
    "cylinder": ("Cylinder", objects.cylinder),
    "box": ("Box", objects.box),
    "plate": ("Plate", objects.plate),
}


def mesh_object(name: str, mesh: TriMesh, collection: bpy.types.Collection) -> bpy.types.Object:
    """A new mesh object with the triangles of ``mesh``, smooth shaded, linked into ``collection``."""
    data = bpy.data.meshes.new(name)
    faces = mesh.faces
    data.vertices.add(mesh.n_vertices)
    data.vertices.foreach_set("co", mesh.vertices.astype(np.float32).ravel())
    data.loops.add(faces.size)
    data.loops.foreach_set("vertex_index", faces.astype(np.int32).ravel())
    data.polygons.add(len(faces))
    data.polygons.foreach_set("loop_start", np.arange(0, faces.size, 3, dtype=np.int32))
    data.polygons.foreach_set("use_smooth", np.ones(len(faces), bool))
    data.update(calc_edges=True)
    data.validate()
    obj = bpy.data.objects.new(name, data)
    collection.objects.link(obj)
    return obj


def hand_objects(
    hand: Hand, name: str, collection: bpy.types.Collection
) -> tuple[bpy.types.Object, bpy.types.Object]:
    """The hand as (mesh object, armature object): the mesh is parented to and deformed by the armature."""
    rig = hand.rig
    armature = bpy.data.objects.new(f"{name} rig", bpy.data.armatures.new(f"{name} rig"))
    collection.objects.link(armature)
    _add_bones(armature, rig)
    for b, bone_name in enumerate(rig.names):
        pose_bone = armature.pose.bones[bone_name]
        pose_bone.rotation_mode = rig.rotation_modes[b]
        if b == 0:
            continue
        limit = pose_bone.constraints.new("LIMIT_ROTATION")
        limit.owner_space = "LOCAL"
        for c, axis in enumerate("xyz"):
            d = rig.rotation_dof(b, c)
            setattr(limit, f"use_limit_{axis}", True)
            setattr(limit, f"min_{axis}", float(rig.lower[d]))
            setattr(limit, f"max_{axis}", float(rig.upper[d]))
    obj = mesh_object(name, hand.mesh, collection)
    groups = [obj.vertex_groups.new(name=n) for n in rig.names]
    W = hand.weights.tocsc()
    for b, group in enumerate(groups):
        rows = W.indices[W.indptr[b] : W.indptr[b + 1]]
        values = W.data[W.indptr[b] : W.indptr[b + 1]]
        for value in np.unique(values):  # one call per distinct weight, not per vertex
            group.add(rows[values == value].tolist(), float(value), "REPLACE")
    modifier = obj.modifiers.new("Armature", "ARMATURE")
    modifier.object = armature
    obj.parent = armature
    return obj, armature


def _add_bones(armature: bpy.types.Object, rig) -> None:
    """Edit bones with the rig's heads, tails and rolls (edit mode is needed to create bones)."""
    view_layer = bpy.context.view_layer
    previous = view_layer.objects.active
    view_layer.objects.active = armature
    bpy.ops.object.mode_set(mode="EDIT")
    try:
        edit_bones = []
        for b, bone_name in enumerate(rig.names):
            bone = armature.data.edit_bones.new(bone_name)
            bone.head, bone.tail = Vector(rig.heads[b]), Vector(rig.tails[b])
            bone.align_roll(Vector(rig.matrix_local[b, :3, 2]))
            bone.parent = edit_bones[rig.parents[b]] if b else None
            bone.use_connect = False
            edit_bones.append(bone)
    finally:
        bpy.ops.object.mode_set(mode="OBJECT")
        view_layer.objects.active = previous


#: The example's mug (metres), and how far the open hand's skin is from its wall.
MUG_RADIUS, MUG_HEIGHT, PALM_GAP = 0.04, 0.095, 0.0005


def example_scene(context, where) -> tuple[Hand, bpy.types.Object, bpy.types.Object]:
    """A human hand ready to grasp a mug standing at ``where`` (what the demo starts from); both become
    the scene's hand and object. Returns the procedural hand, its mesh object and the mug."""
    hand = hands.make_hand("human")
    hand_obj, armature = hand_objects(hand, "Hand", context.collection)
    mug_mesh = objects.mug(radius=MUG_RADIUS, height=MUG_HEIGHT)
    mug = mesh_object("Mug", mug_mesh, context.collection)
    offset = np.eye(4)
    offset[:3, 3] = where
    armature.matrix_world = Matrix(offset @ placement(hand, mug_mesh, PALM_GAP))
    mug.location = where
    context.scene.contact_edit.hand, context.scene.contact_edit.target = hand_obj, mug
    return hand, hand_obj, mug
