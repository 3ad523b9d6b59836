"""What the operators share: reporting library errors, picking points with the mouse, directions."""

from __future__ import annotations

import functools
from collections.abc import Callable

import bpy
import numpy as np
from bpy_extras import view3d_utils

from geodesics import ContactError, GeodesicError, MeshError, SurfacePoints, tangent_from_3d
from solver import SolverError

from .. import bridge

#: Events that move the view: the modal tools pass them through to Blender while waiting for a click.
NAVIGATION = {
    "MIDDLEMOUSE", "WHEELUPMOUSE", "WHEELDOWNMOUSE", "TRACKPADPAN", "TRACKPADZOOM", "MOUSEROTATE",
    "NDOF_MOTION", "NUMPAD_1", "NUMPAD_2", "NUMPAD_3", "NUMPAD_4", "NUMPAD_5", "NUMPAD_6", "NUMPAD_7",
    "NUMPAD_8", "NUMPAD_9", "NUMPAD_PERIOD",
}  # fmt: skip
#: Errors the libraries raise for bad input; the operators report them instead of failing.
USER_ERRORS = (ContactError, GeodesicError, MeshError, SolverError, bridge.BridgeError)


def guarded(operator: bpy.types.Operator, action: Callable[[], set]) -> set:
    """Run ``action``; report a library error as an operator error and cancel. Nothing else changes,
    except that a mesh's offending polygons and vertices are selected, to show where it is broken."""
    try:
        return action()
    except USER_ERRORS as err:
        obj = bpy.data.objects.get(getattr(err, "object_name", ""))
        if obj is not None and obj.type == "MESH" and (err.polygons.size or err.vertices.size):
            if obj.mode == "EDIT":
                bpy.ops.object.mode_set(mode="OBJECT")
            bridge.select_elements(obj, err.polygons, err.vertices)
            operator.report({"ERROR"}, f"{err} — the offending elements are selected")
        else:
            operator.report({"ERROR"}, str(err))
        return {"CANCELLED"}


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
    if reason is None and not context.active_object.contact_edit.patches:
        reason = f"'{context.active_object.name}' has no contact patches yet: paint one first"
    return reason


def poll_with(cls, reason: str | None) -> bool:
    """A poll for buttons and menus: False, with the reason as the disabled button's tooltip."""
    if reason is not None:
        cls.poll_message_set(reason)
        return False
    return True


def poll_mesh(cls, context) -> bool:
    return poll_with(cls, need_mesh(context))


def poll_patch(cls, context) -> bool:
    return poll_with(cls, need_patch(context))


class HotkeyTool:
    """For operators that a hotkey starts. When a hotkey's operator cannot run (its poll fails) Blender
    does nothing at all, silently; these leave poll open instead, and their ``invoke`` and ``execute``
    (wrapped here, in every subclass that defines them) report ``why_not(context)`` as an error and
    cancel when it gives a reason."""

    @classmethod
    def poll(cls, context):
        return context.scene is not None

    @staticmethod
    def why_not(context) -> str | None:
        return None

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        for name in ("invoke", "execute"):
            if name in cls.__dict__:
                setattr(cls, name, _checked(cls.__dict__[name]))


def _checked(method):
    """``method`` (``execute(self, context)`` or ``invoke(self, context, event)``: Blender checks the
    argument count) preceded by the ``why_not`` check."""

    def refused(self, context) -> set | None:
        reason = self.why_not(context)
        if reason is None:
            return None
        self.report({"ERROR"}, reason)
        return {"CANCELLED"}

    if method.__code__.co_argcount == 3:

        @functools.wraps(method)
        def invoke(self, context, event):
            return refused(self, context) or method(self, context, event)

        return invoke

    @functools.wraps(method)
    def execute(self, context):
        return refused(self, context) or method(self, context)

    return execute
