"""A scene's hand restyled as users' files have it, world geometry unchanged: shared by the window
sessions and the bpy tests (tests/test_addon_imported.py), which import it from this folder."""

import bpy
import numpy as np
from mathutils import Matrix


def fbx_style(armature, hand) -> None:
    """As Blender's FBX importer brings a Mixamo character: the armature object turned 90° about X and
    scaled 0.01, its bones and the mesh in centimetres, the mesh a child with no transform of its own."""
    A, H = np.array(armature.matrix_world), np.array(hand.matrix_world)
    new = A @ np.array(Matrix.Rotation(np.pi / 2, 4, "X") @ Matrix.Scale(0.01, 4))
    for obj in bpy.context.view_layer.objects:
        obj.select_set(obj == armature)
    bpy.context.view_layer.objects.active = armature
    bpy.ops.object.mode_set(mode="EDIT")  # as edit bones, so that Blender rebuilds their rest
    armature.data.transform(Matrix(np.linalg.inv(new) @ A))
    bpy.ops.object.mode_set(mode="OBJECT")
    armature.matrix_world = Matrix(new)
    hand.matrix_parent_inverse = Matrix.Identity(4)
    hand.matrix_basis = Matrix.Identity(4)
    hand.data.transform(Matrix(np.linalg.inv(new) @ H))
