"""Paint a contact patch: from the selected vertices, or with the area brush (Contact Edit §4.2).

The brush is a circle of a radius in screen pixels (F resizes it, as in Blender's own brushes) that
paints points inside faces at the scene's density (points per cm² of surface), wherever it passes over
the surface facing the view (:mod:`geodesics.brush`). A plain stroke makes a new patch; Shift adds to
the active patch and Ctrl takes away from it, keeping its axis. Adding to or taking from a hand patch
that was transferred carries the change over to its counterpart on the object, which keeps its place.

From a script, ``stroke`` lists the brush's dabs: a world-space ``location`` on the surface, the
``polygon`` it is on and the ``radius`` of the ball (world units; 0 paints the location itself, one
point); ``eye`` (a perspective view) or ``view_direction`` (an orthographic one) say where the viewer is,
so that only surface facing it is painted (both zero: all of it).
"""

from __future__ import annotations

import bpy
import numpy as np
from bpy_extras import view3d_utils

from geodesics import (
    ContactError,
    ContactPatch,
    Dab,
    SurfacePoints,
    erase,
    paint,
)

from .. import bridge, store
from ..properties import DEFAULT_AXES
from ..ui import overlays
from .background import Background, Plan
from .common import NAVIGATION, HotkeyTool, default_axis, guarded, mesh_object, need_mesh, unique_name

#: Brush dabs per radius of stroke length.
DABS_PER_RADIUS = 3.0
#: Square centimetres per square metre (the density is set per cm², the scene is in metres).
CM2_PER_M2 = 1e4
SUBTRACT_COLOR = (0.95, 0.2, 0.2, 1.0)


class CONTACT_EDIT_PG_stroke_point(bpy.types.PropertyGroup):
    """A brush dab. From a script, pass ``stroke=[{"name": "", "location": (x, y, z), "polygon": i,
    "radius": r}, ...]`` (as for Blender's own paint strokes, each item needs every key)."""

    location: bpy.props.FloatVectorProperty(name="Location", size=3, description="World space")
    polygon: bpy.props.IntProperty(
        name="Polygon", min=-1, description="The mesh's polygon hit; -1: unknown (the nearest surface point)"
    )
    radius: bpy.props.FloatProperty(name="Radius", min=0.0, description="World units; 0: just this point")


AXIS_METHODS = [("SCENE", "Scene default", "Use the scene's default axis method"), *DEFAULT_AXES]
MODES = [
    ("NEW", "New patch", "Make a new patch of what the stroke covers"),
    ("ADD", "Add", "Add what the stroke covers to the active patch (Shift)"),
    ("SUBTRACT", "Subtract", "Take what the stroke covers away from the active patch (Ctrl)"),
]


def shown_shape(obj):
    """The shape the viewport shows for ``obj`` (posed, if an armature poses it) as a TriMesh with the
    faces of its rest shape, so that points found on it are points of the rest shape too."""
    try:
        return bridge.trimesh(obj, deformed=True)
    except bridge.BridgeError:
        return bridge.trimesh(obj)


def local_density(context, obj) -> float:
    """The scene's brush density (points per cm² of world surface) per object-space unit area."""
    metres = context.scene.unit_settings.scale_length or 1.0
    return context.scene.contact_edit.brush_density * CM2_PER_M2 * (metres * bridge.uniform_scale(obj)) ** 2


class CONTACT_EDIT_OT_paint(Background, HotkeyTool, bpy.types.Operator):
    """Create a contact patch from the selected vertices, or paint one with the area brush (Shift adds to
    the active patch, Ctrl takes away from it, F resizes the brush)"""

    bl_idname = "contact_edit.paint"
    bl_label = "Paint Contact"
    bl_options = {"REGISTER", "UNDO"}

    name: bpy.props.StringProperty(name="Name", default="contact")
    source: bpy.props.EnumProperty(
        name="From",
        items=[
            ("SELECTION", "Selection", "The selected vertices of the object"),
            ("STROKE", "Stroke", "A brush stroke over the surface (points inside faces)"),
        ],
        default="SELECTION",
    )
    mode: bpy.props.EnumProperty(name="Mode", items=MODES, default="NEW", options={"SKIP_SAVE"})
    stroke: bpy.props.CollectionProperty(type=CONTACT_EDIT_PG_stroke_point, options={"SKIP_SAVE"})
    eye: bpy.props.FloatVectorProperty(
        name="Eye", size=3, description="The viewer's place (perspective)", options={"SKIP_SAVE"}
    )
    view_direction: bpy.props.FloatVectorProperty(
        name="View direction",
        size=3,
        description="The direction the viewer looks in (orthographic)",
        options={"SKIP_SAVE"},
    )
    object_name: bpy.props.StringProperty(name="Object", description="Paint on this object (default: active)")
    axis_method: bpy.props.EnumProperty(name="Axis", items=AXIS_METHODS, default="SCENE")

    why_not = staticmethod(need_mesh)

    # ------------------------------------------------------------------ the brush, interactively

    @guarded
    def invoke(self, context, event):
        if context.area is None or context.area.type != "VIEW_3D":
            return self.execute(context)
        self._object = mesh_object(context, self.object_name or None)
        if self.source == "SELECTION":
            return self.in_background(context, self._plan(context))
        self.stroke.clear()
        self._painting = False
        self._last = None
        self._mesh = None  # the rest is set up by the first dab
        context.window.cursor_modal_set("CROSSHAIR")
        context.window_manager.modal_handler_add(self)
        self._show_brush(context, event)
        self._hint = (
            f"Paint on '{self._object.name}': drag · Shift: add to the active patch · Ctrl: take away · "
            "F: radius · Esc: cancel"
        )
        context.area.header_text_set(self._hint)
        return {"RUNNING_MODAL"}

    @guarded
    def modal(self, context, event):
        if self.waiting():
            try:
                return self.modal_background(context, event)
            finally:
                if not self.waiting():
                    overlays.preview(self._object)
        if event.type in {"ESC", "RIGHTMOUSE"} and event.value == "PRESS":
            return self._end(context, {"CANCELLED"})
        if not self._painting:
            if event.type in NAVIGATION:
                return {"PASS_THROUGH"}
            if event.type == "F" and event.value == "PRESS":
                bpy.ops.wm.radial_control(
                    "INVOKE_DEFAULT", data_path_primary="scene.contact_edit.brush_radius"
                )
                return {"RUNNING_MODAL"}
            # The radial control clears the header when it ends: the brush's keys are still live.
            context.area.header_text_set(self._hint)
        if event.type == "LEFTMOUSE" and event.value == "PRESS" and not self._painting:
            self._painting = True
            self.mode = "SUBTRACT" if event.ctrl else "ADD" if event.shift else "NEW"
            if self.mode != "NEW" and not store.entries(self._object):
                self.report({"ERROR"}, f"'{self._object.name}' has no patch to add to or take from yet")
                return self._end(context, {"CANCELLED"})
            self._dab(context, event)
        elif event.type in {"MOUSEMOVE", "INBETWEEN_MOUSEMOVE"} and self._painting:
            self._dab(context, event)
        elif event.type == "LEFTMOUSE" and event.value == "RELEASE" and self._painting:
            self._end(context, set(), keep_preview=True)  # what was painted stays shown until it is stored
            try:
                return self.in_background(context, self._plan(context), add_handler=False)
            finally:
                if not self.waiting():
                    overlays.preview(self._object)
        self._show_brush(context, event)
        return {"RUNNING_MODAL"}

    def _show_brush(self, context, event) -> None:
        radius = context.scene.contact_edit.brush_radius
        held = self.mode if self._painting else "SUBTRACT" if event.ctrl else "ADD" if event.shift else "NEW"
        color = SUBTRACT_COLOR if held == "SUBTRACT" else (1.0, 1.0, 1.0, 1.0)
        centre = (event.mouse_region_x, event.mouse_region_y)
        overlays.brush(overlays.Brush(context.region, centre, radius, color))
        context.area.tag_redraw()

    def _dab(self, context, event) -> None:
        """Dabs from the last one to the mouse, a third of the radius apart, each where its ray meets the
        surface; the overlay shows what the stroke covers so far."""
        region, rv3d = context.region, context.region_data
        here = np.array([event.mouse_region_x, event.mouse_region_y], float)
        radius = context.scene.contact_edit.brush_radius
        if self._last is None:
            spots = [here]
        else:
            steps = int(np.linalg.norm(here - self._last) * DABS_PER_RADIUS / max(radius, 1))
            if steps == 0:
                return
            spots = [self._last + (here - self._last) * (i + 1) / steps for i in range(steps)]
        self._last = here
        view = (np.array(rv3d.perspective_matrix), float(region.width))
        if rv3d.is_perspective:
            self.eye = rv3d.view_matrix.inverted().translation
        else:
            self.view_direction = -np.array(rv3d.view_matrix.inverted().col[2][:3])
        inverse = self._object.matrix_world.inverted()
        shown = self._object.evaluated_get(context.evaluated_depsgraph_get()).data
        refined = len(shown.polygons) != len(self._object.data.polygons)  # ray_cast's polygons are not ours
        added = []
        for spot in spots:
            origin = view3d_utils.region_2d_to_origin_3d(region, rv3d, spot)
            ray = view3d_utils.region_2d_to_vector_3d(region, rv3d, spot)
            hit, location, _normal, polygon = self._object.ray_cast(
                inverse @ origin, (inverse.to_3x3() @ ray).normalized()
            )
            if not hit:
                continue
            world = np.array(self._object.matrix_world @ location)
            item = self.stroke.add()
            item.location, item.polygon = world, -1 if refined else polygon
            item.radius = float(overlays.pixel_size(world[None], view)[0] * radius)
            added.append(item)
        if added:
            self._preview(context, added)

    def _preview(self, context, items) -> None:
        """Show what the stroke covers so far, working only on its new dabs: the points painted, each
        once, or the active patch without the points erased."""
        obj = self._object
        if self._mesh is None:
            self._mesh = shown_shape(obj)
            name = store.active_patch_name(obj)
            self._touched = (name, store.load(obj)[name]) if name is not None else None
            self._kept = np.ones(len(self._touched[1]), bool) if self._touched else None
            self._painted, self._ids = SurfacePoints.concatenate([]), np.empty(0, np.int64)
        dabs = self._dabs(obj, self._mesh, items)[0]
        entries = {e.name: tuple(e.color) for e in store.entries(obj)}
        if self.mode == "SUBTRACT":
            name, patch = self._touched
            self._kept &= erase(self._mesh, patch.points, dabs)
            overlays.preview(
                obj, hidden={name}, loose=[(patch.points[np.flatnonzero(self._kept)], entries[name])]
            )
        else:
            points, ids = paint(self._mesh, dabs, local_density(context, obj))
            new = ~np.isin(ids, self._ids)
            self._painted = SurfacePoints.concatenate([self._painted, points[np.flatnonzero(new)]])
            self._ids = np.concatenate([self._ids, ids[new]])
            color = (
                entries[self._touched[0]]
                if self.mode == "ADD"
                else store.PALETTE[len(entries) % len(store.PALETTE)]
            )
            overlays.preview(obj, loose=[(self._painted, color)])
        context.area.tag_redraw()

    def _end(self, context, status: set, keep_preview: bool = False) -> set:
        overlays.brush(None)
        if not keep_preview:
            overlays.preview(self._object)
        context.window.cursor_modal_restore()
        context.area.header_text_set(None)
        context.area.tag_redraw()
        return status

    # ------------------------------------------------------------------ making the patch

    def _dabs(self, obj, mesh, items) -> tuple[list[Dab], SurfacePoints]:
        """The stroke as brush dabs on ``mesh`` (the shown shape, in object space), and the points of
        its zero-radius items."""
        items = list(items)
        if not items:
            return [], SurfacePoints(np.empty(0, np.int64), np.empty((0, 3)))
        hits = bridge.world_to_object(obj, [i.location for i in items])
        at = bridge.points_from_hits(mesh, [i.polygon for i in items], hits)
        scale = bridge.uniform_scale(obj)
        eye = tuple(bridge.world_to_object(obj, self.eye)[0]) if any(self.eye) else None
        M = np.linalg.inv(np.array(obj.matrix_world)[:3, :3])
        direction = tuple(M @ np.array(self.view_direction)) if any(self.view_direction) and not eye else None
        dabs = [
            Dab(int(at.faces[k]), tuple(hits[k]), item.radius / scale, eye, direction)
            for k, item in enumerate(items)
            if item.radius > 0
        ]
        points = at[np.flatnonzero([i.radius <= 0 for i in items])]
        return dabs, points

    @guarded
    def execute(self, context):
        return self.now(context, self._plan(context))

    def _plan(self, context) -> Plan | set:
        """What the stroke or selection makes (:class:`~.background.Plan`); a subtraction is quick and
        done at once."""
        obj = mesh_object(context, self.object_name or None)
        if obj.mode == "EDIT":
            obj.update_from_editmode()
        settings = context.scene.contact_edit
        deformed = settings.deformed and obj == settings.hand
        mesh = bridge.trimesh(obj, deformed=deformed)
        if self.source == "SELECTION":
            selected = bridge.points_from_vertices(obj, mesh, bridge.selected_vertices(obj))
            return self._new(context, obj, mesh, selected)
        active = self._active(context, obj) if self.mode != "NEW" else None  # refused before any work
        shape = shown_shape(obj)
        dabs, single = self._dabs(obj, shape, self.stroke)
        if not dabs and not len(single):
            self.report({"ERROR"}, f"The stroke missed '{obj.name}': paint over its surface")
            return {"CANCELLED"}
        if self.mode == "SUBTRACT":
            return self._subtract(context, obj, active, shape, dabs)
        painted = SurfacePoints.concatenate([paint(shape, dabs, local_density(context, obj))[0], single])
        if not len(painted):
            self.report(
                {"ERROR"},
                f"The stroke covered no surface of '{obj.name}' facing the view at "
                f"{settings.brush_density:g} points per cm²: paint more slowly or raise the density",
            )
            return {"CANCELLED"}
        if self.mode == "ADD":
            return self._add(context, obj, active, painted)
        return self._new(context, obj, mesh, painted)

    def _new(self, context, obj, mesh, points):
        settings = context.scene.contact_edit
        method = settings.axis_method if self.axis_method == "SCENE" else self.axis_method
        deformed, base, where = settings.deformed and obj == settings.hand, self.name or "contact", obj.name
        make_axis = default_axis(obj, mesh, points, method, deformed)

        def commit(context, patch):
            obj = mesh_object(context, where)
            contacts = store.load(obj, deformed)
            name = unique_name(contacts, base)
            store.save(obj, contacts.add(name, patch))
            store.set_active(obj, len(store.entries(obj)) - 1)
            self.report(
                {"INFO"},
                f"Painted '{name}' on '{obj.name}': {len(patch)} points, axis of {len(patch.axis)} points",
            )
            return {"FINISHED"}

        label = f"Making a patch of {len(points)} points on '{where}'"
        return Plan(label, lambda: ContactPatch(mesh, points, make_axis()), commit)

    def _add(self, context, obj, active, points):
        contacts, name = active
        patch = contacts[name]
        counterpart = self._counterpart(context, obj, contacts, name)

        def work():
            grown = ContactPatch(contacts.mesh, SurfacePoints.concatenate([patch.points, points]), patch.axis)
            if counterpart is None:
                return grown, None
            _, others, paired = counterpart
            return grown, grown.mirrored_onto(others[paired].axis)

        def commit(context, result):
            grown, follows = result
            carried = self._carry(counterpart, lambda _: follows)
            store.save(obj, contacts.replace(name, grown))
            self.report({"INFO"}, f"Added {len(points)} points to '{name}' (now {len(grown)}){carried}")
            return {"FINISHED"}

        watched = (obj,) if counterpart is None else (obj, counterpart[0])
        return Plan(f"Adding {len(points)} points to '{name}'", work, commit, watched)

    def _subtract(self, context, obj, active, shape, dabs):
        contacts, name = active
        patch = contacts[name]
        keep = erase(shape, patch.points, dabs)
        removed = int((~keep).sum())
        if removed == 0:
            self.report({"WARNING"}, f"The stroke covered none of the points of '{name}'; nothing changed")
            return {"CANCELLED"}
        if removed == len(patch):
            raise ContactError(f"that would take every point of '{name}'; remove the patch instead")
        counterpart = self._counterpart(context, obj, contacts, name)
        carried = self._carry(counterpart, lambda other: other.subset(keep))
        store.save(obj, contacts.replace(name, patch.subset(keep)))
        self.report({"INFO"}, f"Took {removed} points from '{name}' (now {int(keep.sum())}){carried}")
        return {"FINISHED"}

    def _active(self, context, obj):
        settings = context.scene.contact_edit
        contacts = store.load(obj, settings.deformed and obj == settings.hand)
        name = store.active_patch_name(obj)
        if name is None:
            raise ContactError(f"'{obj.name}' has no patch to add to or take from yet")
        if obj == settings.target and settings.hand is not None and name in contacts.pairs:
            raise ContactError(
                f"'{name}' is the transfer of the hand's patch '{contacts.pairs[name]}': paint on the hand "
                "patch and the change is carried over here"
            )
        return contacts, name

    @staticmethod
    def _counterpart(context, obj, contacts, name):
        """``(target object, its contacts, the name of its patch)`` paired with the hand patch ``name``, or
        None when it has none."""
        settings = context.scene.contact_edit
        counterpart = contacts.pairs.get(name)
        target = settings.target
        if obj != settings.hand or counterpart is None or target is None:
            return None
        others = store.load(target)
        return (target, others, counterpart) if counterpart in others else None

    @staticmethod
    def _carry(counterpart, change) -> str:
        """Carry a change of a hand patch over to its ``counterpart`` (:meth:`_counterpart`) on the
        object, which keeps its place: ``change(old patch)`` is the new one. Returns what to add to the
        report."""
        if counterpart is None:
            return ""
        target, others, name = counterpart
        store.save(target, others.replace(name, change(others[name])))
        return f"; its transfer '{name}' on '{target.name}' follows"


classes = (CONTACT_EDIT_PG_stroke_point, CONTACT_EDIT_OT_paint)
