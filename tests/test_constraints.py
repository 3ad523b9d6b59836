"""Bones posed as Blender poses them: parenting with every inherit flag, channels in every rotation mode,
constraints of every modelled type in many spaces, options and influences, and the real Rigify hand —
all against ``pose_bone.matrix`` of bpy 5.0.1 — plus complex-step derivatives through the constraint
solve against central finite differences."""

import base64
import importlib.util
import pickle

import numpy as np
import pytest

from solver.errors import SolverError
from solver.rig import analytic
from solver.rig.bones import Bone, channel_matrix, rotation_matrix
from solver.rig.constraints import Constraint, Target, TargetBone, pose_bone
from solver.rig.interpolation import interp_m4_m4m4

from .blender import run_blender

needs_bpy = pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="needs bpy (the dev extra)")

#: Blender computes in float32; long chains of short bones amplify its rounding to a few 1e-6.
TOLERANCE = 1e-5

SETUP = """
import base64, pickle
import numpy as np
from mathutils import Euler, Matrix
from contact_edit_addon.bridge.constraints import read_bone, read_constraints

def channels(pb):
    mode = pb.rotation_mode
    if mode == "QUATERNION":
        rotation = list(pb.rotation_quaternion)
    elif mode == "AXIS_ANGLE":
        rotation = list(pb.rotation_axis_angle)
    else:
        rotation = list(pb.rotation_euler)
    return (mode, list(pb.location), rotation, list(pb.scale))

def rig_data(ob):
    return dict(
        bones={pb.name: read_bone(pb) for pb in ob.pose.bones},
        constraints={pb.name: read_constraints(ob, pb) for pb in ob.pose.bones},
        world=np.array(ob.matrix_world),
    )

def pose_data(ob):
    return dict(
        channels={pb.name: channels(pb) for pb in ob.pose.bones},
        pose={pb.name: np.array(pb.matrix) for pb in ob.pose.bones},
        basis={pb.name: np.array(pb.matrix_basis) for pb in ob.pose.bones},
    )

def send(value):
    result(base64.b64encode(pickle.dumps(value)).decode())
"""


def _receive(text: str):
    return pickle.loads(base64.b64decode(text))


def _dependencies(bones, constraints, name):
    bone = bones[name]
    out = [bone.parent] if bone.parent else []
    for con in constraints.get(name, ()):
        out += [t.subtarget for t in con.targets if t.subtarget]
        if con.space_subtarget:
            out.append(con.space_subtarget)
    return out


def _order(bones, constraints, names):
    seen, out = set(), []

    def visit(name):
        if name in seen:
            return
        seen.add(name)
        for dep in _dependencies(bones, constraints, name):
            visit(dep)
        out.append(name)

    for name in names:
        visit(name)
    return out


def _local(channel):
    mode, location, rotation, scale = channel
    return channel_matrix(
        np.asarray(location), rotation_matrix(mode, np.asarray(rotation)), np.asarray(scale)
    )


def evaluate(bones, constraints, channels, world, names, given=None):
    """Pose matrices of ``names`` (parents and targets first), those of other bones taken from ``given``."""
    poses = dict(given or {})
    for name in _order(bones, constraints, names):
        if name in poses and name not in names:
            continue
        bone = bones[name]
        parent = bones[bone.parent] if bone.parent else None
        targets = {}
        for dep in _dependencies(bones, constraints, name):
            tb = bones[dep]
            targets[dep] = TargetBone(
                tb, bones[tb.parent] if tb.parent else None, poses[dep], poses.get(tb.parent)
            )
        poses[name] = pose_bone(
            bone,
            parent,
            poses.get(bone.parent),
            _local(channels[name]),
            constraints.get(name, ()),
            targets,
            world,
        )
    return poses


SMALL_RIGS = """
from solver.rig.spaces import convert_space
bpy.ops.wm.read_factory_settings(use_empty=True)
arm = bpy.data.armatures.new("A")
ob = bpy.data.objects.new("A", arm)
bpy.context.scene.collection.objects.link(ob)
bpy.context.view_layer.objects.active = ob
# Turned, uniformly scaled and moved armature object; an Empty as an object target.
ob.matrix_world = Matrix.LocRotScale((0.3, -0.2, 0.5), Euler((0.3, 0.5, -0.7)), (1.2, 1.2, 1.2))
empty = bpy.data.objects.new("E", None)
bpy.context.scene.collection.objects.link(empty)
empty.matrix_world = Matrix.LocRotScale((0.5, 0.4, -0.3), Euler((0.2, -0.4, 1.0)), (0.9, 1.1, 1.3))
bpy.ops.object.mode_set(mode="EDIT")

def add(name, head, tail, parent=None, connect=False, roll=0.0):
    e = arm.edit_bones.new(name)
    e.head, e.tail, e.roll = head, tail, roll
    if parent:
        e.parent = arm.edit_bones[parent]
        e.use_connect = connect
    return e

add("root", (0, 0, 0), (0, 0.5, 0.2), roll=0.3)
add("mid", (0.1, 0.6, 0.2), (0.2, 1.2, 0.4), "root", roll=-0.5)
add("tgt", (0.5, 1.0, 0.2), (0.7, 1.5, 0.6), "mid", roll=0.7)  # sheared: its parent chain scales unevenly
add("tgt2", (-0.4, 0.8, 0.1), (-0.6, 1.1, 0.5), "root", roll=-0.2)
add("space", (0.2, 0.2, 0.9), (0.1, 0.6, 1.2), "root", roll=1.0)
# Every inherit-scale mode, with and without inherited rotation and local location, under a sheared parent.
for i, mode in enumerate(["FULL", "FIX_SHEAR", "ALIGNED", "AVERAGE", "NONE", "NONE_LEGACY"]):
    for rot in (True, False):
        for loc in (True, False):
            e = add(f"inh_{mode}_{int(rot)}{int(loc)}", (0.1 * i, 1.3, 0.5), (0.1 * i + 0.2, 1.6, 0.9), "tgt",
                    roll=0.2 * i)
            e.inherit_scale, e.use_inherit_rotation, e.use_local_location = mode, rot, loc
add("conn", (0.7, 1.5, 0.6), (0.8, 1.9, 0.5), "tgt", connect=True)
add("conn2", (0.8, 1.9, 0.5), (0.8, 2.2, 0.3), "conn", connect=True)

cases = []
def case(type, parent="mid", connect_to=None, **kw):
    name = f"c{len(cases)}_{type}"
    i = len(cases)
    if connect_to:
        add(name, arm.edit_bones[connect_to].tail, (0.3 + 0.05 * i, 2.0, 0.1 * i), connect_to, connect=True)
    else:
        head, tail = (0.05 * i, 0.9, -0.3 + 0.03 * i), (0.05 * i + 0.1, 1.3, -0.1 + 0.03 * i)
        add(name, head, tail, parent, roll=0.1 * i)
    cases.append((name, type, kw))
    return name

S = lambda owner, target: dict(owner_space=owner, target_space=target)
for mix in ["REPLACE", "BEFORE_FULL", "AFTER_FULL", "BEFORE", "AFTER", "BEFORE_SPLIT", "AFTER_SPLIT"]:
    case("COPY_TRANSFORMS", mix_mode=mix, influence=0.6 if mix in ("BEFORE", "AFTER_SPLIT") else 1.0)
for o, t in [("WORLD", "WORLD"), ("LOCAL", "LOCAL"), ("POSE", "LOCAL_WITH_PARENT"),
             ("LOCAL", "LOCAL_OWNER_ORIENT"),
             ("LOCAL_WITH_PARENT", "POSE"), ("CUSTOM", "LOCAL_OWNER_ORIENT"), ("LOCAL", "CUSTOM")]:
    case("COPY_TRANSFORMS", mix_mode="BEFORE", remove_target_shear=(o == "POSE"), influence=0.45, **S(o, t))
case("COPY_TRANSFORMS", connect_to="conn2", **S("LOCAL", "LOCAL"), influence=0.8)
for mix in ["REPLACE", "ADD", "BEFORE", "AFTER", "OFFSET"]:
    case("COPY_ROTATION", mix_mode=mix, **S("LOCAL", "LOCAL"), influence=0.7)
case("COPY_ROTATION", use_y=False, invert_x=True, euler_order="ZXY", **S("WORLD", "WORLD"))
case("COPY_ROTATION", use_z=False, invert_y=True, mix_mode="ADD", **S("LOCAL_WITH_PARENT", "LOCAL"),
     influence=0.3)
case("COPY_LOCATION", use_offset=True, invert_z=True, head_tail=0.6, **S("WORLD", "WORLD"))
case("COPY_LOCATION", use_y=False, head_tail=0.3, **S("LOCAL", "LOCAL"), influence=0.5)
case("COPY_LOCATION", target="EMPTY", **S("WORLD", "WORLD"), influence=0.8)
case("COPY_LOCATION", connect_to="mid", **S("WORLD", "WORLD"))
case("COPY_SCALE", power=0.7, use_offset=True, **S("WORLD", "WORLD"))
case("COPY_SCALE", use_make_uniform=True, **S("LOCAL", "LOCAL"))
case("COPY_SCALE", use_make_uniform=True, use_x=False, use_offset=True, use_add=True, **S("WORLD", "POSE"),
     influence=0.5)
case("COPY_SCALE", use_z=False, **S("POSE", "WORLD"))
for vol, keep in [("VOLUME_XZX", "PLANE_X"), ("VOLUME_X", "PLANE_Z"), ("VOLUME_Z", "SWING_Y"),
                  ("NO_VOLUME", "SWING_Y")]:
    case("STRETCH_TO", volume=vol, keep_axis=keep, rest_length=0.6, bulge=1.7, head_tail=0.4)
case("STRETCH_TO", rest_length=1.1, bulge=2.0, use_bulge_min=True, use_bulge_max=True, bulge_min=0.8,
     bulge_max=1.3,
     bulge_smooth=0.4, keep_axis="SWING_Y", influence=0.7)
case("STRETCH_TO", rest_length=0.3, bulge=2.0, use_bulge_min=True, use_bulge_max=True, bulge_min=0.8,
     bulge_max=1.3,
     bulge_smooth=0.6, keep_axis="PLANE_X")
case("STRETCH_TO", rest_length=0.5, connect_to="mid")
case("CHILD_OF", inverse=True, **S("WORLD", "WORLD"))
case("CHILD_OF", inverse=True, use_location_y=False, use_rotation_x=False, use_scale_z=False,
     **S("WORLD", "WORLD"),
     influence=0.6)
case("CHILD_OF", use_rotation_z=False, **S("LOCAL", "WORLD"))  # stays in local space (CONSTRAINT_SPACEONCE)
case("CHILD_OF", inverse=True, **S("POSE", "LOCAL"), influence=0.5)
case("ARMATURE", arm_targets=[("tgt", 0.4), ("tgt2", 0.7), ("mid", 0.2)], parent=None)
case("ARMATURE", arm_targets=[("tgt", 0.4), ("tgt2", 0.7)], use_deform_preserve_volume=True, parent=None)
case("ARMATURE", arm_targets=[("tgt", 1.0), ("tgt2", 0.5)], use_bone_envelopes=True,
     use_current_location=True,
     parent="root")
case("LIMIT_ROTATION", use_limit_x=True, min_x=-0.3, max_x=0.4, use_limit_z=True, min_z=0.1, max_z=0.9,
     owner_space="LOCAL")
case("LIMIT_ROTATION", use_limit_y=True, min_y=-0.2, max_y=0.2, euler_order="YZX", owner_space="WORLD",
     influence=0.5)
case("LIMIT_ROTATION", use_limit_x=True, min_x=-0.2, max_x=0.2, use_legacy_behavior=True, owner_space="POSE")
case("LIMIT_ROTATION", owner_space="LOCAL")  # no limit: only removes shear
case("LIMIT_LOCATION", use_min_x=True, min_x=0.1, use_max_y=True, max_y=0.05, use_min_z=True, min_z=-0.02,
     owner_space="LOCAL")
case("LIMIT_LOCATION", use_min_x=True, min_x=0.5, use_max_z=True, max_z=0.3, owner_space="WORLD",
     influence=0.4)
case("LIMIT_SCALE", use_min_x=True, min_x=1.2, use_max_y=True, max_y=0.8, owner_space="LOCAL")
case("LIMIT_SCALE", use_min_z=True, min_z=1.3, use_max_x=True, max_x=0.7, owner_space="WORLD")
for ax in ["TRACK_X", "TRACK_NEGATIVE_Y", "TRACK_Z"]:
    case("DAMPED_TRACK", track_axis=ax, head_tail=0.5, influence=0.8 if ax == "TRACK_Z" else 1.0)
case("DAMPED_TRACK", track_axis="TRACK_Y", **S("LOCAL", "LOCAL"))
for ax, up, tz in [("TRACK_NEGATIVE_Z", "UP_Y", False), ("TRACK_Y", "UP_Z", True),
                   ("TRACK_X", "UP_Z", False)]:
    case("TRACK_TO", track_axis=ax, up_axis=up, use_target_z=tz)
for ax, lock in [("TRACK_Y", "LOCK_Z"), ("TRACK_NEGATIVE_X", "LOCK_Y"), ("TRACK_Z", "LOCK_X")]:
    case("LOCKED_TRACK", track_axis=ax, lock_axis=lock, influence=0.9)
stack = case("COPY_ROTATION", **S("LOCAL", "LOCAL"), influence=0.5)  # a stack of four, partial influences
cases.append((stack, "COPY_LOCATION", dict(target="tgt2", influence=0.4)))
cases.append((stack, "LIMIT_ROTATION", dict(use_limit_x=True, min_x=-0.1, max_x=0.1, owner_space="LOCAL",
                                             influence=0.7)))
cases.append((stack, "STRETCH_TO", dict(rest_length=0.9, target="tgt2")))
muted = case("COPY_LOCATION")
cases.append((muted, "COPY_ROTATION", dict(mute=True)))
bpy.ops.object.mode_set(mode="POSE")

for name, type, kw in cases:
    c = ob.pose.bones[name].constraints.new(type)
    kw = dict(kw)
    target = kw.pop("target", "tgt")
    if type == "ARMATURE":
        for sub, w in kw.pop("arm_targets"):
            t = c.targets.new()
            t.target, t.subtarget, t.weight = ob, sub, w
    elif not type.startswith("LIMIT_"):
        if target == "EMPTY":
            c.target = empty
        else:
            c.target, c.subtarget = ob, target
    if type == "CHILD_OF":
        c.set_inverse_pending = False
    if kw.pop("inverse", False):
        c.inverse_matrix = Matrix.LocRotScale((0.1, 0.2, -0.1), Euler((0.4, 0.1, -0.3)), (1.1, 0.9, 1.2))
    if "CUSTOM" in (kw.get("owner_space"), kw.get("target_space")):
        c.space_object, c.space_subtarget = ob, "space"
    for k, v in kw.items():
        setattr(c, k, v)

modes = ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX", "QUATERNION", "AXIS_ANGLE"]
rng = np.random.default_rng(11)
poses, spaces = [], []
space_names = ["WORLD", "POSE", "LOCAL_WITH_PARENT", "LOCAL"]
for k, pb in enumerate(ob.pose.bones):
    pb.rotation_mode = modes[k % len(modes)]  # constraints decompose Euler angles in the owner's order
for trial in range(3):
    for pb in ob.pose.bones:
        pb.location = rng.uniform(-0.3, 0.3, 3)
        pb.scale = rng.uniform(0.6, 1.5, 3)
        pb.rotation_euler = rng.uniform(-1.5, 1.5, 3)
        pb.rotation_quaternion = rng.uniform(-1, 1, 4)  # not normalized: Blender normalizes it
        pb.rotation_axis_angle = rng.uniform(-1, 1, 4)
    bpy.context.view_layer.update()
    poses.append(pose_data(ob))
    # Blender's own space conversion of a random matrix, for the parenting-sensitive bones.
    M = Matrix(np.r_[rng.normal(size=(3, 4)), [[0, 0, 0, 1]]].tolist())
    conv = {}
    for pb in ob.pose.bones:
        if pb.name.startswith(("inh_", "conn", "mid", "root")):
            for a in space_names:
                for b in space_names:
                    got = ob.convert_space(pose_bone=pb, matrix=M, from_space=a, to_space=b)
                    conv[pb.name, a, b] = np.array(got)
    spaces.append((np.array(M), conv))
send(dict(rig=rig_data(ob), poses=poses, spaces=spaces, cases=len(cases)))
"""


@needs_bpy
def test_small_rigs_every_inherit_mode_and_constraint_match_blender(tmp_path):
    """Each inherit mode under a sheared parent, hinge and non-local-location bones, connected bones, every
    rotation mode, and 60-odd constraints (each type, its options, spaces, partial influences, a stack and
    a muted one) on an armature object that is turned, scaled and moved: every pose matrix, three poses."""
    out = _receive(run_blender(SMALL_RIGS, tmp_path, setup=SETUP, timeout=600))
    rig = out["rig"]
    bones, constraints, world = rig["bones"], rig["constraints"], rig["world"]
    assert out["cases"] > 60
    assert sum(len(c) for c in constraints.values()) == out["cases"] - 1  # the muted one is skipped
    assert all(c.unsupported() is None for cs in constraints.values() for c in cs)
    names = list(bones)
    worst = worst_local = 0.0
    for trial in out["poses"]:
        poses = evaluate(bones, constraints, trial["channels"], world, names)
        for name in names:
            worst = max(worst, np.abs(poses[name] - trial["pose"][name]).max())
            local = _local(trial["channels"][name])
            if bones[name].use_connect:  # BKE_pchan_to_mat4 drops a connected bone's location
                local[:3, 3] = 0.0
            worst_local = max(worst_local, np.abs(local - trial["basis"][name]).max())
    assert worst_local < 1e-6, worst_local
    assert worst < TOLERANCE, worst
    # Space conversion against Object.convert_space, with the parents posed as Blender posed them.
    from solver.rig.spaces import convert_space

    worst_space = 0.0
    for (M, conv), trial in zip(out["spaces"], out["poses"], strict=True):
        for (name, a, b), expected in conv.items():
            bone = bones[name]
            parent = bones[bone.parent] if bone.parent else None
            parent_pose = trial["pose"][bone.parent] if bone.parent else None
            got = convert_space(M, a, b, bone, parent, parent_pose, world)
            worst_space = max(worst_space, np.abs(got - expected).max() / max(1.0, np.abs(expected).max()))
    assert worst_space < TOLERANCE, worst_space


RIGIFY = """
import addon_utils
bpy.ops.wm.read_factory_settings(use_empty=True)
addon_utils.enable("rigify", default_set=True)
bpy.ops.object.armature_human_metarig_add()
bpy.ops.pose.rigify_generate()
rig = bpy.context.object
rig.matrix_world = Matrix.LocRotScale((0.05, -0.02, 0.0), Euler((0.0, 0.0, 0.3)), (1.0, 1.0, 1.0))

def is_hand(name):
    return (name.endswith(".L") or ".L." in name) and any(k in name for k in ("hand", "f_", "thumb", "palm"))

hand = [pb.name for pb in rig.pose.bones if is_hand(pb.name)]
controls = [
    pb for pb in rig.pose.bones
    if pb.name in ("palm.L", "hand_fk.L")
    or (is_hand(pb.name) and pb.name.startswith(("f_", "thumb")) and not pb.name.endswith(".001"))
]
rng = np.random.default_rng(5)
poses = []
for trial in range(2):
    for pb in controls:
        if pb.rotation_mode == "QUATERNION":
            pb.rotation_quaternion = np.array([1.0, 0, 0, 0]) + rng.normal(0, 0.35, 4)
        else:
            pb.rotation_euler = rng.uniform(-0.6, 0.6, 3)
    bpy.context.view_layer.update()
    poses.append(pose_data(rig))
send(dict(rig=rig_data(rig), poses=poses, hand=hand, controls=[pb.name for pb in controls]))
"""


@needs_bpy
def test_rigify_hand_matches_blender(tmp_path):
    """The generated Rigify human's left hand (FK fingers, masters, palm spread, DEF/ORG/MCH chains with
    Copy Transforms, Stretch To, Copy Rotation ADD at partial influence, inherit scale NONE/AVERAGE):
    with its FK controls, palm and hand turned at random, every hand bone's pose from ours equals Blender's,
    the bones outside the hand taken from Blender."""
    out = _receive(run_blender(RIGIFY, tmp_path, setup=SETUP, timeout=600))
    rig, hand = out["rig"], out["hand"]
    bones, constraints, world = rig["bones"], rig["constraints"], rig["world"]
    assert len(hand) > 90 and {"DEF-f_index.01.L", "ORG-palm.02.L", "MCH-f_index.01_drv.L"} <= set(hand)
    assert len(out["controls"]) >= 20
    problems = [c.unsupported() for name in hand for c in constraints[name] if c.unsupported()]
    assert not problems, problems
    types = {c.type for name in hand for c in constraints[name]}
    assert {"COPY_TRANSFORMS", "COPY_LOCATION", "COPY_SCALE", "COPY_ROTATION", "STRETCH_TO"} <= types
    worst = 0.0
    for trial in out["poses"]:
        given = {name: pose for name, pose in trial["pose"].items() if name not in hand}
        poses = evaluate(bones, constraints, trial["channels"], world, hand, given)
        for name in hand:
            worst = max(worst, np.abs(poses[name] - trial["pose"][name]).max())
        # The pose really moved the hand.
        moved = max(np.abs(trial["pose"][n] - out["poses"][0]["pose"][n]).max() for n in hand)
        assert trial is out["poses"][0] or moved > 0.1
    assert worst < TOLERANCE, worst


# ----------------------------------------------------------------------------------------------------
# Complex-step derivatives (no bpy).


def _frame(head, y, roll_axis):
    y = np.asarray(y, float) / np.linalg.norm(y)
    x = np.cross(y, roll_axis)
    x /= np.linalg.norm(x)
    M = np.eye(4)
    M[:3, 0], M[:3, 1], M[:3, 2], M[:3, 3] = x, y, np.cross(x, y), head
    return M


def _synthetic_rig():
    """Bones and constraints covering the constraint math, built without Blender."""
    up = np.array([0.0, 0.0, 1.0])
    spec = [
        # name, parent, head, direction, length, extra Bone settings
        ("root", None, (0, 0, 0), (0, 1, 0.2), 0.5, {}),
        ("ctrl", "root", (0.1, 0.6, 0.2), (0.2, 1, 0.3), 0.6, {"rotation_mode": "XYZ"}),
        ("ctrl2", "root", (-0.3, 0.5, 0.1), (-0.2, 1, 0.4), 0.4, {"rotation_mode": "ZXY"}),
        ("avg", "ctrl", (0.3, 1.2, 0.5), (0.1, 1, 0.1), 0.3, {"inherit_scale": "AVERAGE"}),
        (
            "nonlocal",
            "ctrl",
            (0.2, 1.1, 0.4),
            (0.3, 1, 0.2),
            0.3,
            {"use_local_location": False, "inherit_scale": "ALIGNED"},
        ),
        ("rot", "root", (0.0, 0.8, -0.2), (0, 1, 0), 0.4, {"rotation_mode": "YXZ"}),
        ("stretch", "root", (0.2, 0.4, -0.1), (0.1, 1, 0), 0.5, {}),
        ("trans", "root", (-0.2, 0.9, 0.1), (0, 1, 0.3), 0.3, {"inherit_scale": "FIX_SHEAR"}),
        ("damped", "ctrl2", (-0.4, 0.9, 0.3), (0.1, 1, 0), 0.3, {}),
        ("limit", "ctrl", (0.3, 1.0, 0.2), (0, 1, 0.2), 0.3, {"rotation_mode": "XYZ"}),
        ("arm", None, (0.4, 0.7, 0.0), (0, 1, 0), 0.3, {}),
        ("armdq", None, (0.4, 0.7, 0.3), (0, 1, 0.1), 0.3, {}),
        ("child", "root", (0.5, 0.2, 0.0), (0, 1, 0), 0.3, {"rotation_mode": "XZY"}),
        ("track", "root", (0.6, 0.3, 0.2), (0, 1, 0), 0.3, {}),
        ("locked", "root", (0.6, 0.5, 0.2), (0, 1, 0.5), 0.3, {}),
        ("scale", "ctrl2", (-0.5, 0.9, 0.4), (0, 1, 0), 0.2, {}),
        ("conn", "ctrl", None, (0.1, 1, -0.3), 0.3, {"use_connect": True}),
    ]
    bones = {}
    for name, parent, head, direction, length, extra in spec:
        if head is None:
            P = bones[parent].matrix_local
            head = P[:3, 3] + bones[parent].length * P[:3, 1]
        bones[name] = Bone(name, _frame(np.asarray(head, float), direction, up), length, parent, **extra)
    T = Target
    constraints = {
        "rot": (Constraint("COPY_ROTATION", "r", 0.4, "LOCAL", "LOCAL", (T("ctrl"),), {"mix_mode": "ADD"}),),
        "stretch": (
            Constraint(
                "STRETCH_TO",
                "s",
                0.8,
                targets=(T("ctrl", head_tail=0.7),),
                settings={
                    "rest_length": 0.9,
                    "bulge": 1.5,
                    "use_bulge_max": True,
                    "bulge_max": 1.2,
                    "use_bulge_min": True,
                    "bulge_min": 0.9,
                    "bulge_smooth": 0.5,
                    "keep_axis": "SWING_Y",
                },
            ),
        ),
        "trans": (
            Constraint(
                "COPY_TRANSFORMS",
                "t",
                0.7,
                "LOCAL_WITH_PARENT",
                "LOCAL",
                (T("ctrl2"),),
                {"mix_mode": "BEFORE", "remove_target_shear": True},
            ),
        ),
        "damped": (
            Constraint(
                "DAMPED_TRACK",
                "d",
                0.6,
                targets=(T("ctrl", head_tail=0.5),),
                settings={"track_axis": "TRACK_NEGATIVE_X"},
            ),
        ),
        "limit": (
            Constraint(
                "LIMIT_ROTATION",
                "l",
                0.9,
                "LOCAL",
                settings={
                    "use_limit_x": True,
                    "min_x": -0.1,
                    "max_x": 0.05,
                    "use_limit_z": True,
                    "min_z": -2.0,
                    "max_z": 2.0,
                },
            ),
        ),
        "arm": (Constraint("ARMATURE", "a", 1.0, targets=(T("ctrl", weight=0.6), T("ctrl2", weight=0.3))),),
        "armdq": (
            Constraint(
                "ARMATURE",
                "q",
                1.0,
                targets=(T("ctrl", weight=0.6), T("avg", weight=0.5)),
                settings={"use_deform_preserve_volume": True},
            ),
        ),
        "child": (
            Constraint(
                "CHILD_OF",
                "c",
                0.75,
                targets=(T("ctrl2"),),
                settings={
                    "use_rotation_y": False,
                    "inverse_matrix": np.linalg.inv(bones["ctrl2"].matrix_local),
                },
            ),
        ),
        "track": (Constraint("TRACK_TO", "k", 1.0, targets=(T("avg"),), settings={"use_target_z": True}),),
        "locked": (Constraint("LOCKED_TRACK", "o", 0.5, targets=(T("nonlocal"),)),),
        "scale": (
            Constraint(
                "COPY_SCALE",
                "c",
                0.6,
                "LOCAL",
                "LOCAL",
                (T("ctrl"),),
                {"use_make_uniform": True, "power": 0.8, "use_offset": True},
            ),
            Constraint("LIMIT_SCALE", "ls", 1.0, "LOCAL", settings={"use_max_y": True, "max_y": 0.9}),
        ),
        "conn": (
            Constraint("COPY_LOCATION", "cl", 1.0, "LOCAL", "LOCAL", (T("ctrl2"),)),
            Constraint("COPY_ROTATION", "cr", 1.0, "WORLD", "WORLD", (T("ctrl2"),), {"use_x": False}),
        ),
    }
    return bones, constraints


def _pose_synthetic(x, bones, constraints, world):
    """All pose matrices (k, 4, 4) for DOFs x (k, 6): ctrl's and ctrl2's Euler angles; others fixed."""
    rng = np.random.default_rng(2)
    fixed = {
        name: (rng.uniform(-0.2, 0.2, 3), rng.uniform(-0.6, 0.6, 3), rng.uniform(0.8, 1.25, 3))
        for name in bones
    }
    k = x.shape[0]
    channels = {}
    for name, bone in bones.items():
        loc, eul, scale = fixed[name]
        eul = np.broadcast_to(eul, (k, 3)).astype(x.dtype)
        if name == "ctrl":
            eul = eul + x[:, :3]
        elif name == "ctrl2":
            eul = eul + x[:, 3:]
        mode = bone.rotation_mode if bone.rotation_mode != "QUATERNION" else "XYZ"
        channels[name] = (mode, np.broadcast_to(loc, (k, 3)), eul, np.broadcast_to(scale, (k, 3)))
    return evaluate(bones, constraints, channels, world, list(bones))


def test_complex_step_derivatives_through_constraints_match_finite_differences():
    bones, constraints = _synthetic_rig()
    world = np.eye(4)
    world[:3, :3] = 1.3 * rotation_matrix("XYZ", np.array([0.3, -0.2, 0.5]))
    world[:3, 3] = (0.2, -0.1, 0.4)
    x0 = np.random.default_rng(4).uniform(-0.4, 0.4, 6)
    X = analytic.directions(x0, np.ones(6, bool))
    poses = _pose_synthetic(X, bones, constraints, world)
    real = _pose_synthetic(x0[None], bones, constraints, world)
    h = 1e-6
    worst = 0.0
    for name in bones:
        assert np.abs(analytic.value(poses[name]) - real[name][0]).max() < 1e-12
        step = np.eye(6) * h
        plus = _pose_synthetic(x0 + step, bones, constraints, world)[name]
        minus = _pose_synthetic(x0 - step, bones, constraints, world)[name]
        fd = (plus - minus) / (2 * h)
        cs = analytic.derivative(poses[name])
        worst = max(worst, np.abs(cs - fd).max())
        if name in ("rot", "stretch", "trans", "arm", "armdq", "child", "scale", "damped", "conn"):
            assert np.abs(cs).max() > 1e-3, name  # the constraint carries the controls' motion
    assert worst < 1e-6, worst


def test_interpolate_is_blenders_polar_blend():
    """interp_m4_m4m4's ends, and a blend of a rotation with a stretch along a turned axis."""
    rng = np.random.default_rng(0)
    A = np.eye(4)
    A[:3, :3] = rotation_matrix("XYZ", rng.uniform(-1, 1, 3)) @ np.diag([1.2, 0.7, 1.0])
    A[:3, 3] = rng.normal(size=3)
    B = np.eye(4)
    B[:3, :3] = rotation_matrix("ZXY", rng.uniform(-1, 1, 3))
    B[:3, 3] = rng.normal(size=3)
    assert np.allclose(interp_m4_m4m4(A, B, 0.0), A, atol=1e-12)
    assert np.allclose(interp_m4_m4m4(A, B, 1.0), B, atol=1e-12)
    R = rotation_matrix("XYZ", np.array([0.4, 0.0, 0.0]))
    C = np.eye(4)
    C[:3, :3] = R @ np.diag([1.0, 3.0, 1.0])
    mid = interp_m4_m4m4(np.eye(4), C, 0.5)
    half = rotation_matrix("XYZ", np.array([0.2, 0.0, 0.0]))
    assert np.allclose(mid[:3, :3], half @ np.diag([1.0, 2.0, 1.0]), atol=1e-12)


def test_unsupported_names_what_is_not_modelled():
    assert (
        Constraint("IK", "IK").unsupported() == "Ik constraint 'IK': constraints of type IK are not modelled"
    )
    stretch = Constraint("STRETCH_TO", "S", targets=(Target("b"),))
    assert "rest length" in stretch.unsupported()
    bbone = Constraint(
        "COPY_LOCATION", "L", targets=(Target("b", head_tail=0.5, use_bbone_shape=True, bbone_segments=4),)
    )
    assert "B-Bone" in bbone.unsupported()
    plain = Constraint("COPY_LOCATION", "L", targets=(Target("b", head_tail=0.5, use_bbone_shape=True),))
    assert plain.unsupported() is None
    full = Constraint("COPY_TRANSFORMS", "T", targets=(Target("b", use_bbone_shape=True, bbone_segments=3),))
    assert "B-Bone" in full.unsupported()
    assert (
        "pending"
        in Constraint(
            "CHILD_OF", "C", targets=(Target("b"),), settings={"set_inverse_pending": True}
        ).unsupported()
    )
    assert (
        "another armature"
        in Constraint(
            "COPY_LOCATION", "X", refusal="it targets bone 'x' of another armature ('B')"
        ).unsupported()
    )


def test_rotation_conversions_are_complex_step_safe():
    """solver.rotations on complex input: same values, derivatives equal to central differences."""
    from solver import rotations

    rng = np.random.default_rng(3)
    h = 1e-6
    checks = [
        (lambda a: rotations.euler_to_matrix(a, "YZX"), rng.uniform(-1, 1, 3)),
        (
            lambda a: rotations.matrix_to_euler(rotations.euler_to_matrix(a, "ZXY"), "ZXY"),
            rng.uniform(-1, 1, 3),
        ),
        (lambda q: rotations.quaternion_to_matrix(q), rng.normal(size=4)),
        (
            lambda q: rotations.matrix_to_quaternion(rotations.quaternion_to_matrix(q)),
            np.array([0.9, 0.2, -0.3, 0.1]),
        ),
        (lambda a: rotations.axis_angle_to_matrix(a), rng.normal(size=4)),
        (lambda a: rotations.matrix_to_axis_angle(rotations.euler_to_matrix(a)), rng.uniform(-1, 1, 3)),
        (lambda a: rotation_matrix("QUATERNION", a), rng.normal(size=4)),
        (lambda a: rotation_matrix("AXIS_ANGLE", a), rng.normal(size=4)),
    ]
    for f, x in checks:
        n = x.size
        cs = f(analytic.directions(x, np.ones(n, bool)))
        assert np.allclose(analytic.value(cs), f(x[None])[0], atol=1e-14)
        fd = np.stack([(f(x + h * e) - f(x - h * e)) / (2 * h) for e in np.eye(n)])
        assert np.abs(analytic.derivative(cs) - fd).max() < 1e-7


# ----------------------------------------------------------------------------------------------------
# Stacks: many bones at once, the same as one at a time (no bpy).


def _dependencies_closed(bones, constraints, name):
    """A bone's inputs and, for its constraints' targets, the targets' parents."""
    out = set(_dependencies(bones, constraints, name))
    for con in constraints.get(name, ()):
        for t in con.targets:
            if t.subtarget and bones[t.subtarget].parent:
                out.add(bones[t.subtarget].parent)
    return out


def _stacks(bones, constraints, names):
    """The bones grouped as a caller stacks them: equal dependency depth, bone_key and constraint keys."""
    from solver.rig.bones import bone_key
    from solver.rig.constraints import constraint_key

    depth, groups = {}, {}
    for name in _order(bones, constraints, names):
        deps = _dependencies_closed(bones, constraints, name)
        depth[name] = 1 + max([depth[d] for d in deps] + [-1])
        bone = bones[name]
        parent = bones[bone.parent] if bone.parent else None
        key = (
            depth[name],
            bone_key(bone, parent),
            tuple(constraint_key(c, bones, bone) for c in constraints.get(name, ())),
        )
        groups.setdefault(key, []).append(name)
    return sorted(groups.values(), key=lambda group: depth[group[0]])


def evaluate_stacked(bones, constraints, locals_, world, names):
    """Pose matrices of ``names`` by :func:`stack_pose_bones`, one call per stack of :func:`_stacks`."""
    from solver.rig.bones import BoneStack
    from solver.rig.constraints import ConstraintStack, stack_pose_bones
    from solver.rig.spaces import World

    world = World.of(world)
    poses = {}

    def stacked(matrices):
        return np.stack(np.broadcast_arrays(*matrices), -3)

    for group in _stacks(bones, constraints, names):
        owners = [bones[n] for n in group]
        parents = [bones[b.parent] if b.parent else None for b in owners]
        bone_stack = BoneStack.of(owners, parents)
        count = len(constraints.get(group[0], ()))
        cstacks = [
            ConstraintStack.of([constraints[n][i] for n in group], owners, bones) for i in range(count)
        ]
        targets = [
            [None if ns is None else stacked([poses[x] for x in ns]) for ns in cs.inputs] for cs in cstacks
        ]
        target_parents = [
            [None if ns is None else stacked([poses[x] for x in ns]) for ns in cs.parent_inputs]
            for cs in cstacks
        ]
        parent_poses = None if parents[0] is None else stacked([poses[b.parent] for b in owners])
        out = stack_pose_bones(
            bone_stack,
            parent_poses,
            stacked([locals_[n] for n in group]),
            cstacks,
            targets,
            target_parents,
            world,
        )
        for j, name in enumerate(group):
            poses[name] = out[..., j, :, :]
    return poses


def _random_layered_rig(seed: int):
    """Layers of bones; in each, a few templates (inherit flags, constraint types and discrete options)
    instantiated three times with their own rest frames, lengths, influences and limits, targets in the
    layers above: bones that a caller stacks together, in every inherit mode and modelled constraint."""
    rng = np.random.default_rng(seed)
    up = np.array([0.0, 0.0, 1.0])
    modes = ["FULL", "FIX_SHEAR", "ALIGNED", "AVERAGE", "NONE", "NONE_LEGACY"]
    rotation_modes = ["XYZ", "ZXY", "YZX", "QUATERNION", "AXIS_ANGLE"]
    spaces = ["WORLD", "POSE", "LOCAL", "LOCAL_WITH_PARENT", "LOCAL_OWNER_ORIENT", "CUSTOM"]
    tracking = ["WORLD", "POSE"]  # turning towards a point is ill-posed where local origins coincide
    bones, constraints, layers = {}, {}, [[]]

    def add(name, parent, **extra):
        head = rng.normal(size=3) * 0.4
        if extra.get("use_connect"):
            P = bones[parent]
            head = P.matrix_local[:3, 3] + P.length * P.matrix_local[:3, 1]
        bones[name] = Bone(name, _frame(head, rng.normal(size=3), up), rng.uniform(0.3, 0.8), parent, **extra)

    for i in range(3):
        add(f"r{i}", None, rotation_mode=rotation_modes[i])
        layers[0].append(f"r{i}")
    kinds = [
        ("COPY_TRANSFORMS", {"mix_mode": ["REPLACE", "BEFORE", "AFTER_FULL", "BEFORE_SPLIT"]}),
        ("COPY_LOCATION", {"use_y": [True, False], "invert_x": [False, True], "use_offset": [False, True]}),
        (
            "COPY_ROTATION",
            {"mix_mode": ["REPLACE", "ADD", "BEFORE", "OFFSET"], "euler_order": ["AUTO", "YZX"]},
        ),
        ("COPY_SCALE", {"use_make_uniform": [False, True], "use_offset": [False, True]}),
        (
            "STRETCH_TO",
            {"keep_axis": ["SWING_Y", "PLANE_X", "PLANE_Z"], "volume": ["VOLUME_XZX", "NO_VOLUME"]},
        ),
        ("DAMPED_TRACK", {"track_axis": ["TRACK_Y", "TRACK_NEGATIVE_X"]}),
        ("LOCKED_TRACK", {"track_axis": ["TRACK_Y", "TRACK_Z"], "lock_axis": ["LOCK_X", "LOCK_Z"]}),
        ("TRACK_TO", {"use_target_z": [False, True]}),
        ("CHILD_OF", {"use_rotation_y": [True, False], "use_location_x": [True, False]}),
        ("LIMIT_ROTATION", {"use_limit_x": [True], "use_limit_z": [False, True]}),
        ("LIMIT_LOCATION", {"use_min_x": [True, False], "use_max_y": [True]}),
        ("LIMIT_SCALE", {"use_min_y": [True], "use_max_z": [False, True]}),
        ("ARMATURE", {"use_deform_preserve_volume": [False, True]}),
    ]
    for layer in range(1, 5):
        layers.append([])
        for t in range(4):
            kind, options = kinds[int(rng.integers(len(kinds)))]
            settings = {k: v[int(rng.integers(len(v)))] for k, v in options.items()}
            flags = dict(
                inherit_scale=modes[int(rng.integers(len(modes)))],
                use_inherit_rotation=bool(rng.random() < 0.8),
                use_local_location=bool(rng.random() < 0.8),
                use_connect=bool(rng.random() < 0.3),
                rotation_mode=rotation_modes[int(rng.integers(len(rotation_modes)))],
            )
            choices = (
                tracking if kind in ("STRETCH_TO", "DAMPED_TRACK", "LOCKED_TRACK", "TRACK_TO") else spaces
            )
            owner_space = choices[int(rng.integers(len(choices)))]
            target_space = choices[int(rng.integers(len(choices)))]
            full = bool(rng.random() < 0.5)
            for copy in range(3):
                name = f"l{layer}t{t}c{copy}"
                add(name, layers[layer - 1][int(rng.integers(len(layers[layer - 1])))], **flags)
                layers[layer].append(name)
                above = [n for level in layers[:layer] for n in level]
                target = above[int(rng.integers(len(above)))]
                own = dict(settings)
                if kind == "STRETCH_TO":
                    own.update(rest_length=float(rng.uniform(0.3, 1.2)), bulge=float(rng.uniform(0.7, 1.6)))
                if kind == "COPY_SCALE":
                    own["power"] = 1.0 if copy else float(rng.uniform(0.7, 1.3))
                if kind == "CHILD_OF":
                    own["inverse_matrix"] = np.linalg.inv(bones[target].matrix_local)
                if kind.startswith("LIMIT_"):
                    base = 1.0 if kind == "LIMIT_SCALE" else 0.0
                    for c in "xyz":
                        lo = base + float(rng.uniform(-0.4, 0.1))
                        own[f"min_{c}"], own[f"max_{c}"] = lo, lo + float(rng.uniform(0.05, 0.6))
                influence = 1.0 if full else float(rng.uniform(0.2, 0.9))
                if kind == "ARMATURE":
                    targets = tuple(
                        Target(above[int(rng.integers(len(above)))], weight=w) for w in (0.6, 0.3)
                    )
                    con = Constraint(kind, f"{name}.c", influence, targets=targets, settings=own)
                elif kind.startswith("LIMIT_"):
                    con = Constraint(kind, f"{name}.c", influence, owner_space, settings=own)
                else:
                    space_bone = above[int(rng.integers(len(above)))]
                    head_tail = float(rng.choice([0.0, 0.0, rng.uniform(0.2, 0.8)])) if copy == 0 else 0.0
                    con = Constraint(
                        kind,
                        f"{name}.c",
                        influence,
                        owner_space,
                        target_space,
                        (Target(target, head_tail=head_tail),),
                        own,
                        space_subtarget=space_bone if "CUSTOM" in (owner_space, target_space) else "",
                    )
                constraints[name] = (con,)
    return bones, constraints


def _random_locals(bones, rng, k=None, distinct=False):
    """Channel matrices: random rotations, locations and scales; with ``k``, a complex step on every
    entry of each bone's matrix in each of ``k`` directions (which share their values unless
    ``distinct``)."""
    out = {}
    for name in bones:
        local = channel_matrix(
            rng.uniform(-0.2, 0.2, 3), rotation_matrix("XYZ", rng.uniform(-1, 1, 3)), rng.uniform(0.7, 1.3, 3)
        )
        if k is not None:
            local = np.repeat(local[None].astype(complex), k, 0)
            local[:, :3] += 1j * analytic.STEP * rng.normal(size=(k, 3, 4))
            if distinct:
                local[:, :3] += 0.05 * rng.normal(size=(k, 3, 4))
        out[name] = local
    return out


def _worlds():
    similar = np.eye(4)
    similar[:3, :3] = 1.3 * rotation_matrix("XYZ", np.array([0.3, -0.2, 0.5]))
    similar[:3, 3] = (0.2, -0.1, 0.4)
    sheared = similar.copy()
    sheared[:3, :3] = sheared[:3, :3] @ np.diag([1.0, 0.8, 1.2])
    return {"identity": np.eye(4), "similarity": similar, "affine": sheared}


def _per_bone(bones, constraints, locals_, world, names):
    poses = {}
    for name in _order(bones, constraints, names):
        bone = bones[name]
        parent = bones[bone.parent] if bone.parent else None
        targets = {}
        for dep in _dependencies_closed(bones, constraints, name):
            tb = bones[dep]
            targets[dep] = TargetBone(
                tb, bones[tb.parent] if tb.parent else None, poses[dep], poses.get(tb.parent)
            )
        poses[name] = pose_bone(
            bone, parent, poses.get(bone.parent), locals_[name], constraints.get(name, ()), targets, world
        )
    return poses


def _compare(stacked, single):
    """Largest difference of values and of complex-step derivatives, relative to their sizes."""
    value = derivative = 0.0
    for name, a in single.items():
        b = stacked[name]
        value = max(value, np.abs(a.real - b.real).max() / max(1.0, np.abs(a.real).max()))
        if np.iscomplexobj(a) or np.iscomplexobj(b):
            da, db = analytic.derivative(np.asarray(a)), analytic.derivative(np.asarray(b))
            derivative = max(derivative, np.abs(da - db).max() / max(1.0, np.abs(da).max()))
    return value, derivative


def test_stacks_pose_random_mixed_rigs_as_bone_by_bone():
    """Random layered rigs (every inherit mode, every modelled constraint type with its discrete options in
    many spaces, partial influences, head_tail, custom spaces), stacked by bone_key and constraint_key
    at equal depth: stack_pose_bones gives pose_bone's matrices to 1e-12 in values (1e-10 in complex-step
    derivatives), for real poses, complex-step directions sharing one value and complex batches of
    distinct values, under identity, similarity and sheared world matrices."""
    stack_sizes = []
    for seed in range(4):
        bones, constraints = _random_layered_rig(seed)
        names = list(bones)
        stacks = _stacks(bones, constraints, names)
        stack_sizes += [len(s) for s in stacks]
        rng = np.random.default_rng(100 + seed)
        for world in _worlds().values():
            for k, distinct in ((None, False), (4, False), (3, True)):
                locals_ = _random_locals(bones, rng, k, distinct)
                single = _per_bone(bones, constraints, locals_, world, names)
                stacked = evaluate_stacked(bones, constraints, locals_, world, names)
                value, derivative = _compare(stacked, single)
                assert value < 1e-12, (seed, value)
                assert derivative < 1e-10, (seed, derivative)
    assert max(stack_sizes) >= 3 and np.mean(stack_sizes) > 2  # bones really were stacked


def _rigify_like_hand():
    """A hand built the way Rigify builds one (no Blender needed): FK finger controls under masters, MCH
    driver bones (Copy Location and Copy Rotation in local space), MCH stretch bones (Copy Location,
    Copy Scale, Stretch To with Swing Y), ORG and DEF chains following them by Copy Transforms (connected
    bones keep their heads), palm bones that inherit no scale and follow a palm control in local space at
    partial influences (Copy Transforms, then Copy Scale, then Copy Rotation with Add), a palm control
    with average scale inheritance, and a forearm tweak blended between two targets then tracking one.
    Returns (bones, constraints, controls)."""
    up = np.array([0.0, 0.0, 1.0])
    bones, constraints, controls = {}, {}, []

    def add(name, parent, head, direction, length, constrained=(), control=False, **extra):
        if extra.get("use_connect"):
            P = bones[parent]
            head = P.matrix_local[:3, 3] + P.length * P.matrix_local[:3, 1]
        bones[name] = Bone(name, _frame(np.asarray(head, float), direction, up), length, parent, **extra)
        constraints[name] = tuple(constrained)
        if control:
            controls.append(name)

    def rest(name, target, at_tail=False):
        a, b = bones[name].matrix_local, bones[target].matrix_local
        point = b[:3, 3] + (bones[target].length * b[:3, 1] if at_tail else 0.0)
        return float(np.linalg.norm(point - a[:3, 3]))

    T = Target
    world = dict(owner_space="WORLD", target_space="WORLD")
    local = dict(owner_space="LOCAL", target_space="LOCAL")
    add("DEF-upper", None, (0, -0.6, 0), (0.1, 1, 0), 0.3)
    add("root", None, (0, 0, 0), (0, 1, 0), 0.2)
    add("hand_fk", "root", (0.02, 0.3, 0.0), (0.05, 1, 0.1), 0.15, control=True, rotation_mode="XYZ")
    add("ORG-forearm", "root", (0, -0.3, 0), (0.05, 1, 0.02), 0.3)
    add(
        "ORG-hand",
        "ORG-forearm",
        None,
        (0.05, 1, 0.1),
        0.15,
        [Constraint("COPY_TRANSFORMS", "ct", 1.0, **world, targets=(T("hand_fk"),))],
        use_connect=True,
    )
    add("MCH-hand_tweak", "ORG-hand", (0.02, 0.3, 0.0), (0.05, 1, 0.1), 0.05)
    add("hand_tweak", "MCH-hand_tweak", (0.02, 0.3, 0.0), (0.05, 1, 0.1), 0.05, control=True)
    add("forearm_tweak", "root", (0, -0.28, 0), (0.05, 1, 0.02), 0.05)
    add(
        "MCH-forearm_tweak.001",
        "ORG-forearm",
        (0.01, -0.1, 0.0),
        (0.05, 1, 0.02),
        0.05,
        [
            Constraint("COPY_TRANSFORMS", "a", 1.0, **world, targets=(T("forearm_tweak"),)),
            Constraint("COPY_TRANSFORMS", "b", 0.5, **world, targets=(T("hand_tweak"),)),
            Constraint("DAMPED_TRACK", "c", 1.0, **world, targets=(T("hand_tweak"),)),
        ],
    )
    add("forearm_tweak.001", "MCH-forearm_tweak.001", (0.01, -0.1, 0.0), (0.05, 1, 0.02), 0.05)
    add("DEF-forearm", "DEF-upper", None, (0.05, 1, 0.02), 0.3, use_connect=True)
    constraints["DEF-forearm"] = (
        Constraint("COPY_TRANSFORMS", "ct", 1.0, **world, targets=(T("forearm_tweak"),)),
        Constraint(
            "STRETCH_TO",
            "st",
            1.0,
            **world,
            targets=(T("forearm_tweak.001"),),
            settings={"rest_length": rest("DEF-forearm", "forearm_tweak.001"), "keep_axis": "SWING_Y"},
        ),
    )
    add(
        "DEF-hand",
        "DEF-forearm",
        None,
        (0.05, 1, 0.1),
        0.15,
        [Constraint("COPY_TRANSFORMS", "ct", 1.0, **world, targets=(T("hand_tweak"),))],
        use_connect=True,
    )
    add(
        "palm",
        "DEF-hand",
        (0.03, 0.35, 0.0),
        (0.2, 1, 0.1),
        0.1,
        control=True,
        inherit_scale="AVERAGE",
        rotation_mode="YXZ",
    )
    scale = Constraint("COPY_SCALE", "cs", 1.0, **world, targets=(T("DEF-hand"),))
    fingers = []
    for p, (x, influence) in enumerate([(-0.03, None), (0.0, 1 / 3), (0.03, 2 / 3), (0.06, 1.0)], start=1):
        name = f"ORG-palm.0{p}"
        if influence is None:
            palm = (scale,)
        else:
            palm = (Constraint("COPY_TRANSFORMS", "ct", influence, **local, targets=(T("palm"),)), scale)
            if influence < 1:
                palm += (
                    Constraint(
                        "COPY_ROTATION",
                        "cr",
                        0.27 * influence + 0.1,
                        **local,
                        targets=(T("palm"),),
                        settings={
                            "use_y": False,
                            "use_z": False,
                            "invert_x": True,
                            "mix_mode": "ADD",
                            "euler_order": "YXZ",
                        },
                    ),
                )
        add(
            name,
            "DEF-hand",
            (x, 0.32, 0.0),
            (x, 1, 0.05),
            0.08,
            palm,
            inherit_scale="NONE",
            rotation_mode="YXZ",
        )
        if p in (2, 3):
            fingers.append((f"f{p - 1}", name, x))
    for f, palm, x in fingers:
        add(f"{f}_master", palm, (x, 0.42, 0.0), (x, 1, -0.1), 0.09, control=True)
        add(
            f"MCH-{f}.01_drv",
            palm,
            (x, 0.42, 0.0),
            (x, 1, -0.1),
            0.04,
            [
                Constraint("COPY_LOCATION", "cl", 1.0, **world, targets=(T(f"{f}_master"),)),
                Constraint("COPY_ROTATION", "cr", 1.0, **local, targets=(T(f"{f}_master"),)),
            ],
        )
        add(
            f"{f}.01",
            f"MCH-{f}.01_drv",
            (x, 0.42, 0.0),
            (x, 1, -0.1),
            0.04,
            control=True,
            rotation_mode="YZX",
        )
        add(f"MCH-{f}.02_drv", f"{f}.01", None, (x, 1, -0.3), 0.03, use_connect=True)
        add(f"{f}.02", f"MCH-{f}.02_drv", None, (x, 1, -0.3), 0.03, control=True, use_connect=True)
        add(f"{f}.03", f"{f}.02", None, (x, 1, -0.5), 0.025, control=True, use_connect=True)
        stretch = {"keep_axis": "SWING_Y", "volume": "NO_VOLUME"}
        add(
            f"MCH-{f}.01",
            palm,
            (x, 0.42, 0.0),
            (x, 1, -0.1),
            0.04,
            [
                Constraint("COPY_LOCATION", "cl", 1.0, **world, targets=(T(f"{f}.01"),)),
                Constraint("COPY_SCALE", "cs", 1.0, **world, targets=(T(f"{f}.01"),)),
                Constraint(
                    "STRETCH_TO",
                    "st",
                    1.0,
                    **world,
                    targets=(T(f"{f}.02"),),
                    settings={**stretch, "rest_length": 0.04},
                ),
            ],
        )
        add(f"MCH-{f}.02", f"{f}.02", bones[f"{f}.02"].head_local, (x, 1, -0.3), 0.03)
        constraints[f"MCH-{f}.02"] = (
            Constraint(
                "STRETCH_TO",
                "st",
                1.0,
                **world,
                targets=(T(f"{f}.03"),),
                settings={**stretch, "rest_length": rest(f"MCH-{f}.02", f"{f}.03")},
            ),
        )
        add(
            f"ORG-{f}.01",
            palm,
            (x, 0.42, 0.0),
            (x, 1, -0.1),
            0.04,
            [Constraint("COPY_TRANSFORMS", "ct", 1.0, **world, targets=(T(f"MCH-{f}.01"),))],
        )
        add(
            f"ORG-{f}.02",
            f"ORG-{f}.01",
            None,
            (x, 1, -0.3),
            0.03,
            [Constraint("COPY_TRANSFORMS", "ct", 1.0, **world, targets=(T(f"MCH-{f}.02"),))],
            use_connect=True,
        )
        add(
            f"DEF-{f}.01",
            palm,
            (x, 0.42, 0.0),
            (x, 1, -0.1),
            0.04,
            [Constraint("COPY_TRANSFORMS", "ct", 1.0, **world, targets=(T(f"ORG-{f}.01"),))],
        )
        add(
            f"DEF-{f}.02",
            f"DEF-{f}.01",
            None,
            (x, 1, -0.3),
            0.03,
            [Constraint("COPY_TRANSFORMS", "ct", 1.0, **world, targets=(T(f"ORG-{f}.02"),))],
            use_connect=True,
        )
    return bones, constraints, controls


def _hand_locals(bones, controls, x):
    """Identity channels, the controls turned by Euler angles ``x`` (..., 3 n) (n controls) about a fixed
    random pose."""
    rng = np.random.default_rng(8)
    base = rng.uniform(-0.4, 0.4, (len(controls), 3))
    out = {name: np.eye(4) for name in bones}
    for c, name in enumerate(controls):
        out[name] = channel_matrix(
            np.zeros(3), rotation_matrix("XYZ", base[c] + x[..., 3 * c : 3 * c + 3]), np.ones(3)
        )
    return out


def test_stacks_pose_a_rigify_like_hand_and_carry_derivatives():
    """The Rigify-like hand stacked as a caller would (one stack per kind of bone at each depth: finger
    chains side by side) equals bone-by-bone posing to 1e-12 under a turned and scaled armature object,
    and its complex-step derivatives with respect to every control's angles equal central differences."""
    bones, constraints, controls = _rigify_like_hand()
    names = list(bones)
    stacks = _stacks(bones, constraints, names)
    assert len(stacks) <= len(names) - 12 and max(len(s) for s in stacks) >= 2
    world = _worlds()["similarity"]
    n = 3 * len(controls)
    x0 = np.random.default_rng(9).uniform(-0.3, 0.3, n)
    X = analytic.directions(x0, np.ones(n, bool))
    locals_ = _hand_locals(bones, controls, X)
    stacked = evaluate_stacked(bones, constraints, locals_, world, names)
    single = _per_bone(bones, constraints, locals_, world, names)
    value, derivative = _compare(stacked, single)
    assert value < 1e-12 and derivative < 1e-10, (value, derivative)
    real = evaluate_stacked(bones, constraints, _hand_locals(bones, controls, x0[None]), world, names)
    h = 1e-6
    worst = 0.0
    plus = [
        evaluate_stacked(bones, constraints, _hand_locals(bones, controls, x0 + h * e), world, names)
        for e in np.eye(n)
    ]
    minus = [
        evaluate_stacked(bones, constraints, _hand_locals(bones, controls, x0 - h * e), world, names)
        for e in np.eye(n)
    ]
    for name in names:
        assert np.abs(analytic.value(stacked[name]) - real[name][0]).max() < 1e-12
        fd = np.stack([(p[name] - m[name]) / (2 * h) for p, m in zip(plus, minus, strict=True)])
        worst = max(worst, np.abs(analytic.derivative(stacked[name]) - fd).max())
    assert worst < 1e-6, worst
    moved = [name for name in names if np.abs(analytic.derivative(stacked[name])).max() > 1e-3]
    assert {"DEF-f1.02", "DEF-f2.02", "ORG-palm.02", "MCH-forearm_tweak.001", "DEF-forearm"} <= set(moved)


def test_stacks_refuse_bones_and_constraints_whose_discrete_settings_differ():
    """bone_key and constraint_key separate what one stack cannot hold; stacks of mixed keys are refused."""
    from solver.rig.bones import BoneStack, bone_key
    from solver.rig.constraints import ConstraintStack, constraint_key, parent_needed

    root = Bone("root", np.eye(4), 1.0)
    a = Bone("a", np.eye(4), 0.5, "root")
    b = Bone("b", np.eye(4), 0.5, "root", inherit_scale="NONE")
    c = Bone("c", np.eye(4), 0.5, "root", use_connect=True)
    assert bone_key(a, root) != bone_key(b, root) != bone_key(c, root) != bone_key(root, None)
    with pytest.raises(SolverError, match="bone_key"):
        BoneStack.of([a, b], [root, root])
    bones = {"root": root, "a": a}
    plain = Constraint("COPY_TRANSFORMS", "t", 1.0, targets=(Target("root"),))
    partial = Constraint("COPY_TRANSFORMS", "t", 0.5, targets=(Target("root"),))
    tail = Constraint("COPY_TRANSFORMS", "t", 1.0, targets=(Target("root", head_tail=0.5),))
    local = Constraint("COPY_TRANSFORMS", "t", 1.0, "LOCAL", "LOCAL", (Target("a"),))
    keys = {constraint_key(x, bones, a) for x in (plain, partial, tail, local)}
    assert len(keys) == 4
    assert constraint_key(Constraint("COPY_TRANSFORMS", "t", 0.0, targets=(Target("root"),)), bones, a) == (
        "OFF",
    )
    with pytest.raises(SolverError, match="constraint_key"):
        ConstraintStack.of([plain, partial], [a, a], bones)
    with pytest.raises(SolverError, match="not given"):
        constraint_key(local, {"a": a}, a)  # the local target space needs the target's parent
    # A bone whose transform Copy Transforms replaces does not read its parent unless connected.
    replace = ConstraintStack.of([plain], [a], bones)
    assert not parent_needed(BoneStack.of([a], [root]), [replace])
    assert parent_needed(BoneStack.of([c], [root]), [replace])
    assert parent_needed(BoneStack.of([a], [root]), [replace, ConstraintStack.of([local], [a], bones)])
