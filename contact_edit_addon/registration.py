"""Registering and unregistering everything, in dependency order (and the reverse).

Once registered, the objects Python tracks for its cycle collector (Blender's, NumPy's, SciPy's and our
modules, functions and classes, which live as long as the session) are frozen out of it
(:func:`gc.freeze`). Otherwise every full collection walks them all, and the pause falls inside whatever
runs then: a tool's response, a solve's first pose (``contact-edit bench operators`` shows the longest run
of each tool beside its median). Freezing changes nothing else: reference counting still frees those
objects, and only garbage cycles among them (a few, once) are never collected.

After start-up, timer ticks make the procedural hands that Retarget checks its hands against, one per
tick, so that the first Retarget of a session need not make them all while Blender waits.
"""

import gc

import bpy

from solver.retarget import make_next_procedural_topology

from . import operators, posing, properties
from .assets import operators as add_menu
from .device import operators as device_operators
from .device import panel as device_panel
from .device import properties as device_properties
from .device import session as device_session
from .preferences import CONTACT_EDIT_AP_preferences
from .retarget import operators as retarget_operators
from .retarget import properties as retarget_properties
from .ui import keymaps, overlays, panels

#: Each class after those it refers to: property groups before the groups and operators that hold them,
#: a sub-panel after its parent.
classes = (
    CONTACT_EDIT_AP_preferences,
    *properties.classes,
    *device_properties.classes,
    *retarget_properties.classes,
    *operators.classes,
    *retarget_operators.classes,
    *device_operators.classes,
    *add_menu.classes,
    *panels.classes,
    *device_panel.classes,
)
#: What else the add-on adds to Blender (pointer properties on its types, handlers, menus, draw callbacks,
#: hotkeys), once the classes are registered; taken away in the reverse order, before them.
modules = (
    properties, device_properties, retarget_properties, device_session, posing, add_menu, overlays, keymaps
)  # fmt: skip

register_classes, unregister_classes = bpy.utils.register_classes_factory(classes)


def register() -> None:
    register_classes()
    for module in modules:
        module.register()
    gc.collect()  # today's garbage goes first: what is frozen is never collected
    gc.freeze()
    bpy.app.timers.register(make_procedural_topologies, first_interval=1.0, persistent=True)


def unregister() -> None:
    if bpy.app.timers.is_registered(make_procedural_topologies):
        bpy.app.timers.unregister(make_procedural_topologies)
    gc.unfreeze()  # the add-on's modules can go once unloaded
    for module in reversed(modules):
        module.unregister()
    unregister_classes()


def make_procedural_topologies() -> float | None:
    """Timer: make the next kind of procedural hand, and come back a moment later until all are made."""
    return 0.05 if make_next_procedural_topology() else None
