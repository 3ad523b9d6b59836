"""Transfer hand patches onto the object as their mirror images, and pair them (Algorithm 5, §5.3)."""

from __future__ import annotations

import bpy
import numpy as np

from .. import store
from .common import guarded, nearest_point, poll_hand_and_object, ray_hit, surface_direction


class CONTACT_EDIT_OT_transfer(bpy.types.Operator):
    """Transfer a hand contact patch (and the patches parented to it) onto the object"""

    bl_idname = "contact_edit.transfer"
    bl_label = "Transfer Contact"
    bl_options = {"REGISTER", "UNDO"}

    patch: bpy.props.StringProperty(
        name="Patch", description="Hand patch to transfer (default: the active one)"
    )
    location: bpy.props.FloatVectorProperty(
        name="Start",
        size=3,
        subtype="TRANSLATION",
        description="World-space point on the object for the axis start",
    )
    direction: bpy.props.FloatVectorProperty(
        name="Direction",
        size=3,
        default=(0.0, 0.0, 1.0),
        description="World-space direction of the axis there",
    )
    hierarchy: bpy.props.BoolProperty(name="With children", default=True)
    suffix: bpy.props.StringProperty(
        name="Suffix", default="", description="Appended to the transferred names"
    )

    @classmethod
    def poll(cls, context):
        settings = context.scene.contact_edit
        if not poll_hand_and_object(cls, context):
            return False
        if not settings.hand.contact_edit.patches:
            cls.poll_message_set(f"The hand '{settings.hand.name}' has no contact patches yet")
            return False
        return True

    def invoke(self, context, event):
        if context.area is None or context.area.type != "VIEW_3D":
            return self.execute(context)
        self._pressed = None
        context.window_manager.modal_handler_add(self)
        context.area.header_text_set(
            "Transfer: press on the object where the axis starts, drag its direction · Esc"
        )
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        target = context.scene.contact_edit.target
        if event.type in {"ESC", "RIGHTMOUSE"}:
            context.area.header_text_set(None)
            return {"CANCELLED"}
        if event.type == "LEFTMOUSE" and event.value == "PRESS":
            hit = ray_hit(context, event, target)
            if hit is not None:
                self._pressed = hit[0]
                self.location = hit[0]
        if event.type == "LEFTMOUSE" and event.value == "RELEASE" and self._pressed is not None:
            hit = ray_hit(context, event, target)
            if hit is not None and np.linalg.norm(hit[0] - self._pressed) > 0:
                self.direction = hit[0] - self._pressed
            context.area.header_text_set(None)
            return self.execute(context)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        return guarded(self, lambda: self._transfer(context))

    def _transfer(self, context):
        settings = context.scene.contact_edit
        hand, target = settings.hand, settings.target
        hand_set = store.load(hand, settings.deformed)
        name = self.patch or store.active_patch_name(hand)
        object_set = store.load(target)
        mesh = object_set.mesh
        start = nearest_point(target, mesh, self.location)
        direction = surface_direction(target, mesh, start, self.direction)
        hand_after, object_after = hand_set.transfer(
            name, object_set, start, direction, rename=lambda n: f"{n}{self.suffix}", hierarchy=self.hierarchy
        )
        colors = {e.name: tuple(e.color) for e in hand.contact_edit.patches}
        store.save(target, object_after, colors={f"{n}{self.suffix}": c for n, c in colors.items()})
        store.save(hand, hand_after)
        moved = len(object_after) - len(object_set)
        self.report({"INFO"}, f"Transferred {moved} patch{'es' if moved > 1 else ''} onto '{target.name}'")
        return {"FINISHED"}


classes = (CONTACT_EDIT_OT_transfer,)
