"""Viewport overlay: every object's contact patches as coloured points, their axes as outlined lines
from a large white start marker to a small dark end marker, a live preview while a tool runs, and the
brush circle while painting.

Contacts are intrinsic (face and barycentric coordinates), so each draw places them on the shape the
viewport shows: the evaluated (posed) mesh in Object and Pose Mode, the edit cage in Edit Mode. Points
and lines are lifted off the surface along its normal by a few pixels' worth of distance, so they
neither sink into it nor z-fight with it at any zoom. Shaders are chosen by what the running Blender
offers (round ``POINT_UNIFORM_COLOR`` points from 4.5 on, ``UNIFORM_COLOR`` before) and built on the
first draw (background mode draws nothing and registers no handler).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

import bmesh
import bpy
import numpy as np

from .. import bridge, store

#: Screen pixels the overlay floats above the surface: points lowest, the axis over them, its markers on top.
POINT_LIFT, AXIS_LIFT, MARKER_LIFT = 1.5, 3.0, 4.5
POINT_SIZE = 4.0
START_SIZE, START_RIM = 13.0, 17.0
END_SIZE = 8.0
AXIS_WIDTH, AXIS_RIM = 2.0, 4.5
WHITE, DARK = (1.0, 1.0, 1.0, 1.0), (0.05, 0.05, 0.05, 1.0)


@dataclass
class Preview:
    """What to show for one object instead of its stored patches while a tool runs (a drag, a transfer
    being placed, a brush stroke): another contact set (None: the stored one), colours for patches the
    object has no entry for, patches to hide, and loose points (SurfacePoints, colour) to add."""

    contacts: object = None
    colors: dict = field(default_factory=dict)
    hidden: frozenset = frozenset()
    loose: tuple = ()


@dataclass
class Brush:
    """The brush circle: region pixels of its centre, radius in pixels, and its mode's colour."""

    region: object
    centre: tuple[float, float]
    radius: float
    color: tuple


_handles: list = []
_previews: dict[str, Preview] = {}
_brush: list[Brush | None] = [None]
_parsed: dict[str, tuple] = {}
_shaders: dict = {}


def preview(obj, contacts=None, colors: dict | None = None, hidden=(), loose=()) -> None:
    """Show a :class:`Preview` for ``obj`` (see there); ``preview(obj)`` shows its stored patches again
    and ``preview(None)`` stops every preview."""
    if obj is None:
        _previews.clear()
    elif contacts is None and not hidden and not loose:
        _previews.pop(obj.name, None)
    else:
        _previews[obj.name] = Preview(contacts, dict(colors or {}), frozenset(hidden), tuple(loose))


def brush(cursor: Brush | None) -> None:
    """Show the brush circle (None hides it)."""
    _brush[0] = cursor


def shaders() -> dict:
    """The built-in shaders this Blender offers for points, wide lines and 2D lines."""
    if not _shaders:
        import gpu

        try:  # Blender 4.5+: round points of a given size, on every GPU backend
            points, sized = gpu.shader.from_builtin("POINT_UNIFORM_COLOR"), True
        except ValueError:  # 4.2-4.4: square points sized by the GPU state
            points, sized = gpu.shader.from_builtin("UNIFORM_COLOR"), False
        lines = gpu.shader.from_builtin("POLYLINE_UNIFORM_COLOR")
        _shaders.update(points=points, sized=sized, lines=lines)
    return _shaders


def _stored_patches(obj) -> list[tuple]:
    """(name, point faces, point bary, axis faces, axis bary) per patch, parsed once per data change."""
    text = store.text(obj)
    key = f"{obj.name}:{hash(text)}"
    if key not in _parsed:
        patches = json.loads(text).get("patches", []) if text else []
        _parsed[key] = tuple(
            (
                p["name"],
                np.asarray(p["points"]["faces"], np.int64),
                np.asarray(p["points"]["bary"], np.float64),
                np.asarray(p["axis"]["points"]["faces"], np.int64),
                np.asarray(p["axis"]["points"]["bary"], np.float64),
            )
            for p in patches
        )
        if len(_parsed) > 64:
            _parsed.pop(next(iter(_parsed)))
    return list(_parsed[key])


def _patches(obj) -> tuple[list[tuple], dict, tuple]:
    """What to draw for ``obj``: its patches (stored, or a preview's), their colours, and loose points."""
    colors = {e.name: tuple(e.color) for e in store.entries(obj)}
    hidden = {e.name for e in store.entries(obj) if not e.visible}
    shown = _previews.get(obj.name, Preview())
    if shown.contacts is None:
        patches = _stored_patches(obj)
    else:
        patches = [
            (n, p.points.faces, p.points.bary, p.axis.points.faces, p.axis.points.bary)
            for n, p in shown.contacts.patches.items()
        ]
    colors = {**shown.colors, **colors}
    hidden |= shown.hidden
    return [p for p in patches if p[0] not in hidden and p[0] in colors], colors, shown.loose


def shown_vertices(obj, depsgraph) -> np.ndarray | None:
    """(n, 3) object-space vertex positions of the shape the viewport shows for ``obj``: the edit cage in
    Edit Mode, else the evaluated mesh's (its first n when a Subdivision Surface after the armature
    refines it; the rest shape if other modifiers change the vertex count); None if the mesh being
    edited no longer has the vertices its contacts were made on."""
    count = len(obj.data.vertices)
    if obj.mode == "EDIT":
        edited = bmesh.from_edit_mesh(obj.data)
        if len(edited.verts) != count:
            return None
        return np.fromiter((c for v in edited.verts for c in v.co), np.float64, 3 * count).reshape(-1, 3)
    evaluated = obj.evaluated_get(depsgraph).data
    if len(evaluated.vertices) != count and not _keeps_vertices_first(obj):
        return bridge.mesh_arrays(obj.data)[0]
    vertices = np.empty(3 * len(evaluated.vertices))
    evaluated.vertices.foreach_get("co", vertices)
    return vertices.reshape(-1, 3)[:count]


#: Modifiers whose result starts with the mesh's own vertices, in order (a Subdivision Surface puts each
#: at its place on the smooth surface), so that the mesh's faces drawn on them follow what is shown.
_VERTICES_FIRST = {"SUBSURF", "TRIANGULATE", "MIRROR", "WEIGHTED_NORMAL"}


def _keeps_vertices_first(obj) -> bool:
    """Whether the modifiers that make ``obj``'s evaluated mesh bigger than its own all keep its own
    vertices first: every modifier shown after its Armature modifier is one of :data:`_VERTICES_FIRST`
    (and there is one)."""
    later = bridge.after_armature(obj)
    return bool(later) and all(m.type in _VERTICES_FIRST for m in later)


def placer(obj, vertices, triangles, view):
    """A function (faces, bary, pixels) -> world positions of those surface points of ``obj`` on
    ``vertices``, raised along their faces' normals by ``pixels`` of screen; the object's matrices are
    worked out once for all its patches."""
    M = np.array(obj.matrix_world)
    to_normals = np.linalg.inv(M[:3, :3])  # normals transform by the inverse transpose

    def place(faces, bary, pixels: float) -> np.ndarray:
        corners = vertices[triangles[faces]]
        world = np.einsum("kj,kjd->kd", bary, corners) @ M[:3, :3].T + M[:3, 3]
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]) @ to_normals
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
        return (world + normals * pixel_size(world, view)[:, None] * pixels).astype(np.float32)

    return place


def pixel_size(world, view) -> np.ndarray:
    """(k,) the world length one screen pixel spans at each point's depth."""
    P, width = view
    w = np.abs(np.c_[world, np.ones(len(world))] @ P[3])
    return 2.0 * np.maximum(w, 1e-9) / (width * np.linalg.norm(P[0, :3]))


def draw_view() -> None:
    """The 3D part: patches, axes and previews on every visible mesh object that has contacts."""
    import gpu
    from gpu_extras.batch import batch_for_shader

    context = bpy.context
    region = context.region
    view = (np.array(context.region_data.perspective_matrix), float(region.width))
    depsgraph = context.evaluated_depsgraph_get()
    shader = shaders()
    points_shader, line_shader = shader["points"], shader["lines"]
    line_shader.uniform_float("viewportSize", (region.width, region.height))

    def points(where, size, color):
        if shader["sized"]:
            points_shader.uniform_float("size", size)
        gpu.state.point_size_set(size)  # what OpenGL uses unless Blender lets the shader size points
        points_shader.uniform_float("color", color)
        batch_for_shader(points_shader, "POINTS", {"pos": where}).draw(points_shader)

    def line(where, width, color):
        line_shader.uniform_float("lineWidth", width)
        line_shader.uniform_float("color", color)
        batch_for_shader(line_shader, "LINE_STRIP", {"pos": where}).draw(line_shader)

    gpu.state.depth_test_set("LESS_EQUAL")
    gpu.state.blend_set("ALPHA")
    for obj in context.visible_objects:
        if obj.type != "MESH" or not (store.entries(obj) or obj.name in _previews):
            continue
        try:
            triangles = bridge.trimesh(obj).faces
        except bridge.BridgeError:
            continue
        vertices = shown_vertices(obj, depsgraph)
        if vertices is None:
            continue
        patches, colors, loose = _patches(obj)
        place = placer(obj, vertices, triangles, view)
        for points_of, color in loose:
            points(place(points_of.faces, points_of.bary, POINT_LIFT), POINT_SIZE, color)
        for name, faces, bary, axis_faces, axis_bary in patches:
            points(place(faces, bary, POINT_LIFT), POINT_SIZE, colors[name])
            axis = place(axis_faces, axis_bary, AXIS_LIFT)
            line(axis, AXIS_RIM, DARK)
            line(axis, AXIS_WIDTH, WHITE)
            ends = place(axis_faces[[0, -1]], axis_bary[[0, -1]], MARKER_LIFT)
            points(ends[1:], END_SIZE + 3.0, WHITE)
            points(ends[1:], END_SIZE, DARK)
            points(ends[:1], START_RIM, DARK)
            points(ends[:1], START_SIZE, WHITE)
    gpu.state.blend_set("NONE")
    gpu.state.depth_test_set("NONE")
    gpu.state.point_size_set(1.0)


def draw_pixel() -> None:
    """The 2D part: the brush circle, in the region it was opened in."""
    cursor = _brush[0]
    if cursor is None or bpy.context.region != cursor.region:
        return
    from gpu_extras.batch import batch_for_shader

    shader = shaders()["lines"]
    angle = np.linspace(0.0, 2.0 * math.pi, 65)
    x, y = cursor.centre
    ring = np.c_[x + cursor.radius * np.cos(angle), y + cursor.radius * np.sin(angle), np.zeros(65)]
    shader.uniform_float("viewportSize", (bpy.context.region.width, bpy.context.region.height))
    for width, color in ((3.5, DARK), (1.5, cursor.color)):
        shader.uniform_float("lineWidth", width)
        shader.uniform_float("color", color)
        batch_for_shader(shader, "LINE_STRIP", {"pos": ring.astype(np.float32)}).draw(shader)


def register() -> None:
    if bpy.app.background:
        return
    space = bpy.types.SpaceView3D
    _handles.append(space.draw_handler_add(draw_view, (), "WINDOW", "POST_VIEW"))
    _handles.append(space.draw_handler_add(draw_pixel, (), "WINDOW", "POST_PIXEL"))


def unregister() -> None:
    for handle in _handles:
        bpy.types.SpaceView3D.draw_handler_remove(handle, "WINDOW")
    _handles.clear()
    _parsed.clear()
    _shaders.clear()
    _previews.clear()
    brush(None)
