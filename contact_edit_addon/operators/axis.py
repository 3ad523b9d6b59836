"""Set a patch's axis: pick its start and end (every edge crossing between becomes an axis point), or
reset it to a default axis (§6.2)."""

from __future__ import annotations

import bpy

from geodesics import Axis

from .. import store
from ..properties import DEFAULT_AXES
from .background import Background, Plan
from .common import HotkeyTool, default_axis, guarded, mesh_object, nearest_point, need_patch, ray_hit


class CONTACT_EDIT_OT_axis(Background, HotkeyTool, bpy.types.Operator):
    """Set the axis of a contact patch (pick start and end on the surface, or use a default)"""

    bl_idname = "contact_edit.axis"
    bl_label = "Set Contact Axis"
    bl_options = {"REGISTER", "UNDO"}

    patch: bpy.props.StringProperty(name="Patch", description="Patch name (default: the active patch)")
    object_name: bpy.props.StringProperty(name="Object", description="The patch's object (default: active)")
    method: bpy.props.EnumProperty(
        name="Axis",
        items=[
            ("POINTS", "Start and end", "The shortest geodesic from a start point to an end point"),
            *DEFAULT_AXES,
        ],
        default="POINTS",
    )
    start: bpy.props.FloatVectorProperty(name="Start", size=3, subtype="TRANSLATION")
    end: bpy.props.FloatVectorProperty(name="End", size=3, subtype="TRANSLATION")

    why_not = staticmethod(need_patch)

    @guarded
    def invoke(self, context, event):
        if context.area is None or context.area.type != "VIEW_3D":
            return self.execute(context)
        if self.method != "POINTS":
            return self.in_background(context, self._plan(context))
        self._obj = mesh_object(context, self.object_name or None)
        self._picked = 0
        context.window_manager.modal_handler_add(self)
        context.area.header_text_set("Axis: click its start, then its end · Esc cancels")
        return {"RUNNING_MODAL"}

    @guarded
    def modal(self, context, event):
        if self.waiting():
            return self.modal_background(context, event)
        if event.type in {"ESC", "RIGHTMOUSE"}:
            context.area.header_text_set(None)
            return {"CANCELLED"}
        if event.type == "LEFTMOUSE" and event.value == "PRESS":
            hit = ray_hit(context, event, self._obj)
            if hit is not None:
                if self._picked == 0:
                    self.start = hit[0]
                else:
                    self.end = hit[0]
                self._picked += 1
            if self._picked == 2:
                context.area.header_text_set(None)
                return self.in_background(context, self._plan(context), add_handler=False)
        return {"RUNNING_MODAL"}

    @guarded
    def execute(self, context):
        return self.now(context, self._plan(context))

    def _plan(self, context) -> Plan:
        """The new axis and the patch parameterized around it (slow: :mod:`.background`), then stored."""
        obj = mesh_object(context, self.object_name or None)
        contacts = store.load(obj)
        name = self.patch or store.active_patch_name(obj)
        patch, mesh = contacts[name], contacts.mesh
        if self.method == "POINTS":
            ends = nearest_point(obj, mesh, self.start), nearest_point(obj, mesh, self.end)

            def make_axis():
                return Axis.between(mesh, *ends)
        else:
            make_axis = default_axis(obj, mesh, patch.points, self.method, deformed=False)  # as loaded

        def commit(context, changed):
            store.save(obj, contacts.replace(name, changed))
            self.report({"INFO"}, f"'{name}' now has an axis of {len(changed.axis)} points")
            return {"FINISHED"}

        return Plan(f"Laying out the axis of '{name}'", lambda: patch.with_axis(make_axis()), commit, (obj,))


classes = (CONTACT_EDIT_OT_axis,)
