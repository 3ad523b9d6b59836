"""Transfer hand patches onto the object as their mirror images, and pair them (Algorithm 5, §5.3).

Interactively the transferred patch follows the mouse before anything is stored: hovering places its
axis start under the pointer, its direction pointing up the screen; pressing fixes the start and
dragging turns the direction towards the pointer; releasing stores it (one undo step). The preview is
recomputed on a timer for the latest pointer position only, so a slow transfer never queues up.
"""

from __future__ import annotations

import bpy
import numpy as np

from .. import bridge, store
from ..ui import overlays
from .common import (
    NAVIGATION,
    USER_ERRORS,
    HotkeyTool,
    guarded,
    nearest_point,
    need_hand_and_object,
    ray_hit,
    surface_direction,
)

#: Preview updates per second while placing.
PREVIEW_RATE = 30.0


class CONTACT_EDIT_OT_transfer(HotkeyTool, bpy.types.Operator):
    """Transfer a hand contact patch (and the patches parented to it) onto the object, previewing it under
    the mouse: press where its axis starts, drag its direction, release"""

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

    @staticmethod
    def why_not(context) -> str | None:
        hand, reason = context.scene.contact_edit.hand, need_hand_and_object(context)
        if reason is None and not hand.contact_edit.patches:
            reason = f"The hand '{hand.name}' has no contact patches yet: paint one first"
        return reason

    # ------------------------------------------------------------------ placing it with the mouse

    @guarded
    def invoke(self, context, event):
        if context.area is None or context.area.type != "VIEW_3D":
            return self.execute(context)
        self._sets = self._load(context)
        self._pressed = False
        self._wanted = self._shown = None
        self._problem = ""
        self._timer = context.window_manager.event_timer_add(1.0 / PREVIEW_RATE, window=context.window)
        context.window_manager.modal_handler_add(self)
        self._hint(context)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        target = context.scene.contact_edit.target
        if event.type in {"ESC", "RIGHTMOUSE"} and event.value == "PRESS":
            return self._end(context, {"CANCELLED"})
        if event.type == "TIMER":
            self._update_preview(context)
            return {"RUNNING_MODAL"}
        if event.type in NAVIGATION:
            return {"PASS_THROUGH"}
        hit = ray_hit(context, event, target) if event.type in {"MOUSEMOVE", "LEFTMOUSE"} else None
        if event.type == "LEFTMOUSE" and event.value == "PRESS" and hit is not None:
            self._pressed = True
            self.location = hit[0]
        elif event.type == "MOUSEMOVE" and hit is not None:
            if self._pressed:
                if np.linalg.norm(hit[0] - np.array(self.location)) > 0:
                    self.direction = hit[0] - np.array(self.location)
            else:
                self.location = hit[0]
                self.direction = np.array(context.region_data.view_rotation.to_matrix().col[1])  # screen up
        if event.type == "LEFTMOUSE" and event.value == "RELEASE" and self._pressed:
            self._end(context, set())
            return self.execute(context)
        if hit is not None:
            self._wanted = (tuple(self.location), tuple(self.direction))
        return {"RUNNING_MODAL"}

    def _update_preview(self, context) -> None:
        if self._wanted is None or self._wanted == self._shown:
            return
        self._shown = self._wanted
        target = context.scene.contact_edit.target
        try:
            _, object_after, colors = self._transferred(context, *self._sets)
        except USER_ERRORS as err:
            overlays.preview(target)
            self._problem = str(err)
        else:
            overlays.preview(target, object_after, colors)
            self._problem = ""
        self._hint(context)
        context.area.tag_redraw()

    def _hint(self, context) -> None:
        step = "drag the axis direction, release" if self._pressed else "press where the axis starts"
        text = f"Transfer '{self._name(context)}': {step} · Esc: cancel"
        context.area.header_text_set(f"{text} · cannot go here: {self._problem}" if self._problem else text)

    def _end(self, context, status: set) -> set:
        context.window_manager.event_timer_remove(self._timer)
        overlays.preview(context.scene.contact_edit.target)
        context.area.header_text_set(None)
        context.area.tag_redraw()
        return status

    # ------------------------------------------------------------------ the transfer

    def _name(self, context) -> str:
        return self.patch or store.active_patch_name(context.scene.contact_edit.hand)

    def _load(self, context):
        settings = context.scene.contact_edit
        return (
            store.load(settings.hand, settings.deformed, layer="CONTACTS"),
            store.load(settings.target, layer="CONTACTS"),
        )

    def _transferred(self, context, hand_set, object_set):
        """(hand set, object set) after the transfer at the operator's start and direction, and the
        colours the new object patches take from their hand patches."""
        settings = context.scene.contact_edit
        target = settings.target
        for obj in (settings.hand, target):
            scale = bridge.uneven_scale(obj)
            if scale is not None:
                raise bridge.BridgeError(
                    f"'{obj.name}' is scaled unevenly ({scale}), which would stretch the transferred patches "
                    "one way; apply its scale (Ctrl+A, Scale) first",
                    obj.name,
                )
        mesh = object_set.mesh
        start = nearest_point(target, mesh, self.location)
        direction = surface_direction(target, mesh, start, self.direction)
        hand_after, object_after = hand_set.transfer(
            self._name(context),
            object_set,
            start,
            direction,
            rename=lambda n: f"{n}{self.suffix}",
            hierarchy=self.hierarchy,
            scale=bridge.uniform_scale(settings.hand) / bridge.uniform_scale(target),
            mirror=bridge.handedness(settings.hand) == bridge.handedness(target),
        )
        colors = {f"{e.name}{self.suffix}": tuple(e.color) for e in settings.hand.contact_edit.patches}
        return hand_after, object_after, colors

    @guarded
    def execute(self, context):
        settings = context.scene.contact_edit
        hand_set, object_set = self._load(context)
        hand_after, object_after, colors = self._transferred(context, hand_set, object_set)
        store.save(settings.target, object_after, colors=colors, layer="CONTACTS")
        store.save(settings.hand, hand_after, layer="CONTACTS")
        moved = len(object_after) - len(object_set)
        self.report(
            {"INFO"}, f"Transferred {moved} patch{'es' if moved > 1 else ''} onto '{settings.target.name}'"
        )
        return {"FINISHED"}


classes = (CONTACT_EDIT_OT_transfer,)
