"""Registering and unregistering everything, in dependency order (and the reverse)."""

import bpy

from . import (
    assets,
    keymaps,
    operators,
    overlays,
    panels,
    properties,
)
from .preferences import CONTACT_EDIT_AP_preferences

classes = (
    CONTACT_EDIT_AP_preferences,
    *properties.classes,
    *operators.classes,
    *assets.classes,
    *panels.classes,
)


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)
    properties.register()
    assets.register()
    overlays.register()
    keymaps.register()


def unregister() -> None:
    keymaps.unregister()
    overlays.unregister()
    assets.unregister()
    properties.unregister()
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
