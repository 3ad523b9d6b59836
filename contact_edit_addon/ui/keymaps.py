"""Hotkeys for every tool in the 3D viewport, on the add-on keyconfig so users can change them. Background
mode has no add-on keyconfig, so nothing is registered there.

Ctrl+Shift starts the tools that make patches and pose the hand; Shift+Alt the ones that move patches
over a surface. None of these is bound in Blender's default keymap (4.2 to 5.x) in any mode a mesh or an
armature can be in, which the tests check against Blender's own keyconfig: Blender would otherwise run
its own operator, since a mode's keymap comes before the 3D View keymap.
"""

import bpy

#: (operator, key, modifiers, properties)
HOTKEYS = (
    ("contact_edit.paint", "P", ("ctrl", "shift"), {"source": "STROKE"}),
    ("contact_edit.axis", "A", ("ctrl", "shift"), {}),
    ("contact_edit.transfer", "T", ("shift", "alt"), {}),
    ("contact_edit.translate", "M", ("shift", "alt"), {}),
    ("contact_edit.rotate", "R", ("shift", "alt"), {}),
    ("contact_edit.bend", "B", ("shift", "alt"), {}),
    ("contact_edit.solve", "E", ("ctrl", "shift"), {}),
    ("contact_edit.flex_to_contact", "F", ("ctrl", "shift"), {}),
    ("contact_edit.device_key", "K", ("ctrl", "shift"), {}),
)

_items: list = []


def shortcut(idname: str) -> str:
    """How the README and the tooltips write an operator's hotkey, e.g. 'Ctrl+Shift+P'."""
    for name, key, modifiers, _ in HOTKEYS:
        if name == idname:
            return "+".join([*(m.title() for m in modifiers), key])
    raise KeyError(idname)


def register() -> None:
    keyconfig = bpy.context.window_manager.keyconfigs.addon
    if keyconfig is None:  # background mode
        return
    keymap = keyconfig.keymaps.new(name="3D View", space_type="VIEW_3D")
    for idname, key, modifiers, properties in HOTKEYS:
        item = keymap.keymap_items.new(idname, key, "PRESS", **dict.fromkeys(modifiers, True))
        for name, value in properties.items():
            setattr(item.properties, name, value)
        _items.append((keymap, item))


def unregister() -> None:
    for keymap, item in _items:
        keymap.keymap_items.remove(item)
    _items.clear()
