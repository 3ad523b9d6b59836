"""Registering and unregistering everything, in dependency order (and the reverse)."""

import bpy

from . import (
    assets,
    device_panel,
    device_properties,
    device_session,
    keymaps,
    operators,
    overlays,
    panels,
    properties,
    retarget_properties,
)
from .preferences import CONTACT_EDIT_AP_preferences

#: Each class after those it refers to: property groups before the groups and operators that hold them,
#: a sub-panel after its parent.
classes = (
    CONTACT_EDIT_AP_preferences,
    *properties.classes,
    *device_properties.classes,
    *retarget_properties.classes,
    *operators.classes,
    *assets.classes,
    *panels.classes,
    *device_panel.classes,
)
#: What else the add-on adds to Blender (pointer properties on its types, handlers, menus, draw callbacks,
#: hotkeys), once the classes are registered; taken away in the reverse order, before them.
modules = (properties, device_properties, retarget_properties, device_session, assets, overlays, keymaps)

register_classes, unregister_classes = bpy.utils.register_classes_factory(classes)


def register() -> None:
    register_classes()
    for module in modules:
        module.register()


def unregister() -> None:
    for module in reversed(modules):
        module.unregister()
    unregister_classes()
