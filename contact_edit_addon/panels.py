"""The "Contact" tab of the 3D viewport's sidebar: the objects, the patch list, the tools."""

import bpy

from . import posing


class CONTACT_EDIT_UL_patches(bpy.types.UIList):
    """One row per patch: colour, name, point count, parent and pair."""

    def draw_item(self, context, layout, data, item, icon, active_data, active_property, index=0, flt_flag=0):
        row = layout.row(align=True)
        row.prop(item, "color", text="")
        row.prop(item, "name", text="", emboss=False)
        detail = f"{item.points} pts"
        if item.parent:
            detail += f" · in {item.parent}"
        if item.pair:
            detail += f" · ↔ {item.pair}"
        row.label(text=detail)
        row.prop(item, "visible", text="", icon="HIDE_OFF" if item.visible else "HIDE_ON", emboss=False)


class VIEW3D_PT_contact_edit(bpy.types.Panel):
    bl_label = "Contact Edit"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Contact"

    def draw(self, context):
        layout = self.layout
        settings = context.scene.contact_edit
        column = layout.column(align=True)
        column.prop(settings, "hand")
        column.prop(settings, "target")
        layout.prop(settings, "axis_method")
        layout.prop(settings, "deformed")
        self.draw_solver(layout, settings)

        obj = context.active_object
        if obj is None or obj.type != "MESH":
            layout.label(text="Select a mesh to see its contacts", icon="INFO")
            return
        layout.label(text=f"Patches of {obj.name}")
        layout.template_list(
            "CONTACT_EDIT_UL_patches", "", obj.contact_edit, "patches", obj.contact_edit, "active"
        )

        grid = layout.grid_flow(columns=2, align=True)
        grid.operator("contact_edit.paint", text="From selection").source = "SELECTION"
        grid.operator("contact_edit.paint", text="Brush").source = "STROKE"
        grid.operator("contact_edit.axis", text="Axis")
        grid.operator("contact_edit.transfer", text="Transfer")
        grid.operator("contact_edit.translate", text="Translate")
        grid.operator("contact_edit.rotate", text="Rotate")
        grid.operator("contact_edit.bend", text="Bend")
        grid.operator("contact_edit.clear", text="Remove")
        layout.operator("contact_edit.make_proxy", text="Make manifold proxy", icon="MOD_REMESH")
        row = layout.row(align=True)
        row.operator("contact_edit.library_save", text="Save library", icon="EXPORT")
        row.operator("contact_edit.library_load", text="Load library", icon="IMPORT")

    @staticmethod
    def draw_solver(layout, settings) -> None:
        box = layout.box()
        row = box.row()
        row.label(text="Pose", icon="ARMATURE_DATA")
        row.operator("contact_edit.reset_weights", text="", icon="LOOP_BACK")
        column = box.column(align=True)
        column.prop(settings, "weight_distance")
        column.prop(settings, "weight_normal")
        column.prop(settings, "weight_prior")
        box.prop(settings, "keyframe")
        row = box.row(align=True)
        for stage, label, _ in posing.STAGES:
            solve = row.operator("contact_edit.solve", text=label.split()[0])
            solve.stage, solve.keyframe = stage, settings.keyframe
        box.operator("contact_edit.flex_to_contact", icon="VIEW_PAN").keyframe = settings.keyframe
        if settings.last_solve:
            box.label(text=settings.last_solve, icon="INFO")


classes = (CONTACT_EDIT_UL_patches, VIEW3D_PT_contact_edit)
