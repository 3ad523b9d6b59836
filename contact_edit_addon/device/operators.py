"""The puppet device's operators (Glauser et al. 2016): connect to a port or the built-in simulator, bind
joints to bones (as a proposed device says, or by hand) and to shape keys or any number property,
calibrate, key, stop, and propose a device for a kit.

The live connection they start and stop is a :class:`~.session.Session`, in
:mod:`.session` (which keeps one per driven armature and says what each tick
applies); the bindings and settings they edit are the scene's, in
:mod:`.properties`. Interactively ``contact_edit.device_connect`` ticks the
session from a modal timer; in background mode (no window, so no timers) scripts call
``contact_edit.device_update`` instead, e.g. once per frame. ``contact_edit.device_stop`` closes the port
and gives the bones and numbers the device touched back their values from before connecting.
"""

from __future__ import annotations

import bpy
import numpy as np

from tangible import Kit, instructions_text, reduce

from .. import store
from ..bridge import BridgeError
from ..operators.common import ExplainedPoll, HotkeyTool, guarded
from .bridge import ArmatureRig, ScalarTarget, action_sample_poses, scalar_target
from .panel import draw_mapping
from .properties import CHANNEL_ITEMS, TARGETS
from .session import (
    Session,
    build_puppet,
    device_armature,
    live_session,
    open_device,
    plan_device,
    plan_json,
    sessions,
    wait_for_device,
)

#: The text datablock that receives a proposed device's assembly instructions.
INSTRUCTIONS_TEXT = "Device assembly"


def need_armature(context) -> str | None:
    if device_armature(context) is None:
        return "Choose the armature to drive in the Device panel, or select one"
    return None


def need_live(context) -> str | None:
    reason = need_armature(context)
    if reason is None and live_session(context) is None:
        reason = f"No device is driving '{device_armature(context).name}': connect one first"
    return reason


class CONTACT_EDIT_OT_device_connect(ExplainedPoll, bpy.types.Operator):
    """Connect the puppet device (or the simulator) and drive the armature live from it"""

    bl_idname = "contact_edit.device_connect"
    bl_label = "Connect Device"
    bl_options = {"REGISTER", "UNDO"}

    @staticmethod
    def why_not(context) -> str | None:
        reason = need_armature(context)
        if reason is None and live_session(context) is not None:
            reason = f"'{device_armature(context).name}' is already driven by the device"
        return reason

    @guarded(capitalised=True)
    def execute(self, context):
        settings = context.scene.contact_edit_device
        armature = device_armature(context)
        rig = ArmatureRig.capture(armature)
        build_puppet(settings, rig, armature)  # refuse bad bindings before opening anything
        plan = plan_device(settings.plan) if settings.plan else None
        reader, simulator, port = open_device(settings)
        try:
            ids = wait_for_device(reader, port, plan, {b.joint for b in settings.bindings})
        except BaseException:
            reader.close()
            if simulator is not None:
                simulator.close()
            raise
        if plan is not None:
            for binding in settings.bindings:
                binding.joint = ids.get(binding.joint, binding.joint)
            settings.plan = ""
        settings.armature = armature  # so the panel keeps finding the session whatever is selected
        session = sessions[armature.name] = Session(rig, reader, simulator, port)
        _, message = session.tick(context.scene)
        self.report({"INFO"}, message)
        return {"FINISHED"}

    def invoke(self, context, event):
        if context.window is None:
            return self.execute(context)
        if self.execute(context) != {"FINISHED"}:
            return {"CANCELLED"}
        self._armature = device_armature(context).name
        self._session = sessions[self._armature]
        self._reported = context.scene.contact_edit_device.status  # what execute reported
        rate = context.scene.contact_edit_device.rate
        self._timer = context.window_manager.event_timer_add(1.0 / rate, window=context.window)
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if sessions.get(self._armature) is not self._session:
            return self._end(context)  # stopped
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        try:
            level, message = self._session.tick(context.scene)
        except BridgeError as err:
            sessions.pop(self._armature, None)
            self._session.stop(restore=False)
            self.report({"ERROR"}, f"Stopped driving: {err}")
            return self._end(context)
        if message != self._reported:  # the status bar says what the panel says
            self.report({level}, message)
            self._reported = message
        store.redraw("VIEW_3D")
        return {"PASS_THROUGH"}

    def _end(self, context) -> set:
        context.window_manager.event_timer_remove(self._timer)
        store.redraw()
        return {"CANCELLED"}


class CONTACT_EDIT_OT_device_update(ExplainedPoll, bpy.types.Operator):
    """Apply the device's latest state to the armature once (what the live timer does; for scripts)"""

    bl_idname = "contact_edit.device_update"
    bl_label = "Update from Device"
    bl_options = {"REGISTER", "UNDO"}

    why_not = staticmethod(need_live)

    @guarded(capitalised=True)
    def execute(self, context):
        session = live_session(context)
        try:
            level, message = session.tick(context.scene)
        except BridgeError:
            sessions.pop(session.armature, None)
            session.stop(restore=False)
            raise
        self.report({level}, message)
        return {"FINISHED"}


class CONTACT_EDIT_OT_device_stop(ExplainedPoll, bpy.types.Operator):
    """Disconnect the device and give the armature back its pose from before connecting"""

    bl_idname = "contact_edit.device_stop"
    bl_label = "Stop Device"
    bl_options = {"REGISTER", "UNDO"}

    keep_pose: bpy.props.BoolProperty(
        name="Keep pose", description="Keep the device's last pose instead of the pose from before connecting"
    )

    why_not = staticmethod(need_live)

    def execute(self, context):
        session = sessions.pop(device_armature(context).name)
        session.stop(restore=not self.keep_pose)
        kept = "kept the device's pose" if self.keep_pose else "the pose from before connecting is back"
        context.scene.contact_edit_device.status = f"Stopped: {kept}"
        self.report({"INFO"}, f"Disconnected the device from '{session.armature}'; {kept}")
        store.redraw()
        return {"FINISHED"}


class CONTACT_EDIT_OT_device_calibrate(ExplainedPoll, bpy.types.Operator):
    """Hold the device like the character and take its shape as the bound bones' rest pose"""

    bl_idname = "contact_edit.device_calibrate"
    bl_label = "Calibrate Device"
    bl_options = {"REGISTER", "UNDO"}

    pose: bpy.props.EnumProperty(
        name="Device matches",
        items=[
            ("REST", "Rest pose", "The device is held like the armature's rest pose"),
            ("START", "Starting pose", "The device is held like the pose the armature had before connecting"),
        ],
        default="REST",
    )
    zero_device: bpy.props.BoolProperty(
        name="Zero the joints",
        description="Also store this shape as each bound joint's zero on the device itself (in its flash, "
        "the firmware's zero command), so that any host reads the joints straight in it",
        default=False,
    )

    why_not = staticmethod(need_live)

    @guarded(capitalised=True)
    def execute(self, context):
        session = live_session(context)
        count = session.calibrate(context.scene.contact_edit_device, self.pose == "START", self.zero_device)
        session.tick(context.scene)
        what = "rest pose" if self.pose == "REST" else "starting pose"
        zeroed = ", zeroed on the device" if self.zero_device else ""
        self.report(
            {"INFO"},
            f"Calibrated {count} joint{'s' * (count != 1)}{zeroed}: the device's shape is the {what}",
        )
        return {"FINISHED"}


class CONTACT_EDIT_OT_device_identify(ExplainedPoll, bpy.types.Operator):
    """Blink the joint's green LED on the device, to find it"""

    bl_idname = "contact_edit.device_identify"
    bl_label = "Identify Joint"

    joint: bpy.props.IntProperty(name="Joint", description="The joint's id", min=0)

    why_not = staticmethod(need_live)

    @guarded(capitalised=True)
    def execute(self, context):
        live_session(context).identify(self.joint)
        self.report({"INFO"}, f"Joint {self.joint} blinks its green LED")
        return {"FINISHED"}


class CONTACT_EDIT_OT_device_key(HotkeyTool, bpy.types.Operator):
    """Key what the device poses (bones and numbers) at the current frame"""

    bl_idname = "contact_edit.device_key"
    bl_label = "Key Device Pose"
    bl_options = {"REGISTER", "UNDO"}

    @staticmethod
    def why_not(context) -> str | None:
        armature = device_armature(context)
        if armature is None:
            return "No device is connected: choose an armature and connect in the Puppet Device panel"
        if live_session(context) is None:
            return f"No device is driving '{armature.name}': connect one in the Puppet Device panel first"
        return None

    @guarded(capitalised=True)
    def execute(self, context):
        count = live_session(context).key(context.scene)
        self.report(
            {"INFO"}, f"Keyed {count} channel{'s' * (count != 1)} at frame {context.scene.frame_current}"
        )
        return {"FINISHED"}


class CONTACT_EDIT_OT_device_bind(ExplainedPoll, bpy.types.Operator):
    """Bind a device joint to a bone (by default the active bone), a shape key or a property"""

    bl_idname = "contact_edit.device_bind"
    bl_label = "Bind Joint"
    bl_options = {"REGISTER", "UNDO"}

    joint: bpy.props.IntProperty(name="Joint", min=1, default=1, description="The device joint's id")
    target: bpy.props.EnumProperty(name="Drives", items=TARGETS, default="BONE")
    bone: bpy.props.StringProperty(name="Bone", description="Default: the active bone")
    object_name: bpy.props.StringProperty(name="Object", description="Owner of the shape key or property")
    shape_key: bpy.props.StringProperty(name="Shape key")
    data_path: bpy.props.StringProperty(name="Data path")
    channel: bpy.props.EnumProperty(name="Angle", items=CHANNEL_ITEMS, default="bend_a")
    source_min: bpy.props.FloatProperty(name="From angle", subtype="ANGLE", default=0.0)
    source_max: bpy.props.FloatProperty(name="To angle", subtype="ANGLE", default=np.pi / 2)
    target_min: bpy.props.FloatProperty(name="From value", default=0.0)
    target_max: bpy.props.FloatProperty(name="To value", default=1.0)

    why_not = staticmethod(need_armature)

    def invoke(self, context, event):
        self.bone = self.bone or active_bone(context)
        if context.window is None:
            return self.execute(context)
        return context.window_manager.invoke_props_dialog(self)

    def draw(self, context):
        layout = self.layout
        layout.prop(self, "joint")
        layout.prop(self, "target")
        if self.target == "BONE":
            layout.prop_search(self, "bone", device_armature(context).pose, "bones")
            return
        layout.prop_search(self, "object_name", bpy.data, "objects")
        obj = bpy.data.objects.get(self.object_name)
        keys = getattr(obj.data, "shape_keys", None) if obj is not None else None
        if self.target == "SHAPE_KEY" and keys is not None:
            layout.prop_search(self, "shape_key", keys, "key_blocks")
        elif self.target == "SHAPE_KEY":
            layout.prop(self, "shape_key")
        else:
            layout.prop(self, "data_path")
        draw_mapping(layout, self)

    @guarded(capitalised=True)
    def execute(self, context):
        settings = context.scene.contact_edit_device
        bindings = settings.bindings
        if self.target == "BONE":
            armature = device_armature(context)
            bone = self.bone or active_bone(context)
            if not bone:
                raise BridgeError("choose the bone to drive (make it the active bone)")
            if bone not in armature.pose.bones:
                raise BridgeError(f"'{armature.name}' has no bone called '{bone}'")
            replaced = [i for i, b in enumerate(bindings) if b.target == "BONE" and b.bone == bone]
            what = f"bone '{bone}'"
        else:
            obj = bpy.data.objects.get(self.object_name)
            if obj is None:
                raise BridgeError(f"there is no object called '{self.object_name}'")
            path = self.shape_key if self.target == "SHAPE_KEY" else self.data_path
            target = ScalarTarget(obj.name, self.target, path)
            target.check()
            if self.source_min == self.source_max:
                raise BridgeError("the angle range needs two different angles")
            replaced = [
                i for i, b in enumerate(bindings) if b.target != "BONE" and scalar_target(b) == target
            ]
            what = target.label()
        for i in reversed(replaced):
            bindings.remove(i)
        binding = bindings.add()
        binding.joint, binding.target = self.joint, self.target
        if self.target == "BONE":
            binding.bone = bone
        else:
            binding.object = obj
            binding.shape_key, binding.data_path, binding.channel = (
                self.shape_key,
                self.data_path,
                self.channel,
            )
            binding.source_min, binding.source_max = self.source_min, self.source_max
            binding.target_min, binding.target_max = self.target_min, self.target_max
        settings.active_binding = len(bindings) - 1
        self.report({"INFO"}, f"Joint {self.joint} drives {what}")
        return {"FINISHED"}


def active_bone(context) -> str:
    """The name of the device armature's active bone ("" if none)."""
    armature = device_armature(context)
    if armature is None:
        return ""
    active = context.active_pose_bone if context.active_object == armature else None
    active = active or armature.data.bones.active
    return active.name if active is not None else ""


class CONTACT_EDIT_OT_device_unbind(ExplainedPoll, bpy.types.Operator):
    """Remove a binding (by default the active one)"""

    bl_idname = "contact_edit.device_unbind"
    bl_label = "Unbind Joint"
    bl_options = {"REGISTER", "UNDO"}

    index: bpy.props.IntProperty(
        name="Binding", default=-1, min=-1, description="Which binding (-1: the active one)"
    )

    @staticmethod
    def why_not(context) -> str | None:
        return None if context.scene.contact_edit_device.bindings else "There are no bindings"

    def execute(self, context):
        settings = context.scene.contact_edit_device
        index = settings.active_binding if self.index < 0 else self.index
        if not 0 <= index < len(settings.bindings):
            self.report({"ERROR"}, f"There is no binding {index + 1} (there are {len(settings.bindings)})")
            return {"CANCELLED"}
        settings.bindings.remove(index)
        settings.active_binding = max(0, min(settings.active_binding, len(settings.bindings) - 1))
        return {"FINISHED"}


class CONTACT_EDIT_OT_device_propose(ExplainedPoll, bpy.types.Operator):
    """Fit the kit to the armature's sample poses: which bones get joints, where splitters go, and the
    assembly instructions; binds the planned joints to their bones"""

    bl_idname = "contact_edit.device_propose"
    bl_label = "Propose Device"
    bl_options = {"REGISTER", "UNDO"}

    @staticmethod
    def why_not(context) -> str | None:
        reason = need_armature(context)
        if reason is None and live_session(context) is not None:
            reason = "Stop the device before proposing a new one"
        if reason is None and context.scene.contact_edit_device.sample_action is None:
            reason = "Choose the sample poses (an action with a few keyed poses) first"
        return reason

    @guarded(capitalised=True)
    def execute(self, context):
        settings = context.scene.contact_edit_device
        armature = device_armature(context)
        rig = ArmatureRig.capture(armature, weights=True)
        samples = action_sample_poses(armature, settings.sample_action, rig)
        counts = {
            "T": settings.kit_t,
            "Y": settings.kit_y,
            "cross": settings.kit_cross,
            "trident": settings.kit_trident,
        }
        reduction = reduce(
            rig.skeleton, samples, Kit(settings.kit_joints, {k: v for k, v in counts.items() if v})
        )
        joints = reduction.device.joints
        if not joints:
            raise BridgeError(
                f"the kit cannot drive any bone of '{armature.name}' (it needs a bone with a parent)"
            )
        settings.bindings.clear()
        for piece in joints:
            binding = settings.bindings.add()
            binding.joint, binding.target = piece, "BONE"
            binding.bone = rig.names[reduction.bones[piece]]
            binding.rest = reduction.rest[piece]
        settings.active_binding = 0
        settings.plan = plan_json(reduction.device)
        text = bpy.data.texts.get(INSTRUCTIONS_TEXT) or bpy.data.texts.new(INSTRUCTIONS_TEXT)
        text.from_string(instructions_text(reduction))
        splitters = len(reduction.device.splitters)
        error = 100 * reduction.relative_error
        self.report(
            {"INFO"},
            f"Proposed {len(joints)} joint{'s' * (len(joints) != 1)} and {splitters} splitter"
            f"{'s' * (splitters != 1)} ({error:.0f}% of a rigid device's pose error); "
            f"assembly instructions are in the text '{INSTRUCTIONS_TEXT}'",
        )
        return {"FINISHED"}


classes = (
    CONTACT_EDIT_OT_device_connect,
    CONTACT_EDIT_OT_device_update,
    CONTACT_EDIT_OT_device_stop,
    CONTACT_EDIT_OT_device_calibrate,
    CONTACT_EDIT_OT_device_identify,
    CONTACT_EDIT_OT_device_key,
    CONTACT_EDIT_OT_device_bind,
    CONTACT_EDIT_OT_device_unbind,
    CONTACT_EDIT_OT_device_propose,
)
