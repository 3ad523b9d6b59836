"""Hotkeys for every tool (3D viewport, Ctrl+Shift+letter), on the add-on keyconfig so users can
change them. Background mode has no add-on keyconfig, so nothing is registered there."""

import bpy

#: (operator, key, properties)
HOTKEYS = (
    ("contact_edit.paint", "P", {"source": "STROKE"}),
    ("contact_edit.axis", "A", {}),
    ("contact_edit.transfer", "T", {}),
    ("contact_edit.translate", "G", {}),
    ("contact_edit.rotate", "R", {}),
    ("contact_edit.bend", "B", {}),
    ("contact_edit.solve", "E", {}),
    ("contact_edit.flex_to_contact", "F", {}),
    ("contact_edit.device_key", "K", {}),
)

_items: list = []


def register() -> None:
    keyconfig = bpy.context.window_manager.keyconfigs.addon
    if keyconfig is None:  # background mode
        return
    keymap = keyconfig.keymaps.new(name="3D View", space_type="VIEW_3D")
    for idname, key, properties in HOTKEYS:
        item = keymap.keymap_items.new(idname, key, "PRESS", ctrl=True, shift=True)
        for name, value in properties.items():
            setattr(item.properties, name, value)
        _items.append((keymap, item))


def unregister() -> None:
    for keymap, item in _items:
        keymap.keymap_items.remove(item)
    _items.clear()
