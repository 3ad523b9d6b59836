"""What the operators share: polls that say why not, reporting library errors, picking points with the
mouse, directions."""

from __future__ import annotations

import functools

import bpy
import numpy as np
from bpy_extras import view3d_utils

from geodesics import (
    ContactError,
    GeodesicError,
    MeshError,
    SurfacePoints,
    directed_axis,
    farthest_pair_axis,
    medial_axis,
    tangent_from_3d,
)
from solver import SolverError
from tangible import TangibleError

from .. import bridge, store

#: Events that move the view: the modal tools pass them through to Blender while waiting for a click.
NAVIGATION = {
    "MIDDLEMOUSE", "WHEELUPMOUSE", "WHEELDOWNMOUSE", "TRACKPADPAN", "TRACKPADZOOM", "MOUSEROTATE",
    "NDOF_MOTION", "NUMPAD_1", "NUMPAD_2", "NUMPAD_3", "NUMPAD_4", "NUMPAD_5", "NUMPAD_6", "NUMPAD_7",
    "NUMPAD_8", "NUMPAD_9", "NUMPAD_PERIOD",
}  # fmt: skip
#: Errors the libraries raise for bad input (and the device for a bad port or a broken link); the operators
#: report them instead of failing.
USER_ERRORS = (ContactError, GeodesicError, MeshError, SolverError, TangibleError, bridge.BridgeError)


def guarded(method=None, *, capitalised: bool = False):
    """``method`` (an operator's ``execute`` or ``invoke``) reporting a library or device error as an
    operator error (its first letter capitalised, with ``@guarded(capitalised=True)``) and cancelling.
    Nothing else changes, except that a mesh's offending polygons and vertices are selected, to show
    where it is broken."""
    if method is None:
        return functools.partial(guarded, capitalised=capitalised)

    def run(self, context, *event) -> set:
        try:
            return method(self, context, *event)
        except USER_ERRORS as err:
            message = str(err)
            if capitalised:
                message = message[:1].upper() + message[1:]
            obj = bpy.data.objects.get(getattr(err, "object_name", ""))
            if obj is not None and obj.type == "MESH" and (err.polygons.size or err.vertices.size):
                if obj.mode == "EDIT":
                    bpy.ops.object.mode_set(mode="OBJECT")
                bridge.select_elements(obj, err.polygons, err.vertices)
                message += " — the offending elements are selected"
            self.report({"ERROR"}, message)
            return {"CANCELLED"}

    return _as_method(method, run)


def unique_name(existing, base: str) -> str:
    if base not in existing:
        return base
    i = 1
    while f"{base}.{i:03d}" in existing:
        i += 1
    return f"{base}.{i:03d}"


def mesh_object(context, name: str | None = None):
    """The named mesh object, or the active one."""
    obj = bpy.data.objects.get(name) if name else context.active_object
    if obj is None or obj.type != "MESH":
        raise bridge.BridgeError(f"'{name or getattr(obj, 'name', 'nothing')}' is not a mesh object")
    return obj


def nearest_point(obj, mesh, world_location) -> SurfacePoints:
    """The surface point of ``obj`` closest to a world-space location."""
    return SurfacePoints.nearest(mesh, bridge.world_to_object(obj, world_location))


def surface_direction(obj, mesh, point: SurfacePoints, world_direction) -> complex:
    """A world-space direction as a unit tangent vector (complex) in the point's basis."""
    M = np.array(obj.matrix_world.inverted())[:3, :3]
    local = M @ np.asarray(world_direction, np.float64)
    z = tangent_from_3d(mesh, point, local[None])[0]
    if abs(z) < 1e-12:
        raise ContactError("the direction is perpendicular to the surface there; pick one along it")
    return z / abs(z)


def default_axis(obj, mesh, points: SurfacePoints, method: str, deformed: bool):
    """The work that lays the default axis of ``points`` on ``obj``'s ``mesh`` by ``method`` (one of
    :data:`~..properties.DEFAULT_AXES`), to run off the main thread: what it needs of Blender (the bone
    under the patch) is read now."""
    if method == "MEDIAL":
        return lambda: medial_axis(mesh, points)
    direction = bridge.bone_direction(obj, mesh.faces, points, deformed) if method == "BONE" else None
    if direction is None:
        return lambda: farthest_pair_axis(mesh, points)
    return lambda: directed_axis(mesh, points, direction)


def ray_hit(context, event, obj):
    """Where the mouse ray meets ``obj``: (world location, polygon index) or None."""
    region, rv3d = context.region, context.region_data
    if region is None or rv3d is None:
        return None
    coord = (event.mouse_region_x, event.mouse_region_y)
    origin = view3d_utils.region_2d_to_origin_3d(region, rv3d, coord)
    direction = view3d_utils.region_2d_to_vector_3d(region, rv3d, coord)
    inverse = obj.matrix_world.inverted()
    local_origin = inverse @ origin
    local_direction = (inverse.to_3x3() @ direction).normalized()
    hit, location, _normal, polygon = obj.ray_cast(local_origin, local_direction)
    if not hit:
        return None
    return np.array(obj.matrix_world @ location), polygon


def need_mesh(context) -> str | None:
    """Why a tool that works on the active mesh cannot run now (None: it can)."""
    obj = context.active_object
    if obj is None or obj.type != "MESH":
        return "Select a mesh object (the hand or the object) first"
    return None


def need_hand_and_object(context) -> str | None:
    settings = context.scene.contact_edit
    if settings.hand is None or settings.target is None:
        return "Choose the hand and the object in the Contact tab first (or add the example)"
    return None


def need_patch(context) -> str | None:
    reason = need_mesh(context)
    obj = context.active_object
    if reason is None and not store.entries(obj):
        what = "annotation curves or markers" if obj.contact_edit.layer == "ANNOTATION" else "contact patches"
        reason = f"'{obj.name}' has no {what} yet: paint one first"
    return reason


class ExplainedPoll:
    """For operators that cannot always run: ``why_not(context)`` says why not (None: they can). Their
    poll fails then, and Blender shows the reason as the disabled button's tooltip (and raises it, to a
    script that calls them)."""

    @staticmethod
    def why_not(context) -> str | None:
        return None

    @classmethod
    def poll(cls, context):
        reason = cls.why_not(context)
        if reason is not None:
            cls.poll_message_set(reason)
            return False
        return True


#: The ``keyframe`` property of the tools that pose the hand (Solve, Flex, Wrap, Mirror Pose).
KEYFRAME = dict(
    name="Keyframe",
    description="Key the pose on the current frame. Left unset (by a hotkey, a button, a script that does "
    "not say), the Pose panel's Key toggle decides, or Blender's auto-keying when it is on",
    options={"SKIP_SAVE"},
)


def key_frame(operator, context) -> int | None:
    """The frame a pose tool keys its pose on, or None: the operator's ``keyframe`` where it was set (a
    script, the Adjust Last Operation panel), else the scene's Key toggle or Blender's auto-keying, so that
    every way of starting the tool keys alike."""
    scene = context.scene
    if operator.properties.is_property_set("keyframe"):
        on = operator.keyframe
    else:
        on = scene.contact_edit.keyframe or scene.tool_settings.use_keyframe_insert_auto
    return scene.frame_current if on else None


def keyed(frame: int | None, what: str = "the pose") -> str:
    """What a report adds when a pose tool keyed (nothing when it did not)."""
    return "" if frame is None else f"; keyed {what} on frame {frame}"


class HotkeyTool(ExplainedPoll):
    """For operators that a hotkey starts. When a hotkey's operator cannot run (its poll fails) Blender
    does nothing at all, silently; these leave poll open instead, and their ``invoke`` and ``execute``
    (wrapped here, in every subclass that defines them) report ``why_not(context)`` as an error and
    cancel when it gives a reason."""

    @classmethod
    def poll(cls, context):
        return context.scene is not None

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        for name in ("invoke", "execute"):
            if name in cls.__dict__:
                setattr(cls, name, _checked(cls.__dict__[name]))


def _checked(method):
    """``method`` preceded by the ``why_not`` check."""

    def run(self, context, *event) -> set:
        reason = self.why_not(context)
        if reason is not None:
            self.report({"ERROR"}, reason)
            return {"CANCELLED"}
        return method(self, context, *event)

    return _as_method(method, run)


def _as_method(method, run):
    """``run(self, context, *event)`` as an operator method in place of ``method``: ``execute(self,
    context)`` or ``invoke(self, context, event)``, as ``method`` is (Blender checks the argument count)."""
    if method.__code__.co_argcount == 3:

        @functools.wraps(method)
        def invoke(self, context, event):
            return run(self, context, event)

        return invoke

    @functools.wraps(method)
    def execute(self, context):
        return run(self, context)

    return execute
