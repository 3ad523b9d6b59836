"""Organise patches: parent and unparent (§4.3.4), clear, and the contact library (JSON templates that
users keep for fingertips, palms and whole grips)."""

from __future__ import annotations

import bpy
from bpy_extras.io_utils import ExportHelper, ImportHelper

from geodesics import ContactSet

from .. import store
from .common import ExplainedPoll, guarded, mesh_object, need_mesh, need_patch


def change_patch(operator, context, name: str, change) -> set:
    """Store ``change(contacts, name)``, the contact set of the operator's object changed at the patch
    ``name`` (default: the active patch)."""
    obj = mesh_object(context, operator.object_name or None)
    store.save(obj, change(store.load(obj), name or store.active_patch_name(obj)))
    return {"FINISHED"}


class CONTACT_EDIT_OT_parent(ExplainedPoll, bpy.types.Operator):
    """Parent a contact patch to another, so editing the parent carries it along"""

    bl_idname = "contact_edit.parent"
    bl_label = "Parent Contact"
    bl_options = {"REGISTER", "UNDO"}

    child: bpy.props.StringProperty(name="Child", description="Default: the active patch")
    parent: bpy.props.StringProperty(name="Parent")
    object_name: bpy.props.StringProperty(name="Object", description="Default: the active object")

    why_not = staticmethod(need_patch)

    @guarded
    def execute(self, context):
        return change_patch(
            self, context, self.child, lambda contacts, child: contacts.parent(child, self.parent)
        )


class CONTACT_EDIT_OT_unparent(ExplainedPoll, bpy.types.Operator):
    """Detach a contact patch from its parent (it stays where it is)"""

    bl_idname = "contact_edit.unparent"
    bl_label = "Unparent Contact"
    bl_options = {"REGISTER", "UNDO"}

    child: bpy.props.StringProperty(name="Child", description="Default: the active patch")
    object_name: bpy.props.StringProperty(name="Object", description="Default: the active object")

    why_not = staticmethod(need_patch)

    @guarded
    def execute(self, context):
        return change_patch(self, context, self.child, lambda contacts, child: contacts.unparent(child))


class CONTACT_EDIT_OT_clear(ExplainedPoll, bpy.types.Operator):
    """Remove a contact patch, or all of an object's patches"""

    bl_idname = "contact_edit.clear"
    bl_label = "Clear Contacts"
    bl_options = {"REGISTER", "UNDO"}

    patch: bpy.props.StringProperty(name="Patch", description="Default: the active patch")
    all: bpy.props.BoolProperty(name="All patches", default=False)
    object_name: bpy.props.StringProperty(name="Object", description="Default: the active object")

    why_not = staticmethod(need_patch)

    @guarded
    def execute(self, context):
        def cleared(contacts, name):
            return ContactSet(contacts.mesh) if self.all else contacts.remove(name)

        return change_patch(self, context, self.patch, cleared)


class CONTACT_EDIT_OT_library_save(ExplainedPoll, bpy.types.Operator, ExportHelper):
    """Save the object's contact patches as a reusable contact library (JSON)"""

    bl_idname = "contact_edit.library_save"
    bl_label = "Save Contact Library"
    filename_ext = ".json"
    filter_glob: bpy.props.StringProperty(default="*.json", options={"HIDDEN"})
    object_name: bpy.props.StringProperty(name="Object", description="Default: the active object")

    why_not = staticmethod(need_patch)

    @guarded
    def execute(self, context):
        obj = mesh_object(context, self.object_name or None)
        store.load(obj).save(self.filepath)  # written atomically: never half a file
        self.report({"INFO"}, f"Saved {len(store.entries(obj))} patches to {self.filepath}")
        return {"FINISHED"}


class CONTACT_EDIT_OT_library_load(ExplainedPoll, bpy.types.Operator, ImportHelper):
    """Load a contact library onto the object (projected onto it if it was made for another mesh)"""

    bl_idname = "contact_edit.library_load"
    bl_label = "Load Contact Library"
    bl_options = {"REGISTER", "UNDO"}
    filename_ext = ".json"
    filter_glob: bpy.props.StringProperty(default="*.json", options={"HIDDEN"})
    object_name: bpy.props.StringProperty(name="Object", description="Default: the active object")
    remap: bpy.props.BoolProperty(
        name="Remap", default=False, description="Project a library made for another mesh onto this one"
    )

    why_not = staticmethod(need_mesh)

    @guarded
    def execute(self, context):
        obj = mesh_object(context, self.object_name or None)
        mesh = store.load(obj).mesh
        library = ContactSet.load(self.filepath, mesh, remap=self.remap)
        merged = store.load(obj)
        clash = [name for name in library if name in merged]
        if clash:
            self.report({"ERROR"}, f"'{obj.name}' already has patches named {', '.join(clash)}; rename first")
            return {"CANCELLED"}
        merged = ContactSet(
            mesh,
            {**merged.patches, **library.patches},
            {**merged.links, **library.links},
            {**merged.pairs, **library.pairs},
        )
        store.save(obj, merged)
        self.report({"INFO"}, f"Loaded {len(library)} patches onto '{obj.name}'")
        return {"FINISHED"}


classes = (
    CONTACT_EDIT_OT_parent,
    CONTACT_EDIT_OT_unparent,
    CONTACT_EDIT_OT_clear,
    CONTACT_EDIT_OT_library_save,
    CONTACT_EDIT_OT_library_load,
)
