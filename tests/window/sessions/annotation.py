"""Annotating hands in a real window: *Propose* in the Retarget > Annotation panel draws the example hand's
curves and markers from its armature in a worker thread (the operator's own calls are timed: that is how
long it holds Blender up), the viewport then shows the annotation instead of the contacts, the layer
switch shows the contacts again, and Ctrl+Z takes the proposal back in one step."""

import bpy
from brush import until
from common import addon, example, open_contact_tab, timed_calls
from mathutils import Matrix
from retarget import open_by_default

from solver import hands


def steps(s):
    view = s.view3d()
    hand_obj, mug = example(view)
    scene = bpy.context.scene
    assets = addon("assets")
    alien_obj, alien_rig = assets.hand_objects(hands.make_hand("alien"), "Alien", scene.collection)
    alien_rig.matrix_world = Matrix.Translation((0.0, 0.3, 0.0))
    settings = scene.contact_edit_retarget
    settings.source, settings.held, settings.target = hand_obj, mug, alien_obj
    bpy.ops.ed.undo_push(message="Scene set up")  # what this script made is an undo step of its own
    panels = addon("ui.panels")
    for panel in (panels.VIEW3D_PT_contact_edit_retarget, panels.VIEW3D_PT_contact_edit_annotation):
        open_by_default(panel)
    yield from open_contact_tab(s, view)
    yield from s.move(*view.centre())
    yield from s.shot("contacts")
    store = addon("store")
    calls = timed_calls(addon("retarget.operators").CONTACT_EDIT_OT_annotation_propose)

    with view.override():
        bpy.ops.contact_edit.annotation_propose("INVOKE_DEFAULT", object_name=hand_obj.name)
    s.record("proposing", (yield from until(lambda: bool(store.entries(hand_obj, "ANNOTATION")), timeout=60)))
    yield 0.5
    s.record("layer", hand_obj.contact_edit.layer)
    s.record("entries", [(e.name, e.marker, round(e.girth, 6)) for e in store.entries(hand_obj)])
    s.record("calls", calls)
    yield from s.shot("annotation")
    s.record("reports", s.reports())

    hand_obj.contact_edit.layer = "CONTACTS"  # as the switch above the patch list sets it
    yield from s.shot("contacts again")
    hand_obj.contact_edit.layer = "ANNOTATION"
    yield from s.shot("annotation again")

    ui = s.region(view, "UI")  # the sidebar scrolled down to the Annotation panel
    yield from s.move(ui.x + ui.width / 2, view.window.height - (ui.y + ui.height / 2))
    for _ in range(12):
        s.xdotool("click", 5)
        yield 0.05
    yield from s.shot("panel")

    name = hand_obj.name
    yield from s.move(*view.centre())
    yield from s.key("ctrl+z", settle=1.0)
    hand_obj = bpy.data.objects[name]  # undo reloads the data: the old references are gone
    s.record("after_undo", len(store.entries(hand_obj, "ANNOTATION")))
