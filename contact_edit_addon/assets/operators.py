"""The viewport's *Add › Contact Edit* menu: a procedural hand or object, the example (a hand beside a
mug, framed) and a Rigify hand, each added at the 3D cursor and made the scene's hand or object. The
objects themselves are built by :mod:`.builders` (and :mod:`.rigify`), which the demo and the tests use
without the menu.
"""

from __future__ import annotations

import bpy
import numpy as np

from solver import hands

from .builders import OBJECTS, example_scene, hand_objects, mesh_object


def _select_only(context, obj: bpy.types.Object) -> None:
    for other in context.selected_objects:
        other.select_set(False)
    obj.select_set(True)
    context.view_layer.objects.active = obj


class CONTACT_EDIT_OT_add_hand(bpy.types.Operator):
    """Add a procedural rigged hand (or tentacle) to pose against objects"""

    bl_idname = "contact_edit.add_hand"
    bl_label = "Procedural Hand"
    bl_options = {"REGISTER", "UNDO"}

    kind: bpy.props.EnumProperty(
        name="Kind", items=[(k, k.title(), f"The procedural {k} manipulator") for k in hands.KINDS]
    )
    scale: bpy.props.FloatProperty(
        name="Scale", default=1.0, min=1e-3, description="1 is life size in metres"
    )

    def execute(self, context):
        hand = hands.make_hand(self.kind, self.scale)
        obj, armature = hand_objects(hand, self.kind.title(), context.collection)
        armature.location = context.scene.cursor.location
        context.scene.contact_edit.hand = obj
        _select_only(context, obj)
        self.report({"INFO"}, f"Added '{obj.name}' ({hand.rig.n_dofs} DOF) as the hand")
        return {"FINISHED"}


class CONTACT_EDIT_OT_add_object(bpy.types.Operator):
    """Add a procedural object to grasp (a mug has a genus-1 handle; a plate has two holes)"""

    bl_idname = "contact_edit.add_object"
    bl_label = "Procedural Object"
    bl_options = {"REGISTER", "UNDO"}

    shape: bpy.props.EnumProperty(
        name="Shape", items=[(k, label, f"A {label.lower()}") for k, (label, _) in OBJECTS.items()]
    )

    def execute(self, context):
        label, build = OBJECTS[self.shape]
        obj = mesh_object(label, build(), context.collection)
        obj.location = context.scene.cursor.location
        context.scene.contact_edit.target = obj
        _select_only(context, obj)
        self.report({"INFO"}, f"Added '{obj.name}' as the object")
        return {"FINISHED"}


class CONTACT_EDIT_OT_add_example(bpy.types.Operator):
    """Add a rigged human hand next to a mug, ready to paint, transfer and solve (what the demo starts
    from), and frame them in the view"""

    bl_idname = "contact_edit.add_example"
    bl_label = "Example: Hand and Mug"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        _, hand, mug = example_scene(context, np.array(context.scene.cursor.location))
        _select_only(context, hand)
        mug.select_set(True)  # both, for framing
        if context.area is not None and context.area.type == "VIEW_3D":
            bpy.ops.view3d.view_selected()
        self.report({"INFO"}, f"Added '{hand.name}' and '{mug.name}': paint on the hand, then transfer")
        return {"FINISHED"}


class CONTACT_EDIT_OT_add_rigify_hand(bpy.types.Operator):
    """Add a Rigify human whose right hand is the procedural hand, skinned with automatic weights: a
    production rig to pose through its controls (generating the rig takes several seconds)"""

    bl_idname = "contact_edit.add_rigify_hand"
    bl_label = "Rigify Hand"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        from . import rigify

        if not rigify.available():
            cls.poll_message_set("Rigify is not part of this Blender")
            return False
        return context.mode == "OBJECT"

    def execute(self, context):
        from . import rigify

        hand, rig = rigify.rigify_hand(context.collection)
        context.scene.contact_edit.hand = hand
        _select_only(context, hand)
        if context.area is not None and context.area.type == "VIEW_3D":
            bpy.ops.view3d.view_selected()
        self.report(
            {"INFO"}, f"Added '{hand.name}' on the Rigify rig '{rig.name}'; pose it through its controls"
        )
        return {"FINISHED"}


class VIEW3D_MT_contact_edit_add(bpy.types.Menu):
    bl_label = "Contact Edit"

    def draw(self, context):
        layout = self.layout
        layout.operator(CONTACT_EDIT_OT_add_example.bl_idname, text="Example", icon="HAND")
        layout.separator()
        for kind in hands.KINDS:
            label = "Tentacle" if kind == "tentacle" else f"{kind.title()} Hand"
            layout.operator(CONTACT_EDIT_OT_add_hand.bl_idname, text=label).kind = kind
        layout.operator(CONTACT_EDIT_OT_add_rigify_hand.bl_idname, text="Rigify Hand", icon="ARMATURE_DATA")
        layout.separator()
        for key, (label, _) in OBJECTS.items():
            layout.operator(CONTACT_EDIT_OT_add_object.bl_idname, text=label).shape = key


def draw_add_menu(self, context) -> None:
    self.layout.menu(VIEW3D_MT_contact_edit_add.__name__, icon="HAND")


classes = (
    CONTACT_EDIT_OT_add_hand,
    CONTACT_EDIT_OT_add_object,
    CONTACT_EDIT_OT_add_example,
    CONTACT_EDIT_OT_add_rigify_hand,
    VIEW3D_MT_contact_edit_add,
)


def register() -> None:
    bpy.types.VIEW3D_MT_add.append(draw_add_menu)


def unregister() -> None:
    bpy.types.VIEW3D_MT_add.remove(draw_add_menu)
