"""The Contact tab as a new user meets it: hotkeys pressed too early say why, the Add menu's Example
frames a hand and a mug, the sidebar shows the tab; and Blender's own default keymap, for the clash test."""

import bpy
from common import addon as module
from common import example, open_contact_tab
from mathutils import Vector


def steps(s):
    view = s.view3d()
    yield from s.move(*view.centre())
    for combo in ("ctrl+shift+e", "ctrl+shift+k", "shift+alt+t"):
        yield from s.key(combo)
        yield from s.move(view.centre()[0] + 300, view.centre()[1] + 200)  # away from the error's popup,
        yield from s.key("Escape")  # which Blender 5 keeps open until told
        yield from s.move(*view.centre())
    s.record("early", s.reports())
    yield from s.key("shift+a")
    yield from s.shot("add_menu")
    yield from s.key("Escape")
    hand, mug = example(view)
    yield 0.6  # the view glides to frame them
    s.record(
        "example",
        {
            obj.name: view.project([obj.matrix_world @ Vector(corner) for corner in obj.bound_box])
            for obj in (hand, mug)
        },
    )
    s.record(
        "viewport",
        [
            view.region.x,
            view.window.height - view.region.y - view.region.height,
            view.region.width,
            view.region.height,
        ],
    )
    yield from open_contact_tab(s, view)
    ui = s.region(view, "UI")
    s.record("sidebar", {"width": ui.width, "height": ui.height, "x": ui.x, "y": ui.y})
    yield from s.shot("panel")
    report = module("posing").rig_report(bpy.context.scene)  # what the Rig sub-panel shows
    s.record("rig", None if report is None else [report.ok, *report.lines])
    default = bpy.context.window_manager.keyconfigs.default
    s.record(
        "default_keymap",
        [
            [
                km.name,
                km.space_type,
                km.is_modal,
                it.idname,
                it.type,
                it.value,
                it.any,
                it.ctrl,
                it.shift,
                it.alt,
                it.oskey,
                it.key_modifier,
            ]
            for km in default.keymaps
            for it in km.keymap_items
            if it.active
        ],
    )
    addon = bpy.context.window_manager.keyconfigs.addon
    s.record(
        "our_keymap",
        [
            [km.name, it.idname, it.type, it.ctrl, it.shift, it.alt]
            for km in addon.keymaps
            for it in km.keymap_items
            if it.idname.startswith("contact_edit.")
        ],
    )
