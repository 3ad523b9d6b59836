"""Move a patch over its surface: translate, rotate, bend (Contact Edit §4.3), by dragging or by value.

While dragging, each step starts again from the patch as it was when the drag began (so nothing drifts)
and only the overlay shows it; confirming stores the result as one undo step, cancelling changes nothing.
"""

from __future__ import annotations

import contextlib
import math

import bpy
import numpy as np
from bpy_extras import view3d_utils

from .. import bridge, store
from ..ui import overlays
from .common import (
    NAVIGATION,
    USER_ERRORS,
    HotkeyTool,
    guarded,
    mesh_object,
    nearest_point,
    need_patch,
    ray_hit,
)


def patch_under_cursor(context, event):
    """The contact patch under the mouse on the scene's hand or object, nearest the view: (object, patch
    name, world point hit), or None where the mouse is over neither or over no patch of the one it hits.

    A hit is on a patch when it lies within two point spacings of one of its points (the spacing of a
    patch of ``k`` points and radius ``r`` taken as ``r √(π / k)``)."""
    settings = context.scene.contact_edit
    origin = np.array(view3d_utils.region_2d_to_origin_3d(
        context.region, context.region_data, (event.mouse_region_x, event.mouse_region_y)
    ))  # fmt: skip
    hits = []
    for obj in dict.fromkeys((settings.hand, settings.target)):
        if obj is not None and obj.type == "MESH" and store.text(obj):
            hit = ray_hit(context, event, obj)
            if hit is not None:
                hits.append((float(np.linalg.norm(hit[0] - origin)), obj, hit[0]))
    if not hits:
        return None
    _, obj, point = min(hits, key=lambda h: h[0])
    contacts = store.load(obj, deformed=obj == settings.hand)  # where the evaluated (posed) skin shows them
    local = bridge.world_to_object(obj, point[None])[0]
    best = None
    for name in contacts:
        positions = contacts[name].positions()
        gap = float(np.min(np.linalg.norm(positions - local, axis=1)))
        radius = float(np.max(np.linalg.norm(positions - positions.mean(axis=0), axis=1)))
        if gap <= 2 * radius * math.sqrt(math.pi / len(positions)) and (best is None or gap < best[0]):
            best = (gap, name)
    return None if best is None else (obj, best[1], point)


class _PatchEdit(HotkeyTool):
    """Shared plumbing: which patch, the modal loop, preview and commit. Each tool defines
    ``edited(contacts, name)`` (the edit by its properties) and ``drag(context, event)``."""

    bl_options = {"REGISTER", "UNDO"}

    patch: bpy.props.StringProperty(name="Patch", description="Patch name (default: the active patch)")
    object_name: bpy.props.StringProperty(name="Object", description="The patch's object (default: active)")

    why_not = staticmethod(need_patch)

    def _target(self, context):
        obj = mesh_object(context, self.object_name or None)
        name = self.patch or store.active_patch_name(obj)
        settings = context.scene.contact_edit
        contacts = store.load(obj, settings.deformed and obj == settings.hand)
        contacts[name]  # raises a clear error for an unknown name
        return obj, contacts, name

    @guarded
    def execute(self, context):
        obj, contacts, name = self._target(context)
        store.save(obj, self.edited(contacts, name))
        return {"FINISHED"}

    @guarded
    def invoke(self, context, event):
        if context.area is None or context.area.type != "VIEW_3D":
            return self.execute(context)
        self._grab = None  # the world point the drag holds: where the patch was picked, or first dragged
        in_view = context.region is not None and context.region.type == "WINDOW"
        if in_view and not (self.patch or self.object_name):  # a hotkey over the viewport, not a button
            picked = patch_under_cursor(context, event)
            if picked is not None:
                obj, self.patch, self._grab = picked
                self.object_name = obj.name
                store.set_active(obj, store.entries(obj).find(self.patch))
        self._obj, self._start, self._name = self._target(context)
        self._result = None
        self._mouse = (event.mouse_region_x, event.mouse_region_y)
        context.window_manager.modal_handler_add(self)
        context.area.header_text_set(self.hint)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type in {"ESC", "RIGHTMOUSE"}:
            return self._finish(context, commit=False)
        if event.type in NAVIGATION:
            return {"PASS_THROUGH"}
        if event.type in {"LEFTMOUSE", "RET", "NUMPAD_ENTER"} and event.value == "PRESS":
            return self._finish(context, commit=True)
        if event.type == "MOUSEMOVE":
            self.drag(context, event)
            if self._result is not None:
                overlays.preview(self._obj, self._result)
                context.area.tag_redraw()
        return {"RUNNING_MODAL"}

    def _finish(self, context, commit: bool):
        context.area.header_text_set(None)
        overlays.preview(self._obj)
        context.area.tag_redraw()
        if not commit or self._result is None:
            return {"CANCELLED"}
        store.save(self._obj, self._result)
        return {"FINISHED"}

    def attempt(self, make) -> None:
        """Try an edit while dragging; a position that fails (off the boundary) is simply not taken."""
        with contextlib.suppress(*USER_ERRORS):
            self._result = make()


class CONTACT_EDIT_OT_translate(_PatchEdit, bpy.types.Operator):
    """Slide a contact patch over its surface (its children follow)"""

    bl_idname = "contact_edit.translate"
    bl_label = "Move Contact"
    hint = "Move: move the mouse over the surface · click to confirm · Esc cancels"

    location: bpy.props.FloatVectorProperty(
        name="To",
        size=3,
        subtype="TRANSLATION",
        description="World-space point the patch's axis should start at",
    )

    def edited(self, contacts, name):
        obj = mesh_object(bpy.context, self.object_name or None)
        return contacts.translate(name, nearest_point(obj, contacts.mesh, self.location))

    def drag(self, context, event):
        hit = ray_hit(context, event, self._obj)
        if hit is None:
            return
        if self._grab is None:
            self._grab = hit[0]
        # The patch moves by what the cursor moved from where it grabbed the patch, as Blender's G moves
        # what it holds: it does not jump to the cursor. (The axis start moves by the cursor's move, taken
        # to the surface nearest; across a tight curve the point held drifts from under the cursor.)
        start = self._start[self._name].axis.points[0:1].positions(self._start.mesh)
        self.location = bridge.object_to_world(self._obj, start)[0] + (hit[0] - self._grab)
        to = nearest_point(self._obj, self._start.mesh, self.location)
        self.attempt(lambda: self._start.translate(self._name, to))


class CONTACT_EDIT_OT_rotate(_PatchEdit, bpy.types.Operator):
    """Turn a contact patch about the first point of its axis (its children follow)"""

    bl_idname = "contact_edit.rotate"
    bl_label = "Turn Contact"
    hint = "Turn: move the mouse left or right · click to confirm · Esc cancels"

    angle: bpy.props.FloatProperty(
        name="Angle", subtype="ANGLE", description="Counter-clockwise on the surface"
    )

    def edited(self, contacts, name):
        return contacts.rotate(name, self.angle)

    def drag(self, context, event):
        self.angle = (event.mouse_region_x - self._mouse[0]) * math.radians(0.5)
        self.attempt(lambda: self._start.rotate(self._name, self.angle))


class CONTACT_EDIT_OT_bend(_PatchEdit, bpy.types.Operator):
    """Bend a contact patch: turn its part from an axis point on about that point"""

    bl_idname = "contact_edit.bend"
    bl_label = "Bend Contact"
    hint = "Bend: move the mouse left or right · click to confirm · Esc cancels"

    index: bpy.props.IntProperty(name="Axis point", min=1, default=1, description="Where the axis bends")
    angle: bpy.props.FloatProperty(name="Angle", subtype="ANGLE")

    @guarded
    def invoke(self, context, event):
        obj = mesh_object(context, self.object_name or None)
        contacts = store.load(obj)
        name = self.patch or store.active_patch_name(obj)
        self.index = max(1, len(contacts[name].axis) // 2)  # the middle, unless a script chose
        return super().invoke(context, event)

    def edited(self, contacts, name):
        return contacts.bend(name, self.index, self.angle)

    def drag(self, context, event):
        self.angle = (event.mouse_region_x - self._mouse[0]) * math.radians(0.5)
        self.attempt(lambda: self._start.bend(self._name, self.index, self.angle))


classes = (CONTACT_EDIT_OT_translate, CONTACT_EDIT_OT_rotate, CONTACT_EDIT_OT_bend)
