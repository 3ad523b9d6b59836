"""What the scene keeps about the puppet device (``scene.contact_edit_device``): which armature it drives,
the port or the built-in simulator, the bindings of device joints to bones and to other properties, the
kit and sample poses for proposing a device, the record mode, and a status line.

A binding's ``joint`` is the component id the device reports (shown in the panel while connected). After
:class:`~contact_edit_addon.device.operators.CONTACT_EDIT_OT_device_propose`, the ids are the planned
pieces' until the assembled device is connected and matched to the plan (``plan``), which turns them into
the live ids. Everything here is saved with the .blend and follows undo; the live connection is not.
"""

import math

import bpy

from tangible import CHANNELS

_CHANNEL_WORDS = {
    "bend_a": ("First hinge", "The first hinge angle"),
    "bend_b": ("Second hinge", "The second hinge angle"),
    "twist_proximal": ("Near ring", "The twisting ring at the joint's base"),
    "twist_distal": ("Far ring", "The twisting ring at the joint's tip"),
    "twist": ("Twist", "Both rings together"),
    "bend": ("Bend", "How far the joint is bent, in any direction"),
}
#: How a scalar binding reads its joint: tangible.puppet.CHANNELS, in words.
CHANNEL_ITEMS = [(channel, *_CHANNEL_WORDS[channel]) for channel in CHANNELS]

TARGETS = [
    ("BONE", "Bone", "The joint's rotation turns a bone of the armature"),
    ("SHAPE_KEY", "Shape key", "One angle of the joint sets a shape key's value"),
    ("PROPERTY", "Property", "One angle of the joint sets any number property of an object (a data path)"),
]

RECORD_MODES = [
    ("OFF", "Off", "Drive the armature without keying"),
    ("EVERY_FRAME", "Every frame", "Key the pose on every new frame (play the timeline while you perform)"),
    ("ON_DEMAND", "On demand", "Key the pose only when asked (Key Pose)"),
]

IDENTITY = (1.0, 0.0, 0.0, 0.0)


def _is_armature(_self, obj) -> bool:
    return obj.type == "ARMATURE"


class CONTACT_EDIT_PG_device_binding(bpy.types.PropertyGroup):
    """One device joint driving a bone's rotation, or one of its angles driving a number."""

    joint: bpy.props.IntProperty(name="Joint", min=1, default=1, description="The device joint's id")
    target: bpy.props.EnumProperty(name="Drives", items=TARGETS, default="BONE")
    bone: bpy.props.StringProperty(name="Bone", description="The bone the joint turns")
    object: bpy.props.PointerProperty(
        name="Object", type=bpy.types.Object, description="The object owning the shape key or property"
    )
    shape_key: bpy.props.StringProperty(name="Shape key")
    data_path: bpy.props.StringProperty(
        name="Data path",
        description='The number to set, from the object, as for drivers: location.z, ["open"], '
        'pose.bones["jaw"]["open"]',
    )
    channel: bpy.props.EnumProperty(name="Angle", items=CHANNEL_ITEMS, default="bend_a")
    source_min: bpy.props.FloatProperty(name="From angle", subtype="ANGLE", default=0.0)
    source_max: bpy.props.FloatProperty(name="To angle", subtype="ANGLE", default=math.pi / 2)
    target_min: bpy.props.FloatProperty(name="From value", default=0.0)
    target_max: bpy.props.FloatProperty(name="To value", default=1.0)
    rest: bpy.props.FloatVectorProperty(
        name="Calibration reading",
        size=4,
        default=IDENTITY,
        description="The joint's rotation (w, x, y, z) when the bone is at its calibration pose",
    )
    pose: bpy.props.FloatVectorProperty(
        name="Calibration pose",
        size=4,
        default=IDENTITY,
        description="The bone's rotation (w, x, y, z) at calibration (identity: the rest pose)",
    )


class CONTACT_EDIT_PG_device(bpy.types.PropertyGroup):
    """The puppet device of a scene."""

    armature: bpy.props.PointerProperty(
        name="Armature",
        type=bpy.types.Object,
        poll=_is_armature,
        description="The armature the device drives (default: the active armature)",
    )
    port: bpy.props.StringProperty(
        name="Port", description="Serial port or pyserial URL of the device (/dev/ttyACM0, COM3, socket://…)"
    )
    simulator: bpy.props.BoolProperty(
        name="Simulator", description="Drive from a simulated device instead of a port, to try things out"
    )
    simulator_seed: bpy.props.IntProperty(
        name="Motion seed", min=0, description="Seed of the simulated motion"
    )
    simulator_corruption: bpy.props.FloatProperty(
        name="Corrupt frames",
        subtype="PERCENTAGE",
        min=0.0,
        max=50.0,
        default=0.0,
        description="Share of the simulated device's records damaged on the way to the computer",
    )
    rate: bpy.props.FloatProperty(
        name="Updates per second",
        min=1.0,
        max=240.0,
        default=60.0,
        description="How often the pose is updated",
    )
    bindings: bpy.props.CollectionProperty(type=CONTACT_EDIT_PG_device_binding)
    active_binding: bpy.props.IntProperty(name="Active binding", min=0)
    sample_action: bpy.props.PointerProperty(
        name="Sample poses",
        type=bpy.types.Action,
        description="An action whose keyed frames are sample poses: bones no joint drives follow them by "
        "pose interpolation, and Propose Device fits the kit to them",
    )
    interpolate: bpy.props.BoolProperty(
        name="Interpolate other bones",
        default=True,
        description="Move the bones no joint drives by pose interpolation between the sample poses",
    )
    kit_joints: bpy.props.IntProperty(name="Joints", min=1, max=64, default=5)
    kit_t: bpy.props.IntProperty(name="T", min=0, max=16, description="T splitters (two outlets at ±90°)")
    kit_y: bpy.props.IntProperty(name="Y", min=0, max=16, description="Y splitters (two outlets at ±45°)")
    kit_cross: bpy.props.IntProperty(
        name="Cross", min=0, max=16, description="Cross splitters (-90°, 0°, 90°)"
    )
    kit_trident: bpy.props.IntProperty(
        name="Trident", min=0, max=16, description="Trident splitters (-45°, 0°, 45°)"
    )
    plan: bpy.props.StringProperty(
        name="Planned device",
        description="The proposed device (JSON) the bindings refer to until it is connected",
    )
    record: bpy.props.EnumProperty(name="Record", items=RECORD_MODES, default="OFF")
    status: bpy.props.StringProperty(name="Status", description="What the device is doing")


classes = (CONTACT_EDIT_PG_device_binding, CONTACT_EDIT_PG_device)


def register() -> None:
    bpy.types.Scene.contact_edit_device = bpy.props.PointerProperty(type=CONTACT_EDIT_PG_device)


def unregister() -> None:
    del bpy.types.Scene.contact_edit_device
