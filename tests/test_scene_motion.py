"""Reading a Blender scene's hand-object motion (contact_edit_addon.retarget.motion) in the real bpy module.

The scene (:mod:`tests.held_mug`): the procedural human hand as an armature and a skinned mesh and a
mug scaled (1.5, 1.5, 1.2), keyed linearly: the open hand approaches the mug (frames 1-15), closes on it
(the flex-to-contact grasp, frame 25), lifts it by 8 cm (35-50) while the mug turns about its axis
(35-60), and presses the fingers 0.08 rad deeper in (50-60). Frames 11-60 are read. Oracles: Blender's
own evaluated and transformed meshes, the solver's skinning (parity-tested against Blender), the keyed
values in closed form, and brute-force distances and winding numbers for the contacts.
"""

from __future__ import annotations

import importlib.util
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from geodesics import TriMesh
from solver import objects
from solver.hands import make_hand
from solver.retarget import Motion, annotate
from solver.retarget.frames import HandSpec
from solver.retarget.pipeline import RetargetOptions, retarget

from .blender import run_blender
from .held_mug import FPS, KEYS, LIFT, MUG_HEIGHT, MUG_RADIUS, MUG_SCALE, TURN, WHERE, scene_script

pytestmark = pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="needs bpy (the dev extra)")

FIRST, LAST = 11, 60  # the frames read
CHECK = (11, 22, 30, 42, 60)  # frames compared with Blender's meshes
HELD = 30  # the grasp, unchanged between its keys at 25 and 35
SCENE = scene_script(KEYS)


@pytest.fixture(scope="module")
def scene_read(tmp_path_factory):
    """The scene read once: the saved motion, its raw arrays, and Blender's meshes at :data:`CHECK`."""
    folder = tmp_path_factory.mktemp("scene-motion")
    out = run_blender(
        f"""
        import time
        calls = []
        t = time.perf_counter()
        motion = scene_motion.motion_from_scene(
            scene, hand_obj, mug, {FIRST}, {LAST}, progress=lambda done, total: calls.append((done, total)))
        seconds = time.perf_counter() - t
        restored = scene.frame_current == 7
        motion.save({str(folder / "motion.npz")!r})
        np.savez({str(folder / "raw.npz")!r}, **motion.to_arrays())
        oracle = {{}}
        for f in {CHECK}:
            oracle[f"hand_{{f}}"] = blender_world(hand_obj, f)
            oracle[f"mug_{{f}}"] = blender_world(mug, f)
        oracle["skinned"] = hand.posed_vertices(closed) @ place[:3, :3].T + place[:3, 3]
        size = detection.hand_size(motion)
        distance = detection.CONTACT_FRACTION * size
        np.savez({str(folder / "oracle.npz")!r}, **oracle)
        result({{"seconds": seconds, "calls": calls, "restored": restored, "size": size,
                 "distance": distance, "cutoff": detection.CUTOFF_FACTOR * distance,
                 "hand_size": hand.size}})
        """,
        folder,
        setup=SCENE,
    )
    out["motion"] = Motion.load(folder / "motion.npz")
    out["raw"] = dict(np.load(folder / "raw.npz"))
    out["oracle"] = dict(np.load(folder / "oracle.npz"))
    print(f"\nread {LAST - FIRST + 1} frames in {out['seconds']:.2f} s: {out['motion']}")
    return out


def _frame(f: int) -> int:
    """The motion frame of scene frame f."""
    return f - FIRST


def test_hand_vertices_are_blenders_evaluated_mesh(scene_read):
    motion, oracle = scene_read["motion"], scene_read["oracle"]
    assert motion.n_frames == LAST - FIRST + 1
    assert motion.fps == pytest.approx(FPS, rel=1e-7)  # fps_base is a float32
    assert motion.source_scale == 1.0 and motion.source_kind is None
    for f in CHECK:
        blender = oracle[f"hand_{f}"].astype(np.float64)
        # Blender transforms in float32: a few units in the last place of coordinates below 0.5 m.
        assert np.abs(motion.hand_vertices[_frame(f)] - blender).max() < 4 * np.finfo(np.float32).eps * 0.5
    # Independently of Blender: the solver's skinning of the keyed grasp, where the keys hold it still.
    skinned = oracle["skinned"]
    assert np.abs(motion.hand_vertices[_frame(HELD)] - skinned).max() < 1e-6 * scene_read["hand_size"]
    # The hand's topology is the procedural hand's, so its annotations apply.
    assert motion.hand_mesh.topology_hash == make_hand("human").mesh.topology_hash
    assert np.abs(motion.hand_mesh.vertices - make_hand("human").mesh.vertices).max() < 1e-7


def test_object_poses_are_rigid_and_carry_the_scaled_mug(scene_read):
    motion, oracle = scene_read["motion"], scene_read["oracle"]
    mug = objects.mug(radius=MUG_RADIUS, height=MUG_HEIGHT)
    # The constant scale is baked into the rest vertices (stored in float32 by Blender).
    assert np.abs(motion.object_mesh.vertices - mug.vertices * MUG_SCALE).max() < 1e-7
    assert np.array_equal(motion.object_mesh.faces, mug.faces)
    R = motion.object_poses[:, :3, :3]
    assert np.abs(R.transpose(0, 2, 1) @ R - np.eye(3)).max() < 1e-12
    assert np.allclose(np.linalg.det(R), 1.0, atol=1e-12)
    for f in CHECK:
        pose = motion.object_poses[_frame(f)]
        posed = motion.object_mesh.vertices @ pose[:3, :3].T + pose[:3, 3]
        assert np.abs(posed - oracle[f"mug_{f}"]).max() < 4 * np.finfo(np.float32).eps * 0.5
    # In closed form at the last key: lifted by LIFT and turned by TURN about z.
    last = motion.object_poses[-1]
    assert np.abs(last[:3, :3] - Rotation.from_euler("z", TURN).as_matrix()).max() < 1e-6
    assert np.abs(last[:3, 3] - (np.array(WHERE) + LIFT)).max() < 1e-6


def test_motion_round_trips_through_its_file(scene_read):
    loaded, raw = scene_read["motion"].to_arrays(), scene_read["raw"]
    assert sorted(loaded) == sorted(raw)
    for name, value in raw.items():
        assert np.array_equal(loaded[name], value), name
        assert loaded[name].shape == value.shape


def test_progress_and_the_scene_frame(scene_read):
    F = LAST - FIRST + 1
    assert scene_read["calls"] == [[k, 3 * F] for k in range(1, 3 * F + 1)]
    assert scene_read["restored"]


def _point_triangle_distances(P: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(k,) distance of each point of P (k, 3) to the nearest triangle of T (m, 3, 3), by brute force:
    the nearest of the projections inside each triangle and the nearest points on all its edges."""
    best = np.full(len(P), np.inf)
    a, b, c = T[:, 0], T[:, 1], T[:, 2]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    for chunk in np.array_split(np.arange(len(P)), max(1, len(P) // 64)):
        X = P[chunk, None, :]  # (c, 1, 3) against (m, 3)
        h = np.einsum("cmk,mk->cm", X - a, n)
        Q = X - h[..., None] * n
        inside = np.ones(h.shape, bool)
        for u, v in ((a, b), (b, c), (c, a)):
            inside &= np.einsum("cmk,mk->cm", np.cross(v - u, Q - u), n) >= 0
        d = np.where(inside, np.abs(h), np.inf)
        for u, v in ((a, b), (b, c), (c, a)):
            e = v - u
            s = np.clip(np.einsum("cmk,mk->cm", X - u, e) / np.einsum("mk,mk->m", e, e), 0.0, 1.0)
            d = np.minimum(d, np.linalg.norm(X - (u + s[..., None] * e), axis=2))
        best[chunk] = d.min(axis=1)
    return best


def _winding_numbers(P: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(k,) generalized winding number of a closed triangle mesh T (m, 3, 3) at points P (k, 3):
    1 inside, 0 outside (Van Oosterom and Strackee's solid angles, summed over 4π)."""
    out = np.empty(len(P))
    for i in range(0, len(P), 64):
        A, B, C = (T[None, :, j] - P[i : i + 64, None] for j in range(3))
        la, lb, lc = (np.linalg.norm(X, axis=2) for X in (A, B, C))
        det = np.einsum("cmk,cmk->cm", A, np.cross(B, C))
        dot = la * lb * lc + np.einsum("cmk,cmk->cm", A, B) * lc
        dot += np.einsum("cmk,cmk->cm", B, C) * la + np.einsum("cmk,cmk->cm", C, A) * lb
        out[i : i + 64] = 2 * np.arctan2(det, dot).sum(axis=1) / (4 * np.pi)
    return out


def test_contacts_where_the_fingers_close_and_none_before(scene_read):
    motion = scene_read["motion"]
    count = motion.object_contacts.count()
    assert np.array_equal(count, motion.hand_contacts.count())
    # The open hand is at least 7 mm away until frame 13 (5 cm back at frame 1, 0.5 mm at frame 15).
    assert np.all(count[: _frame(13) + 1] == 0)
    held = count[_frame(25) :]
    print(f"\ncontacts per frame while held: median {np.median(held):.0f}, min {held.min()}")
    assert np.all(held >= 300)


@pytest.mark.parametrize("f", [HELD, 42, 55, LAST])
def test_contacts_lie_on_the_hand_and_pair_nearby(scene_read, f):
    motion, distance, cutoff = scene_read["motion"], scene_read["distance"], scene_read["cutoff"]
    i = _frame(f)
    pose = motion.object_poses[i]
    O = motion.object_contacts.frame(i).positions(motion.object_mesh) @ pose[:3, :3].T + pose[:3, 3]
    hand_triangles = motion.hand_vertices[i][motion.hand_mesh.faces]
    d = _point_triangle_distances(O, hand_triangles)
    inside = _winding_numbers(O, hand_triangles) > 0.5
    # Every contact is within the contact distance of the skin, or inside the hand no deeper than ε.
    assert np.all((d <= distance * (1 + 1e-9)) | (inside & (d <= cutoff * (1 + 1e-9))))
    if f == HELD:
        # The flex-to-contact grasp rests on the mug: its skin's vertices are outside it, though the mug's
        # curved wall may bulge a little through a flat skin triangle between them (24 µm here).
        assert np.all(d[inside] < 0.05 * distance)
    if f == LAST:  # the fingers pressed 0.08 rad into the mug: contacts deeper than the contact distance
        assert np.count_nonzero(inside & (d > distance)) > 0
    # Each pairs with a point of the posed hand within ε along the mug's normal there, mostly much nearer.
    points = motion.object_contacts.frame(i)
    H = motion.hand_contacts.frame(i).positions(TriMesh(motion.hand_vertices[i], motion.hand_mesh.faces))
    gap = np.linalg.norm(H - O, axis=1)
    assert gap.max() <= cutoff * (1 + 1e-9)
    if f != LAST:  # (where the fingers are pressed in, the inside contacts pair across the finger)
        assert np.median(gap) <= distance
    normal = motion.object_mesh.face_normals[points.faces] @ pose[:3, :3].T
    assert np.linalg.norm(np.cross(H - O, normal), axis=1).max() < 1e-9


# ------------------------------------------------------------------------------------------ errors

ERRORS = """
import re
from contact_edit_addon.bridge import BridgeError
from contact_edit_addon.retarget import motion_from_scene
from solver import SolverError

def message(*args, **kwargs):
    try:
        motion_from_scene(scene, *args, **kwargs)
    except (BridgeError, SolverError) as err:
        return str(err)
    return None

def add(op, name, **kwargs):
    getattr(bpy.ops.mesh, op)(**kwargs)
    obj = bpy.context.active_object
    obj.name = name
    return obj

out = {}
out["not a mesh"] = message(armature, mug, 1, 10)
out["object not a mesh"] = message(hand_obj, bpy.data.objects.new("Empty", None), 1, 10)
out["reversed"] = message(hand_obj, mug, 10, 5)
out["same"] = message(mug, mug, 1, 2)
points = bpy.data.meshes.new("Points")
points.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 1)], [])
cloud = bpy.data.objects.new("Cloud", points)
scene.collection.objects.link(cloud)
out["no faces"] = message(hand_obj, cloud, 1, 2)
# A hand whose Subdivision Surface modifier goes from level 0 (none) to 1 by frame 4.
ball = add("primitive_uv_sphere_add", "Ball", radius=0.05, location=(1, 0, 0))
subdivision = ball.modifiers.new("Subdivision", "SUBSURF")
subdivision.levels = 0
subdivision.keyframe_insert("levels", frame=1)
subdivision.levels = 1
subdivision.keyframe_insert("levels", frame=4)
out["topology"] = message(ball, mug, 1, 10)
# A hand whose Build modifier shuffles its faces.
builder = add("primitive_uv_sphere_add", "Builder", radius=0.05, location=(1, 0, 0))
build = builder.modifiers.new("Build", "BUILD")
build.frame_start, build.frame_duration, build.use_reverse = 3, 20, True
out["reordered"] = message(builder, mug, 1, 10)
# A box scaled 1 until frame 3, then growing.
box = add("primitive_cube_add", "Box", size=0.1, location=(2, 0, 0))
box.keyframe_insert("scale", frame=3)
box.scale = (2, 2, 2)
box.keyframe_insert("scale", frame=10)
out["scale"] = message(hand_obj, box, 1, 10, contacts=False)
# An object deformed by an animated shape key.
blob = add("primitive_ico_sphere_add", "Blob", radius=0.05, location=(3, 0, 0))
blob.shape_key_add(name="Basis")
key = blob.shape_key_add(name="Squash")
co = np.empty(3 * len(blob.data.vertices)); blob.data.vertices.foreach_get("co", co)
key.data.foreach_set("co", co * 0.5)
key.value = 0.0; key.keyframe_insert("value", frame=1)
key.value = 1.0; key.keyframe_insert("value", frame=5)
out["deformed"] = message(hand_obj, blob, 1, 5, contacts=False)
# The mug with its normals turned in.
inverted = bpy.data.objects.new("Inverted", mug.data.copy())
scene.collection.objects.link(inverted)
inverted.data.flip_normals()
out["inwards"] = message(hand_obj, inverted, 1, 2, contacts=False)
# Far from the hand: no contacts, unless asked for a motion of markers only.
far = add("primitive_cube_add", "Far", size=0.1, location=(0, 0, 5))
out["never"] = message(hand_obj, far, 1, 20)
markers = motion_from_scene(scene, hand_obj, far, 1, 20, contacts=False)
out["markers only"] = [markers.n_frames, markers.object_contacts is None, markers.hand_contacts is None]
# A shape-key "hand" holding a mirrored cube (a constant negative scale, baked).
sheet = add("primitive_grid_add", "Sheet", x_subdivisions=6, y_subdivisions=6, size=0.2, location=(4, 0, 0))
sheet.shape_key_add(name="Basis")
wave = sheet.shape_key_add(name="Wave")
co = np.empty(3 * len(sheet.data.vertices)); sheet.data.vertices.foreach_get("co", co)
co = co.reshape(-1, 3); co[:, 2] += 0.03 * np.sin(20 * co[:, 0]); wave.data.foreach_set("co", co.ravel())
wave.value = 0.0; wave.keyframe_insert("value", frame=1)
wave.value = 1.0; wave.keyframe_insert("value", frame=9)
mirror = add("primitive_cube_add", "Mirror", size=0.1, location=(4, 0, 0.2))
mirror.scale = (-1.0, 2.0, 1.0)
mirror.rotation_euler = (0.3, 0.0, 0.0); mirror.keyframe_insert("rotation_euler", frame=1)
mirror.rotation_euler = (0.3, 0.0, 1.0); mirror.keyframe_insert("rotation_euler", frame=9)
sheet_motion = motion_from_scene(scene, sheet, mirror, 1, 9, contacts=False)
gaps = []
for f in (1, 5, 9):
    hand_gap = np.abs(sheet_motion.hand_vertices[f - 1] - blender_world(sheet, f)).max()
    pose = sheet_motion.object_poses[f - 1]
    posed = sheet_motion.object_mesh.vertices @ pose[:3, :3].T + pose[:3, 3]
    gaps.append([float(hand_gap), float(np.abs(posed - blender_world(mirror, f)).max())])
T = sheet_motion.object_mesh.vertices[sheet_motion.object_mesh.faces]
volume = float(np.einsum("ij,ij->i", T[:, 0], np.cross(T[:, 1], T[:, 2])).sum() / 6)
det = np.linalg.det(sheet_motion.object_poses[:, :3, :3]).tolist()
out["sheet"] = {"gaps": gaps, "volume": volume, "det": det}
result(out)
"""

MESSAGES = {
    "not a mesh": r"the hand 'Hand rig' is not a mesh object \(its type is Armature\) \(choose the mesh",
    "object not a mesh": r"the object 'Empty' is not a mesh object \(its type is Empty\)",
    "reversed": r"the frame range 10-5 is empty: it ends before it starts",
    "same": r"'Mug' cannot be both the hand and the object",
    "no faces": r"'Cloud' has no faces",
    "topology": r"at frame 3 the evaluated mesh of 'Ball' has 1986 vertices and 1984 faces where its own "
    r"mesh has 482 and 512: its modifiers change its topology \(as Subdivision Surface",
    "reordered": r"at frame 1 the evaluated mesh of 'Builder' connects its 482 vertices and 512 faces "
    r"otherwise than its own mesh: its modifiers change its topology",
    "scale": r"the scale of 'Box' changes over the frames: \(1, 1, 1\) at frame 1, "
    r"\(([\d.]+), \1, \1\) at frame 4 \(frames 4, 5, .*10\); a rigid object keeps one scale",
    "deformed": r"'Blob' is not rigid at frame 2: its modifiers or shape keys change its shape \(by up to",
    "inwards": r"the normals of 'Inverted' point inwards; recalculate them outside",
    "never": r"'Hand' never comes within 2.4\d mm of 'Far' in frames 1-20, so there are no contacts to "
    r"retarget; .* read the motion without contacts \(markers only\)",
}


@pytest.fixture(scope="module")
def errors(tmp_path_factory):
    return run_blender(ERRORS, tmp_path_factory.mktemp("scene-motion-errors"), setup=SCENE)


@pytest.mark.parametrize("case", list(MESSAGES))
def test_errors_name_what_is_wrong_and_where(errors, case):
    assert errors[case] is not None, f"{case}: no error"
    assert re.fullmatch(MESSAGES[case] + ".*", errors[case]), errors[case]


def test_markers_only_and_other_sources(errors):
    assert errors["markers only"] == [20, True, True]
    sheet = errors["sheet"]
    # Shape keys drive the source; the mirrored cube's scale is baked, its poses rotations (det +1), its
    # triangles reversed so that it still encloses a positive volume (0.1 x 0.2 x 0.1 m).
    assert np.max(sheet["gaps"]) < 4 * np.finfo(np.float32).eps * 5
    assert np.allclose(sheet["det"], 1.0, atol=1e-9)
    assert sheet["volume"] == pytest.approx(0.002, rel=1e-5)


# ------------------------------------------------------------------------------------------ retarget

BAR = 0.015  # of the target hand's length: tests/test_retarget_pipeline.py's bar (the issue's)


def test_read_motion_retargets_onto_another_hand(scene_read):
    """The read motion, ten frames of the held grasp, retargeted onto a larger human hand (§4.4)."""
    motion = scene_read["motion"].select(slice(_frame(25), _frame(35) + 1))
    target = HandSpec("human", 1.25)
    annotation = annotate.default_annotation(make_hand("human"), target.build())
    result = retarget(motion, target, annotation, RetargetOptions(intersections=False), workers=1)
    d = np.asarray(result.contact_distance)
    d = d[np.isfinite(d)]
    length = make_hand("human", 1.25).length
    print(f"\nretargeted {motion.n_frames} frames: median contact distance {np.median(d) * 1e3:.2f} mm "
          f"(bar {BAR * length * 1e3:.2f} mm); {result.seconds}")  # fmt: skip
    assert d.size == motion.n_frames
    assert np.median(d) <= BAR * length
