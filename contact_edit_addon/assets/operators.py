"""The viewport's *Add › Contact Edit* menu: a procedural hand or object, the example (a hand beside a
mug, framed) and a Rigify hand, each added at the 3D cursor and made the scene's hand or object. The
objects themselves are built by :mod:`.builders` (and :mod:`.rigify`), which the demo and the tests use
without the menu.
"""

from __future__ import annotations

import bpy
import numpy as np
from mathutils import Vector

from solver import hands

from .builders import OBJECTS, example_scene, hand_objects, mesh_object

#: Gap left between what is added and what is already in the scene, as a fraction of the added box's size.
CLEARANCE = 0.1
#: Steps of its own width either way that something added is moved at most to clear the scene.
SEARCH_STEPS = 8


def _world_box(objs) -> tuple[np.ndarray, np.ndarray]:
    """The world-space axis-aligned box around the objects' bounding boxes: (lower, upper) corners."""
    corners = np.concatenate([
        np.array([tuple(obj.matrix_world @ Vector(c)) for c in obj.bound_box]) for obj in objs
    ])  # fmt: skip
    return corners.min(axis=0), corners.max(axis=0)


def _clear_of_the_scene(context, added, movers) -> None:
    """Move ``movers`` (what carries ``added``: a hand's armature, an object) the least whole number of
    steps of the added box's size, along the view's right, up or depth axis (the world's outside a 3D
    view; right first on a tie), that leaves the added box clear of every other visible object's: a
    person sees what was added, not the inside of the startup cube, and a mug added to a hand lands
    beside it."""
    lower, upper = _world_box(added)
    mine = set(added) | set(movers)
    others = [
        _world_box([obj])
        for obj in context.visible_objects
        if obj not in mine and obj.type in ("MESH", "CURVE")
    ]
    space = context.space_data if context.area is not None and context.area.type == "VIEW_3D" else None
    axes = np.array(space.region_3d.view_rotation.to_matrix()).T if space else np.eye(3)
    size = upper - lower
    gap = CLEARANCE * float(np.linalg.norm(size))
    steps = axes * (np.abs(axes) @ size + gap)[:, None]  # a row per axis

    def clear(move: np.ndarray) -> bool:
        lo, hi = lower + move - gap, upper + move + gap
        return not any(np.all(lo < o_hi) and np.all(o_lo < hi) for o_lo, o_hi in others)

    moves = (n * sign * step for n in range(SEARCH_STEPS + 1) for step in steps for sign in (1, -1))
    move = next((m for m in moves if clear(m)), np.zeros(3))
    for obj in movers:
        obj.location = obj.location + Vector(move)
    context.view_layer.update()


def _frame(context, objs) -> None:
    """Select ``objs`` (the first active) and frame them in the 3D view the operator runs in."""
    _select_only(context, objs[0])
    for obj in objs[1:]:
        obj.select_set(True)
    if context.area is not None and context.area.type == "VIEW_3D":
        bpy.ops.view3d.view_selected()
    _select_only(context, objs[0])


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
        context.view_layer.update()
        _clear_of_the_scene(context, [obj], [armature])
        context.scene.contact_edit.hand = obj
        _frame(context, [obj])
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
        hand = context.scene.contact_edit.hand
        if hand is not None and hand.name in context.view_layer.objects:
            # Beside the hand it is for: from the middle of the hand's box, then clear of it.
            lower, upper = _world_box([hand])
            obj.location = Vector((lower + upper) / 2)
        else:
            obj.location = context.scene.cursor.location
        context.view_layer.update()
        _clear_of_the_scene(context, [obj], [obj])
        context.scene.contact_edit.target = obj
        _frame(
            context, [obj, hand] if hand is not None and hand.name in context.view_layer.objects else [obj]
        )
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
        context.view_layer.update()
        _clear_of_the_scene(context, [hand, mug], [hand.parent, mug])
        _frame(context, [hand, mug])
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
