"""B-Bones (solver.rig.bbone, contact_edit_addon.bridge.bbones) against Blender's own Armature modifier and
``PoseBone.bbone_segment_matrix`` / ``bbone_segment_index`` in bpy 5.0.1, and their complex-step
derivatives against central finite differences."""

import base64
import importlib.util
import pickle

import numpy as np
import pytest

from solver import SolverError
from solver.rig import analytic
from solver.rig.bbone import (
    BBone,
    BBoneHandle,
    BBoneStack,
    blend_segments,
    deform_matrices,
    spline_matrices,
    stack_deform_matrices,
    stacks,
    vertex_segments,
)
from solver.rig.bbone.reference import deform_matrices_reference

from .blender import run_blender

needs_bpy = pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="needs bpy (the dev extra)")

# One armature with every B-Bone option, a tube of vertices around each deform bone weighted to it and
# to its chain neighbours, and four seeded random poses (rotations, locations, uniform and non-uniform
# scales). The armature and mesh objects sit at the origin, so armature space is the mesh's space.
SCRIPT = """
import base64, pickle
import numpy as np
from mathutils import Quaternion, Vector
from contact_edit_addon.bridge.bbones import read_bbone
from contact_edit_addon.bridge.errors import BridgeError
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
arm = bpy.data.objects.new("Arm", bpy.data.armatures.new("Arm"))
scene.collection.objects.link(arm)
bpy.context.view_layer.objects.active = arm
bpy.ops.object.mode_set(mode="EDIT")
def add(name, head, tail, roll=0.0, parent=None, connect=False):
    b = arm.data.edit_bones.new(name); b.head, b.tail, b.roll = head, tail, roll
    if parent:
        b.parent = arm.data.edit_bones[parent]; b.use_connect = connect
# A connected chain with AUTO handles (segments 4, 10, 1, 10).
add("c0", (0, 0, 0), (0, 1, 0.1), 0.3)
add("c1", (0, 1, 0.1), (0.2, 2, 0.4), -0.4, "c0", True)
add("c2", (0.2, 2, 0.4), (0.3, 2.8, 0.5), 0.2, "c1", True)
add("c3", (0.3, 2.8, 0.5), (0.2, 3.6, 0.9), 0.0, "c2", True)
# Custom handle bones (hA, hB parented, hC a root, hN inheriting no scale) and the bones using them.
add("hp", (2, -0.5, 0), (2, -0.2, 0))
add("hA", (2, -0.6, 0.2), (2.1, 0.1, 0.2), 0.5, "hp")
add("hB", (2.2, 1.3, 0), (2.2, 2.0, -0.1), -0.2, "hp")
add("hC", (3.2, 1.6, 0), (3.3, 2.2, 0.1), 0.1)
add("hN", (5, 1.6, 0), (5, 2.2, 0), 0.0, "hp")
add("d0", (2, 0, 0), (2.1, 1.2, 0.1), 0.2)
add("d1", (2.6, 0, 0), (2.7, 1.1, -0.1), -0.3)
add("d2", (1.0, 0, 0), (1.1, 1.0, 0.2), 0.1)
add("d3", (3.2, 0, 0), (3.2, 1.3, 0.0), 0.6)
add("e0", (5, 0, 0), (5, 1, 0))
bpy.ops.object.mode_set(mode="POSE")
B, P = arm.data.bones, arm.pose.bones
def set_all(target, **values):
    for key, value in values.items():
        setattr(target, key, value)
set_all(B["c0"], bbone_segments=4, bbone_easein=0.5, bbone_easeout=1.3, bbone_rollin=0.2, bbone_rollout=-0.3,
        bbone_curveinx=0.1, bbone_curveoutz=-0.15, bbone_scalein=(1.2, 1.1, 0.9),
        bbone_scaleout=(0.8, 1.3, 1.1), bbone_mapping_mode="CURVED")
set_all(P["c0"], bbone_easein=0.2, bbone_rollout=0.25, bbone_curveinz=0.05, bbone_scaleout=(1.1, 0.9, 1.05))
set_all(B["c1"], bbone_segments=10, bbone_easein=1.0, bbone_easeout=0.7, use_endroll_as_inroll=True,
        use_scale_easing=True, bbone_scalein=(1, 1.4, 1), bbone_curveinx=-0.1)
set_all(P["c1"], bbone_easeout=0.3, bbone_rollin=-0.2, bbone_scalein=(1, 0.8, 1.2), bbone_curveoutx=0.12)
set_all(B["c2"], bbone_segments=1)
set_all(B["c3"], bbone_segments=10, bbone_mapping_mode="CURVED", bbone_easein=0.0, bbone_easeout=0.0)
set_all(B["d0"], bbone_segments=8, bbone_handle_type_start="ABSOLUTE", bbone_custom_handle_start=B["hA"],
        bbone_handle_type_end="RELATIVE", bbone_custom_handle_end=B["hB"], bbone_easein=0.8,
        bbone_handle_use_scale_start=(True, True, False), bbone_handle_use_ease_start=True,
        bbone_handle_use_scale_end=(False, True, True), bbone_handle_use_ease_end=True)
set_all(B["d1"], bbone_segments=6, bbone_handle_type_start="TANGENT", bbone_custom_handle_start=B["hA"],
        bbone_handle_type_end="TANGENT", bbone_custom_handle_end=B["hB"], bbone_mapping_mode="CURVED",
        bbone_handle_use_scale_end=(True, False, True), bbone_rollin=0.4)
set_all(B["d2"], bbone_segments=5, bbone_handle_type_start="ABSOLUTE", bbone_custom_handle_start=B["c1"],
        bbone_handle_type_end="ABSOLUTE", bbone_custom_handle_end=B["hB"], use_endroll_as_inroll=True,
        bbone_handle_use_scale_start=(True, True, True))
set_all(B["d3"], bbone_segments=7, bbone_handle_type_start="ABSOLUTE", bbone_handle_type_end="RELATIVE",
        bbone_custom_handle_end=B["hC"], bbone_handle_use_scale_end=(True, True, True),
        bbone_handle_use_ease_end=True)
set_all(B["e0"], bbone_segments=4, bbone_handle_type_end="ABSOLUTE", bbone_custom_handle_end=B["hN"],
        bbone_handle_use_ease_end=True)
B["hN"].inherit_scale = "NONE"
chains = [["c0", "c1", "c2", "c3"], ["d2", "d0", "d1", "d3"]]
deform = [name for chain in chains for name in chain]
for bone in B:
    bone.use_deform = bone.name in deform
bpy.ops.object.mode_set(mode="OBJECT")

rng = np.random.default_rng(3)
verts, faces, weights = [], [], []
around, along = 8, 14
for chain in chains:
    for k, name in enumerate(chain):
        bone = B[name]
        head, tail = np.array(bone.head_local), np.array(bone.tail_local)
        x, z = np.array(bone.matrix_local)[:3, 0], np.array(bone.matrix_local)[:3, 2]
        base = len(verts)
        for i in range(along):
            centre = head + (-0.15 + 1.3 * i / (along - 1)) * (tail - head)
            for j in range(around):
                a = 2 * np.pi * j / around
                verts.append(centre + 0.12 * (np.cos(a) * x + np.sin(a) * z))
                w = {name: 1.0}
                for other in chain[max(k - 1, 0): k + 2]:
                    if other != name and rng.random() < 0.7:
                        w[other] = rng.uniform(0.05, 0.6)
                weights.append(w)
        for i in range(along - 1):
            for j in range(around):
                a, b = base + i * around + j, base + i * around + (j + 1) % around
                faces.append((a, b, b + around, a + around))
verts = np.array(verts)
skin = bpy.data.objects.new("Skin", bpy.data.meshes.new("Skin"))
skin.data.from_pydata(verts.tolist(), [], faces)
scene.collection.objects.link(skin)
groups = {name: skin.vertex_groups.new(name=name) for name in deform}
for v, w in enumerate(weights):
    for name, value in w.items():
        groups[name].add([v], value, "REPLACE")
skin.modifiers.new("Armature", "ARMATURE").object = arm

def evaluated(obj):
    bpy.context.view_layer.update()
    ev = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    mesh = ev.to_mesh()
    co = np.empty(3 * len(mesh.vertices)); mesh.vertices.foreach_get("co", co)
    ev.to_mesh_clear()
    return co.reshape(-1, 3)

bbones = {bone.name: read_bbone(arm, bone.name) for bone in B}
bendy = [name for name in deform if B[name].bbone_segments > 1]
trials = []
for trial in range(4):
    for pb in P:
        pb.rotation_mode = "QUATERNION"
        pb.rotation_quaternion = Quaternion(rng.normal(size=3), rng.uniform(-0.7, 0.7))
        if not pb.bone.use_connect:
            pb.location = rng.uniform(-0.2, 0.2, 3)
        pb.scale = (1, 1, 1)
    if trial > 0:
        for name, scale in (("c1", (0.9, 1.2, 1.0)), ("d0", (1.0, 1.3, 0.8)), ("hA", (1.4, 0.7, 1.1)),
                            ("hB", (1.2, 1.2, 1.2)), ("hC", (0.8, 1.25, 1.1)), ("hp", (1.1, 0.9, 1.0)),
                            ("c0", (1.15, 1.15, 1.15))):
            P[name].scale = scale
    co = evaluated(skin)
    trials.append(dict(
        co=co.tolist(),
        poses={pb.name: np.array(pb.matrix).tolist() for pb in P},
        segments={n: [np.array(P[n].bbone_segment_matrix(i, rest=False)).tolist()
                      for i in range(B[n].bbone_segments + 1)] for n in bendy}))
rest_segments = {n: [np.array(P[n].bbone_segment_matrix(i, rest=True)).tolist()
                     for i in range(B[n].bbone_segments + 1)] for n in bendy}
index = {n: [list(P[n].bbone_segment_index(Vector(v))) for v in verts] for n in bendy}
errors = {}
for name in ("nothing", ""):
    try:
        read_bbone(arm, name)
    except BridgeError as err:
        errors[name] = str(err)
result(dict(verts=verts.tolist(), weights=weights, deform=deform, trials=trials, rest_segments=rest_segments,
            index=index, errors=errors, bbones=base64.b64encode(pickle.dumps(bbones)).decode()))
"""


@pytest.fixture(scope="module")
def blender(tmp_path_factory):
    out = run_blender(SCRIPT, tmp_path_factory.mktemp("bbone"))
    out["bbones"] = pickle.loads(base64.b64decode(out["bbones"]))
    out["verts"] = np.array(out["verts"])
    for trial in out["trials"]:
        trial["poses"] = {name: np.array(m) for name, m in trial["poses"].items()}
    return out


def handle_args(bbone, poses):
    """The posed matrices deform_matrices takes for a bone, looked up by the names the BBone gives."""
    start, end = bbone.handle_names
    start_parent, end_parent = bbone.handle_parent_names
    return [
        None if name is None else poses[name] for name in (bbone.name, start, end, start_parent, end_parent)
    ]


def skin(bbones, deform, weights, verts, poses):
    """Blender's Armature modifier (vertex groups, Preserve Volume off), rebuilt from bbone's pieces."""
    total = np.zeros_like(verts)
    weight_sum = np.zeros(len(verts))
    for name in deform:
        w = np.array([row.get(name, 0.0) for row in weights])
        bbone = bbones[name]
        A = blend_segments(deform_matrices(bbone, *handle_args(bbone, poses)), *vertex_segments(bbone, verts))
        moved = np.einsum("nij,nj->ni", A[:, :3, :3], verts) + A[:, :3, 3]
        total += w[:, None] * (moved - verts)
        weight_sum += w
    return verts + total / weight_sum[:, None]


@needs_bpy
def test_bridge_reads_handles_and_settings_as_blender_resolves_them(blender):
    bbones = blender["bbones"]
    assert bbones["c0"].handle_names == (None, "c1")  # a root: no start; AUTO end = the connected child
    assert bbones["c1"].handle_names == ("c0", "c2")
    assert bbones["c2"].handle_names == (None, None)  # a plain bone
    assert bbones["c3"].handle_names == ("c2", None)
    assert bbones["d0"].handle_names == ("hA", "hB")
    assert bbones["d0"].handle_parent_names == ("hp", "hp")  # both handles' scales are read
    assert bbones["d1"].handle_parent_names == (None, "hp")
    assert bbones["d2"].handle_names == ("c1", "hB")
    assert bbones["d2"].handle_parent_names == (None, None)  # c1 is a B-Bone: Blender skips its scale
    assert bbones["d3"].handle_names == (None, "hC") and bbones["d3"].handle_parent_names == (None, None)
    c0, c1 = bbones["c0"], bbones["c1"]
    assert (c0.segments, c0.mapping_mode, c1.segments, c1.mapping_mode) == (4, "CURVED", 10, "STRAIGHT")
    assert c0.bone_ease_in == pytest.approx(0.5) and c0.pose_ease_in == pytest.approx(0.2)
    assert np.allclose(c0.pose_scale_out, (1.1, 0.9, 1.05))
    assert c1.use_endroll_as_inroll and c1.use_scale_easing and c1.start.bone_roll_out == pytest.approx(-0.3)
    assert c1.start.pose_roll_out == pytest.approx(0.25)
    assert bbones["d0"].handle_use_scale_start == (True, True, False) and bbones["d0"].handle_use_ease_end
    assert all(bbones[name].unsupported() is None for name in blender["deform"])
    message = bbones["e0"].unsupported()
    assert "'e0'" in message and "'hN'" in message and "'NONE'" in message
    assert "'nothing'" in blender["errors"]["nothing"] and "''" in blender["errors"][""]


@needs_bpy
def test_skinned_vertices_equal_blenders_armature_modifier(blender):
    """The parity that matters: every deformed vertex, B-Bones of 4 to 10 segments next to a plain bone,
    every handle type and option, posed with rotations and (non-)uniform scales."""
    verts = blender["verts"]
    size = np.ptp(verts, axis=0).max()
    worst = 0.0
    for trial in blender["trials"]:
        ours = skin(blender["bbones"], blender["deform"], blender["weights"], verts, trial["poses"])
        worst = max(worst, np.abs(ours - np.array(trial["co"])).max() / size)
        assert np.abs(ours - verts).max() > 0.05 * size  # the poses really move the mesh
    assert worst < 1e-5, worst  # measured 3e-7 (Blender computes in float32)


@needs_bpy
def test_segment_matrices_equal_blenders(blender):
    """``spline_matrices`` is ``PoseBone.bbone_segment_matrix`` at rest and posed. Blender computes the
    handle length with ``1 - cos(a)`` in float32 for small angles a (cubic_tangent_factor_circle_v3),
    which is noisy to ~1e-4 relative when a chain is almost straight, hence the looser bound."""
    bbones = blender["bbones"]
    for name, theirs in blender["rest_segments"].items():
        assert np.abs(spline_matrices(bbones[name], rest=True) - np.array(theirs)).max() < 1e-5
    worst = []
    for trial in blender["trials"]:
        for name, theirs in trial["segments"].items():
            ours = spline_matrices(bbones[name], *handle_args(bbones[name], trial["poses"]))
            worst.append(np.abs(ours - np.array(theirs)).max())
    assert max(worst) < 1e-4, max(worst)  # measured 4e-6; 2.5e-5 seen with other seeds
    assert np.median(worst) < 2e-6


@needs_bpy
def test_segment_index_and_blend_equal_blenders(blender):
    """Both mappings: ``vertex_segments`` is ``PoseBone.bbone_segment_index`` (points beyond the ends
    included)."""
    bbones, verts = blender["bbones"], blender["verts"]
    modes = set()
    for name, theirs in blender["index"].items():
        theirs = np.array(theirs)
        index, blend = vertex_segments(bbones[name], verts)
        modes.add(bbones[name].mapping_mode)
        # Position along the bone in segments (10 at most): measured 6e-6, Blender's float32 planes.
        assert np.abs((index + blend) - (theirs[:, 0] + theirs[:, 1])).max() < 3e-5
        inside = (theirs[:, 1] > 1e-4) & (theirs[:, 1] < 1 - 1e-4)
        assert np.array_equal(index[inside], theirs[inside, 0].astype(int))
        assert (index == 0).any() and (index == bbones[name].segments - 1).any()
    assert modes == {"STRAIGHT", "CURVED"}


# --------------------------------------------------------------------------------------------------
# Plain numpy


def frame(head, tail, roll=0.0):
    """A rest matrix with its y axis from head to tail (any roll: the tests only need some frame)."""
    head, tail = np.asarray(head, float), np.asarray(tail, float)
    y = (tail - head) / np.linalg.norm(tail - head)
    x = np.cross(y, (0.3, 0.1, 1.0))
    x /= np.linalg.norm(x)
    z = np.cross(x, y)
    c, s = np.cos(roll), np.sin(roll)
    M = np.eye(4)
    M[:3, 0], M[:3, 1], M[:3, 2], M[:3, 3] = c * x - s * z, y, s * x + c * z, head
    return M


def handle(name, head, tail, roll=0.0, **kw):
    M = frame(head, tail, roll)
    return BBoneHandle(name, M, np.linalg.norm(np.subtract(tail, head)), head, tail, **kw)


def rotation(axis, angle):
    """(..., 4, 4) rotations by angles (...,) about a fixed axis; complex angles give complex matrices."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    angle = np.asarray(angle)[..., None, None]
    R = np.zeros((*angle.shape[:-2], 4, 4), dtype=angle.dtype)
    R[..., :3, :3] = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * (K @ K)
    R[..., 3, 3] = 1
    return R


def about_head(M, axis, angle, scale=(1.0, 1.0, 1.0), pivot=None):
    """A posed matrix: rest matrix ``M`` scaled in its own axes, then turned about its head (or ``pivot``)."""
    T = np.eye(4)
    T[:3, 3] = M[:3, 3] if pivot is None else pivot
    return T @ rotation(axis, angle) @ np.linalg.inv(T) @ M @ np.diag([*scale, 1.0])


def test_segments_one_is_the_plain_bone_matrix():
    M = frame((0, 0, 0), (0, 1, 0))
    bone = BBone("plain", M, 1.0, (0, 0, 0), (0, 1, 0), segments=1, start=handle("h", (0, -1, 0), (0, 0, 0)))
    pose = about_head(M, (1, 2, 3), 0.7, (1.0, 1.5, 0.5))
    mats = deform_matrices(bone, pose)
    assert mats.shape == (2, 4, 4) and np.allclose(mats, pose @ np.linalg.inv(M), atol=1e-14)
    index, blend = vertex_segments(bone, np.random.default_rng(0).normal(size=(5, 3)))
    assert index.tolist() == [0] * 5 and blend.tolist() == [0.0] * 5
    assert bone.handle_names == (None, None)


def test_rest_pose_deforms_nothing_and_straight_mapping_is_the_projection_on_the_axis():
    M = frame((0.5, 0, 0), (0.5, 2, 0.5), roll=0.4)
    start = handle("s", (0.2, -1.5, 0), (0.5, 0, 0), segments=4)
    end = handle("e", (0.5, 2, 0.5), (1.5, 3, 0.5))
    bone = BBone(
        "b",
        M,
        np.linalg.norm((0, 2, 0.5)),
        (0.5, 0, 0),
        (0.5, 2, 0.5),
        segments=10,
        start=start,
        end=end,
        handle_type_end="RELATIVE",
        bone_ease_in=0.7,
        bone_roll_in=0.3,
        bone_curve_out_x=0.2,
        bone_scale_in=(1.2, 0.8, 1.1),
    )
    mats = deform_matrices(bone, M, start.matrix_local, end.matrix_local)
    assert mats.shape == (11, 4, 4) and np.abs(mats - np.eye(4)).max() < 1e-12
    # 35% and 105% of the way along the bone, 0.1 off its axis.
    points = np.array(
        [M[:3, 3] + f * (bone.tail_local - bone.head_local) + 0.1 * M[:3, 0] for f in (0.35, 1.05)]
    )
    index, blend = vertex_segments(bone, points)
    assert index.tolist() == [3, 9] and np.allclose(blend, [0.5, 1.0])


def test_complex_step_derivatives_equal_central_differences():
    """d(deform matrices)/d(rotation angle) of the bone, both handles and a handle's parent, with
    non-uniform scales, every kind of handle and all offsets."""
    rest = frame((0, 0, 0), (0.2, 1.5, 0.3), roll=0.2)
    parent = frame((1.0, 2.5, 0.0), (1.0, 2.8, 0.0))
    end = handle(
        "end",
        (0.2, 1.7, 0.3),
        (0.5, 2.6, 0.2),
        roll=-0.3,
        parent="p",
        parent_offset=np.linalg.inv(parent) @ frame((0.2, 1.7, 0.3), (0.5, 2.6, 0.2), -0.3),
    )
    cases = {
        "tangent/absolute": dict(handle_type_start="TANGENT", handle_type_end="ABSOLUTE"),
        "relative/relative": dict(handle_type_start="RELATIVE", handle_type_end="RELATIVE"),
        "joined/absolute": dict(handle_type_start="AUTO", handle_type_end="AUTO", use_endroll_as_inroll=True),
    }
    for label, kind in cases.items():
        start = handle(
            "start",
            (-0.5, -0.8, 0.1),
            (0, 0, 0),
            roll=0.5,
            segments=3 if "joined" in label else 1,
            bone_roll_out=0.2,
            pose_roll_out=-0.1,
        )
        bone = BBone(
            "bone",
            rest,
            np.linalg.norm((0.2, 1.5, 0.3)),
            (0, 0, 0),
            (0.2, 1.5, 0.3),
            segments=8,
            start=start,
            end=end,
            bone_ease_in=0.8,
            bone_ease_out=1.2,
            pose_ease_in=0.3,
            bone_roll_in=0.2,
            pose_roll_out=0.4,
            bone_curve_in_x=0.1,
            pose_curve_out_z=-0.2,
            bone_scale_in=(1.1, 1.3, 0.9),
            pose_scale_out=(0.8, 1.2, 1.1),
            use_scale_easing=True,
            handle_use_scale_start=(True, True, True),
            handle_use_ease_start=True,
            handle_use_scale_end=(True, False, True),
            handle_use_ease_end=True,
            **kind,
        )
        assert bone.unsupported() is None

        def f(theta, bone=bone, start=start):
            return deform_matrices(
                bone,
                about_head(rest, (0.3, 0.5, 0.8), 0.4 + theta[..., 0], (1.1, 1.3, 0.9)),
                about_head(
                    start.matrix_local, (1, 0.2, -0.3), -0.3 + theta[..., 1], (1.2, 0.9, 1.0), (0, 0, 0)
                ),
                about_head(end.matrix_local, (-0.2, 0.4, 1.0), 0.5 + theta[..., 2], (0.9, 1.4, 1.1)),
                None,
                about_head(parent, (0.1, 1.0, 0.2), 0.2 + theta[..., 3], (1.3, 0.8, 1.0)),
            )

        x = np.zeros(4)
        y = f(analytic.directions(x, np.ones(4, bool)))
        assert np.abs(analytic.value(y) - f(x)).max() < 1e-13
        exact = analytic.derivative(y)
        for j in range(4):
            step = np.zeros(4)
            step[j] = 1e-5
            central = (f(step) - f(-step)) / 2e-5
            assert np.abs(central).max() > 1e-3, (label, j)  # every angle matters
            # measured 1e-9 relative: the central difference's own error
            assert np.abs(exact[j] - central).max() < 1e-8 * np.abs(central).max(), (label, j)


def test_batched_poses_equal_one_by_one():
    rest = frame((0, 0, 0), (0, 1, 0))
    start = handle("s", (0, -1, 0), (0, 0, 0))
    bone = BBone(
        "b",
        rest,
        1.0,
        (0, 0, 0),
        (0, 1, 0),
        segments=5,
        start=start,
        mapping_mode="CURVED",
        bone_curve_in_x=0.3,
    )
    angles = np.linspace(-1, 1, 6).reshape(2, 3)
    poses = about_head(rest, (1, 0, 0.2), angles)
    batch = deform_matrices(bone, poses, start.matrix_local)
    assert batch.shape == (2, 3, 6, 4, 4)
    for i in np.ndindex(2, 3):
        assert np.allclose(batch[i], deform_matrices(bone, poses[i], start.matrix_local), atol=1e-14)


def test_bad_settings_and_missing_poses_are_refused_by_name():
    rest = frame((0, 0, 0), (0, 1, 0))
    good = dict(name="b", matrix_local=rest, length=1.0, head_local=(0, 0, 0), tail_local=(0, 1, 0))
    for change, words in (
        (dict(segments=40), "bbone_segments"),
        (dict(segments=2.0), "bbone_segments"),
        (dict(length=0.0), "length"),
        (dict(handle_type_start="SMOOTH"), "bbone_handle_type_start"),
        (dict(mapping_mode="BENT"), "bbone_mapping_mode"),
        (dict(pose_ease_in=np.nan), "bbone_easein (pose)"),
        (dict(bone_scale_out=(1, 1)), "bbone_scaleout (bone)"),
        (dict(handle_use_scale_end=(True, False)), "bbone_handle_use_scale_end"),
        (dict(matrix_local=np.zeros((4, 4))), "matrix_local"),
    ):
        with pytest.raises(SolverError, match=f"'b'.*{words.replace('(', '.').replace(')', '.')}"):
            BBone(**{**good, **change})
    with pytest.raises(SolverError, match=r"handle 'h'.*length"):
        BBoneHandle("h", rest, 0.0, (0, 0, 0), (0, 0, 0))
    with pytest.raises(SolverError, match="parent_offset"):
        handle("h", (0, -1, 0), (0, 0, 0), parent="p")
    bone = BBone(**good, segments=4, start=handle("h", (0, -1, 0), (0, 0, 0)))
    with pytest.raises(SolverError, match="start handle 'h'"):
        deform_matrices(bone, rest)
    with pytest.raises(SolverError, match="not a B-Bone"):
        spline_matrices(BBone(**good), rest)
    with pytest.raises(SolverError, match=r"\(n, 3\)"):
        vertex_segments(bone, np.zeros(3))


# --------------------------------------------------------------------------------------------------
# Stacks: many B-Bones at once, against the bone-by-bone port


def random_bbone(rng, name, segments, types, handles, parents):
    """A B-Bone with random continuous settings, handles on the given ends (``"bbone"``: a B-Bone the
    curve joins, ``"plain"``, ``"parented"``: a plain handle whose parent's pose is read, or None) and
    random handle-scale flags; the parents' rest matrices go in ``parents``."""
    head = rng.normal(size=3)
    tail = head + np.array([0.0, 1.0, 0.0]) + 0.3 * rng.normal(size=3)
    ends = {}
    for side, kind in zip(("start", "end"), handles, strict=True):
        if kind is None:
            continue
        h_head = head + rng.normal(size=3) if side == "start" else tail + 0.1 * rng.normal(size=3)
        h_tail = h_head + np.array([0.2, 0.9, 0.1]) + 0.2 * rng.normal(size=3)
        extra = {}
        if kind == "parented":
            parent = frame(h_head - 1.0, h_head - 0.4, rng.normal())
            parents[f"{name}.{side}.parent"] = parent
            extra = dict(
                parent=f"{name}.{side}.parent",
                parent_offset=np.linalg.inv(parent) @ frame(h_head, h_tail, 0.3),
            )
        ends[side] = handle(
            f"{name}.{side}",
            h_head,
            h_tail,
            0.3,
            segments=4 if kind == "bbone" else 1,
            bone_roll_out=rng.normal(),
            pose_roll_out=rng.normal(),
            **extra,
        )
    flags = rng.random(8) < 0.5
    return BBone(
        name,
        frame(head, tail, rng.normal()),
        np.linalg.norm(tail - head),
        head,
        tail,
        segments=segments,
        handle_type_start=types[0],
        handle_type_end=types[1],
        start=ends.get("start"),
        end=ends.get("end"),
        bone_ease_in=rng.uniform(0, 2),
        bone_ease_out=rng.uniform(0, 2),
        pose_ease_in=0.3 * rng.normal(),
        pose_ease_out=0.3 * rng.normal(),
        bone_roll_in=rng.normal(),
        bone_roll_out=rng.normal(),
        pose_roll_in=rng.normal(),
        pose_roll_out=rng.normal(),
        bone_curve_in_x=0.2 * rng.normal(),
        bone_curve_in_z=0.2 * rng.normal(),
        bone_curve_out_x=0.2 * rng.normal(),
        bone_curve_out_z=0.2 * rng.normal(),
        pose_curve_in_z=0.1 * rng.normal(),
        pose_curve_out_x=0.1 * rng.normal(),
        bone_scale_in=rng.uniform(0.7, 1.4, 3),
        bone_scale_out=rng.uniform(0.7, 1.4, 3),
        pose_scale_in=rng.uniform(0.8, 1.2, 3),
        pose_scale_out=rng.uniform(0.8, 1.2, 3),
        use_endroll_as_inroll=bool(flags[0]),
        use_scale_easing=bool(flags[1]),
        handle_use_scale_start=tuple(bool(f) for f in rng.random(3) < 0.5),
        handle_use_scale_end=tuple(bool(f) for f in rng.random(3) < 0.5),
        handle_use_ease_start=bool(flags[2]),
        handle_use_ease_end=bool(flags[3]),
    )


def random_rig(seed, count):
    """B-Bones with every combination of handle types, kinds and missing handles, two segment counts."""
    rng = np.random.default_rng(seed)
    bones, parents = [], {}
    kinds = (None, "bbone", "plain", "parented")
    types = ("AUTO", "ABSOLUTE", "RELATIVE", "TANGENT")
    for i in range(count):
        bones.append(
            random_bbone(
                rng,
                f"b{i}",
                (3, 6)[i % 2],
                (types[rng.integers(4)], types[rng.integers(4)]),
                (kinds[rng.integers(4)], kinds[rng.integers(4)]),
                parents,
            )
        )
    return bones, parents


def random_poses(seed, bones, parents, directions=0, batch=()):
    """Posed matrices of every bone, handle and handle parent: turned, moved and scaled non-uniformly,
    real, or complex-step with ``directions`` directions of one pose."""
    rng = np.random.default_rng(seed)
    rests = dict(parents)
    for bb in bones:
        rests[bb.name] = bb.matrix_local
        rests.update({h.name: h.matrix_local for h in (bb.start, bb.end) if h is not None})
    poses = {}
    for name, rest in sorted(rests.items()):
        angle = 0.6 * rng.normal() + np.zeros(batch)
        if directions:
            angle = angle + 1j * analytic.STEP * rng.normal(size=(directions, *batch))
        scale = rng.uniform(0.8, 1.25, 3)
        move = np.eye(4)
        move[:3, 3] = 0.1 * rng.normal(size=3)
        poses[name] = move @ about_head(rest, rng.normal(size=3), angle, scale)
    return poses


def reference(bb, poses):
    """``deform_matrices`` of one bone, computed bone by bone by the first port."""
    return deform_matrices_reference(bb, *handle_args(bb, poses))


def test_stacks_group_by_discrete_settings_and_mask_missing_handles():
    bones, _ = random_rig(1, 60)
    groups = stacks(bones)
    assert sorted(bb.name for st in groups for bb in st.bbones) == sorted(bb.name for bb in bones)
    # bones without a handle at an end share the stacks of bones with one there
    assert any(None in names for st in groups for names in st.handle_names if names is not None)
    assert len(groups) < len(bones) * 0.7
    for st in groups:
        assert {bb.segments for bb in st.bbones} == {st.segments}
        for side, names in zip((0, 1), st.handle_names, strict=True):
            if names is None:
                assert all(bb.handle_names[side] is None for bb in st.bbones)
            else:
                assert names == tuple(bb.handle_names[side] for bb in st.bbones)
                assert any(n is not None for n in names)
        for side, names in zip((0, 1), st.handle_parent_names, strict=True):
            if names is not None:
                assert names == tuple(bb.handle_parent_names[side] for bb in st.bbones)
    a, b = bones[0], next(bb for bb in bones if bb.segments != bones[0].segments)
    with pytest.raises(SolverError, match=f"'{a.name}' and '{b.name}' cannot share a stack"):
        BBoneStack.of([a, b])
    with pytest.raises(SolverError, match="one or more BBone"):
        BBoneStack.of([])
    with pytest.raises(SolverError, match="stacks takes BBone"):
        stacks([a, "b"])


def test_stacks_equal_bone_by_bone():
    """Every option mixed in stacks, real poses with batch dimensions: the same matrices as the first,
    bone-by-bone port (which the Blender tests above check), to rounding."""
    bones, parents = random_rig(2, 80)
    poses = random_poses(3, bones, parents, batch=(2,))
    worst, count = 0.0, 0
    for st in stacks(bones):
        out = stack_deform_matrices(st, *st.gather(poses))
        assert out.shape == (2, len(st), st.segments + 1, 4, 4)
        for k, bb in enumerate(st.bbones):
            ref = reference(bb, poses)
            worst = max(worst, np.abs(out[:, k] - ref).max() / np.abs(ref).max())
            assert np.abs(deform_matrices(bb, *handle_args(bb, poses)) - ref).max() < 1e-12
            count += 1
    assert count == len(bones)
    assert worst < 1e-12, worst  # measured 3e-14


@pytest.mark.parametrize("directions", [3, 20, 80])
def test_stack_complex_steps_equal_bone_by_bone(directions):
    """Complex-step directions of one pose: below 10 the curve is evaluated on every direction, above it
    is differentiated through the per-bone state (with the state's own derivatives evaluated on the
    directions, or, beyond the number of pose entries the state depends on, through them)."""
    bones, parents = random_rig(4, 40)
    poses = random_poses(5, bones, parents, directions=directions)
    worst_value = worst_derivative = 0.0
    for st in stacks(bones):
        out = stack_deform_matrices(st, *st.gather(poses))
        assert out.shape == (directions, len(st), st.segments + 1, 4, 4) and np.iscomplexobj(out)
        for k, bb in enumerate(st.bbones):
            ref = reference(bb, poses)
            scale = np.abs(ref.real).max()
            worst_value = max(worst_value, np.abs(out[:, k].real - ref.real).max() / scale)
            exact = analytic.derivative(ref)
            error = np.abs(analytic.derivative(out[:, k]) - exact).max() / max(np.abs(exact).max(), 1.0)
            worst_derivative = max(worst_derivative, error)
    assert worst_value < 1e-12, worst_value  # measured 4e-14
    assert worst_derivative < 1e-12, worst_derivative  # measured 1e-13


def finger_rig():
    """Five chains of three connected B-Bones of 10 segments with AUTO handles (no start handle on the
    first bone of a chain, no end handle on the last), the hand of a Rigify rig."""
    bones = []
    for f in range(5):
        points = [np.array([0.02 * f, 0.0, 0.005 * f])]
        for k in range(3):
            points.append(points[-1] + np.array([0.002 * (k - f), 0.03 - 0.006 * k, 0.003 * (f - 2)]))
        rests = [frame(points[k], points[k + 1], 0.1 * (k + f)) for k in range(3)]
        lengths = [np.linalg.norm(points[k + 1] - points[k]) for k in range(3)]
        for k in range(3):
            ends = [
                BBoneHandle(f"f{f}.{j}", rests[j], lengths[j], points[j], points[j + 1], segments=10)
                if 0 <= j < 3
                else None
                for j in (k - 1, k + 1)
            ]
            bones.append(
                BBone(
                    f"f{f}.{k}",
                    rests[k],
                    lengths[k],
                    points[k],
                    points[k + 1],
                    segments=10,
                    start=ends[0],
                    end=ends[1],
                    bone_ease_in=1.0 + 0.1 * k,
                    pose_roll_out=0.05 * f,
                )
            )
    return bones


def test_finger_stack_equals_bone_by_bone():
    """The stack the solver evaluates most: a hand's fingers in one stack, real with many poses and with
    8 and 54 complex-step directions."""
    bones = finger_rig()
    (st,) = stacks(bones)
    assert (
        len(st) == 15
        and st.handle_names[0][0] is None
        and st.handle_names[1][1] == "f0.2"
        and st.handle_names[1][2] is None
    )
    for directions, batch in ((0, (30,)), (8, ()), (54, ())):
        poses = random_poses(11, bones, {}, directions=directions, batch=batch)
        out = stack_deform_matrices(st, *st.gather(poses))
        for k, bb in enumerate(st.bbones):
            ref = reference(bb, poses)
            assert np.abs(out[..., k, :, :, :].real - ref.real).max() < 1e-12 * np.abs(ref).max()
            exact = analytic.derivative(ref) if directions else 0.0
            error = np.abs(analytic.derivative(out[..., k, :, :, :]) - exact).max() if directions else 0.0
            assert error < 1e-12 * max(np.abs(exact).max(), 1.0), (directions, bb.name)


def test_stack_of_different_complex_poses_and_mixed_inputs():
    """Complex poses whose real parts differ along the leading axis (not directions of one pose), and
    real handles with complex bones: both evaluated on every entry."""
    bones, parents = random_rig(6, 12)
    poses = random_poses(7, bones, parents, directions=5, batch=(3,))
    real = {n: p[0].real for n, p in poses.items()}
    for st in stacks(bones):
        args = st.gather(poses)
        out = stack_deform_matrices(st, *args)
        assert out.shape == (5, 3, len(st), st.segments + 1, 4, 4)
        mixed = stack_deform_matrices(st, args[0], *(None if a is None else a[0].real for a in args[1:]))
        for k, bb in enumerate(st.bbones):
            ref = reference(bb, poses)
            assert np.abs(out[..., k, :, :, :] - ref).max() < 1e-12 * np.abs(ref).max()
            handles = {**real, bb.name: poses[bb.name]}
            ref = reference(bb, handles)
            assert np.abs(mixed[..., k, :, :, :] - ref).max() < 1e-12 * np.abs(ref).max()
            assert np.abs(analytic.derivative(mixed[:, :, k]) - analytic.derivative(ref)).max() < 1e-9


def test_stack_special_branches():
    """A start handle on the bone's own axis (the curve's tangent and the handle's direction along -y,
    where vec_roll_to_mat3 takes its special branch), a very short handle (ease_handle_axis), a mirrored
    handle, plain bones, and a stack without handles."""
    rest = frame((0, 0, 0), (0, 1, 0), 0.2)
    ahead = handle("ahead", (0.0, 0.5, 0.0), (0.3, 1.5, 0.0))
    behind = handle("behind", (0.0, -1.0, 0.0), (0.0, 0.0, 0.0))
    flipped = BBone(
        "flipped",
        rest,
        1.0,
        (0, 0, 0),
        (0, 1, 0),
        segments=4,
        handle_type_start="ABSOLUTE",
        start=ahead,
        bone_ease_in=0.3,
    )
    short = BBone(
        "short",
        rest,
        1.0,
        (0, 0, 0),
        (0, 1, 0),
        segments=4,
        handle_type_start="ABSOLUTE",
        start=behind,
        bone_ease_in=0.001,
        bone_ease_out=0.002,
        bone_curve_in_x=0.2,
    )
    mirror = handle("mirror", (0.1, 1.1, 0.0), (0.5, 1.8, 0.3))
    # A mirrored end handle (negative scale): mat3_to_quat negates the matrix whose roll it reads. (With
    # a TANGENT handle that matrix would be a half turn about an axis normal to y, whose twist Blender
    # leaves to rounding.)
    lone = BBone(
        "lone",
        rest,
        1.0,
        (0, 0, 0),
        (0, 1, 0),
        segments=5,
        bone_curve_out_z=0.3,
        handle_type_end="ABSOLUTE",
        end=mirror,
    )
    plain = BBone("plain", rest, 1.0, (0, 0, 0), (0, 1, 0))
    poses = {
        "ahead": ahead.matrix_local,
        "behind": about_head(behind.matrix_local, (1, 0, 0), 0.3),
        "flipped": rest,
        "short": about_head(rest, (0, 0, 1), 0.4),
        "lone": about_head(rest, (1, 1, 0), 0.5, (1.2, 0.9, 1.0)),
        "mirror": about_head(mirror.matrix_local, (0.2, 1, 0.3), 0.7, (-1.1, 0.9, 1.0)),
        "plain": about_head(rest, (1, 1, 0), 0.5, (1.2, 0.9, 1.0)),
    }
    top_rows = np.array([[1.0], [1.0], [1.0], [0.0]])  # posed matrices stay affine
    steps = analytic.STEP * np.random.default_rng(8).normal(size=(6, 4, 4)) * top_rows
    for bb in (flipped, short, lone):
        (st,) = stacks([bb])
        for posed in (poses, {n: p + 1j * steps for n, p in poses.items()}):
            ref = reference(bb, posed)
            out = stack_deform_matrices(st, *st.gather(posed))[..., 0, :, :, :]
            assert np.abs(out.real - ref.real).max() < 1e-12 * np.abs(ref).max(), bb.name
            exact = analytic.derivative(ref)
            assert np.abs(analytic.derivative(out) - exact).max() < 1e-12 * max(np.abs(exact).max(), 1), (
                bb.name
            )
    assert np.linalg.det(poses["mirror"][:3, :3]) < 0
    (st,) = stacks([plain, BBone("plain2", rest, 2.0, (0, 0, 0), (0, 2, 0))])
    out = stack_deform_matrices(st, np.stack([poses["plain"], poses["plain"]]))
    assert out.shape == (2, 2, 4, 4) and np.allclose(out[0, 1], poses["plain"] @ np.linalg.inv(rest))
    (st,) = stacks([BBone("alone", rest, 1.0, (0, 0, 0), (0, 1, 0), segments=3)])
    assert st.handle_names == (None, None) and st.handle_parent_names == (None, None)
    out = stack_deform_matrices(st, about_head(rest, (1, 0, 0), 0.3)[None])
    assert np.abs(out[0] - reference(st.bbones[0], {"alone": about_head(rest, (1, 0, 0), 0.3)})).max() < 1e-12


def test_stack_arguments_are_checked():
    bones, parents = random_rig(9, 30)
    poses = random_poses(10, bones, parents)
    st = next(st for st in stacks(bones) if st.handle_names[1] is not None)
    args = list(st.gather(lambda name: poses[name]))
    assert all(np.array_equal(x, y) for x, y in zip(args, st.gather(poses), strict=True) if x is not None)
    with pytest.raises(SolverError, match="end handles"):
        stack_deform_matrices(st, *args[:2], None, *args[3:])
    with pytest.raises(SolverError, match=rf"\(\.\.\., {len(st)}, 4, 4\)"):
        stack_deform_matrices(st, args[0][:-1], *args[1:])
    with pytest.raises(SolverError, match="BBoneStack"):
        stack_deform_matrices(bones[0], poses[bones[0].name])
    # the entries of bones without a handle are not used, whatever they hold
    st = next(st for st in stacks(bones) if st.handle_names[0] is not None and None in st.handle_names[0])
    args = list(st.gather(poses))
    garbage = args[1].copy()
    garbage[[k for k, n in enumerate(st.handle_names[0]) if n is None]] = np.nan
    assert np.array_equal(
        stack_deform_matrices(st, args[0], garbage, *args[2:]), stack_deform_matrices(st, *args)
    )
