"""Viewport overlay: every object's contact patches as coloured points, their axes as lines with a
marker at the start, drawn on the object's current (possibly posed) shape.

Contacts are intrinsic (face and barycentric coordinates), so they are placed on the evaluated mesh each
time; shaders are created on the first draw (they cannot be built in background mode, where nothing is
drawn at all).
"""

from __future__ import annotations

import json

import bpy
import numpy as np

from . import bridge

_handle = None
_preview: dict = {"object": None, "contacts": None}
_parsed: dict[str, tuple] = {}


def preview(obj, contacts) -> None:
    """Show ``contacts`` for ``obj`` instead of its stored ones (during a drag); None to stop."""
    _preview["object"], _preview["contacts"] = (obj.name if obj else None), contacts


def _stored_patches(obj) -> list[tuple]:
    """(name, point faces, point bary, axis faces, axis bary) per patch, parsed once per data change."""
    text = obj.contact_edit.data
    key = f"{obj.name}:{hash(text)}"
    if key not in _parsed:
        patches = json.loads(text).get("patches", []) if text else []
        _parsed[key] = tuple(
            (
                p["name"],
                np.asarray(p["points"]["faces"]),
                np.asarray(p["points"]["bary"]),
                np.asarray(p["axis"]["points"]["faces"]),
                np.asarray(p["axis"]["points"]["bary"]),
            )
            for p in patches
        )
        if len(_parsed) > 64:
            _parsed.pop(next(iter(_parsed)))
    return list(_parsed[key])


def _world_positions(obj, triangles, faces, bary, depsgraph) -> np.ndarray:
    evaluated = obj.evaluated_get(depsgraph).data
    vertices = np.empty(3 * len(evaluated.vertices))
    evaluated.vertices.foreach_get("co", vertices)
    vertices = vertices.reshape(-1, 3)
    if len(vertices) != len(obj.data.vertices):
        vertices = bridge.mesh_arrays(obj.data)[0]  # modifiers change the topology: draw on the rest shape
    local = np.einsum("kj,kjd->kd", bary, vertices[triangles[faces]])
    return bridge.object_to_world(obj, local).astype(np.float32)


def draw() -> None:
    import gpu
    from gpu_extras.batch import batch_for_shader

    context = bpy.context
    depsgraph = context.evaluated_depsgraph_get()
    points_shader = gpu.shader.from_builtin("POINT_UNIFORM_COLOR")
    line_shader = gpu.shader.from_builtin("POLYLINE_UNIFORM_COLOR")
    line_shader.uniform_float("viewportSize", gpu.state.viewport_get()[2:])
    line_shader.uniform_float("lineWidth", 2.0)
    gpu.state.depth_test_set("LESS_EQUAL")
    for obj in context.visible_objects:
        if obj.type != "MESH" or not obj.contact_edit.patches:
            continue
        try:
            triangles = bridge.trimesh(obj).faces
        except bridge.BridgeError:
            continue
        colors = {e.name: tuple(e.color) for e in obj.contact_edit.patches if e.visible}
        if _preview["object"] == obj.name and _preview["contacts"] is not None:
            patches = [
                (n, p.points.faces, p.points.bary, p.axis.points.faces, p.axis.points.bary)
                for n, p in _preview["contacts"].patches.items()
            ]
        else:
            patches = _stored_patches(obj)
        for name, faces, bary, axis_faces, axis_bary in patches:
            if name not in colors:
                continue
            color = colors[name]
            gpu.state.point_size_set(5.0)
            points_shader.uniform_float("color", color)
            where = _world_positions(obj, triangles, faces, bary, depsgraph)
            batch_for_shader(points_shader, "POINTS", {"pos": where}).draw(points_shader)
            axis = _world_positions(obj, triangles, axis_faces, axis_bary, depsgraph)
            line_shader.uniform_float("color", (1.0, 1.0, 1.0, 1.0))
            batch_for_shader(line_shader, "LINE_STRIP", {"pos": axis}).draw(line_shader)
            gpu.state.point_size_set(11.0)
            points_shader.uniform_float("color", (1.0, 1.0, 1.0, 1.0))
            batch_for_shader(points_shader, "POINTS", {"pos": axis[:1]}).draw(points_shader)
    gpu.state.depth_test_set("NONE")
    gpu.state.point_size_set(1.0)


def register() -> None:
    global _handle
    if bpy.app.background:
        return
    _handle = bpy.types.SpaceView3D.draw_handler_add(draw, (), "WINDOW", "POST_VIEW")


def unregister() -> None:
    global _handle
    if _handle is not None:
        bpy.types.SpaceView3D.draw_handler_remove(_handle, "WINDOW")
        _handle = None
    _parsed.clear()
    preview(None, None)
