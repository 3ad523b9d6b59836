"""Transferring with the live preview, then solving with progress, Esc (keep the best pose) and
right-click (put the start pose back), in a real window."""

import threading
import time

import bpy
import numpy as np
from common import addon, bridge, example, open_contact_tab
from mathutils import Vector


class timed:
    """``module.name`` replaced by itself, timed: the (start, end) monotonic seconds of each call; put
    it back with ``module.name = timed(...).function``."""

    def __init__(self, module, name: str):
        self.function, self.calls = getattr(module, name), []

        def call(*args, **kwargs):
            start = time.monotonic()
            try:
                return self.function(*args, **kwargs)
            finally:
                self.calls.append((start, time.monotonic()))

        setattr(module, name, call)


def select_palm_side(hand, reach: float, width: float = 1.0) -> None:
    """The palm side of the fingers within ``reach`` metres of the longest finger's tip (and ``width``
    of it across), as the paint-from-selection tool takes them."""
    co = bridge.mesh_arrays(hand.data)[0]
    tip = co[np.argmax(co[:, 1])]
    pads = (
        (co[:, 1] > tip[1] - reach) & (np.abs(co[:, 0] - tip[0]) < width) & (co[:, 2] < np.median(co[:, 2]))
    )
    hand.data.vertices.foreach_set("select", pads)


class _Mouse:
    """A mouse event at screen pixels (x, y), as ray_hit reads it."""

    def __init__(self, view, x, y):
        self.mouse_region_x = x - view.region.x
        self.mouse_region_y = view.window.height - y - view.region.y


def steps(s):
    view = s.view3d()
    hand, mug = example(view)
    with view.override():
        bpy.context.view_layer.objects.active = hand
        select_palm_side(hand, 0.02, width=0.01)
        bpy.ops.contact_edit.paint(name="tip", source="SELECTION")
    s.record("hand_patches", [(e.name, e.points) for e in hand.contact_edit.patches])
    # Look at the mug's side facing away from the hand, and place the transfer there with the mouse.
    centre = bridge.object_to_world(mug, bridge.mesh_arrays(mug.data)[0].mean(0))[0]
    view.rv3d.view_location = Vector(centre)
    view.rv3d.view_distance = 0.3
    yield 0.4
    x, y = view.project([centre])[0] + [25.0, 0.0]  # on the mug's wall facing the view
    with view.override():
        hit = addon("operators.common").ray_hit(bpy.context, _Mouse(view, x, y), mug)
    side = hit[0]
    yield from s.move(x, y)
    s.record("mug_box", view.project([mug.matrix_world @ Vector(corner) for corner in mug.bound_box]))
    yield from s.shot("transfer_before")
    yield from s.key("shift+alt+t")
    yield from s.move(x + 3, y)
    yield 0.5
    yield from s.shot("transfer_hover")
    s.record("mug_before", [e.name for e in mug.contact_edit.patches])
    yield from s.drag([(x + 3 + i, y - 2 * i) for i in range(0, 30, 3)])
    yield 0.3
    s.record("mug_after", [(e.name, e.points) for e in mug.contact_edit.patches])
    s.record("paired", [(e.name, e.pair) for e in hand.contact_edit.patches])
    yield from s.shot("transferred")

    # Move's hotkey with the hand active, aimed at the mug's copy well away from its axis start: the copy
    # moves, not the hand's patch, and keeps its offset from the point held (it does not jump).
    store, common = addon("store"), addon("operators.common")
    name = mug.contact_edit.patches[0].name

    def axis_start(obj):
        contacts = store.load(obj)
        return bridge.object_to_world(obj, contacts[name].axis.points[0:1].positions(contacts.mesh))[0]

    def on_mug(x, y):
        with view.override():
            hit = common.ray_hit(bpy.context, _Mouse(view, x, y), mug)
        return None if hit is None else hit[0]

    def held_on_a_smooth_part(k) -> bool:
        """Whether patch point k shows under its pixel, and the drag's pixels stay on the same part of
        the mug (not across the handle's edge to the wall behind it)."""
        x, y = view.project([points[k]])[0]
        hits = [on_mug(x - 2 * i, y - i) for i in range(5)]
        return all(h is not None for h in hits) and (
            np.linalg.norm(hits[0] - points[k]) < 1.5e-3 and np.linalg.norm(hits[-1] - hits[0]) < 5e-3
        )

    start = axis_start(mug)
    points = bridge.object_to_world(mug, store.load(mug)[name].positions())
    away = np.linalg.norm(points - start, axis=1)
    k = next(k for k in np.argsort(np.abs(away - 0.6 * away.max())) if held_on_a_smooth_part(k))
    gx, gy = view.project([points[k]])[0]
    hand_patches = hand.contact_edit.data
    yield from s.move(gx, gy)
    grabbed = on_mug(gx, gy)
    yield from s.key("shift+alt+m")
    for i in range(1, 5):
        yield from s.move(gx - 2 * i, gy - i, settle=0.1)
    released = on_mug(gx - 8, gy - 4)
    yield from s.shot("moving")
    s.xdotool("click", "1")
    yield 0.4
    s.record("move", {
        "cursor_moved": float(np.linalg.norm(released - grabbed)),
        "start_moved": float(np.linalg.norm(axis_start(mug) - start)),
        "start_from_cursor": float(np.linalg.norm(axis_start(mug) - released)),
        "held_from_start": float(np.linalg.norm(grabbed - start)), "patch_length": float(away.max()),
        "hand_unchanged": hand.contact_edit.data == hand_patches,
        "active": bpy.context.view_layer.objects.active.name, "hand": hand.name,
        "mug_active_patch": store.active_patch_name(mug),
    })  # fmt: skip
    yield from s.shot("moved")

    # Solve: the pose improves on screen; Esc stops and keeps the best pose. The patches are big and the
    # hand starts turned away from the mug, so that the solve takes long enough to be stopped.
    hand.select_set(True)
    bpy.context.view_layer.objects.active = hand
    with view.override():
        select_palm_side(hand, 0.2)  # the whole palm side
        bpy.ops.contact_edit.paint(name="fingers", source="SELECTION")
        bpy.ops.contact_edit.transfer(patch="fingers", location=side, direction=(0.0, 0.0, 1.0))
    armature = hand.parent
    posing = addon("posing")
    root = armature.pose.bones[0]
    root.rotation_mode = "XYZ"
    view.rv3d.view_distance = 0.45
    yield from s.move(*view.centre())

    def pose():
        return {b.name: tuple(b.rotation_quaternion) + tuple(b.rotation_euler) for b in armature.pose.bones}

    started = []

    def solving() -> bool:
        return any(t.name == "contact-edit solve" for t in threading.enumerate())

    def solve_from_afar(then=None):
        """Turn the hand away and start the solve with its hotkey; wait for the first better pose drawn,
        or, with ``then`` (xdotool input), send it as soon as the solve's thread runs and wait for the
        solve to end (it takes about a second here; a software-rendered frame, which input waits for,
        takes a few tenths)."""
        root.location, root.rotation_euler = (0.06, -0.08, 0.05), (1.1, -0.9, 1.3)
        bpy.context.view_layer.update()
        started.append(pose())
        posed, began = root.rotation_euler[:], time.monotonic()
        planned = timed(posing, "problem")
        yield from s.key("ctrl+shift+e", settle=0.0)
        while not solving() and time.monotonic() - began < 10:
            yield 0.01
        if then is None:
            while root.rotation_euler[:] == posed and time.monotonic() - began < 10:
                yield 0.01
            now = time.monotonic()
            posing.problem = planned.function
            s.record("first_pose_after", now - began)
            (start, end), *_ = planned.calls
            # Where the time went: the key reaching the operator, its plan on the main thread, and the
            # first evaluation in the worker until the redraw tick applies its pose and the poll sees it.
            s.record("first_pose_parts", {"input": start - began, "plan": end - start, "first": now - end})
            return
        sent = time.monotonic()
        s.xdotool(*then)
        while solving() and time.monotonic() - sent < 10:
            yield 0.01
        s.record(f"{then[-1]}_took", time.monotonic() - sent)
        yield 0.3

    # The progress in the header, as the solve runs to its end.
    yield from solve_from_afar()
    yield from s.shot("solving", settle=0.05)
    while "evaluations in" not in bpy.context.scene.contact_edit.last_solve:
        yield 0.1
    s.record("finished", bpy.context.scene.contact_edit.last_solve)

    # Esc: it stops and keeps the best pose so far.
    yield from solve_from_afar(then=("key", "--clearmodifiers", "Escape"))
    s.record("after_escape", bpy.context.scene.contact_edit.last_solve)
    kept = pose()
    s.record("moved_by_escape", sum(kept[n] != started[-1][n] for n in kept))
    yield from s.shot("stopped")

    # Right-click cancels: the pose goes back to what it was when the solve began.
    yield from solve_from_afar(then=("click", "3"))
    after = pose()
    s.record("cancel_restored", all(np.allclose(after[n], started[-1][n]) for n in after))
    s.record("after_cancel", bpy.context.scene.contact_edit.last_solve)
    s.record("reports", [r for r in s.reports() if not r.startswith("bpy.ops")])
    yield from open_contact_tab(s, view)
    yield from s.shot("panel_after_solve")
