"""Registering and unregistering every class of the add-on, in dependency order."""

import bpy

from .preferences import CONTACT_EDIT_AP_preferences

classes = (CONTACT_EDIT_AP_preferences,)

register, unregister = bpy.utils.register_classes_factory(classes)
