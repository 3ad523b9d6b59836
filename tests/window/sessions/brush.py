"""The area brush and the overlay in a real window: the circle and F to resize it, a stroke, Shift to add
and Ctrl to take away; then where the patch is drawn (Object Mode, posed, and on the edit cage)."""

import time

import bpy
import numpy as np
from common import (
    addon,
    bridge,
    example,
    finger_stroke,
    open_contact_tab,
    patch_points,
    shown_vertices,
)
from mathutils import Euler, Vector

#: Seconds the default axis is made to take, holding the GIL as the geodesics do, so that the stroke's
#: work certainly outlasts the checks made while it runs (on any machine).
SLOW_AXIS = 2.0


def slowed(function):
    """``function`` taking :data:`SLOW_AXIS` seconds longer."""

    def slow(*args):
        end = time.monotonic() + SLOW_AXIS
        while time.monotonic() < end:
            sum(range(1000))
        return function(*args)

    return slow


def patches(hand):
    return [(e.name, e.points) for e in hand.contact_edit.patches]


def until(done, timeout: float = 60.0):
    """Wait (at most ``timeout`` seconds) until ``done()``, recording the event loop's heartbeat
    meanwhile: timer callbacks every 20 ms, which a blocked main thread would hold back."""
    beats = [time.monotonic()]

    def beat():
        beats.append(time.monotonic())
        return 0.02

    bpy.app.timers.register(beat)
    began = time.monotonic()
    while not done() and time.monotonic() - began < timeout:
        yield 0.05
    bpy.app.timers.unregister(beat)
    longest = float(np.diff(beats).max(initial=0.0))
    return {"seconds": time.monotonic() - began, "beats": len(beats), "longest_gap": longest}


def project_patch(s, view, hand, name, vertices):
    """Screen points of the patch drawn on ``vertices``, which of them the view sees, and its axis."""
    points, axis = patch_points(hand, name, vertices)
    return {
        "xy": view.project(points),
        "visible": view.visible(points, tolerance=5e-4),
        "axis": view.project(axis),
    }


def steps(s):
    view = s.view3d()
    hand, _ = example(view)
    hand.parent.hide_set(True)  # its bones would hide parts of the patch from the view (and the test)
    co = bridge.mesh_arrays(hand.data)[0]
    tip = bridge.object_to_world(hand, co[np.argmax(co[:, 1])])[0]
    view.rv3d.view_location = Vector(tip - [0.0, 0.02, 0.0])
    view.rv3d.view_distance = 0.12
    yield 0.5
    yield from open_contact_tab(s, view)
    ui = s.region(view, "UI")
    s.record("sidebar", [ui.x, view.window.height - ui.y - ui.height, ui.width, ui.height])
    yield 0.3
    path = finger_stroke(hand, view)
    s.record("stroke", path)
    yield from s.move(*path[0])
    yield from s.key("ctrl+shift+p")
    yield from s.move(path[0][0] + 2, path[0][1])
    settings = bpy.context.scene.contact_edit
    s.record("radius_before", settings.brush_radius)
    yield from s.shot("brush_circle")
    yield from s.key("f")
    yield from s.move(path[0][0] + 30, path[0][1])
    yield from s.shot("brush_resize")
    s.xdotool("click", 1)
    yield 0.4
    s.record("radius_after", settings.brush_radius)
    yield from s.move(path[0][0] + 4, path[0][1])
    yield from s.shot("brush_after_resize")  # the brush's keys still in the header (issue 37)
    settings.brush_radius = 25

    # The stroke's patch is made off the main thread: Blender keeps drawing and taking input meanwhile,
    # the header says what is being made, and Esc stops it with nothing changed.
    ops, axes = addon("operators.paint"), addon("operators.common")  # common lays the default axis
    originals = axes.farthest_pair_axis, axes.medial_axis
    axes.farthest_pair_axis, axes.medial_axis = (slowed(f) for f in originals)
    yield from s.drag(path)
    yield from s.shot("working", settle=0.3)
    yield from s.key("Escape", settle=0.3)
    yield from until(lambda: patches(hand), timeout=SLOW_AXIS + 1.0)  # nothing comes: it was stopped
    s.record("stopped", {"patches": patches(hand), "reports": s.reports()[-1:]})
    yield from s.move(*path[0])
    yield from s.key("ctrl+shift+p")
    yield from s.drag(path)
    s.record("while_working", len(hand.contact_edit.patches))
    s.record("wait", (yield from until(lambda: patches(hand))))
    s.record("last_operator", bpy.context.window_manager.operators[-1].bl_idname)
    axes.farthest_pair_axis, axes.medial_axis = originals
    s.record("painted", patches(hand))
    yield from s.shot("stroke")

    yield from s.shot("sidebar_after_stroke")  # the mouse is still on the hand: nothing hovered the list

    # Shift adds beside it; if the patch changes while that is worked out, nothing is stored.
    side = [(x + 30, y + 30) for x, y in path]
    painted = patches(hand)
    original = ops.ContactPatch
    ops.ContactPatch = slowed(original)
    yield from s.move(*side[0])
    yield from s.key("ctrl+shift+p")
    yield from s.drag(side, modifiers=("shift",))
    points, _ = patch_points(hand, painted[0][0], shown_vertices(hand))
    with view.override():  # another axis, from one of its points to another
        bpy.ops.contact_edit.axis(method="POINTS", object_name=hand.name, start=points[0], end=points[-1])
    yield from until(lambda: False, timeout=SLOW_AXIS + 2.0)  # the addition's work ends meanwhile
    s.record("stale", {"patches": patches(hand), "painted": painted, "reports": s.reports()[-1:]})
    ops.ContactPatch = original
    yield from s.move(*side[0])
    yield from s.key("ctrl+shift+p")
    yield from s.drag(side, modifiers=("shift",))
    yield from until(lambda: patches(hand) != painted)
    s.record("added", patches(hand))
    # Ctrl takes a band away across it.
    middle = path[len(path) // 2]
    across = [(middle[0] - 40 + 4 * i, middle[1] + 40 - 4 * i) for i in range(21)]
    yield from s.move(*across[0])
    yield from s.key("ctrl+shift+p")
    yield from s.drag(across, modifiers=("ctrl",))
    s.record("subtracted", [(e.name, e.points) for e in hand.contact_edit.patches])
    name = hand.contact_edit.patches[0].name
    s.record("color", list(hand.contact_edit.patches[0].color))

    # Where the overlay draws it: shown, hidden (the control), posed, and on the edit cage.
    s.record("overlay", project_patch(s, view, hand, name, shown_vertices(hand)))
    yield from s.shot("overlay")
    hand.contact_edit.patches[0].visible = False
    yield from s.shot("overlay_hidden")
    hand.contact_edit.patches[0].visible = True
    armature = hand.parent
    for bone in ("middle_2", "middle_3"):  # the stroke's finger curls a little, staying in view
        armature.pose.bones[bone].rotation_mode = "XYZ"
        armature.pose.bones[bone].rotation_euler = Euler((0.3, 0.0, 0.0))
    bpy.context.view_layer.update()
    s.record("posed", project_patch(s, view, hand, name, shown_vertices(hand)))
    yield from s.shot("posed")
    with view.override():
        bpy.context.view_layer.objects.active = hand
        bpy.ops.object.mode_set(mode="EDIT")
        bpy.ops.mesh.select_all(action="DESELECT")  # selected vertices are orange too
    yield 0.3
    s.record("cage", project_patch(s, view, hand, name, bridge.mesh_arrays(hand.data)[0]))
    yield from s.shot("edit_mode")
    with view.override():
        bpy.ops.object.mode_set(mode="OBJECT")

    # A round pad (one click of the brush) with its axis laid along the bone: along the finger, where a
    # round patch's farthest points lie anywhere around its rim (issue 37).
    for bone in ("middle_2", "middle_3"):
        armature.pose.bones[bone].rotation_euler = Euler((0.0, 0.0, 0.0))
    settings.axis_method = "BONE"
    count = len(hand.contact_edit.patches)
    spot = path[len(path) // 4]
    yield from s.move(*spot)
    yield from s.key("ctrl+shift+p")
    yield from s.drag([spot, spot])
    yield from until(lambda: len(hand.contact_edit.patches) > count)
    round_pad = hand.contact_edit.patches[-1].name
    points, axis = patch_points(hand, round_pad, shown_vertices(hand))
    bone = np.array(armature.matrix_world) @ np.array(armature.data.bones["middle_3"].matrix_local)
    s.record("bone_axis", {"axis": axis.tolist(), "finger": bone[:3, 1].tolist(), "points": points.tolist()})
    yield from s.shot("bone_axis")
    s.record("reports", s.reports())
