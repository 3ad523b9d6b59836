"""The grasp session (:mod:`grasp`) on the Example as Blender's FBX importer brings a character's hand:
the armature object turned 90° about X and scaled 0.01, its bones and the mesh in centimetres, and a
Subdivision Surface (level 2) after the Armature modifier. The world is the same, so the same grasp
must come out."""

import bpy
import numpy as np
from grasp import grasp
from mathutils import Matrix


def imported(hand, armature) -> None:
    A, H = np.array(armature.matrix_world), np.array(hand.matrix_world)
    new = A @ np.array(Matrix.Rotation(np.pi / 2, 4, "X") @ Matrix.Scale(0.01, 4))
    for obj in bpy.context.view_layer.objects:
        obj.select_set(obj == armature)
    bpy.context.view_layer.objects.active = armature
    bpy.ops.object.mode_set(mode="EDIT")
    armature.data.transform(Matrix(np.linalg.inv(new) @ A))
    bpy.ops.object.mode_set(mode="OBJECT")
    armature.matrix_world = Matrix(new)
    hand.matrix_parent_inverse = Matrix.Identity(4)
    hand.matrix_basis = Matrix.Identity(4)
    hand.data.transform(Matrix(np.linalg.inv(new) @ H))
    hand.modifiers.new("Subdivision", "SUBSURF").levels = 2
    bpy.context.view_layer.update()


def steps(s):
    yield from grasp(s, imported)
