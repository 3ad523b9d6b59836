"""Posing in the real bpy 5.0.1 module: the armature bridge against Blender's own Armature modifier, the
solve and flex-to-contact operators, and the rigs and settings the solver must refuse."""

import importlib.util

import pytest

from .blender import run_blender

pytestmark = pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="needs bpy (the dev extra)")

SETUP = """
import numpy as np
from mathutils import Matrix
import contact_edit_addon
contact_edit_addon.register()
from contact_edit_addon import assets, bridge, posing, store
from geodesics import ContactPatch, SurfacePoints, farthest_pair_axis
from solver import hands, objects
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
kit = hands.make_hand("human")
hand, armature = assets.hand_objects(kit, "Hand", scene.collection)
scene.contact_edit.hand = hand
bpy.context.view_layer.objects.active = hand

def evaluated_vertices(obj):
    bpy.context.view_layer.update()
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    mesh = evaluated.to_mesh()
    co = np.empty(3 * len(mesh.vertices)); mesh.vertices.foreach_get("co", co)
    evaluated.to_mesh_clear()
    return co.reshape(-1, 3)

def world_vertices(obj):
    M = np.array(obj.matrix_world)
    return evaluated_vertices(obj) @ M[:3, :3].T + M[:3, 3]

def changed(before, after):  # names of the pose bones whose matrix_basis differs
    names = [b.name for b in armature.pose.bones]
    return sorted(names[i] for i in np.flatnonzero(np.abs(after - before).max(axis=(1, 2)) > 1e-9))

def random_pose(rig, rng):
    theta = rng.uniform(np.maximum(rig.lower, -2.5), np.minimum(rig.upper, 2.5))
    theta[:3] = rng.uniform(-0.05, 0.05, 3)
    return theta

def pose_matrices():
    return np.array([np.array(b.matrix_basis) for b in armature.pose.bones])

def error_of(call):
    try:
        call()
    except Exception as err:
        return type(err).__name__ + ": " + str(err)
    return None
"""


def test_skinned_vertices_equal_blenders_evaluated_mesh(tmp_path):
    """The parity the whole add-on rests on: the solver's skinned hand is Blender's deformed hand."""
    out = run_blender(
        """
        # An armature moved, turned and uniformly scaled; the hand offset from it; quaternion, axis-angle
        # and ZXY bones among the Euler ones.
        turn = Matrix.Rotation(0.7, 3, (1, 2, 3)).to_quaternion()
        armature.matrix_world = Matrix.LocRotScale((0.3, -0.2, 0.5), turn, (0.5, 0.5, 0.5))
        hand.matrix_parent_inverse = Matrix.Translation((0.01, 0.02, -0.03))
        armature.pose.bones["index_2"].rotation_mode = "QUATERNION"
        armature.pose.bones["thumb_1"].rotation_mode = "AXIS_ANGLE"
        armature.pose.bones["ring_1"].rotation_mode = "ZXY"
        bpy.context.view_layer.update()
        posed = bridge.posed_hand(hand, bridge.trimesh(hand).faces)
        rig = posed.rig
        rng = np.random.default_rng(7)
        worst = round_trip = 0.0
        for trial in range(5):
            theta = random_pose(rig, rng)
            bridge.apply_pose(posed, theta)
            ours = posed.to_hand(posed.skin.posed_vertices(theta))
            worst = max(worst, float(np.abs(evaluated_vertices(hand) - ours).max()))
            back = bridge.current_pose(armature, rig.names)
            difference = posed.rig.pose_matrices(back) - posed.rig.pose_matrices(theta)
            round_trip = max(round_trip, float(np.abs(difference).max()))
        result(dict(worst=worst, round_trip=round_trip, dofs=rig.n_dofs, modes=list(posed.rotation_modes[:4]),
                    limited=int(np.isfinite(rig.upper).sum())))
        """,
        tmp_path,
        setup=SETUP,
    )
    assert out["dofs"] == 54
    assert out["worst"] < 1e-5  # scene units, on a hand 0.3 m across: Blender's float32
    assert out["round_trip"] < 1e-6
    assert out["limited"] == 51  # every rotation DOF bounded; the root's location is free


def test_limits_and_locks_become_bounds(tmp_path):
    out = run_blender(
        """
        bone = armature.pose.bones["index_1"]
        limit = bone.constraints[0]
        limit.max_x = 0.5
        bone.use_ik_limit_z, bone.ik_min_z, bone.ik_max_z = True, -0.1, 0.05
        bone.lock_rotation[1] = True
        armature.pose.bones["forearm"].lock_location = (False, True, False)
        posed = bridge.posed_hand(hand, bridge.trimesh(hand).faces)
        rig = posed.rig
        b = rig.bone_index("index_1")
        result(dict(upper_x=rig.upper[rig.rotation_dof(b, 0)], lower_z=rig.lower[rig.rotation_dof(b, 2)],
                    upper_z=rig.upper[rig.rotation_dof(b, 2)], locked=np.flatnonzero(rig.locked).tolist(),
                    lock_y=int(rig.rotation_dof(b, 1))))
        """,
        tmp_path,
        setup=SETUP,
    )
    assert out["upper_x"] == pytest.approx(0.5)
    assert out["lower_z"] == pytest.approx(-0.1) and out["upper_z"] == pytest.approx(0.05)
    assert out["locked"] == [1, out["lock_y"]]


def test_rigs_the_solver_cannot_reproduce_are_refused_by_name(tmp_path):
    out = run_blender(
        """
        faces = bridge.trimesh(hand).faces
        errors = {}
        def attempt(key, change, undo):
            change(); bpy.context.view_layer.update()
            errors[key] = error_of(lambda: bridge.posed_hand(hand, faces))
            undo(); bpy.context.view_layer.update()

        copy = armature.pose.bones["middle_2"].constraints.new("COPY_ROTATION")
        attempt("constraint", lambda: None, lambda: armature.pose.bones["middle_2"].constraints.remove(copy))
        attempt("scale", lambda: setattr(armature, "scale", (1, 2, 1)),
                lambda: setattr(armature, "scale", (1, 1, 1)))
        attempt("bbone", lambda: setattr(armature.data.bones["pinky_1"], "bbone_segments", 4),
                lambda: setattr(armature.data.bones["pinky_1"], "bbone_segments", 1))
        modifier = hand.modifiers["Armature"]
        attempt("volume", lambda: setattr(modifier, "use_deform_preserve_volume", True),
                lambda: setattr(modifier, "use_deform_preserve_volume", False))
        attempt("moved", lambda: setattr(armature.pose.bones["ring_3"], "location", (0, 0.01, 0)),
                lambda: setattr(armature.pose.bones["ring_3"], "location", (0, 0, 0)))
        smooth = hand.modifiers.new("Smooth", "SMOOTH")
        bpy.ops.object.modifier_move_to_index(modifier="Smooth", index=0)
        attempt("before", lambda: None, lambda: hand.modifiers.remove(smooth))
        attempt("bone parent",
                lambda: (setattr(hand, "parent_type", "BONE"), setattr(hand, "parent_bone", "hand")),
                lambda: setattr(hand, "parent_type", "OBJECT"))
        groups = {g.name: g.index for g in hand.vertex_groups}
        attempt("no modifier", lambda: setattr(modifier, "show_viewport", False),
                lambda: setattr(modifier, "show_viewport", True))
        plain = bpy.data.objects.new("Plain", bpy.data.meshes.new("Plain"))
        tetrahedron = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
        plain.data.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)], [], tetrahedron)
        scene.collection.objects.link(plain)
        plain.modifiers.new("Armature", "ARMATURE").object = armature
        errors["unweighted"] = error_of(lambda: bridge.posed_hand(plain, bridge.trimesh(plain).faces))
        errors["fine again"] = error_of(lambda: bridge.posed_hand(hand, faces))
        result(errors)
        """,
        tmp_path,
        setup=SETUP,
    )
    assert out.pop("fine again") is None  # every refusal above left the rig as it was
    expected = {
        "constraint": "middle_2: Copy Rotation",
        "scale": "non-uniform scale",
        "bbone": "pinky_1: B-Bone",
        "volume": "Preserve Volume",
        "moved": "ring_3: moved off its parent",
        "before": "modifiers before it",
        "bone parent": "parented to the bone 'hand'",
        "no modifier": "no Armature modifier",
        "unweighted": "no vertex of 'Plain' is weighted",
    }
    for key, words in expected.items():
        assert out[key] is not None and out[key].startswith("BridgeError") and words in out[key], (
            key,
            out[key],
        )


# A hand solved back onto a mould of itself: the object is the hand's own surface at a ground-truth pose,
# with its faces flipped (so its normals face the hand, as an object's do), and patches on the same
# vertices of both, paired point for point.
MOULD = """
posed = bridge.posed_hand(hand, bridge.trimesh(hand).faces)
rng = np.random.default_rng(3)
truth = posed.rig.clip(0.5 * random_pose(posed.rig, rng))
truth[3:6] = [0.3, -0.2, 0.25]
bridge.apply_pose(posed, truth)
cast = world_vertices(hand)
bridge.apply_pose(posed, posed.rig.rest)
faces = bridge.trimesh(hand).faces
mould = assets.mesh_object("Mould", __import__("geodesics").TriMesh(cast, faces[:, ::-1]), scene.collection)
scene.contact_edit.target = mould
hand_set, mould_set = store.load(hand), store.load(mould)
for b in ("index_3", "thumb_3", "hand", "pinky_2"):
    vertices = np.unique(kit.mesh.faces[kit.palmar_faces(kit.rig.bone_index(b))])
    a = SurfacePoints.from_vertices(hand_set.mesh, vertices)
    m = SurfacePoints.from_vertices(mould_set.mesh, vertices)
    patch = lambda mesh, points: ContactPatch(mesh, points, farthest_pair_axis(mesh, points))
    hand_set = hand_set.add(b, patch(hand_set.mesh, a)).pair(b, b)
    mould_set = mould_set.add(b, patch(mould_set.mesh, m)).pair(b, b)
store.save(hand, hand_set); store.save(mould, mould_set)
"""


def test_solve_operator_recovers_a_pose_and_keys_it(tmp_path):
    out = run_blender(
        """
        scene.frame_set(12)
        finished = bpy.ops.contact_edit.solve(stage="ALL", keyframe=True)
        # Where the patch vertices are in Blender's evaluated hand and on the mould.
        vertices = np.concatenate([np.unique(kit.mesh.faces[kit.palmar_faces(kit.rig.bone_index(b))])
                                   for b in ("index_3", "thumb_3", "hand", "pinky_2")])
        gap = np.linalg.norm(world_vertices(hand)[vertices] - cast[vertices], axis=1)
        result(dict(finished=list(finished), summary=scene.contact_edit.last_solve,
                    mean_gap=float(gap.mean()), length=kit.length, keyed=keyed_frames(armature)))
        """,
        tmp_path,
        setup=SETUP + MOULD,
    )
    assert out["finished"] == ["FINISHED"]
    assert "contacts in 4 patch pairs" in out["summary"]
    assert out["mean_gap"] < 0.01 * out["length"]  # the paper's pose-recovery criterion, in Blender's mesh
    assert out["keyed"] == [12.0]


def test_staged_solve_moves_only_what_the_stage_frees(tmp_path):
    out = run_blender(
        """
        before = pose_matrices()
        bpy.ops.contact_edit.solve(stage="ROOT")
        after_root = pose_matrices()
        for bone in armature.pose.bones:
            bone.select = bone.name == "index_3"
        bpy.ops.contact_edit.solve(stage="SELECTED")
        after_selected = pose_matrices()
        for bone in armature.pose.bones:
            bone.select = False
        error = error_of(lambda: bpy.ops.contact_edit.solve(stage="SELECTED"))
        result(dict(root=changed(before, after_root), selected=changed(after_root, after_selected),
                    error=error, unchanged=bool(np.array_equal(pose_matrices(), after_selected))))
        """,
        tmp_path,
        setup=SETUP + MOULD,
    )
    assert out["root"] == ["forearm"]
    assert out["selected"] == ["index_3"]
    assert "no bone of the hand's armature 'Hand rig' is selected" in out["error"]
    assert out["unchanged"]


def test_flex_to_contact_curls_selected_fingers_onto_the_object(tmp_path):
    out = run_blender(
        """
        ball = assets.mesh_object("Ball", objects.sphere(0.05), scene.collection)
        ball.location = (0.0, 0.13, -0.075)  # under the fingers, palm side
        scene.contact_edit.target = ball
        for bone in armature.pose.bones:
            bone.select = bone.name.startswith(("index", "middle"))
        before = pose_matrices()
        finished = bpy.ops.contact_edit.flex_to_contact()
        moved = changed(before, pose_matrices())
        from solver.sdf import MeshSDF
        sdf = MeshSDF(bridge.trimesh(ball))(world_vertices(hand) - np.array(ball.location), np.inf)
        result(dict(finished=list(finished), moved=moved, deepest=float(sdf.min()), length=kit.length))
        """,
        tmp_path,
        setup=SETUP,
    )
    assert out["finished"] == ["FINISHED"]
    assert set(out["moved"]) <= {"index_1", "index_2", "index_3", "middle_1", "middle_2", "middle_3"}
    assert {"index_1", "middle_1"} <= set(out["moved"])
    assert out["deepest"] > -1e-3 * out["length"]  # touching, not sinking in (Blender's float32 mesh)
