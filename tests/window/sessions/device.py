"""The puppet device (the built-in simulator) driving the example's armature live: the status bar and
the Device panel say the same thing as joints are found, and the key hotkey answers."""

import time

import bpy
from common import example


def steps(s):
    view = s.view3d()
    hand, _ = example(view)
    settings = bpy.context.scene.contact_edit_device
    settings.armature = hand.parent
    settings.simulator = True
    with view.override():
        bpy.ops.contact_edit.device_connect("INVOKE_DEFAULT")
    began = time.monotonic()
    statuses = []
    while time.monotonic() - began < 4.0:
        yield 0.25
        if not statuses or statuses[-1] != settings.status:
            statuses.append(settings.status)
    s.record("statuses", statuses)
    s.record("status", settings.status)
    yield from s.move(*view.centre())
    yield from s.key("ctrl+shift+k")
    yield from s.move(view.centre()[0] + 300, view.centre()[1] + 200)
    yield from s.shot("device")
    s.record("reports", [r for r in s.reports() if not r.startswith("bpy.ops")])
    with view.override():
        bpy.ops.contact_edit.device_stop()
    yield 0.5
    s.record("stopped", settings.status)
