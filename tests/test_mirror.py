"""Mirroring to the other side: mesh correspondences and surface points (exact on symmetric meshes, by
position or by topology), mirrored contact sets, Blender's side-name flip and Paste Pose Flipped (checked
against the real bpy 5.0.1)."""

import importlib.util
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from geodesics import (
    ContactError,
    ContactPatch,
    ContactSet,
    MeshError,
    SurfacePoints,
    TriMesh,
    farthest_pair_axis,
)
from geodesics.mirror import MirrorMap, mirror_contacts, reflect, topology_classes
from geodesics.primitives import icosphere
from geodesics.tangent import tangent_to_3d
from solver import hands
from solver.rig.mirror import (
    BBONE_SCALARS,
    ROTATION_MODES,
    PoseChannel,
    flip_channels,
    flip_name,
    mirror_pose,
    paste_channel,
)
from solver.rotations import axis_angle_to_matrix, euler_to_matrix, quaternion_to_matrix

from .blender import run_blender

SETTINGS = settings(max_examples=60, deadline=None, derandomize=True, database=None)
FLIP_X = np.diag([-1.0, 1.0, 1.0])


def symmetric_torus(n_major=48, n_minor=16, major=1.0, minor=0.35):
    """A torus about z whose triangulation is mirror-symmetric through x = 0 (quads split along
    diagonals that mirror into each other; a plain grid split would not be symmetric)."""
    i, j = np.arange(n_major), np.arange(n_minor)
    u, v = 2 * np.pi * i / n_major, 2 * np.pi * j / n_minor
    ring = major + minor * np.cos(v)[:, None] * np.ones(n_major)
    height = minor * np.sin(v)[:, None] * np.ones(n_major)
    V = np.stack([ring * np.cos(u), ring * np.sin(u), height], -1).reshape(-1, 3)

    def at(a, b):
        return (b % n_minor) * n_major + a % n_major

    F = []
    for b in range(n_minor):
        for a in range(n_major):
            p, q, s, t = at(a, b), at(a + 1, b), at(a + 1, b + 1), at(a, b + 1)
            F += [(p, q, s), (p, s, t)] if a % (n_major // 2) < n_major // 4 else [(p, q, t), (q, s, t)]
    return TriMesh(V, np.array(F))


def random_points(mesh, k, seed, on_vertices=0, on_edges=0):
    """k points inside faces, then some exactly on vertices and on edges."""
    rng = np.random.default_rng(seed)
    bary = rng.dirichlet(np.ones(3), k + on_edges)
    bary[k:, 0] = 0.0
    bary[k:] /= bary[k:].sum(1, keepdims=True)
    points = SurfacePoints(rng.integers(0, mesh.n_faces, k + on_edges), bary)
    vertices = SurfacePoints.from_vertices(mesh, rng.integers(0, mesh.n_vertices, on_vertices))
    return SurfacePoints.concatenate([points, vertices])


def mirrored_copy(mesh, seed=1):
    """The mirror image through x = 0 as a separate mesh: vertices shuffled, faces rewound (reversed so
    they face outwards) and rotated. Returns the copy and each source vertex's index in it."""
    perm = np.random.default_rng(seed).permutation(mesh.n_vertices)
    where = np.argsort(perm)
    faces = np.roll(where[mesh.faces[:, ::-1]], 1, axis=1)
    return TriMesh(reflect(mesh.vertices)[perm], faces), where


@pytest.fixture(scope="module")
def kit():
    return hands.make_hand("human")


@pytest.fixture(scope="module")
def hand_pair(kit):
    other, where = mirrored_copy(kit.mesh)
    return kit.mesh, other, where


# ---------------------------------------------------------------------------------------------- meshes


@pytest.mark.parametrize("mesh", [icosphere(3), symmetric_torus()], ids=["icosphere", "torus"])
def test_points_on_a_self_symmetric_mesh_land_on_their_mirror_images(mesh):
    m = MirrorMap(mesh)
    assert m.method == "spatial" and m.target is mesh
    points = random_points(mesh, 400, seed=3, on_vertices=50, on_edges=50)
    image = m.map_points(points)
    np.testing.assert_allclose(image.positions(mesh), reflect(points.positions(mesh)), rtol=0, atol=1e-12)
    # Vertices stay vertices and edge points stay on edges, with the very same weights.
    np.testing.assert_array_equal(np.sort(image.bary, axis=1), np.sort(points.bary, axis=1))
    v = points.vertex_ids(mesh)
    np.testing.assert_array_equal(image.vertex_ids(mesh)[v >= 0], m.vertex_map[v[v >= 0]])
    # The mirror is an involution: mapping twice, or back through the inverse, gives the same bits.
    for back in (m.map_points(image), m.inverse().map_points(image)):
        np.testing.assert_array_equal(back.faces, points.faces)
        np.testing.assert_array_equal(back.bary, points.bary)
    np.testing.assert_array_equal(m.vertex_map[m.vertex_map], np.arange(mesh.n_vertices))
    # Vertices on the plane are their own mirror images.
    on_plane = np.flatnonzero(np.abs(mesh.vertices[:, 0]) < 1e-12)
    assert on_plane.size and np.all(m.vertex_map[on_plane] == on_plane)


def test_a_separate_mirrored_copy_maps_point_for_point(hand_pair):
    hand, other, where = hand_pair
    for method in ("spatial", "topology"):
        m = MirrorMap(hand, other, method=method)
        assert m.method == method
        np.testing.assert_array_equal(m.vertex_map, where)
        points = random_points(hand, 500, seed=4, on_vertices=40, on_edges=40)
        image = m.map_points(points)
        np.testing.assert_allclose(
            image.positions(other), reflect(points.positions(hand)), rtol=0, atol=1e-12
        )
        back = m.inverse().map_points(image)
        np.testing.assert_array_equal(back.faces, points.faces)
        np.testing.assert_array_equal(back.bary, points.bary)
    assert np.nanmax(m.deviation) < 1e-15


def test_any_plane(hand_pair):
    """A copy mirrored through a tilted plane away from the origin maps as exactly."""
    hand, _, _ = hand_pair
    point, normal = np.array([0.03, -0.02, 0.05]), np.array([0.3, 1.0, -0.4])
    copy = TriMesh(reflect(hand.vertices, point, normal), hand.faces[:, ::-1])
    m = MirrorMap(hand, copy, point=point, normal=normal)
    np.testing.assert_array_equal(m.vertex_map, np.arange(hand.n_vertices))
    points = random_points(hand, 300, seed=5)
    np.testing.assert_allclose(
        m.map_points(points).positions(copy), reflect(points.positions(hand), point, normal), atol=1e-12
    )
    np.testing.assert_allclose(m.reflect(m.reflect(hand.vertices)), hand.vertices, atol=1e-15)


@pytest.mark.parametrize("jitter", [1e-3, 0.05])
def test_topology_pairs_meshes_that_are_symmetric_only_in_topology(jitter):
    """Vertices moved off symmetry (as in a hand-modelled mesh): the spatial lookup finds no partners, the
    topology mirror gives the exact correspondence of the symmetric mesh; with large moves, positions no
    longer pair every class of look-alike vertices and the map is grown face by face."""
    exact = icosphere(3)
    truth = MirrorMap(exact).vertex_map
    moved = exact.vertices + jitter * np.random.default_rng(2).normal(size=exact.vertices.shape)
    mesh = TriMesh(moved, exact.faces)
    m = MirrorMap(mesh, max_deviation=1.0)
    assert m.method == "topology"
    np.testing.assert_array_equal(m.vertex_map, truth)
    assert np.nanmax(m.deviation) > jitter
    with pytest.raises(MeshError) as err:
        MirrorMap(mesh, method="spatial")
    assert err.value.vertices.size > 0
    with pytest.raises(MeshError, match="max_deviation" if jitter < 0.01 else "no counterpart"):
        MirrorMap(mesh, max_deviation=1e-4)


def test_one_vertex_off_symmetry_is_named():
    mesh = icosphere(3)
    partner = MirrorMap(mesh).vertex_map
    V = mesh.vertices.copy()
    V[100] += [0.004, 0.003, 0.0]
    moved = TriMesh(V, mesh.faces)
    with pytest.raises(MeshError, match="no counterpart") as err:
        MirrorMap(moved, method="spatial")
    np.testing.assert_array_equal(err.value.vertices, np.sort([100, partner[100]]))
    m = MirrorMap(moved)  # the topology mirror still pairs it, and reports the deviation
    np.testing.assert_array_equal(m.vertex_map, partner)
    assert np.flatnonzero(m.deviation > 1e-12).tolist() == sorted([100, partner[100]])


def test_meshes_that_are_not_mirror_images_are_refused(hand_pair):
    hand, other, _ = hand_pair
    with pytest.raises(MeshError, match="not mirror-symmetric") as err:
        MirrorMap(hand)  # a right hand is not symmetric in itself
    assert err.value.vertices.size > hand.n_vertices // 2
    inward = TriMesh(other.vertices, other.faces[:, ::-1])  # mirrored without rewinding: inside out
    with pytest.raises(MeshError, match="flip its normals") as err:
        MirrorMap(hand, inward)
    assert err.value.faces.size == hand.n_faces
    with pytest.raises(MeshError, match="normal is zero"):
        MirrorMap(hand, other, normal=(0, 0, 0))
    with pytest.raises(MeshError, match="unknown mirror method"):
        MirrorMap(hand, other, method="nearest")


def test_topology_classes_only_merge_look_alikes():
    """On a path graph the two ends look alike, the middle is alone; all vertices of a cycle look alike."""
    path = np.array([[0, 1], [1, 2], [2, 3], [3, 4]])
    labels = topology_classes(5, path)
    assert labels[0] == labels[4] and labels[1] == labels[3] and len(set(labels.tolist())) == 3
    cycle = np.array([[i, (i + 1) % 6] for i in range(6)])
    assert len(set(topology_classes(6, cycle).tolist())) == 1


def test_directions_go_to_their_mirror_images():
    mesh = icosphere(3)
    m = MirrorMap(mesh)
    rng = np.random.default_rng(6)
    faces = random_points(mesh, 300, seed=7, on_edges=50)
    vertices = SurfacePoints.from_vertices(mesh, rng.integers(0, mesh.n_vertices, 100))
    for points in (faces, vertices):
        z = rng.uniform(0.2, 2.0, len(points)) * np.exp(2j * np.pi * rng.random(len(points)))
        w = m.map_directions(points, z)
        np.testing.assert_allclose(np.abs(w), np.abs(z), rtol=1e-14)
        np.testing.assert_allclose(m.inverse().map_directions(m.map_points(points), w), z, atol=1e-14)
    # Face and edge points use face frames: the 3D vector is the reflected one.
    z = np.exp(2j * np.pi * rng.random(len(faces)))
    w = m.map_directions(faces, z)
    np.testing.assert_allclose(
        tangent_to_3d(mesh, m.map_points(faces), w), tangent_to_3d(mesh, faces, z) @ FLIP_X, atol=1e-14
    )


@SETTINGS
@given(
    face=st.integers(0, icosphere(2).n_faces - 1),
    weights=st.lists(st.floats(0.0, 1.0), min_size=3, max_size=3).filter(lambda w: sum(w) > 1e-6),
)
def test_mapped_points_are_mirror_images(face, weights):
    mesh = _SPHERE
    bary = np.array(weights) / sum(weights)
    point = SurfacePoints([face], [bary])
    image = _SPHERE_MAP.map_points(point)
    np.testing.assert_allclose(image.positions(mesh), reflect(point.positions(mesh)), atol=1e-15)
    twice = _SPHERE_MAP.map_points(image)
    assert twice.faces[0] == point.faces[0] and np.array_equal(twice.bary, point.bary)


_SPHERE = icosphere(2)
_SPHERE_MAP = MirrorMap(_SPHERE)


# ---------------------------------------------------------------------------------------------- contacts


@pytest.fixture(scope="module")
def left_contacts(kit):
    mesh = kit.mesh
    patches = kit.contact_patches()
    s = ContactSet(mesh)
    for name in ("hand", "index_1", "index_2", "thumb_1"):
        s = s.add(f"{name}.L", ContactPatch(mesh, patches[name], farthest_pair_axis(mesh, patches[name])))
    s = s.parent("index_1.L", "hand.L").parent("index_2.L", "index_1.L").parent("thumb_1.L", "hand.L")
    return s.pair("hand.L", "mug.L").pair("index_2.L", "handle")


def test_mirrored_contact_set_is_the_mirror_image(left_contacts, hand_pair):
    hand, other, _ = hand_pair
    m = MirrorMap(hand, other)
    right = mirror_contacts(left_contacts, m)
    assert right.mesh is other and list(right) == ["hand.R", "index_1.R", "index_2.R", "thumb_1.R"]
    assert {c: link.parent for c, link in right.links.items()} == {
        "index_1.R": "hand.R",
        "index_2.R": "index_1.R",
        "thumb_1.R": "hand.R",
    }
    assert dict(right.pairs) == {}
    for name, patch in left_contacts.patches.items():
        mirrored = right[flip_name(name)]
        np.testing.assert_allclose(mirrored.positions(), reflect(patch.positions()), rtol=0, atol=1e-12)
        np.testing.assert_allclose(
            mirrored.axis.points.positions(other), reflect(patch.axis.points.positions(hand)), atol=1e-12
        )
        # Parameterized anew on the target: the same binding and the conjugate log maps.
        np.testing.assert_array_equal(mirrored.binding, patch.binding)
        np.testing.assert_allclose(mirrored.coords, np.conj(patch.coords), atol=1e-12)
        np.testing.assert_allclose(mirrored.axis.lengths, patch.axis.lengths, rtol=1e-15)
        np.testing.assert_allclose(mirrored.axis.turning, np.conj(patch.axis.turning), atol=1e-15)
        link, mirrored_link = left_contacts.links.get(name), right.links.get(flip_name(name))
        if link is not None:
            assert mirrored_link.length == link.length and mirrored_link.leave == np.conj(link.leave)
    # The mirrored set behaves as the mirror image: editing both sides alike keeps them mirrored.
    turned_left = left_contacts.rotate("hand.L", 0.3)
    turned_right = right.rotate("hand.R", -0.3)
    for name in left_contacts:
        np.testing.assert_allclose(
            turned_right[flip_name(name)].positions(), reflect(turned_left[name].positions()), atol=1e-9
        )
    # Mirroring back gives the original set, point for point.
    back = mirror_contacts(right, m.inverse())
    assert list(back) == list(left_contacts)
    for name, patch in left_contacts.patches.items():
        np.testing.assert_array_equal(back[name].points.faces, patch.points.faces)
        np.testing.assert_array_equal(back[name].points.bary, patch.points.bary)
        np.testing.assert_array_equal(back[name].axis.points.bary, patch.axis.points.bary)
        np.testing.assert_allclose(back[name].axis.tangents, patch.axis.tangents, atol=1e-14)
        np.testing.assert_allclose(back[name].coords, patch.coords, atol=1e-14)
    assert {c: link.parent for c, link in back.links.items()} == {
        c: link.parent for c, link in left_contacts.links.items()
    }
    # The contact file of the mirrored set round-trips.
    again = ContactSet.from_dict(json.loads(json.dumps(right.to_dict())), other)
    for name in right:
        np.testing.assert_array_equal(again[name].points.bary, right[name].points.bary)


def test_pairs_names_and_merging(left_contacts, hand_pair):
    hand, other, _ = hand_pair
    m = MirrorMap(hand, other)
    kept = mirror_contacts(left_contacts, m, names=["hand.L", "index_2.L"], pairs="keep")
    assert dict(kept.pairs) == {"hand.R": "mug.L", "index_2.R": "handle"}
    assert dict(kept.links) == {}  # index_2's parent was not mirrored and has no counterpart
    flipped = mirror_contacts(left_contacts, m, names=["hand.L", "index_2.L"], pairs="flip")
    assert dict(flipped.pairs) == {"hand.R": "mug.R", "index_2.R": "handle"}
    renamed = mirror_contacts(left_contacts, m, names=["index_2.L"], rename=lambda n: "tip")
    assert list(renamed) == ["tip"]
    # Into an existing set: a child whose parent was not mirrored hangs off the parent's namesake.
    into = mirror_contacts(left_contacts, m, names=["hand.L"])
    merged = mirror_contacts(left_contacts, m, names=["index_1.L"], into=into)
    assert list(merged) == ["hand.R", "index_1.R"] and merged.links["index_1.R"].parent == "hand.R"
    with pytest.raises(ContactError, match=r"already has patches named hand\.R"):
        mirror_contacts(left_contacts, m, into=merged)
    replaced = mirror_contacts(left_contacts, m, into=merged, overwrite=True)
    assert len(replaced) == 4 and replaced.links["index_1.R"].parent == "hand.R"
    with pytest.raises(ContactError, match="no patch named"):
        mirror_contacts(left_contacts, m, names=["wrist.L"])
    with pytest.raises(ContactError, match="repeated names"):
        mirror_contacts(left_contacts, m, rename=lambda n: "same")
    with pytest.raises(ContactError, match="another mesh"):
        mirror_contacts(left_contacts, m.inverse())


def test_mirroring_onto_the_same_body():
    """On a body symmetric in itself, a left patch is mirrored next to itself in the same set."""
    mesh = icosphere(3)
    m = MirrorMap(mesh)
    near = np.flatnonzero(np.linalg.norm(mesh.face_centroids - [0.6, 0.3, 0.7], axis=1) < 0.35)
    pts = SurfacePoints(near, np.random.default_rng(9).dirichlet(np.ones(3), near.size))
    left = ContactSet(mesh).add("pad.L", ContactPatch(mesh, pts, farthest_pair_axis(mesh, pts)))
    both = mirror_contacts(left, m, into=left)
    assert list(both) == ["pad.L", "pad.R"]
    np.testing.assert_allclose(both["pad.R"].positions(), reflect(both["pad.L"].positions()), atol=1e-12)


# ---------------------------------------------------------------------------------------------- names

# From Blender's own test of BLI_string_flip_side_name (the cases bpy 5.0.1 shares) and from bpy 5.0.1
# itself (checked again against it in test_flip_name_and_paste_pose_flipped_match_blender).
FLIP_CASES = {
    "Bone.L": "Bone.R",
    "Bone_R": "Bone_L",
    "L_Bone": "R_Bone",
    "L-Bone": "R-Bone",
    "leftArm": "rightArm",
    "Arm_right": "Arm_left",
    "RIGHT_arm": "LEFT_arm",
    "Spine": "Spine",
    "L": "L",
    "ArmLength": "ArmLength",
    "ManRight": "ManLeft",
    "hand.L.001": "hand.R.001",
    "hand.r.12": "hand.l.12",
    "hand L": "hand R",
    "r.hand": "l.hand",
    ".L": ".L",
    "a.L": "a.R",
    "RIght_x": "LEFT_x",
    "Righty": "Lefty",
    "xLEFT": "xLEFT",  # 5 bytes: too short for the word rule
    "xxLEFT": "xxRIGHT",
    "middle_left_x": "middle_left_x",
    "bip001-L-UpperArm": "bip001-L-UpperArm",  # the newer mid-string rule is not in 5.0.1
    "ManLeftHand": "ManLeftHand",
    "é.L": "é.R",
    "手_left": "手_right",
    "hand.L.1a": "hand.L.1a",
    ".001": ".001",
    "L.001": "L.001",
}


@pytest.mark.parametrize(("name", "flipped"), FLIP_CASES.items())
def test_flip_name_table(name, flipped):
    assert flip_name(name) == flipped


def test_flip_name_options():
    assert flip_name("hand.L.001", strip_digits=True) == "hand.R"
    assert flip_name("x" * 59 + "left", max_bytes=64) == "x" * 59 + "righ"  # Blender's 63-byte buffer


# ---------------------------------------------------------------------------------------------- poses


def _matrix(rotation, mode):
    if mode == "QUATERNION":
        return quaternion_to_matrix(rotation)
    if mode == "AXIS_ANGLE":
        return axis_angle_to_matrix(rotation)
    return euler_to_matrix(rotation, mode)


@SETTINGS
@given(
    mode=st.sampled_from(ROTATION_MODES),
    values=st.lists(st.floats(-3.0, 3.0), min_size=4, max_size=4),
    location=st.lists(st.floats(-2.0, 2.0), min_size=3, max_size=3),
)
def test_flipped_rotation_is_the_mirrored_rotation(mode, values, location):
    """Whatever the mode, the flipped channels are the pose mirrored through x = 0: the rotation M R M
    and the location M t with M = diag(-1, 1, 1)."""
    rotation = np.array(values[:3] if len(mode) == 3 else values)
    if mode == "QUATERNION":
        rotation[0] += 3.5  # keep the quaternion away from zero
    if mode == "AXIS_ANGLE":
        rotation[1:] += [0.0, 3.5, 0.0]
    loc, rot, _ = flip_channels(location, rotation, mode)
    np.testing.assert_allclose(loc, FLIP_X @ location)
    np.testing.assert_allclose(_matrix(rot, mode), FLIP_X @ _matrix(rotation, mode) @ FLIP_X, atol=1e-12)


def test_flip_channels_is_vectorized_and_flips_bbones():
    rng = np.random.default_rng(8)
    q = rng.normal(size=(5, 7, 4))
    loc, rot, bbone = flip_channels(
        rng.normal(size=(5, 7, 3)), q, "QUATERNION", bbone={"bbone_rollin": 0.5, "bbone_easein": 0.25}
    )
    one = flip_channels(np.zeros(3), q[2, 3], "QUATERNION")[1]
    np.testing.assert_allclose(rot[2, 3], one, rtol=1e-15)
    assert loc.shape == (5, 7, 3) and bbone == {"bbone_rollin": -0.5, "bbone_easein": 0.25}


def test_mirror_pose_swaps_sides_and_flips_centre_bones():
    left = PoseChannel(location=(0.1, 0.2, 0.3), rotation_mode="XYZ", rotation_euler=(0.1, 0.2, 0.3))
    right = PoseChannel(rotation_mode="XYZ", rotation_euler=(-0.4, 0.5, 0.6), bbone_rollout=0.7)
    spine = PoseChannel(location=(1.0, 2.0, 3.0))
    lonely = PoseChannel(location=(5.0, 5.0, 5.0))
    pose = {"arm.L": left, "arm.R": right, "spine": spine, "tail.L": lonely}
    out = mirror_pose(pose)
    np.testing.assert_array_equal(out["arm.R"].location, [-0.1, 0.2, 0.3])
    np.testing.assert_array_equal(out["arm.R"].rotation_euler, [0.1, -0.2, -0.3])
    np.testing.assert_array_equal(out["arm.L"].rotation_euler, [-0.4, -0.5, -0.6])
    assert out["arm.L"].bbone_rollout == -0.7 and out["arm.R"].bbone_rollout == 0.0
    np.testing.assert_array_equal(out["spine"].location, [-1.0, 2.0, 3.0])
    assert out["tail.L"] is lonely  # no "tail.R": nothing pasted
    only = mirror_pose(pose, selected=["arm.L"])
    assert only["arm.L"] is left and only["spine"] is spine
    masked = mirror_pose(pose, selected_mask=["arm.L"])
    assert masked["arm.R"] is right and masked["spine"] is spine
    # Pasting onto a bone of another rotation mode converts into that mode and changes only its field.
    quat = PoseChannel(rotation_mode="QUATERNION", rotation_euler=(9.0, 9.0, 9.0))
    pasted = paste_channel(left, quat, flip=False)
    np.testing.assert_allclose(
        quaternion_to_matrix(pasted.rotation_quaternion), euler_to_matrix((0.1, 0.2, 0.3))
    )
    np.testing.assert_array_equal(pasted.rotation_euler, [9.0, 9.0, 9.0])


# ---------------------------------------------------------------------------------------------- Blender

needs_bpy = pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="needs bpy (the dev extra)")

#: Each pair "<name>.L" / "<name>.R": the rotation modes of the two sides.
POSE_PAIRS = [(f"{mode.lower()}{i}", mode, mode) for mode in ROTATION_MODES for i in range(4)] + [
    ("mix_q_xyz", "QUATERNION", "XYZ"),
    ("mix_xyz_q", "XYZ", "QUATERNION"),
    ("mix_zxy_yzx", "ZXY", "YZX"),
    ("mix_aa_q", "AXIS_ANGLE", "QUATERNION"),
    ("mix_q_aa", "QUATERNION", "AXIS_ANGLE"),
    ("mix_aa_zyx", "AXIS_ANGLE", "ZYX"),
    ("mix_xzy_aa", "XZY", "AXIS_ANGLE"),
]
#: Bones without a side (flipped in place) or without a partner (left alone).
POSE_SINGLES = [("spine", "QUATERNION"), ("neck", "ZXY"), ("head", "AXIS_ANGLE"), ("tail.L", "XYZ")]


def random_names(rng, count):
    tokens = ["L", "R", "l", "r", "left", "Left", "LEFT", "right", "Right", "RIGHT", "RIght", "rIGHT", "lEft"]
    tokens += ["hand", "arm", "bip01", "x", "é", "手", "001", "12", "3", "a1"]
    seps = [".", "_", "-", " ", ""]
    names = set(FLIP_CASES)
    while len(names) < count:
        parts = rng.choice(tokens, size=rng.integers(1, 5))
        name = "".join(p + str(rng.choice(seps)) for p in parts)[: rng.integers(1, 30)]
        if rng.random() < 0.3:
            name += "." + str(rng.integers(0, 1000)).zfill(3)
        names.add(name)
    return sorted(names)


BLENDER_POSE = """
import numpy as np
rng = np.random.default_rng(11)
flips = [[bpy.utils.flip_name(n), bpy.utils.flip_name(n, strip_digits=True)] for n in NAMES]

bpy.ops.wm.read_factory_settings(use_empty=True)
arm = bpy.data.armatures.new("Rig")
obj = bpy.data.objects.new("Rig", arm)
bpy.context.scene.collection.objects.link(obj)
bpy.context.view_layer.objects.active = obj
bpy.ops.object.mode_set(mode="EDIT")
bones = []
for k, (name, left, right) in enumerate(PAIRS):
    for side, sx, mode in ((".L", 1.0, left), (".R", -1.0, right)):
        b = arm.edit_bones.new(name + side)
        b.head = (sx * 0.1, 0.0, 0.1 * k)
        b.tail = (sx * 0.5, 0.2, 0.1 * k + 0.1)
        bones.append((name + side, mode))
for k, (name, mode) in enumerate(SINGLES):
    b = arm.edit_bones.new(name)
    b.head, b.tail = (0.0, 1.0, 0.1 * k), (0.0, 1.2, 0.1 * k + 0.1)
    bones.append((name, mode))
bpy.ops.object.mode_set(mode="POSE")

def angle():  # away from 0 and ±2π, where acos makes axis-angle conversions ill-conditioned in float32
    return rng.choice([-1, 1]) * rng.uniform(0.3, 2 * np.pi - 0.3)

for name, mode in bones:
    pb = obj.pose.bones[name]
    pb.rotation_mode = mode
    pb.location = rng.uniform(-1, 1, 3)
    pb.scale = rng.uniform(0.5, 1.5, 3)
    pb.rotation_euler = rng.uniform(-np.pi, np.pi, 3)
    pb.rotation_quaternion = rng.normal(size=4) * 0.3 + np.array([0.8, 0, 0, 0])
    pb.rotation_axis_angle = [angle(), *rng.normal(size=3)]
    for prop in SCALARS:
        setattr(pb, prop, rng.uniform(-1, 1))
    pb.bbone_scalein, pb.bbone_scaleout = rng.uniform(0.5, 1.5, 3), rng.uniform(0.5, 1.5, 3)
    pb.select = True

def state():
    out = {}
    for pb in obj.pose.bones:
        out[pb.name] = {p: (getattr(pb, p) if p == "rotation_mode" else
                            (list(getattr(pb, p)) if hasattr(getattr(pb, p), "__len__") else getattr(pb, p)))
                        for p in CHANNELS}
    return out

before = state()
assert bpy.ops.pose.copy() == {"FINISHED"}
assert bpy.ops.pose.paste(flipped=True) == {"FINISHED"}
result({"flips": flips, "before": before, "after": state()})
"""


@needs_bpy
def test_flip_name_and_paste_pose_flipped_match_blender(tmp_path):
    """Blender itself: bpy.utils.flip_name over a few hundred names, and Copy Pose / Paste Pose Flipped on a
    symmetric armature in every rotation mode (and pairs whose sides differ in mode), channel by channel."""
    names = random_names(np.random.default_rng(12), 400)
    script = (
        f"NAMES = {names!r}\nPAIRS = {POSE_PAIRS!r}\nSINGLES = {POSE_SINGLES!r}\n"
        f"SCALARS = {list(BBONE_SCALARS)!r}\nCHANNELS = {list(PoseChannel.names())!r}\n"
    ) + BLENDER_POSE
    out = run_blender(script, tmp_path)
    ours = [[flip_name(n), flip_name(n, strip_digits=True)] for n in names]
    wrong = [(n, o, b) for n, o, b in zip(names, ours, out["flips"], strict=True) if o != b]
    assert not wrong, wrong[:10]

    before = {name: PoseChannel(**values) for name, values in out["before"].items()}
    after = mirror_pose(before)
    worst = {}
    for name, values in out["after"].items():
        assert after[name].rotation_mode == values["rotation_mode"]
        for channel in PoseChannel.names()[:1] + PoseChannel.names()[2:]:
            error = np.abs(np.asarray(getattr(after[name], channel)) - np.asarray(values[channel])).max()
            worst[channel] = max(worst.get(channel, 0.0), error)
    assert max(worst.values()) < 1e-5, worst  # float32 rounding (measured 2.7e-7)
    # Something was actually pasted: every paired bone and centre bone changed.
    changed = [n for n in before if not np.allclose(before[n].location, out["after"][n]["location"])]
    assert sorted(changed) == sorted(n for n in before if n != "tail.L")
