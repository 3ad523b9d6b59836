"""Paint a contact patch: from the selected vertices, or from a brush stroke cast onto the surface."""

from __future__ import annotations

import bpy
import numpy as np

from geodesics import ContactPatch, farthest_pair_axis, medial_axis

from .. import bridge, store
from .common import guarded, mesh_object, poll_mesh, ray_hit, unique_name


class CONTACT_EDIT_PG_stroke_point(bpy.types.PropertyGroup):
    """A brush sample: where a ray hit the surface (world space) and the polygon it hit. From a script,
    pass ``stroke=[{"name": "", "location": (x, y, z), "polygon": i}, ...]`` (as for Blender's own paint
    strokes, each item needs a "name")."""

    location: bpy.props.FloatVectorProperty(name="Location", size=3)
    polygon: bpy.props.IntProperty(name="Polygon", min=0)


AXIS_METHODS = [
    ("SCENE", "Scene default", "Use the scene's default axis method"),
    ("FARTHEST", "Farthest points", "The geodesic between the patch's two farthest points"),
    ("MEDIAL", "Medial axis", "The patch's smoothed medial axis"),
]


class CONTACT_EDIT_OT_paint(bpy.types.Operator):
    """Create a contact patch from the selected vertices or from a brush stroke on the surface"""

    bl_idname = "contact_edit.paint"
    bl_label = "Paint Contact"
    bl_options = {"REGISTER", "UNDO"}

    name: bpy.props.StringProperty(name="Name", default="contact")
    source: bpy.props.EnumProperty(
        name="From",
        items=[
            ("SELECTION", "Selection", "The selected vertices of the object"),
            ("STROKE", "Stroke", "Brush samples cast onto the surface (points inside faces)"),
        ],
        default="SELECTION",
    )
    stroke: bpy.props.CollectionProperty(type=CONTACT_EDIT_PG_stroke_point, options={"SKIP_SAVE"})
    object_name: bpy.props.StringProperty(name="Object", description="Paint on this object (default: active)")
    axis_method: bpy.props.EnumProperty(name="Axis", items=AXIS_METHODS, default="SCENE")

    @classmethod
    def poll(cls, context):
        return poll_mesh(cls, context)

    def invoke(self, context, event):
        if self.source == "SELECTION" or context.area is None or context.area.type != "VIEW_3D":
            return self.execute(context)
        self._object = mesh_object(context, self.object_name or None)
        self.stroke.clear()
        self._painting = False
        context.window_manager.modal_handler_add(self)
        context.area.header_text_set("Paint contact: drag over the surface, release to finish · Esc cancels")
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type in {"ESC", "RIGHTMOUSE"}:
            context.area.header_text_set(None)
            return {"CANCELLED"}
        if event.type == "LEFTMOUSE" and event.value == "PRESS":
            self._painting = True
        if self._painting and event.type in {"MOUSEMOVE", "LEFTMOUSE", "INBETWEEN_MOUSEMOVE"}:
            hit = ray_hit(context, event, self._object)
            if hit is not None:
                sample = self.stroke.add()
                sample.location, sample.polygon = hit[0], hit[1]
        if event.type == "LEFTMOUSE" and event.value == "RELEASE":
            context.area.header_text_set(None)
            return self.execute(context)
        return {"RUNNING_MODAL"} if self._painting or event.type != "LEFTMOUSE" else {"PASS_THROUGH"}

    def execute(self, context):
        return guarded(self, lambda: self._paint(context))

    def _paint(self, context):
        obj = mesh_object(context, self.object_name or None)
        if obj.mode == "EDIT":
            obj.update_from_editmode()
        settings = context.scene.contact_edit
        deformed = settings.deformed and obj == settings.hand
        mesh = bridge.trimesh(obj, deformed=deformed)
        if self.source == "SELECTION":
            points = bridge.points_from_vertices(obj, mesh, bridge.selected_vertices(obj))
        else:
            if not self.stroke:
                self.report({"ERROR"}, "The stroke missed the surface: paint over the object")
                return {"CANCELLED"}
            hits = np.array([s.location for s in self.stroke])
            polygons = np.array([s.polygon for s in self.stroke])
            points = bridge.points_from_hits(mesh, polygons, bridge.world_to_object(obj, hits))
        method = settings.axis_method if self.axis_method == "SCENE" else self.axis_method
        axis = (medial_axis if method == "MEDIAL" else farthest_pair_axis)(mesh, points)
        contacts = store.load(obj, deformed)
        name = unique_name(contacts, self.name or "contact")
        store.save(obj, contacts.add(name, ContactPatch(mesh, points, axis)))
        obj.contact_edit.active = len(obj.contact_edit.patches) - 1
        self.report(
            {"INFO"}, f"Painted '{name}' on '{obj.name}': {len(points)} points, axis of {len(axis)} points"
        )
        return {"FINISHED"}


classes = (CONTACT_EDIT_PG_stroke_point, CONTACT_EDIT_OT_paint)
