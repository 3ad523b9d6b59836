"""Reading and writing an object's contact set (kept as a contact file in its ``contact_edit.data``),
and pairing files: a hand's and an object's sets together, what ``contact-edit pose --contacts`` reads.
"""

from __future__ import annotations

import json

import bpy

from geodesics import ContactError, ContactSet
from geodesics.files import read_json, write_atomically
from geodesics.schema import Fields

from . import bridge

#: Patch colours, assigned in order; a transferred patch takes its counterpart's colour. Blender's own
#: selection orange comes last, so the first patches never look like selected vertices in Edit Mode.
PALETTE = (
    (0.15, 0.60, 0.95, 1.0),
    (0.30, 0.80, 0.30, 1.0),
    (0.90, 0.25, 0.60, 1.0),
    (0.95, 0.85, 0.20, 1.0),
    (0.55, 0.35, 0.90, 1.0),
    (0.20, 0.85, 0.80, 1.0),
    (0.85, 0.20, 0.20, 1.0),
    (0.95, 0.45, 0.10, 1.0),
)


def load(obj: bpy.types.Object, deformed: bool = False) -> ContactSet:
    """The object's contact set on its current mesh. Contacts saved for a different triangulation or
    topology of the object are projected onto the current surface by their saved positions."""
    mesh = bridge.trimesh(obj, deformed=deformed)
    text = obj.contact_edit.data
    if not text:
        return ContactSet(mesh)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as err:
        raise ContactError(f"the contact data stored on '{obj.name}' is damaged: {err}") from None
    return _from_dict(data, mesh, f"the contacts of '{obj.name}'")


def _from_dict(data, mesh, source: str) -> ContactSet:
    """A set from a contact file's content, projected onto ``mesh`` if it was made for another one."""
    info = data.get("mesh") if isinstance(data, dict) else None
    same = isinstance(info, dict) and info.get("hash") == mesh.topology_hash
    return ContactSet.from_dict(data, mesh, remap=not same, source=source)


def save(obj: bpy.types.Object, contacts: ContactSet, colors: dict | None = None) -> None:
    """Store the set on the object and rebuild the patch list the sidebar shows (keeping colours)."""
    entries = obj.contact_edit.patches
    previous = {e.name: tuple(e.color) for e in entries}
    visible = {e.name: e.visible for e in entries}
    colors = {**previous, **(colors or {})}
    obj.contact_edit.data = json.dumps(contacts.to_dict())
    entries.clear()
    for i, name in enumerate(contacts):
        entry = entries.add()
        entry.name = name
        entry.color = colors.get(name, PALETTE[i % len(PALETTE)])
        entry.points = len(contacts[name])
        entry.parent = contacts.links[name].parent if name in contacts.links else ""
        entry.pair = contacts.pairs.get(name, "")
        entry.visible = visible.get(name, True)
    obj.contact_edit.active = min(obj.contact_edit.active, max(len(entries) - 1, 0))
    redraw()


def redraw(area_type: str | None = None) -> None:
    """Redraw every editor (or every one of ``area_type``). Blender redraws after an undoable operator
    and when a property a panel shows is set, but not when a timer or a script rebuilds a collection
    (the patch list) or poses bones."""
    for window in bpy.context.window_manager.windows:
        for area in window.screen.areas:
            if area_type is None or area.type == area_type:
                area.tag_redraw()


def active_patch_name(obj: bpy.types.Object) -> str | None:
    entries = obj.contact_edit.patches
    if not entries:
        return None
    return entries[min(obj.contact_edit.active, len(entries) - 1)].name


#: The pairing file's format tag.
PAIRING_FORMAT = "contact-edit/pairing"


def save_pairing(path, hand: bpy.types.Object, target: bpy.types.Object) -> None:
    """Write the hand's and the object's contact sets (with their pairs) to one file, atomically."""
    data = {
        "format": PAIRING_FORMAT,
        "version": 1,
        "hand": load(hand).to_dict(),
        "object": load(target).to_dict(),
    }
    write_atomically(path, json.dumps(data, indent=1))


def load_pairing(path, hand: bpy.types.Object, target: bpy.types.Object, remap: bool = False) -> None:
    """Give the hand and the object the contact sets of a pairing file. A file made for other meshes is
    refused with what it was made for, unless ``remap`` projects it onto these by position. Either both
    objects change or neither does."""
    file = Fields(read_json(path, "pairing file", ContactError), str(path), ContactError)
    file.header(PAIRING_FORMAT, 1, "pairing file")
    sets = {}
    for key, obj in (("hand", hand), ("object", target)):
        source = f"{path} ({key} '{obj.name}')"
        sets[key] = ContactSet.from_dict(file.data.get(key), bridge.trimesh(obj), remap=remap, source=source)
    save(hand, sets["hand"])
    save(target, sets["object"])
