"""The retargeting authors' GRAB export (solver.retarget.grab): read against files built here array by array
as their exporter (grab/exportRhandFullSequence.py of lakshmipathyarjun6/GRAB) builds them, the rotation
convention against GRAB's ObjectModel written out with Rodrigues' formula, our writer against the layout
their Maya reader (GRABMotionSequenceIO.cpp) expects, malformed files, and `contact-edit import-grab`."""

import contextlib
import io
import json
import warnings
import zipfile

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from contact_edit_addon.commands import cli
from geodesics import MeshWarning, TriMesh, save_mesh
from geodesics.primitives import icosphere
from solver.retarget import Motion, pair_motion
from solver.retarget import synthetic as sy
from solver.retarget.grab import GRAB_FIRST_FRAME, GRAB_FPS, IGNORED, MEMBERS, GrabError, load_grab, save_grab
from solver.retarget.interchange import ContactSequence, InterchangeError
from solver.retarget.pairing import DEFAULT_CUTOFF

SHORT = 4 * len(sy.PHASES)


# ---------------------------------------------------------------------------------------- independent oracles


def rodrigues(a) -> np.ndarray:
    """R = I + sin θ K + (1 - cos θ) K², θ = |a|, K the cross-product matrix of a / θ."""
    a = np.asarray(a, dtype=np.float64)
    theta = np.linalg.norm(a)
    if theta == 0:
        return np.eye(3)
    x, y, z = a / theta
    K = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    return np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * K @ K


def grab_object_vertices(v_template, a, t) -> np.ndarray:
    """GRAB's tools/objectmodel.py: vertices = v_template @ batch_rodrigues(global_orient) + transl."""
    return np.asarray(v_template) @ rodrigues(a) + np.asarray(t, dtype=np.float64)


def axis_angle_of(M) -> np.ndarray:
    """The a with rodrigues(a) = M (a rotation by less than π)."""
    angle = np.arccos(np.clip((np.trace(M) - 1) / 2, -1.0, 1.0))
    assert angle < 3.0
    if np.sin(angle) < 1e-9:
        return np.zeros(3)
    return np.array([M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]]) * angle / (2 * np.sin(angle))


def authors_export(path, verts_rh, rot_obj, trans_obj, rot_table, trans_table, contacts_obj) -> None:
    """The .npz of exportRhandFullSequence.py, statement for statement from its arrays: verts_rh (T, V, 3)
    world MANO vertices, rot/trans (T, 3) GRAB global_orient/transl, contacts_obj (T, n_obj) contact map."""
    T = len(verts_rh)
    joints_hierarchy = np.array([255, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11, 0, 13, 14], dtype=np.uint8)
    contact_frames = np.array([], dtype=np.uint16)
    object_contact_frame_counts = np.array([], dtype=np.uint16)
    object_contact_locations = np.array([], dtype=np.uint32)
    for frame in range(T):
        contacts_obj_frame = contacts_obj[frame]
        if not np.all(contacts_obj_frame == 0):
            contact_frames = np.append(contact_frames, np.array([frame], dtype=np.uint16))
            locations = np.array(np.where(contacts_obj_frame != 0)[0], dtype=np.uint32)
            object_contact_frame_counts = np.append(
                object_contact_frame_counts, np.array([len(locations)], dtype=np.uint16)
            )
            object_contact_locations = np.append(object_contact_locations, locations)
    f4 = np.float32
    np.savez(
        path,
        numFrames=T,
        handVertices=np.asarray(verts_rh, f4).flatten(),
        handJointHierarchy=joints_hierarchy.flatten(),
        handRootOrientations=np.zeros((T, 3), f4).flatten(),
        handRootTranslations=np.zeros((T, 3), f4).flatten(),
        handJointOrientations=np.zeros((T, 45), f4).flatten(),
        handJointsRestConfiguration=np.zeros((16, 3), f4).flatten(),
        objectRotations=np.asarray(rot_obj, f4).flatten(),
        objectTranslations=np.asarray(trans_obj, f4).flatten(),
        tableRotations=np.asarray(rot_table, f4).flatten(),
        tableTranslations=np.asarray(trans_table, f4).flatten(),
        contactFrames=contact_frames.flatten(),
        objectContactFrameCounts=object_contact_frame_counts.flatten(),
        objectContactLocations=object_contact_locations.flatten(),
    )


def contact_vertex_sets(motion: Motion) -> list[set]:
    """Per frame, the object vertices the object contacts sit on (each contact must be at a vertex)."""
    return vertex_sets(motion.object_mesh, motion.object_contacts)


def vertex_sets(mesh: TriMesh, c) -> list[set]:
    """Per frame, the vertices of ``mesh`` the contacts ``c`` sit on (each contact must be at a vertex)."""
    assert np.all(np.isin(c.bary, (0.0, 1.0))) and np.all(c.bary.sum(1) == 1.0)
    vertex = mesh.faces[c.faces, np.argmax(c.bary, axis=1)]
    return [set(vertex[c.offsets[f] : c.offsets[f + 1]].tolist()) for f in range(c.n_frames)]


def authors_contact_file(path, grab_npz, timeline_end: int) -> None:
    """The object's contact file of the Maya scene their plugin builds from ``grab_npz``, as their
    contact exporter writes it. The import (GRABMotionSequenceIO.cpp) keys frame f at Maya time f for
    f = 0 ... F-1 (lines 257-261) and makes, for each contact frame (389-405), a set named after that
    frame's number holding "v <vertex>" strings (494-506). The exporter (contactSequenceIO.cpp) looks
    the object shape's sets up for frame = 1 ... maxTime, the timeline's end, and writes each one found
    with its number (50-74); ``timeline_end`` is that end, F - 1 once the timeline is set to the
    motion's keys (their GRAB README)."""
    file = members(grab_npz)
    sets, at = {}, 0
    for frame, count in zip(file["contactFrames"], file["objectContactFrameCounts"], strict=True):
        sets[int(frame)] = [f"v {v}" for v in file["objectContactLocations"][at : at + count].tolist()]
        at += int(count)
    data = [{"frame": f, "contacts": sets[f]} for f in range(1, timeline_end + 1) if f in sets]
    path.write_text(json.dumps({"meshName": "objectShape", "data": data}, indent=1))


def world_points(mesh: TriMesh, vertices_per_frame, contacts) -> np.ndarray:
    """(K, 3) world positions of contacts given each frame's posed vertices (F, n, 3)."""
    frame = contacts.frame_index()
    corners = np.asarray(vertices_per_frame)[frame[:, None], mesh.faces[contacts.faces]]
    return np.einsum("kj,kjd->kd", contacts.bary, corners)


def posed_objects(motion: Motion) -> np.ndarray:
    P = motion.object_poses
    return np.einsum("fij,nj->fni", P[:, :3, :3], motion.object_mesh.vertices) + P[:, None, :3, 3]


# ---------------------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def motion() -> Motion:
    """A short synthetic manipulation (the right human hand lifts and turns a sphere)."""
    return sy.generate("sphere", frames=SHORT, seed=0, density=2)


@pytest.fixture(scope="module")
def ours(motion, tmp_path_factory):
    """The motion written by save_grab."""
    path = tmp_path_factory.mktemp("grab") / "ours_right_full_export_motion.npz"
    save_grab(motion, path)
    return path


@pytest.fixture(scope="module")
def theirs(motion, tmp_path_factory):
    """The motion written as the authors' exporter writes it; contact map: every corner of a face that
    holds a contact (so not the rule save_grab uses)."""
    path = tmp_path_factory.mktemp("grab") / "theirs_right_full_export_motion.npz"
    F, mesh = motion.n_frames, motion.object_mesh
    rot = np.array([axis_angle_of(P[:3, :3].T) for P in motion.object_poses])
    contact_map = np.zeros((F, mesh.n_vertices), np.uint8)
    c = motion.object_contacts
    contact_map[np.repeat(c.frame_index(), 3), mesh.faces[c.faces].ravel()] = 1
    table_rot = np.tile(axis_angle_of(motion.table[:3, :3].T), (F, 1))
    table_trans = np.tile(motion.table[:3, 3], (F, 1))
    authors_export(
        path, motion.hand_vertices, rot, motion.object_poses[:, :3, 3], table_rot, table_trans, contact_map
    )
    return path, contact_map


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """A 3-frame export of a 12-vertex 'hand' touching a 42-vertex 'object': (path, hand, object)."""
    hand = TriMesh(icosphere(0, radius=0.01).vertices + np.array([0.0, 0.0, 0.025]), icosphere(0).faces)
    obj = icosphere(1, radius=0.02)
    rng = np.random.default_rng(5)
    a, t = rng.normal(size=(3, 3)), 0.01 * rng.normal(size=(3, 3))
    verts = np.stack([grab_object_vertices(hand.vertices, ai, ti) for ai, ti in zip(a, t, strict=True)])
    contact_map = np.zeros((3, obj.n_vertices), np.uint8)
    contact_map[0, [0, 5, 7]] = 1
    contact_map[2, [3]] = 2
    path = tmp_path_factory.mktemp("grab") / "tiny.npz"
    authors_export(path, verts, a, t, np.zeros((3, 3)), np.zeros((3, 3)), contact_map)
    return path, hand, obj


def members(path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as data:
        return {name: data[name] for name in data.files}


# ---------------------------------------------------------------------------------------- reading


def test_rotation_convention_is_grabs_object_model(tiny, tmp_path):
    """Poses map the rest mesh exactly where GRAB's ObjectModel puts it, for rotations of every size
    (zero, small, near π, beyond π) — the authors' reader's setToRotationAxis(axis, -theta)."""
    _, hand, obj = tiny
    rng = np.random.default_rng(0)
    axes = rng.normal(size=(8, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.array([0.0, 1e-7, 0.3, 1.0, 2.0, np.pi - 1e-6, np.pi, 4.0])
    a = (axes * angles[:, None]).astype(np.float32)
    t = rng.normal(size=(8, 3)).astype(np.float32)
    path = tmp_path / "rot.npz"
    verts = np.tile(hand.vertices, (8, 1, 1))
    authors_export(path, verts, a, t, a, t, np.zeros((8, obj.n_vertices)))
    motion = load_grab(path, hand, obj, pair=False)
    posed = posed_objects(motion)
    for f in range(8):
        expected = grab_object_vertices(obj.vertices, a[f].astype(np.float64), t[f])
        np.testing.assert_allclose(posed[f], expected, rtol=0, atol=1e-12)
        np.testing.assert_allclose(motion.object_poses[f][:3, :3], rodrigues(a[f]).T, rtol=0, atol=1e-12)
    assert motion.fps == GRAB_FPS and motion.table is None and motion.object_contacts.count().sum() == 0


def test_the_authors_layout_imports_to_the_motion(motion, theirs):
    path, contact_map = theirs
    loaded = load_grab(path, motion.hand_mesh, motion.object_mesh, pair=False)
    file = members(path)
    F = motion.n_frames
    assert loaded.n_frames == F and loaded.hand_contacts is None
    a, t = file["objectRotations"].reshape(F, 3), file["objectTranslations"].reshape(F, 3)
    for f in range(F):
        expected = np.eye(4)
        expected[:3, :3], expected[:3, 3] = rodrigues(a[f]).T, t[f]
        np.testing.assert_allclose(loaded.object_poses[f], expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(loaded.object_poses, motion.object_poses, rtol=0, atol=1e-6)  # float32
    np.testing.assert_array_equal(loaded.hand_vertices, file["handVertices"].reshape(F, -1, 3))
    np.testing.assert_allclose(loaded.hand_vertices, motion.hand_vertices, rtol=0, atol=1e-7)
    assert contact_vertex_sets(loaded) == [set(np.flatnonzero(row).tolist()) for row in contact_map]


def test_our_writer_round_trips(motion, ours):
    loaded = load_grab(ours, motion.hand_mesh, motion.object_mesh, pair=False)
    file = members(ours)
    F = motion.n_frames
    a, t = file["objectRotations"].reshape(F, 3), file["objectTranslations"].reshape(F, 3)
    for f in range(F):
        np.testing.assert_allclose(loaded.object_poses[f][:3, :3], rodrigues(a[f]).T, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(loaded.object_poses[:, :3, 3], t.astype(np.float64))
    np.testing.assert_allclose(loaded.object_poses, motion.object_poses, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(loaded.hand_vertices, motion.hand_vertices.astype(np.float32))
    # save_grab: each contact becomes its face's vertex of the largest weight, once per frame.
    c, faces = motion.object_contacts, motion.object_mesh.faces
    nearest = faces[c.faces, np.argmax(c.bary, axis=1)]
    expected = [set(nearest[c.offsets[f] : c.offsets[f + 1]].tolist()) for f in range(F)]
    assert contact_vertex_sets(loaded) == expected
    # The table is written (the motion's box centre) but not read back: the format has no box.
    np.testing.assert_allclose(
        rodrigues(file["tableRotations"][:3]).T, motion.table[:3, :3], rtol=0, atol=1e-6
    )
    assert loaded.table is None


def test_contacts_sit_on_the_first_face_of_their_vertex(motion, ours):
    loaded = load_grab(ours, motion.hand_mesh, motion.object_mesh, pair=False)
    c, faces = loaded.object_contacts, loaded.object_mesh.faces
    vertex = faces[c.faces, np.argmax(c.bary, axis=1)]
    first_face = [int(np.flatnonzero((faces == v).any(axis=1))[0]) for v in np.unique(vertex)]
    lookup = dict(zip(np.unique(vertex).tolist(), first_face, strict=True))
    assert c.faces.tolist() == [lookup[v] for v in vertex.tolist()]


def test_hand_contacts_are_paired_by_ray_casting(motion, theirs):
    path, _ = theirs
    unpaired = load_grab(path, motion.hand_mesh, motion.object_mesh, pair=False)
    calls = []
    loaded = load_grab(path, motion.hand_mesh, motion.object_mesh, progress=lambda d, n: calls.append((d, n)))
    assert calls[-1] == (motion.n_frames, motion.n_frames)
    expected = pair_motion(unpaired, "object").apply(unpaired)
    for name in ("object_contacts", "hand_contacts"):
        got, want = getattr(loaded, name), getattr(expected, name)
        for part in ("offsets", "faces", "bary"):
            np.testing.assert_array_equal(getattr(got, part), getattr(want, part))
    assert np.array_equal(loaded.hand_contacts.offsets, loaded.object_contacts.offsets)
    kept = len(loaded.object_contacts) / len(unpaired.object_contacts)
    assert kept > 0.8
    on_object = world_points(loaded.object_mesh, posed_objects(loaded), loaded.object_contacts)
    on_hand = world_points(loaded.hand_mesh, loaded.hand_vertices, loaded.hand_contacts)
    assert np.linalg.norm(on_object - on_hand, axis=1).max() <= DEFAULT_CUTOFF + 1e-9


def test_fps_and_cutoff_are_the_callers(tiny):
    path, hand, obj = tiny
    assert load_grab(path, hand, obj, fps=30.0, pair=False).fps == 30.0
    for cutoff in (0.0, -1.0, float("nan"), "1"):
        with pytest.raises(GrabError) as err:
            load_grab(path, hand, obj, cutoff=cutoff)
        assert err.value.field == "cutoff"
    with pytest.raises(GrabError, match="fps"):
        load_grab(path, hand, obj, fps=0.0)
    with pytest.raises(GrabError) as err:
        load_grab(path, hand.vertices, obj)
    assert err.value.field == "hand_mesh"


# ---------------------------------------------------------------------------------------- writing


def test_written_file_has_the_layout_the_authors_reader_reads(motion, ours):
    """cnpy reads raw little-endian data, uncompressed: int numFrames, float handVertices and
    rotations/translations, uint16 contactFrames and counts, uint32 locations."""
    file = members(ours)
    F, n = motion.n_frames, motion.hand_mesh.n_vertices
    assert set(file) == set(MEMBERS) and not set(file) & set(IGNORED)
    assert file["numFrames"].dtype == "<i8" and file["numFrames"].shape == ()
    assert np.frombuffer(file["numFrames"].tobytes(), "<i4")[0] == F  # `numFramesNpy.data<int>()[0]`
    expected = {"handVertices": ("<f4", F * n * 3), "contactFrames": ("<u2", None)}
    expected |= {m: ("<f4", 3 * F) for m in MEMBERS if m.endswith(("Rotations", "Translations"))}
    expected |= {"objectContactFrameCounts": ("<u2", None), "objectContactLocations": ("<u4", None)}
    for name, (dtype, size) in expected.items():
        assert file[name].dtype == dtype and file[name].ndim == 1, name
        assert size is None or file[name].size == size, name
    with zipfile.ZipFile(ours) as archive:
        assert all(info.compress_type == zipfile.ZIP_STORED for info in archive.infolist())
    # The reader's walk over the sparse contacts, frame by frame.
    frames, counts = file["contactFrames"], file["objectContactFrameCounts"]
    assert np.all(np.diff(frames.astype(int)) > 0) and np.all(counts > 0)
    assert counts.sum() == file["objectContactLocations"].size
    touching = np.flatnonzero(motion.object_contacts.count())
    np.testing.assert_array_equal(frames, touching)


def test_a_motion_without_contacts_or_table_writes_empty_contacts(motion, tmp_path):
    from dataclasses import replace

    bare = replace(motion, object_contacts=None, hand_contacts=None, table=None, table_size=None)
    save_grab(bare, tmp_path / "bare.npz")
    file = members(tmp_path / "bare.npz")
    assert file["contactFrames"].size == file["objectContactLocations"].size == 0
    assert not file["tableRotations"].any() and not file["tableTranslations"].any()
    loaded = load_grab(tmp_path / "bare.npz", motion.hand_mesh, motion.object_mesh)
    assert len(loaded.object_contacts) == len(loaded.hand_contacts) == 0


def test_writing_refuses_what_the_format_cannot_hold(tiny, tmp_path):
    _, hand, obj = tiny
    F = 65537
    offsets = np.zeros(F + 1, np.int64)
    offsets[-1] = 1
    from solver.retarget import Contacts

    long = Motion(
        fps=120.0, object_mesh=obj, object_poses=np.tile(np.eye(4), (F, 1, 1)), hand_mesh=hand,
        hand_vertices=np.broadcast_to(hand.vertices, (F, hand.n_vertices, 3)),
        object_contacts=Contacts(offsets, [0], [[1.0, 0.0, 0.0]]),
    )  # fmt: skip
    with pytest.raises(GrabError) as err:
        save_grab(long, tmp_path / "long.npz")
    assert err.value.field == "contactFrames" and not (tmp_path / "long.npz").exists()
    with pytest.raises(GrabError):
        save_grab("not a motion", tmp_path / "x.npz")


# ---------------------------------------------------------------------------------------- malformed files


def _write(path, arrays: dict) -> None:
    np.savez(path, **arrays)


def _broken(file: dict, case: str) -> tuple[dict, str]:
    """A copy of a valid export's members with one thing wrong, and the member the error must name."""
    f = dict(file)
    if case.startswith("missing "):
        name = case.split()[1]
        del f[name]
        return f, name
    if case == "short handVertices":
        f["handVertices"] = f["handVertices"][:-3]
        return f, "handVertices"
    if case == "short objectRotations":
        f["objectRotations"] = f["objectRotations"][:-1]
        return f, "objectRotations"
    if case == "long tableTranslations":
        f["tableTranslations"] = np.append(f["tableTranslations"], np.float32(0))
        return f, "tableTranslations"
    if case == "vertex out of range":
        f["objectContactLocations"] = f["objectContactLocations"].copy()
        f["objectContactLocations"][-1] = 42
        return f, "objectContactLocations"
    if case == "counts do not sum":
        f["objectContactFrameCounts"] = f["objectContactFrameCounts"] + np.uint16(1)
        return f, "objectContactFrameCounts"
    if case == "counts and frames differ":
        f["objectContactFrameCounts"] = f["objectContactFrameCounts"][:1]
        return f, "objectContactFrameCounts"
    if case == "frames decreasing":
        f["contactFrames"] = f["contactFrames"][::-1].copy()
        return f, "contactFrames"
    if case == "frame past the end":
        f["contactFrames"] = np.array([0, 3], np.uint16)
        return f, "contactFrames"
    if case == "NaN translation":
        f["objectTranslations"] = f["objectTranslations"].copy()
        f["objectTranslations"][4] = np.nan
        return f, "objectTranslations"
    if case == "float contact frames":
        f["contactFrames"] = f["contactFrames"].astype(np.float32)
        return f, "contactFrames"
    if case == "integer hand vertices":
        f["handVertices"] = f["handVertices"].astype(np.int32)
        return f, "handVertices"
    if case == "unflattened hand vertices":
        f["handVertices"] = f["handVertices"].reshape(3, -1, 3)
        return f, "handVertices"
    if case == "no frames":
        f["numFrames"] = np.array(0)
        return f, "numFrames"
    if case == "two numFrames":
        f["numFrames"] = np.array([3, 3])
        return f, "numFrames"
    raise AssertionError(case)


CASES = [f"missing {name}" for name in MEMBERS] + [
    "short handVertices", "short objectRotations", "long tableTranslations", "vertex out of range",
    "counts do not sum", "counts and frames differ", "frames decreasing", "frame past the end",
    "NaN translation", "float contact frames", "integer hand vertices", "unflattened hand vertices",
    "no frames", "two numFrames",
]  # fmt: skip


@pytest.mark.parametrize("case", CASES)
def test_malformed_members_are_named(tiny, tmp_path, case):
    path, hand, obj = tiny
    arrays, name = _broken(members(path), case)
    _write(tmp_path / "bad.npz", arrays)
    with pytest.raises(GrabError) as err:
        load_grab(tmp_path / "bad.npz", hand, obj)
    assert err.value.field == name and name in str(err.value), str(err.value)


def test_meshes_that_do_not_fit_the_file_are_named(tiny, tmp_path):
    path, hand, obj = tiny
    with pytest.raises(GrabError, match="hand has 12 vertices") as err:
        load_grab(path, icosphere(1), obj)
    assert err.value.field == "handVertices"
    arrays = members(path)  # contacts 0, 5, 7 and 3: on a 12-vertex object too; make one not
    arrays["objectContactLocations"] = np.array([0, 5, 7, 41], np.uint32)
    _write(tmp_path / "far.npz", arrays)
    with pytest.raises(GrabError, match=r"41.*object OBJ") as err:
        load_grab(tmp_path / "far.npz", hand, icosphere(0))
    assert err.value.field == "objectContactLocations"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MeshWarning)
        lonely = TriMesh(np.vstack([obj.vertices, [[1.0, 1.0, 1.0]]]), obj.faces)
    arrays["objectContactLocations"] = np.array([0, 5, 7, 42], np.uint32)
    _write(tmp_path / "lonely.npz", arrays)
    with pytest.raises(GrabError, match="on no face") as err:
        load_grab(tmp_path / "lonely.npz", hand, lonely)
    assert err.value.field == "objectContactLocations"


def test_duplicate_vertices_in_a_frame_are_one_contact(tiny, tmp_path):
    path, hand, obj = tiny
    arrays = members(path)
    arrays["objectContactFrameCounts"] = np.array([4, 1], np.uint16)
    arrays["objectContactLocations"] = np.array([7, 0, 5, 7, 3], np.uint32)
    _write(tmp_path / "dup.npz", arrays)
    loaded = load_grab(tmp_path / "dup.npz", hand, obj, pair=False)
    assert contact_vertex_sets(loaded) == [{0, 5, 7}, set(), {3}]


def test_unreadable_files_are_refused(tiny, tmp_path):
    path, hand, obj = tiny
    data = path.read_bytes()
    (tmp_path / "truncated.npz").write_bytes(data[: len(data) // 2])
    (tmp_path / "garbage.npz").write_bytes(np.random.default_rng(1).bytes(2000))
    (tmp_path / "motion.npz").write_bytes(b"")
    for name in ("truncated.npz", "garbage.npz", "motion.npz", "absent.npz"):
        with pytest.raises(GrabError) as err:
            load_grab(tmp_path / name, hand, obj)
        assert err.value.field == "file" and str(tmp_path / name) in str(err.value)
    arrays = members(path)
    arrays["handVertices"] = np.array([object()] * arrays["handVertices"].size)
    np.savez(tmp_path / "pickled.npz", **arrays)
    with pytest.raises(GrabError, match="pickles") as err:
        load_grab(tmp_path / "pickled.npz", hand, obj)
    assert err.value.field == "handVertices"


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    cut=st.none() | st.integers(min_value=0),
    flips=st.lists(st.tuples(st.integers(min_value=0), st.integers(1, 255)), max_size=4),
)
def test_corrupted_bytes_raise_grab_errors_only(tiny, tmp_path, cut, flips):
    path, hand, obj = tiny
    data = bytearray(path.read_bytes())
    for position, mask in flips:
        data[position % len(data)] ^= mask
    if cut is not None:
        data = data[: cut % len(data)]
    bad = tmp_path / "fuzz.npz"
    bad.write_bytes(bytes(data))
    with contextlib.suppress(GrabError):
        load_grab(bad, hand, obj, pair=False)


_DTYPES = st.sampled_from(["<i1", "<u2", "<i4", "<u4", "<i8", "<u8", "<f2", "<f4", "<f8", ">f8", "?", "<U3"])


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    name=st.sampled_from(sorted(MEMBERS)),
    dtype=_DTYPES,
    shape=st.lists(st.integers(0, 6), max_size=2),
    seed=st.integers(0, 2**32 - 1),
)
def test_corrupted_arrays_raise_grab_errors_only(tiny, tmp_path, name, dtype, shape, seed):
    path, hand, obj = tiny
    arrays = members(path)
    rng = np.random.default_rng(seed)
    values = rng.integers(-3, 50, size=shape) if rng.random() < 0.7 else rng.normal(size=shape) * 1e3
    arrays[name] = values.astype(dtype)
    bad = tmp_path / "fuzz.npz"
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    bad.write_bytes(buffer.getvalue())
    try:
        motion = load_grab(bad, hand, obj, pair=False)
    except GrabError as err:
        assert err.field in MEMBERS, err.field
    else:
        assert isinstance(motion, Motion) and motion.n_frames == 3


def test_a_grab_scenes_contact_file_lines_up_with_its_motion(motion, theirs, tmp_path):
    """A contact file exported from the Maya scene of a GRAB import numbers frames as that scene does,
    from 0: read with the motion, each of its frames lands on the motion's frame of the same contacts,
    the motion read from the export and the same motion saved in our format and read back alike."""
    path, contact_map = theirs
    loaded = load_grab(path, motion.hand_mesh, motion.object_mesh, pair=False)
    assert loaded.first_frame == GRAB_FIRST_FRAME == 0
    F = loaded.n_frames
    authors_contact_file(tmp_path / "objectContacts.json", path, timeline_end=F - 1)
    expected = [set(np.flatnonzero(row).tolist()) for row in contact_map]
    assert contact_vertex_sets(loaded) == expected
    assert sum(len(e) > 0 for e in expected[1:]) > F // 2  # a file with many frames to misplace
    loaded.save(tmp_path / "motion.npz")
    for m in (loaded, Motion.load(tmp_path / "motion.npz")):
        seq = ContactSequence.load(
            tmp_path / "objectContacts.json", m.object_mesh, motion=m, mesh_name="objectShape"
        )
        got = vertex_sets(m.object_mesh, seq.contacts)
        assert seq.first_frame == 0 and len(got) == F
        assert got[1:] == expected[1:]
        assert got[0] == set()  # the exporter's loop starts at frame 1: frame 0 never reaches a file
        for f in np.flatnonzero([len(e) for e in expected[1:]]) + 1:
            np.testing.assert_array_equal(
                np.sort(seq.contacts.frame(f).positions(m.object_mesh), axis=0),
                np.sort(m.object_mesh.vertices[sorted(expected[f])], axis=0),
            )
    # Written back for that scene, frames carry the numbers the import gave their contact sets.
    ContactSequence.of_motion(loaded, "object").save(tmp_path / "ours.json", loaded.object_mesh)
    written = json.loads((tmp_path / "ours.json").read_text())
    assert written["meshName"] == "objectShape"
    assert [e["frame"] for e in written["data"]] == members(path)["contactFrames"].tolist()
    # Numbered from 1, as a fresh Maya timeline is, the same file lands one frame early.
    shifted = vertex_sets(
        loaded.object_mesh,
        ContactSequence.load(tmp_path / "objectContacts.json", loaded.object_mesh, n_frames=F).contacts,
    )
    assert shifted[:-1] == expected[1:] != expected[:-1]
    with pytest.raises(InterchangeError, match="first_frame=1 contradicts the motion's 0"):
        ContactSequence.load(
            tmp_path / "objectContacts.json", loaded.object_mesh, first_frame=1, motion=loaded
        )


# ---------------------------------------------------------------------------------------- the command


def test_import_grab_command_end_to_end(motion, theirs, tmp_path, capsys):
    import trimesh

    from geodesics.meshio import load_mesh

    path, contact_map = theirs
    for name, mesh in (("hand", motion.hand_mesh), ("object", motion.object_mesh)):  # as the exporter does
        trimesh.Trimesh(vertices=mesh.vertices, faces=mesh.faces).export(tmp_path / f"{name}.obj")
    out = tmp_path / "imported.npz"
    args = ["import-grab", str(path), "--hand-mesh", str(tmp_path / "hand.obj")]
    assert cli.main([*args, "--object-mesh", str(tmp_path / "object.obj"), "-o", str(out)]) == 0
    captured = capsys.readouterr()
    assert "contact-edit import-grab: Motion(" in captured.out and "paired" in captured.out
    assert "pairing" in captured.err and str(out) in captured.out
    saved = Motion.load(out)
    expected = load_grab(path, load_mesh(tmp_path / "hand.obj"), load_mesh(tmp_path / "object.obj"))
    np.testing.assert_array_equal(saved.object_poses, expected.object_poses)
    np.testing.assert_array_equal(saved.hand_vertices, expected.hand_vertices)
    np.testing.assert_array_equal(saved.hand_contacts.faces, expected.hand_contacts.faces)
    np.testing.assert_array_equal(saved.object_contacts.offsets, expected.object_contacts.offsets)
    assert saved.fps == 120.0 and saved.hand_contacts is not None
    assert saved.first_frame == 0  # the Maya frame of its first frame, kept for its contact files
    # --no-pair keeps every object contact and finds no hand contacts.
    out2 = tmp_path / "unpaired.npz"
    more = ["--object-mesh", str(tmp_path / "object.obj"), "-o", str(out2), "--no-pair", "--fps", "60"]
    assert cli.main([*args, *more]) == 0
    unpaired = Motion.load(out2)
    assert unpaired.hand_contacts is None and unpaired.fps == 60.0
    assert contact_vertex_sets(unpaired) == [set(np.flatnonzero(row).tolist()) for row in contact_map]


def test_import_grab_command_reports_errors(motion, ours, tmp_path, capsys):
    import trimesh

    trimesh.Trimesh(vertices=motion.object_mesh.vertices, faces=motion.object_mesh.faces).export(
        tmp_path / "object.obj"
    )
    out = tmp_path / "never.npz"
    # The object mesh given as the hand: the vertex counts disagree.
    args = ["import-grab", str(ours), "--hand-mesh", str(tmp_path / "object.obj")]
    assert cli.main([*args, "--object-mesh", str(tmp_path / "object.obj"), "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("contact-edit import-grab: ") and "handVertices" in err
    args = ["import-grab", str(tmp_path / "absent.npz"), "--hand-mesh", str(tmp_path / "object.obj")]
    assert cli.main([*args, "--object-mesh", str(tmp_path / "object.obj"), "-o", str(out)]) == 1
    assert "contact-edit import-grab: " in capsys.readouterr().err and not out.exists()


def test_import_grab_defaults_are_the_librarys():
    args = cli.build_parser().parse_args(
        ["import-grab", "m.npz", "--hand-mesh", "h", "--object-mesh", "o", "-o", "x"]
    )
    assert args.fps == GRAB_FPS and args.cutoff == DEFAULT_CUTOFF and not args.no_pair


def test_import_grab_never_writes_over_its_inputs(tiny, tmp_path, capsys):
    """Issue 39: ``-o`` naming the hand mesh (or the GRAB export) saved the motion zip over it. Refused
    for each input, even with --overwrite, the inputs' bytes as they were; an existing output that is not
    an input is replaced only with --overwrite."""
    path, hand, obj = tiny
    grab_dir = tmp_path / "grab"
    grab_dir.mkdir()
    export = grab_dir / "s_right_full_export_motion.npz"
    export.write_bytes(path.read_bytes())
    save_mesh(hand, grab_dir / "hand.obj")
    save_mesh(obj, grab_dir / "obj.obj")
    inputs = {p: p.read_bytes() for p in (export, grab_dir / "hand.obj", grab_dir / "obj.obj")}
    args = ["import-grab", str(export), "--hand-mesh", str(grab_dir / "hand.obj")]
    args += ["--object-mesh", str(grab_dir / "obj.obj")]
    what = ["the GRAB motion", "the hand mesh (--hand-mesh)", "the object mesh (--object-mesh)"]
    for target, name in zip(inputs, what, strict=True):
        for overwrite in ([], ["--overwrite"]):
            assert cli.main([*args, "-o", str(target), *overwrite]) == 1
            assert capsys.readouterr().err == (
                f"contact-edit import-grab: {target} is {name}: an input, never written, even with "
                "--overwrite; choose another output (-o)\n"
            )
    assert {p: p.read_bytes() for p in inputs} == inputs
    out = tmp_path / "motion.npz"
    out.write_bytes(b"an older import")
    assert cli.main([*args, "-o", str(out)]) == 1
    assert f"{out} exists; choose another output (-o), or pass --overwrite" in capsys.readouterr().err
    assert out.read_bytes() == b"an older import"
    assert cli.main([*args, "-o", str(out), "--overwrite", "--no-pair"]) == 0
    assert Motion.load(out).n_frames == 3
    assert {p: p.read_bytes() for p in inputs} == inputs
