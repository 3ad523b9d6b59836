"""The "Device" sub-panel of the Contact tab: the port, the bindings, the live joints, calibration,
recording and proposing a device for a kit."""

import bpy

from tangible import DeviceState, colour_name, list_ports

from ..ui.panels import SubPanel
from .session import device_armature, live_session


def joint_label(state: DeviceState, joint: int) -> str:
    """How the panel names a live joint: its id and colour."""
    colour = state.components[joint].colour
    return f"Joint {joint} ({colour_name(colour)})" if colour is not None else f"Joint {joint}"


def draw_mapping(layout, binding) -> None:
    """How a scalar binding (or the operator making one) maps its joint's angle to the number it sets."""
    layout.prop(binding, "channel")
    row = layout.row(align=True)
    row.prop(binding, "source_min")
    row.prop(binding, "source_max")
    row = layout.row(align=True)
    row.prop(binding, "target_min")
    row.prop(binding, "target_max")


class CONTACT_EDIT_UL_device_bindings(bpy.types.UIList):
    """One row per binding: the joint and what it drives."""

    def draw_item(self, context, layout, data, item, icon, active_data, active_property, index=0, flt_flag=0):
        row = layout.row(align=True)
        row.label(text=f"#{item.joint}", icon="CON_ROTLIKE" if item.target == "BONE" else "SHAPEKEY_DATA")
        if item.target == "BONE":
            row.label(text=item.bone or "(no bone)")
        else:
            owner = item.object.name if item.object else "(no object)"
            row.label(text=f"{owner}: {item.shape_key if item.target == 'SHAPE_KEY' else item.data_path}")


class CONTACT_EDIT_MT_device_ports(bpy.types.Menu):
    """The serial ports of this computer."""

    bl_label = "Serial Ports"

    def draw(self, context):
        layout = self.layout
        ports = list_ports()
        if not ports:
            layout.label(text="No serial ports found", icon="INFO")
        for device, description in ports:
            choose = layout.operator("wm.context_set_string", text=f"{device} — {description}")
            choose.data_path, choose.value = "scene.contact_edit_device.port", device


class VIEW3D_PT_contact_edit_device(SubPanel, bpy.types.Panel):
    bl_label = "Puppet Device"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        settings = context.scene.contact_edit_device
        armature = device_armature(context)
        session = live_session(context)
        layout.prop(settings, "armature")
        self.draw_connection(layout, settings, session)
        self.draw_bindings(layout, settings, armature)
        if session is not None and session.state is not None:
            self.draw_live_joints(layout, settings, session)
        self.draw_recording(layout, settings)
        self.draw_proposal(layout, settings)

    @staticmethod
    def draw_connection(layout, settings, session) -> None:
        column = layout.column()
        column.enabled = session is None
        row = column.row(align=True)
        row.enabled = not settings.simulator
        row.prop(settings, "port", text="")
        row.menu("CONTACT_EDIT_MT_device_ports", text="", icon="DOWNARROW_HLT")
        column.prop(settings, "simulator")
        if settings.simulator:
            row = column.row(align=True)
            row.prop(settings, "simulator_seed")
            row.prop(settings, "simulator_corruption")
        column.prop(settings, "rate")
        if session is None:
            layout.operator("contact_edit.device_connect", icon="PLAY")
            return
        layout.operator("contact_edit.device_stop", icon="PAUSE")
        layout.label(text=settings.status, icon="ERROR" if session.level == "WARNING" else "INFO")

    @staticmethod
    def draw_bindings(layout, settings, armature) -> None:
        layout.label(text="Bindings")
        row = layout.row()
        row.template_list(
            "CONTACT_EDIT_UL_device_bindings", "", settings, "bindings", settings, "active_binding", rows=3
        )
        column = row.column(align=True)
        column.operator("contact_edit.device_bind", text="", icon="ADD")
        column.operator("contact_edit.device_unbind", text="", icon="REMOVE")
        if not 0 <= settings.active_binding < len(settings.bindings):
            return
        binding = settings.bindings[settings.active_binding]
        box = layout.box()
        box.prop(binding, "joint")
        box.prop(binding, "target")
        if binding.target == "BONE":
            if armature is not None:
                box.prop_search(binding, "bone", armature.pose, "bones")
            return
        box.prop(binding, "object")
        keys = getattr(binding.object.data, "shape_keys", None) if binding.object else None
        if binding.target == "SHAPE_KEY" and keys is not None:
            box.prop_search(binding, "shape_key", keys, "key_blocks")
        elif binding.target == "PROPERTY":
            box.prop(binding, "data_path")
        draw_mapping(box, binding)

    @staticmethod
    def draw_live_joints(layout, settings, session) -> None:
        state = session.state
        bound = {b.joint for b in settings.bindings}
        box = layout.box()
        box.label(text="Attached joints (turn one, or blink it, to spot it)")
        box.operator_context = "EXEC_DEFAULT"  # bind at once, no dialog
        for joint in state.attached:
            if state.components[joint].kind != "joint":
                continue
            row = box.row(align=True)
            row.label(text=joint_label(state, joint), icon="LINKED" if joint in bound else "UNLINKED")
            row.operator("contact_edit.device_identify", text="", icon="LIGHT").joint = joint
            bind = row.operator("contact_edit.device_bind", text="Bind to Active Bone")
            bind.joint, bind.target = joint, "BONE"
        row = box.row(align=True)
        row.operator("contact_edit.device_calibrate", text="Calibrate to Rest").pose = "REST"
        row.operator("contact_edit.device_calibrate", text="To Starting Pose").pose = "START"
        zero = box.operator("contact_edit.device_calibrate", text="Zero Joints on Device and Calibrate")
        zero.pose, zero.zero_device = "REST", True

    @staticmethod
    def draw_recording(layout, settings) -> None:
        row = layout.row(align=True)
        row.prop(settings, "record")
        if settings.record == "ON_DEMAND":
            row.operator("contact_edit.device_key", text="", icon="KEY_HLT")
        layout.prop(settings, "sample_action")
        layout.prop(settings, "interpolate")

    @staticmethod
    def draw_proposal(layout, settings) -> None:
        box = layout.box()
        box.label(text="Kit", icon="MOD_BUILD")
        box.prop(settings, "kit_joints")
        row = box.row(align=True)
        for name in ("kit_t", "kit_y", "kit_cross", "kit_trident"):
            row.prop(settings, name)
        box.operator("contact_edit.device_propose", icon="OUTLINER_DATA_ARMATURE")
        if settings.plan:
            box.label(text="Bindings refer to the proposed device until it is connected", icon="INFO")


classes = (CONTACT_EDIT_UL_device_bindings, CONTACT_EDIT_MT_device_ports, VIEW3D_PT_contact_edit_device)
