"""What the sessions share: a clean scene with the example hand and mug, places on them, and the
installed extension's own modules."""

import importlib
import json
import time

import bpy
import numpy as np


def addon(module: str):
    """A module of the installed extension, e.g. addon('store')."""
    return importlib.import_module(f"bl_ext.user_default.contact_edit.{module}")


#: The installed extension's Blender-to-numpy bridge (object_to_world, mesh_arrays, trimesh…).
bridge = addon("bridge")


def example(view) -> tuple[bpy.types.Object, bpy.types.Object]:
    """The default scene's cube gone, the Contact Edit example added and framed; (hand, mug)."""
    with view.override():
        cube = bpy.data.objects.get("Cube")
        if cube is not None:
            bpy.data.objects.remove(cube)
        bpy.ops.contact_edit.add_example()
    settings = bpy.context.scene.contact_edit
    return settings.hand, settings.target


def shown_vertices(obj) -> np.ndarray:
    """Object-space vertices of the evaluated (posed) mesh."""
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    co = np.empty(3 * len(evaluated.vertices))
    evaluated.vertices.foreach_get("co", co)
    return co.reshape(-1, 3)


def finger_stroke(hand, view, back: float = 0.025, steps: int = 20) -> list[tuple[float, float]]:
    """Screen points from near the tip of the longest finger back along it by ``back`` metres."""
    co = bridge.mesh_arrays(hand.data)[0]
    tip = co[np.argmax(co[:, 1])]
    ring = co[(np.abs(co[:, 0] - tip[0]) < 0.008) & (np.abs(co[:, 1] - (tip[1] - back)) < 0.003)]
    ends = bridge.object_to_world(hand, [tip + (ring.mean(0) - tip) * 0.15, ring.mean(0)])
    (x0, y0), (x1, y1) = view.project(ends)
    return [(x0 + (x1 - x0) * t, y0 + (y1 - y0) * t) for t in np.linspace(0.0, 1.0, steps)]


def patch_points(obj, name: str, vertices: np.ndarray) -> np.ndarray:
    """World positions of a stored patch's points and of its axis on the given object-space vertices."""
    triangles = bridge.trimesh(obj).faces
    patch = next(p for p in json.loads(obj.contact_edit.data)["patches"] if p["name"] == name)

    def place(points):
        faces, bary = np.asarray(points["faces"]), np.asarray(points["bary"])
        return bridge.object_to_world(obj, np.einsum("kj,kjd->kd", bary, vertices[triangles[faces]]))

    return place(patch["points"]), place(patch["axis"]["points"])


def open_contact_tab(s, view):
    """Open the sidebar (N) and step its tabs with Ctrl+wheel over the tab strip to the Contact tab;
    records the tabs passed as 'categories'. A generator of the session's steps."""
    yield from s.move(*view.centre())
    yield from s.key("n")
    ui = s.region(view, "UI")
    yield from s.move(ui.x + ui.width - 8, view.window.height - (ui.y + ui.height / 2))
    categories = []
    s.xdotool("keydown", "ctrl")
    for _ in range(8):
        categories.append(ui.active_panel_category)
        if ui.active_panel_category == "Contact":
            break
        s.xdotool("click", 5)
        yield 0.4
    s.xdotool("keyup", "ctrl")
    s.record("categories", categories)
    yield from s.move(*view.centre())  # away from the sidebar, which must now redraw by itself


def timed_calls(op) -> list[tuple]:
    """Time every call of the operator class's invoke and modal from now on: (method, seconds, what it
    returned, the stage it left if it has stages)."""
    calls = []
    invoke, modal = op.invoke, op.modal

    def timed(name, method):
        def call(self, context, event):  # Blender checks the arguments a method takes
            began = time.monotonic()
            status = method(self, context, event)
            calls.append((name, time.monotonic() - began, sorted(status), getattr(self, "_stage", ("",))[0]))
            return status

        return call

    op.invoke, op.modal = timed("invoke", invoke), timed("modal", modal)
    return calls
