"""The "Contact" tab of the 3D viewport's sidebar: the objects, then sub-panels for the patches and their
tools, the brush, the pose solve, and the library. Every line is short enough for the sidebar's
default width; long messages (the last solve) are split into one line per clause."""

import blf
import bpy

from .. import posing, store
from ..retarget import annotation


class CONTACT_EDIT_UL_patches(bpy.types.UIList):
    """One row per patch: colour, name, point count, parent and pair."""

    def draw_item(self, context, layout, data, item, icon, active_data, active_property, index=0, flt_flag=0):
        row = layout.row(align=True)
        swatch = row.row(align=True)
        swatch.ui_units_x = 1.2  # a swatch, so that the name has the room
        swatch.prop(item, "color", text="")
        row.prop(item, "name", text="", emboss=False)
        detail = f"{item.points}" + (" · marker" if item.marker else "")
        if item.parent:
            detail += f" · in {item.parent}"
        if item.pair:
            detail += " · ↔"
        row.label(text=detail)
        row.prop(item, "visible", text="", icon="HIDE_OFF" if item.visible else "HIDE_ON", emboss=False)


#: Sidebar pixels (at UI scale 1) that a boxed label with an icon does not have for its text: the tabs,
#: the panel's and the box's margins, the icon (measured in Blender 4.3 and 5.2 windows).
LABEL_MARGIN = 105


def wrapped(context, text: str) -> list[str]:
    """``text`` in lines that fit the sidebar's width as it is now (Blender cuts a long label short)."""
    scale = context.preferences.system.ui_scale
    room = context.region.width - LABEL_MARGIN * scale
    blf.size(0, 11 * scale)
    lines = [""]
    for word in text.split():
        trial = f"{lines[-1]} {word}".strip()
        if lines[-1] and blf.dimensions(0, trial)[0] > room:
            lines.append(word)
        else:
            lines[-1] = trial
    return lines


def draw_message(context, layout, texts, icon: str) -> None:
    """A message in a box, ``texts`` each starting a line and wrapped to the sidebar's width, the icon on
    the first line."""
    box = layout.box().column(align=True)
    lines = [line for text in texts for line in wrapped(context, text)]
    for i, line in enumerate(lines):
        box.label(text=line, icon=icon if i == 0 else "BLANK1")


class ContactTab:
    """Where the panels live: the Contact tab of the 3D viewport's sidebar."""

    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Contact"


class SubPanel(ContactTab):
    """A panel under the main one."""

    bl_parent_id = "VIEW3D_PT_contact_edit"


class VIEW3D_PT_contact_edit(ContactTab, bpy.types.Panel):
    """The hand and the object posed against each other."""

    bl_label = "Contact Edit"

    def draw(self, context):
        layout = self.layout
        settings = context.scene.contact_edit
        column = layout.column(align=True)
        column.prop(settings, "hand", text="", icon="VIEW_PAN")
        column.prop(settings, "target", text="", icon="MESH_CUBE")
        if settings.hand is None or settings.target is None:
            layout.operator("contact_edit.add_example", icon="ADD")


class VIEW3D_PT_contact_edit_patches(SubPanel, bpy.types.Panel):
    """The active object's patches and the tools that make and move them."""

    bl_label = "Patches"

    def draw(self, context):
        layout = self.layout
        obj = context.active_object
        if obj is None or obj.type != "MESH":
            layout.label(text="Select a mesh", icon="INFO")
            return
        layout.label(text=obj.name, icon="MESH_DATA")
        if _may_have_annotation(context, obj):
            layout.row().prop(obj.contact_edit, "layer", expand=True)
        _, listed, active = store.LAYERS[obj.contact_edit.layer]
        rows = min(max(len(getattr(obj.contact_edit, listed)), 3), 8)  # every patch shown, up to eight
        layout.template_list(
            "CONTACT_EDIT_UL_patches", "", obj.contact_edit, listed, obj.contact_edit, active, rows=rows
        )
        entry = store.active_entry(obj)
        if obj.contact_edit.layer == "ANNOTATION" and entry is not None:
            row = layout.row(align=True)
            row.prop(entry, "marker", toggle=True)
            if not entry.marker:
                row.prop(entry, "girth")
                row = layout.row(align=True)
                row.prop(entry, "axis_scale")
                row.prop(entry, "radial_scale")
        column = layout.column(align=True)
        row = column.row(align=True)
        row.operator("contact_edit.paint", text="Brush", icon="BRUSH_DATA").source = "STROKE"
        row.operator("contact_edit.paint", text="Selected", icon="RESTRICT_SELECT_OFF").source = "SELECTION"
        row = column.row(align=True)
        row.operator("contact_edit.axis", text="Axis", icon="CURVE_PATH")
        row.operator("contact_edit.transfer", text="Transfer", icon="FORWARD")
        row = column.row(align=True)
        row.operator("contact_edit.translate", text="Move", icon="VIEW_PAN")
        row.operator("contact_edit.rotate", text="Turn", icon="DRIVER_ROTATIONAL_DIFFERENCE")
        row.operator("contact_edit.bend", text="Bend", icon="MOD_SIMPLEDEFORM")
        row = column.row(align=True)
        row.operator("contact_edit.mirror_contacts", text="Mirror", icon="MOD_MIRROR")
        row.operator("contact_edit.clear", text="Remove", icon="X")


def _may_have_annotation(context, obj) -> bool:
    """Whether ``obj`` is a hand that a retarget could read an annotation from."""
    settings = context.scene.contact_edit_retarget
    return (
        obj in (settings.source, settings.target)
        or obj.contact_edit.layer == "ANNOTATION"  # never stuck in a layer without the switch
        or annotation.has_annotation(obj)
        or any(m.type == "ARMATURE" for m in obj.modifiers)
    )


class VIEW3D_PT_contact_edit_brush(SubPanel, bpy.types.Panel):
    """The area brush and the default axis of new patches."""

    bl_label = "Brush"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        settings = context.scene.contact_edit
        column = layout.column(align=True)
        column.prop(settings, "brush_radius")
        column.prop(settings, "brush_density", text="Points/cm²")
        layout.prop(settings, "axis_method", text="Axis")
        layout.prop(settings, "deformed", text="Posed")


class VIEW3D_PT_contact_edit_pose(SubPanel, bpy.types.Panel):
    """Contact IK and flex-to-contact, with the solver's weights and how the last solve went."""

    bl_label = "Pose"

    def draw(self, context):
        layout = self.layout
        settings = context.scene.contact_edit
        row = layout.row(align=True)
        # The tools key by the Key toggle themselves (as from their hotkeys): the buttons do not say.
        for stage, label, _ in posing.STAGES:
            row.operator("contact_edit.solve", text=label.split()[0]).stage = stage
        row = layout.row(align=True)
        for joints, label in (("TOGETHER", "Flex"), ("IN_TURN", "Wrap")):
            row.operator("contact_edit.flex_to_contact", text=label, icon="VIEW_PAN").joints = joints
        row.operator("contact_edit.mirror_pose", text="Mirror", icon="MOD_MIRROR")
        row.prop(settings, "keyframe", text="Key", toggle=True, icon="KEY_HLT")
        if settings.last_solve:
            draw_message(context, layout, settings.last_solve.split("; "), "INFO")
        header, body = layout.panel("contact_edit_weights", default_closed=True)
        header.label(text="Weights")
        header.operator("contact_edit.reset_weights", text="", icon="LOOP_BACK", emboss=False)
        if body is not None:
            body.use_property_split = True
            body.use_property_decorate = False
            column = body.column(align=True)
            column.prop(settings, "weight_distance", text="Distance")
            column.prop(settings, "weight_normal", text="Normals")
            column.prop(settings, "weight_prior", text="Rest pose")
            column.prop(settings, "weight_penetration", text="Keep out")


class VIEW3D_PT_contact_edit_rig(SubPanel, bpy.types.Panel):
    """The hand's rig: its wrist (the hand root), what moves it, and whether contact IK can pose it."""

    bl_label = "Rig"
    bl_parent_id = "VIEW3D_PT_contact_edit_pose"

    def draw(self, context):
        layout = self.layout
        settings = context.scene.contact_edit
        armature = next(
            (m.object for m in getattr(settings.hand, "modifiers", ()) if m.type == "ARMATURE" and m.object),
            None,
        )
        row = layout.row(align=True)
        if armature is not None:
            row.prop_search(settings, "hand_root", armature.data, "bones", text="", icon="BONE_DATA")
        else:
            row.prop(settings, "hand_root", text="", icon="BONE_DATA")
        row.operator("contact_edit.check_rig", text="", icon="FILE_REFRESH")
        report = posing.rig_report(context.scene)
        if report is None:
            return
        draw_message(context, layout, report.lines, "CHECKMARK" if report.ok else "ERROR")


class VIEW3D_PT_contact_edit_retarget(SubPanel, bpy.types.Panel):
    """Retargeting a hand-object motion onto another hand (Kinematic Motion Retargeting)."""

    bl_label = "Retarget"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        settings = context.scene.contact_edit_retarget
        column = layout.column(align=True)
        column.prop(settings, "source", text="Source", icon="VIEW_PAN")
        column.prop(settings, "held", text="Object", icon="MESH_CUBE")
        column.prop(settings, "target", text="Target", icon="ARMATURE_DATA")
        layout.prop(settings, "use_scene_range")
        if not settings.use_scene_range:
            row = layout.row(align=True)
            row.prop(settings, "frame_start")
            row.prop(settings, "frame_end")
        row = layout.row()
        row.prop(settings, "contacts")
        row.prop(settings, "workers")
        # File paths and names take the sidebar's width, their labels above them.
        for name, label in (("annotation", "Annotation file (empty: the hands')"),
                            ("folder", "Frames folder"), ("action_name", "New action's name")):  # fmt: skip
            column = layout.column(align=True)
            column.label(text=label)
            column.prop(settings, name, text="")
        layout.operator("contact_edit.retarget", icon="ACTION")
        if settings.last:
            draw_message(context, layout, [settings.last], "INFO")


class VIEW3D_PT_contact_edit_annotation(SubPanel, bpy.types.Panel):
    """The two hands' annotations: curves and markers that say how one hand's contacts land on the other."""

    bl_label = "Annotation"
    bl_parent_id = "VIEW3D_PT_contact_edit_retarget"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        settings = context.scene.contact_edit_retarget
        for role, obj in (("Source", settings.source), ("Target", settings.target)):
            if obj is None:
                continue
            listed = store.entries(obj, annotation.LAYER)
            markers = sum(e.marker for e in listed)
            column = layout.column(align=True)
            text = f"{len(listed) - markers} curves, {markers} markers" if listed else "none"
            column.label(text=f"{role}: {text}", icon="VIEW_PAN")
            propose = column.operator(
                "contact_edit.annotation_propose", text="Propose", icon="OUTLINER_OB_ARMATURE"
            )
            propose.object_name = obj.name
        layout.operator("contact_edit.annotation_export", text="Export annotation.json", icon="EXPORT")
        column = layout.column(align=True)
        column.label(text="Without a file, Retarget reads these,")
        column.label(text="or with neither, the procedural hands'.")


class VIEW3D_PT_contact_edit_library(SubPanel, bpy.types.Panel):
    """Saving and loading patches as reusable libraries; manifold proxies for broken meshes."""

    bl_label = "Library"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        row = layout.row(align=True)
        row.operator("contact_edit.library_save", text="Save", icon="EXPORT")
        row.operator("contact_edit.library_load", text="Load", icon="IMPORT")
        layout.operator("contact_edit.make_proxy", text="Manifold Proxy", icon="MOD_REMESH")


classes = (
    CONTACT_EDIT_UL_patches,
    VIEW3D_PT_contact_edit,
    VIEW3D_PT_contact_edit_patches,
    VIEW3D_PT_contact_edit_brush,
    VIEW3D_PT_contact_edit_pose,
    VIEW3D_PT_contact_edit_rig,
    VIEW3D_PT_contact_edit_retarget,
    VIEW3D_PT_contact_edit_annotation,
    VIEW3D_PT_contact_edit_library,
)
