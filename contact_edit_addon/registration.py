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
)
from .preferences import CONTACT_EDIT_AP_preferences

classes = (
    CONTACT_EDIT_AP_preferences,
    *properties.classes,
    *device_properties.classes,
    *operators.classes,
    *assets.classes,
    *panels.classes,
    *device_panel.classes,
)


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)
    properties.register()
    device_properties.register()
    device_session.register()
    assets.register()
    overlays.register()
    keymaps.register()


def unregister() -> None:
    keymaps.unregister()
    overlays.unregister()
    assets.unregister()
    device_session.unregister()
    device_properties.unregister()
    properties.unregister()
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
