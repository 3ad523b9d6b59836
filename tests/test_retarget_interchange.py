"""The retargeting authors' contact, virtual-marker and ``.kmexp`` files: hand-made fixtures in their
documented layouts (``tests/fixtures/kmr``), round trips ours → theirs → ours, and malformed files
refused with the file, frame and entry named."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from geodesics import SurfacePoints, TriMesh
from solver import Rig
from solver.hands import make_hand
from solver.retarget import default_annotation
from solver.retarget.interchange import (
    ContactSequence,
    InterchangeError,
    KeyframeMotion,
    load_markers,
    pair_markers,
    save_kmexp,
    save_markers,
)
from solver.retarget.motion import Contacts

from .test_point_strings import OCTA_FACES, OCTA_VERTICES

FIXTURES = Path(__file__).parent / "fixtures" / "kmr"


@pytest.fixture(scope="module")
def octa():
    return TriMesh(OCTA_VERTICES, OCTA_FACES)


# ------------------------------------------------------------------------------------------ contacts


def test_contact_fixture(octa):
    seq = ContactSequence.load(FIXTURES / "contacts.json", octa, n_frames=5)
    assert seq.mesh_name == "octaShape" and seq.contacts.n_frames == 5
    assert seq.contacts.count().tolist() == [0, 3, 0, 2, 0]  # file frames 2 and 4 are ours 1 and 3
    f1 = seq.contacts.frame(1).positions(octa)
    np.testing.assert_allclose(f1, [[1, 0, 0], [-0.25, 0.75, 0], [-1 / 3, 1 / 3, -1 / 3]], atol=1e-6)
    assert seq.omitted.tolist() == [False, False, False, False, True]
    kept = seq.kept()
    assert kept.count().tolist() == [0, 3, 0, 1, 0]
    np.testing.assert_allclose(kept.frame(3).positions(octa), [[0.1, 0.2, 0.7]], atol=1e-12)


def test_contacts_round_trip(tmp_path):
    mesh = make_hand("human").mesh
    rng = np.random.default_rng(7)
    counts = [4, 0, 9, 1, 0, 0]
    frames = []
    for n in counts:
        bary = rng.dirichlet([1, 1, 1], n)
        bary[: n // 3, 0] = 0  # some on edges
        bary[: n // 3] /= bary[: n // 3].sum(1, keepdims=True)
        frames.append(SurfacePoints(rng.integers(0, mesh.n_faces, n), bary))
    contacts = Contacts.from_frames(frames)
    omitted = rng.random(len(contacts)) < 0.3
    seq = ContactSequence("handShape", contacts, omitted, first_frame=1)
    seq.save(tmp_path / "c.json", mesh)
    text = json.loads((tmp_path / "c.json").read_text())
    assert [e["frame"] for e in text["data"]] == [1, 3, 4]  # frames without contacts left out
    assert all(("omissionIndices" in e) == bool(e.get("omissionIndices")) for e in text["data"])
    back = ContactSequence.load(tmp_path / "c.json", mesh, n_frames=6, mesh_name="handShape")
    assert np.array_equal(back.contacts.offsets, contacts.offsets)
    np.testing.assert_allclose(
        SurfacePoints(back.contacts.faces, back.contacts.bary).positions(mesh),
        SurfacePoints(contacts.faces, contacts.bary).positions(mesh),
        rtol=0, atol=1e-15,
    )  # fmt: skip
    assert np.array_equal(back.omitted, omitted)
    # Without n_frames the sequence ends at the last frame with contacts.
    assert ContactSequence.load(tmp_path / "c.json", mesh).contacts.n_frames == 4


@pytest.mark.parametrize(
    "name, message",
    [
        ("truncated.json", "not valid JSON"),
        ("unknown_kind.json", "frame 1's contacts: entry 1 ('p 3 0.5') is not a point"),
        ("out_of_range.json", "frame 1's contacts: entry 0 ('f 8 0.2 0.3 0.5') names a face"),
        ("float_index.json", "frame 1's contacts: entry 0 ('v 1.5') has an index that is not an integer"),
        ("bad_omission.json", "frame 1.omissionIndices holds [1]: not indices in 0..0"),
        ("missing.json", "there is no contacts file at that path"),
    ],
)
def test_malformed_contact_files(octa, name, message):
    with pytest.raises(InterchangeError) as err:
        ContactSequence.load(FIXTURES / name, octa)
    assert message in str(err.value)
    assert name in str(err.value)


def test_contact_file_checks(octa, tmp_path):
    with pytest.raises(InterchangeError, match="is for mesh 'octaShape', not 'handShape'"):
        ContactSequence.load(FIXTURES / "contacts.json", octa, mesh_name="handShape")
    with pytest.raises(InterchangeError, match="frame 4 is outside the motion's frames 1 to 3"):
        ContactSequence.load(FIXTURES / "contacts.json", octa, n_frames=3)
    cases = {
        "[1, 2]": "must be a JSON object, not a list",
        '{"data": []}': "meshName is missing",
        '{"meshName": "m", "data": [{"frame": true, "contacts": []}]}': "frame must be an integer",
        '{"meshName": "m", "data": [{"frame": 1, "contacts": "v 1"}]}': "contacts must be a list",
        '{"meshName": "m", "data": [{"frame": 1, "contacts": []}, {"frame": 1, "contacts": []}]}': (
            "frame 1 appears more than once"
        ),
    }
    for text, message in cases.items():
        (tmp_path / "x.json").write_text(text)
        with pytest.raises(InterchangeError, match=message.replace("(", r"\(").replace("[", r"\[")):
            ContactSequence.load(tmp_path / "x.json", octa)


# ------------------------------------------------------------------------------------------ markers


def test_marker_fixture(octa):
    markers = load_markers(FIXTURES / "markers.virtualmarkers", octa, mesh_name="octaShape")
    assert list(markers) == ["tip", "pad"]
    np.testing.assert_allclose(markers["tip"].positions(octa), [[0, 0, 1]])
    np.testing.assert_allclose(markers["pad"].positions(octa)[1:], [[0.5, 0.5, 0], [0, 0, -1]], atol=1e-15)


def test_markers_round_trip_into_the_annotation(tmp_path):
    source, target = make_hand("human"), make_hand("witch")
    annotation = default_annotation(source, target)
    save_markers(
        tmp_path / "s.virtualmarkers",
        "handShape",
        source.mesh,
        {m.name: m.source for m in annotation.markers},
    )
    save_markers(
        tmp_path / "t.virtualmarkers",
        "witchShape",
        target.mesh,
        {m.name: m.target for m in annotation.markers},
    )
    paired = pair_markers(
        load_markers(tmp_path / "s.virtualmarkers", source.mesh),
        load_markers(tmp_path / "t.virtualmarkers", target.mesh, mesh_name="witchShape"),
    )
    assert [m.name for m in paired] == [m.name for m in annotation.markers]
    for ours, theirs in zip(annotation.markers, paired, strict=True):
        assert ours.kind == theirs.kind
        np.testing.assert_allclose(
            theirs.source.positions(source.mesh), ours.source.positions(source.mesh), atol=1e-15
        )
        np.testing.assert_allclose(
            theirs.target.positions(target.mesh), ours.target.positions(target.mesh), atol=1e-15
        )


def test_marker_errors(octa, tmp_path):
    a = {"tip": SurfacePoints.from_vertices(octa, [4])}
    with pytest.raises(InterchangeError, match="markers 'pad' are on one hand only"):
        pair_markers(a, {**a, "pad": a["tip"]})
    cases = {
        '{"meshName": "m", "data": [{"name": "a", "MarkerPoints": []}]}': "marker 'a' has no points",
        json.dumps({"meshName": "m", "data": [{"name": "a", "MarkerPoints": ["v 1"]}] * 2}): (
            "marker name 'a' is empty or repeated"
        ),
        '{"meshName": "m", "data": [{"name": "a", "MarkerPoints": ["v 9"]}]}': "marker 'a''s points: entry 0",
        '{"meshName": "m", "data": [{"MarkerPoints": ["v 1"]}]}': "data\\[0\\].name is missing",
    }
    for text, message in cases.items():
        (tmp_path / "x.virtualmarkers").write_text(text)
        with pytest.raises(InterchangeError, match=message):
            load_markers(tmp_path / "x.virtualmarkers", octa)


# ------------------------------------------------------------------------------------------ kmexp


def _three_bone_rig() -> Rig:
    """root, a hinge free about x only, and a ball joint: the three kinds the exporter writes."""
    M = np.repeat(np.eye(4)[None], 3, axis=0)
    M[1, :3, 3] = [0, 0.05, 0]
    M[2, :3, 3] = [0, 0.1, 0]
    locked = np.zeros(12, bool)
    locked[[7, 8]] = True  # the hinge's y and z
    return Rig(["root", "hinge", "ball"], [-1, 0, 1], M, [0.05, 0.05, 0.05], locked=locked)


def test_kmexp_fixture_reads_as_the_authors_schema_says():
    rig = _three_bone_rig()
    k = KeyframeMotion.load(FIXTURES / "motion.kmexp")
    assert k.framerate == 120 and k.joint_dofs == (7, 1, 4) and k.frames.tolist() == [1, 2]
    np.testing.assert_allclose(k.table, [80, 2.5, 60, 1, 0, 0, 0, 0, -1.25, 30])
    poses = k.object_poses()
    np.testing.assert_allclose(poses[1, :3, 3], [0.1, 0.02, 0.05])  # centimetres to metres
    np.testing.assert_allclose(
        poses[1, :3, :3], Rotation.from_euler("z", 90, degrees=True).as_matrix(), atol=1e-15
    )
    theta = k.theta(rig)
    np.testing.assert_allclose(theta[1, :3], [0.01, 0.02, 0.03])
    basis = rig.basis(theta[1])
    np.testing.assert_allclose(
        basis[0, :3, :3], Rotation.from_euler("x", 90, degrees=True).as_matrix(), atol=1e-15
    )
    np.testing.assert_allclose(theta[1, 6:9], [-0.25, 0, 0])
    np.testing.assert_allclose(
        basis[2, :3, :3], Rotation.from_euler("y", 60, degrees=True).as_matrix(), atol=1e-15
    )


def test_kmexp_round_trip(tmp_path):
    rig = _three_bone_rig()
    rng = np.random.default_rng(3)
    F = 6
    theta = rng.uniform(-1, 1, (F, rig.n_dofs))
    theta[:, :3] *= 0.1
    theta[:, rig.locked] = 0
    poses = np.repeat(np.eye(4)[None], F, axis=0)
    poses[:, :3, :3] = Rotation.random(F, random_state=4).as_matrix()
    poses[:, :3, 3] = rng.normal(size=(F, 3))
    table = np.eye(4)
    table[:3, 3] = [0, 0, -0.4]
    written = save_kmexp(tmp_path / "m.kmexp", rig, theta, poses, 120, table, [0.8, 0.6, 0.05])
    data = json.loads((tmp_path / "m.kmexp").read_text())
    assert data["jointNames"] == ["root", "hinge", "ball"] and data["jointDofs"] == [7, 1, 4]
    assert len(data["data"][0]["hand"]) == 12 and data["data"][0]["frame"] == 1
    np.testing.assert_allclose(data["table"][:3], [80, 60, 5])
    back = KeyframeMotion.load(tmp_path / "m.kmexp")
    np.testing.assert_array_equal(back.hand, written.hand)
    np.testing.assert_allclose(back.theta(rig), theta, atol=1e-12)
    np.testing.assert_allclose(back.object_poses(), poses, atol=1e-14)


def test_kmexp_of_a_procedural_hand_round_trips(tmp_path):
    hand = make_hand("witch")
    rng = np.random.default_rng(5)
    theta = np.clip(rng.normal(0, 0.4, (4, hand.rig.n_dofs)), hand.rig.lower, hand.rig.upper)
    poses = np.repeat(np.eye(4)[None], 4, axis=0)
    save_kmexp(tmp_path / "w.kmexp", hand.rig, theta, poses, 60)
    back = KeyframeMotion.load(tmp_path / "w.kmexp").theta(hand.rig)
    np.testing.assert_allclose(hand.posed_vertices(back[2]), hand.posed_vertices(theta[2]), atol=1e-12)


def test_kmexp_errors(tmp_path):
    rig = _three_bone_rig()
    with pytest.raises(InterchangeError, match=r"frame 1\.hand must be 8 finite numbers, got \[1, 0"):
        KeyframeMotion.load(FIXTURES / "short_hand.kmexp")
    k = KeyframeMotion.load(FIXTURES / "motion.kmexp")
    with pytest.raises(InterchangeError, match=r"motion\.kmexp: the rig's joints 'forearm', 'hand'"):
        k.theta(make_hand("human").rig)
    with pytest.raises(InterchangeError, match="whole frame rate"):
        KeyframeMotion.from_rig(rig, np.zeros((1, 12)), np.eye(4)[None], 29.97)
    shutil.copy(FIXTURES / "motion.kmexp", tmp_path / "m.kmexp")
    text = (tmp_path / "m.kmexp").read_text().replace('"jointDofs": [7, 1, 4]', '"jointDofs": [6, 1, 4]')
    (tmp_path / "m.kmexp").write_text(text)
    with pytest.raises(InterchangeError, match="7 for the root"):
        KeyframeMotion.load(tmp_path / "m.kmexp")


def _locked_human_rig() -> Rig:
    """The human hand's skeleton with the three kinds of joint the exporter writes and one it leaves
    out: ball joints (all axes free), hinges (index_2 and index_3 free about x only), a two-axis
    joint (thumb_1, z locked) and a welded joint (ring_2, every axis locked), left out while its child
    ring_3 is still listed."""
    human = make_hand("human").rig
    locked = np.zeros(human.n_dofs, bool)
    for name, axes in {"index_2": [1, 2], "index_3": [1, 2], "thumb_1": [2], "ring_2": [0, 1, 2]}.items():
        locked[human.bone_dofs(name)[axes]] = True
    return Rig(human.names, human.parents, human.matrix_local, human.lengths, locked=locked)


# The order KeyframeMotionSequenceIO::parseKinematicTree lists this rig's joints (keyframeMotionSequenceIO.cpp
# 428-439 and 627-636): pop a joint, list it unless it has no free axis (611), push its children in
# order, so the hand's last child (thumb_1) comes out first, and ring_2 is left out but not ring_3.
STACK_ORDER = [
    ("forearm", 7), ("hand", 4), ("thumb_1", 2), ("thumb_2", 4), ("thumb_3", 4), ("pinky_1", 4),
    ("pinky_2", 4), ("pinky_3", 4), ("ring_1", 4), ("ring_3", 4), ("middle_1", 4), ("middle_2", 4),
    ("middle_3", 4), ("index_1", 4), ("index_2", 1), ("index_3", 1),
]  # fmt: skip


def test_kmexp_in_the_exporters_stack_order_loads_joint_by_joint(tmp_path):
    """A file laid out as their exporter writes this rig (joints in its stack order, each joint's own
    values in its own columns) puts every joint's values on that joint of the rig."""
    rig = _locked_human_rig()
    rng = np.random.default_rng(11)
    F = 3
    root_rotations = Rotation.random(F, random_state=12)
    root_cm = rng.uniform(-20, 20, (F, 3))
    balls = {n: Rotation.from_rotvec(rng.uniform(-0.6, 0.6, (F, 3))) for n, d in STACK_ORDER[1:] if d == 4}
    angles = {"thumb_1": rng.uniform(-0.5, 0.5, (F, 2)), "index_2": rng.uniform(0, 1, (F, 1))}
    angles["index_3"] = rng.uniform(0, 1, (F, 1))

    def wxyz(rotation):  # w >= 0, as ours writes them (Maya's sign is either; the reader takes both)
        q = rotation.as_quat()[[3, 0, 1, 2]]
        return list(q if q[0] >= 0 else -q)

    hand = []
    for f in range(F):
        row = wxyz(root_rotations[f]) + list(root_cm[f])
        for name, d in STACK_ORDER[1:]:
            row += wxyz(balls[name][f]) if d == 4 else list(angles[name][f])
        hand.append(row)
    export = {
        "framerate": 120,
        "jointNames": [n for n, _ in STACK_ORDER],
        "jointDofs": [d for _, d in STACK_ORDER],
        "data": [{"frame": f + 1, "object": [1, 0, 0, 0, 0, 0, 0], "hand": hand[f]} for f in range(F)],
    }
    (tmp_path / "theirs.kmexp").write_text(json.dumps(export))
    theta = KeyframeMotion.load(tmp_path / "theirs.kmexp").theta(rig)

    for f in range(F):
        root = rig.pose_matrices(theta[f])[0]
        np.testing.assert_allclose(root[:3, :3], root_rotations[f].as_matrix(), atol=1e-12)
        np.testing.assert_allclose(root[:3, 3], root_cm[f] / 100, atol=1e-12)
        basis = rig.basis(theta[f])
        for name, rotation in balls.items():
            b = rig.bone_index(name)
            np.testing.assert_allclose(basis[b, :3, :3], rotation[f].as_matrix(), atol=1e-12, err_msg=name)
    for name, free in {"thumb_1": [0, 1], "index_2": [0], "index_3": [0]}.items():
        dofs = rig.bone_dofs(name)
        np.testing.assert_allclose(theta[:, dofs[free]], angles[name], err_msg=name)
        locked = np.setdiff1d(np.arange(3), free)
        np.testing.assert_array_equal(
            theta[:, dofs[locked]], np.broadcast_to(rig.rest[dofs[locked]], (F, len(locked)))
        )
    welded = rig.bone_dofs("ring_2")
    np.testing.assert_array_equal(theta[:, welded], np.broadcast_to(rig.rest[welded], (F, 3)))

    # ours lists the same rig's joints in the same order, with the same numbers in every column
    ours = save_kmexp(tmp_path / "ours.kmexp", rig, theta, np.repeat(np.eye(4)[None], F, axis=0), 120)
    written = json.loads((tmp_path / "ours.kmexp").read_text())
    assert list(zip(written["jointNames"], written["jointDofs"], strict=True)) == STACK_ORDER
    np.testing.assert_allclose(ours.hand, hand, atol=1e-9)


def test_kmexp_joints_that_differ_from_the_rigs_are_named():
    k = KeyframeMotion.load(FIXTURES / "motion.kmexp")  # root, hinge (x), ball
    M = np.repeat(np.eye(4)[None], 3, axis=0)
    locked = np.zeros(12, bool)
    locked[[7, 8]] = True
    renamed = Rig(["root", "elbow", "ball"], [-1, 0, 1], M, [0.05] * 3, locked=locked)
    with pytest.raises(
        InterchangeError,
        match=r"motion\.kmexp: the rig's joints 'elbow' are not in the export; "
        r"the export's joints 'hinge' are not on the rig",
    ):
        k.theta(renamed)
    welded = locked.copy()
    welded[9:] = True
    with pytest.raises(InterchangeError, match=r"'ball' \(every axis locked on the rig\) are not on the rig"):
        k.theta(Rig(["root", "hinge", "ball"], [-1, 0, 1], M, [0.05] * 3, locked=welded))
    two_axes = locked.copy()
    two_axes[11] = True
    with pytest.raises(InterchangeError, match=r"'ball' has 4 values in the export, 2 on the rig"):
        k.theta(Rig(["root", "hinge", "ball"], [-1, 0, 1], M, [0.05] * 3, locked=two_axes))
