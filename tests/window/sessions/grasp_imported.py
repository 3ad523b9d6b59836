"""The grasp session (:mod:`grasp`) on the Example as Blender's FBX importer brings a character's hand
(:func:`styles.fbx_style`), with a Subdivision Surface (level 2) after the Armature modifier. The world
is the same, so the same grasp must come out."""

import bpy
from grasp import grasp
from styles import fbx_style


def imported(hand, armature) -> None:
    fbx_style(armature, hand)
    hand.modifiers.new("Subdivision", "SUBSURF").levels = 2
    bpy.context.view_layer.update()


def steps(s):
    yield from grasp(s, imported)
