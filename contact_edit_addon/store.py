"""Reading and writing an object's contact set (kept as a contact file in its ``contact_edit.data``),
and pairing files: a hand's and an object's sets together, what ``contact-edit pose --contacts`` reads.

A hand has a second set, its retargeting annotation (``contact_edit.annotation``, with its own patch
list). Every function here works on the set the object's ``contact_edit.layer`` says the tools edit, or on
the one ``layer`` names, so that every tool edits either.
"""

from __future__ import annotations

import json

import bpy

from geodesics import ContactError, ContactSet, Fields, read_json, write_atomically

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


#: Per layer: the object's property holding the set, its patch list, and the list's active index.
LAYERS = {
    "CONTACTS": ("data", "patches", "active"),
    "ANNOTATION": ("annotation", "annotation_patches", "annotation_active"),
}
#: What a patch list's entry keeps by name when the list is rebuilt: set by hand, not by the set.
KEPT = ("color", "visible", "marker", "axis_scale", "radial_scale", "girth")


def _names(obj: bpy.types.Object, layer: str | None) -> tuple[str, str, str]:
    return LAYERS[layer or obj.contact_edit.layer]


def text(obj: bpy.types.Object, layer: str | None = None) -> str:
    """The set as stored (a contact file's JSON; empty for none)."""
    return getattr(obj.contact_edit, _names(obj, layer)[0])


def entries(obj: bpy.types.Object, layer: str | None = None):
    """The patch list the sidebar shows."""
    return getattr(obj.contact_edit, _names(obj, layer)[1])


def active_index(obj: bpy.types.Object, layer: str | None = None) -> int:
    return getattr(obj.contact_edit, _names(obj, layer)[2])


def set_active(obj: bpy.types.Object, index: int, layer: str | None = None) -> None:
    setattr(obj.contact_edit, _names(obj, layer)[2], max(index, 0))


def load(obj: bpy.types.Object, deformed: bool = False, layer: str | None = None) -> ContactSet:
    """The object's contact set on its current mesh. Contacts saved for a different triangulation or
    topology of the object are projected onto the current surface by their saved positions."""
    mesh = bridge.trimesh(obj, deformed=deformed)
    stored = text(obj, layer)
    what = "annotation" if (layer or obj.contact_edit.layer) == "ANNOTATION" else "contacts"
    if not stored:
        return ContactSet(mesh)
    try:
        data = json.loads(stored)
    except json.JSONDecodeError as err:
        raise ContactError(f"the {what} stored on '{obj.name}' is damaged: {err}") from None
    return _from_dict(data, mesh, f"the {what} of '{obj.name}'")


def _from_dict(data, mesh, source: str) -> ContactSet:
    """A set from a contact file's content, projected onto ``mesh`` if it was made for another one."""
    info = data.get("mesh") if isinstance(data, dict) else None
    same = isinstance(info, dict) and info.get("hash") == mesh.topology_hash
    return ContactSet.from_dict(data, mesh, remap=not same, source=source)


def save(
    obj: bpy.types.Object,
    contacts: ContactSet,
    colors: dict | None = None,
    layer: str | None = None,
    markers=(),
) -> None:
    """Store the set on the object and rebuild the patch list the sidebar shows, keeping what was set by
    hand (:data:`KEPT`) per name; ``colors`` and ``markers`` (names) set those of new patches."""
    data, list_name, _ = _names(obj, layer)
    listed = getattr(obj.contact_edit, list_name)
    # Copied out: a colour read from an entry is a live view of it, which would read the new entry at the
    # same place once the list is rebuilt (every partner's colour swapped at the next edit).
    kept = {e.name: {key: _copied(getattr(e, key)) for key in KEPT} for e in listed}
    setattr(obj.contact_edit, data, json.dumps(contacts.to_dict()))
    listed.clear()
    for i, name in enumerate(contacts):
        entry = listed.add()
        entry.stored_name = name
        entry.name = name
        entry.color = PALETTE[i % len(PALETTE)]
        for key, value in kept.get(name, {}).items():
            setattr(entry, key, value)
        if name in (colors or {}):
            entry.color = colors[name]
        if name in markers:
            entry.marker = True
        entry.points = len(contacts[name])
        entry.parent = contacts.links[name].parent if name in contacts.links else ""
        entry.pair = contacts.pairs.get(name, "")
    set_active(obj, min(active_index(obj, layer), len(listed) - 1), layer)
    redraw()


def _copied(value):
    """A property's value, arrays (colours) as tuples rather than views of the entry they belong to."""
    return value if isinstance(value, (str, bool, int, float)) else tuple(value)


def recolour(entry, scene: bpy.types.Scene) -> None:
    """Give a contact patch's partner on the scene's other object (hand or object) the colour just set on
    its list entry: a pair is drawn in one colour on both."""
    if not entry.pair or entry.path_from_id().startswith("contact_edit.annotation_patches"):
        return
    settings = scene.contact_edit
    for counterpart in {settings.hand, settings.target} - {entry.id_data, None}:
        for other in entries(counterpart, "CONTACTS"):
            if (
                other.name == entry.pair
                and other.pair == entry.name
                and tuple(other.color) != tuple(entry.color)
            ):
                other.color = entry.color


def rename(obj: bpy.types.Object, entry, scene: bpy.types.Scene) -> None:
    """Rename the patch of a list entry whose name was edited (from ``entry.stored_name`` to
    ``entry.name``) in its set, its children's entries and, for a contact patch, the pair recorded on the
    scene's other object. A name the set cannot take (empty, or another patch's) is put back, as Blender
    puts back names it refuses."""
    old, new = entry.stored_name, entry.name
    layer = "ANNOTATION" if entry.path_from_id().startswith("contact_edit.annotation_patches") else "CONTACTS"
    contacts = load(obj, layer=layer)
    try:
        renamed = contacts.rename(old, new)
    except ContactError:
        entry.name = old
        return
    # The entries are edited in place: rebuilding the list would remove the entry being edited.
    setattr(obj.contact_edit, LAYERS[layer][0], json.dumps(renamed.to_dict()))
    entry.stored_name = new
    for other in entries(obj, layer):
        if other.parent == old:
            other.parent = new
    settings = scene.contact_edit
    if layer == "CONTACTS" and old in contacts.pairs:
        for counterpart in {settings.hand, settings.target} - {obj, None}:
            theirs = load(counterpart, layer="CONTACTS")
            changed = [k for k, v in theirs.pairs.items() if v == old]
            for k in changed:
                theirs = theirs.pair(k, new)
            if changed:
                counterpart.contact_edit.data = json.dumps(theirs.to_dict())
                for e in entries(counterpart, "CONTACTS"):
                    e.pair = theirs.pairs.get(e.name, "")
    redraw()


def redraw(area_type: str | None = None) -> None:
    """Redraw every editor (or every one of ``area_type``). Blender redraws after an undoable operator
    and when a property a panel shows is set, but not when a timer or a script rebuilds a collection
    (the patch list) or poses bones."""
    for window in bpy.context.window_manager.windows:
        for area in window.screen.areas:
            if area_type is None or area.type == area_type:
                area.tag_redraw()


def active_entry(obj: bpy.types.Object, layer: str | None = None):
    """The patch list's active entry, or None for an empty list."""
    listed = entries(obj, layer)
    if not listed:
        return None
    return listed[min(active_index(obj, layer), len(listed) - 1)]


def active_patch_name(obj: bpy.types.Object, layer: str | None = None) -> str | None:
    entry = active_entry(obj, layer)
    return None if entry is None else entry.name


#: The pairing file's format tag.
PAIRING_FORMAT = "contact-edit/pairing"


def save_pairing(path, hand: bpy.types.Object, target: bpy.types.Object) -> None:
    """Write the hand's and the object's contact sets (with their pairs) to one file, atomically."""
    data = {
        "format": PAIRING_FORMAT,
        "version": 1,
        "hand": load(hand, layer="CONTACTS").to_dict(),
        "object": load(target, layer="CONTACTS").to_dict(),
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
    save(hand, sets["hand"], layer="CONTACTS")
    save(target, sets["object"], layer="CONTACTS")
