"""Hand-pair annotations and bulk contact transfer (§3.3, Appendix A): the JSON file, the default
annotations of the procedural hands (Table 2's marker counts, λ closed forms) and the contact atlas's
transfer (exact on the same hand, scaled on a scaled hand, ring and pinky dropped on the alien)."""

import dataclasses
import json
import os

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from geodesics import SurfacePoints, TriMesh
from solver.hands import KINDS, make_hand
from solver.retarget import annotate, synthetic, transfer
from solver.retarget.annotations import (
    AnnotationError,
    CurveAnnotation,
    HandPairAnnotation,
    HandRef,
    MarkerAnnotation,
)
from solver.retarget.motion import Contacts
from solver.retarget.transfer import ContactTransfer

from .json_mutations import mutate

FINGERS = ("thumb", "index", "middle", "ring", "pinky")


# ------------------------------------------------------------------------------------------ fixtures


@pytest.fixture(scope="module")
def human():
    return make_hand("human")


@pytest.fixture(scope="module")
def small_human():
    return make_hand("human", 0.75)


@pytest.fixture(scope="module")
def alien():
    return make_hand("alien")


@pytest.fixture(scope="module")
def same(human):
    return annotate.default_annotation(human, human)


@pytest.fixture(scope="module")
def to_small(human, small_human):
    return annotate.default_annotation(human, small_human)


@pytest.fixture(scope="module")
def to_alien(human, alien):
    return annotate.default_annotation(human, alien)


@pytest.fixture(scope="module")
def motion():
    """The shortest synthetic grasp (44 frames, about 3,100 paired contacts)."""
    return synthetic.generate("cylinder", frames=4 * len(synthetic.PHASES), seed=0)


def _owner_bone(hand, points: SurfacePoints) -> np.ndarray:
    """Name of the bone that the corner nearest each point is skinned to most (an independent labelling)."""
    owner = np.asarray(hand.weights.tocsr().argmax(axis=1)).reshape(-1)
    corner = hand.mesh.faces[points.faces, np.argmax(points.bary, axis=1)]
    return np.array(hand.rig.names)[owner[corner]]


def _chain(names) -> np.ndarray:
    """'index_2' -> 'index', 'hand' -> 'hand'."""
    return np.array([n.rsplit("_", 1)[0] if n[-1].isdigit() else n for n in names])


def _small_annotation(human) -> HandPairAnnotation:
    """A hand-made annotation on the human mesh with every kind of curve and marker (small, for fuzzing)."""
    ref = HandRef.of(human.mesh, "human", 1.0)
    sp = SurfacePoints
    return HandPairAnnotation(
        ref,
        ref,
        (
            CurveAnnotation(
                "a",
                sp([10, 11, 12], [[0.2, 0.3, 0.5], [1, 0, 0], [0.1, 0.1, 0.8]]),
                sp([5], [[0.3, 0.3, 0.4]]),
                0.6 + 0.8j,
                1.25,
                0.8,
            ),
            CurveAnnotation("b", sp([20, 21], [[0.5, 0.5, 0], [1 / 3, 1 / 3, 1 / 3]])),
        ),
        (
            MarkerAnnotation("single", sp([1], [[0.1, 0.2, 0.7]]), sp([2], [[0.7, 0.2, 0.1]])),
            MarkerAnnotation(
                "many", sp([3], [[1, 0, 0]]), sp([4, 5, 6], [[0, 1, 0], [0, 0, 1], [0.5, 0.5, 0]])
            ),
        ),
        0.0123456789,
    )


# ------------------------------------------------------------------------------------------ the file


def _assert_same(a: HandPairAnnotation, b: HandPairAnnotation):
    assert a.source == b.source and a.target == b.target
    assert a.threshold == b.threshold
    assert [c.name for c in a.curves] == [c.name for c in b.curves]
    for c, d in zip(a.curves, b.curves, strict=True):
        np.testing.assert_array_equal(c.source.faces, d.source.faces)
        np.testing.assert_array_equal(c.source.bary, d.source.bary)  # bit for bit
        assert c.dropped == d.dropped
        if not c.dropped:
            np.testing.assert_array_equal(c.target_start.bary, d.target_start.bary)
            assert (c.target_direction, c.axis_scale, c.radial_scale) == (
                d.target_direction,
                d.axis_scale,
                d.radial_scale,
            )
    for m, n in zip(a.markers, b.markers, strict=True):
        assert m.name == n.name and m.kind == n.kind
        for p, q in ((m.source, n.source), (m.target, n.target)):
            np.testing.assert_array_equal(p.faces, q.faces)
            np.testing.assert_array_equal(p.bary, q.bary)


def test_file_round_trips_exactly(tmp_path, human, alien, to_alien):
    path = tmp_path / "human_to_alien.json"
    to_alien.save(path)
    back = HandPairAnnotation.load(path, human.mesh, alien.mesh)
    _assert_same(back, to_alien)
    assert back.to_dict() == to_alien.to_dict()
    assert [c.name for c in back.curves if c.dropped] == ["ring", "pinky"]
    data = json.loads(path.read_text())
    assert data["format"] == "contact-edit/hand-pair" and data["version"] == 1
    # An infinite threshold is written as null and read back as infinite.
    unlimited = dataclasses.replace(to_alien, threshold=np.inf)
    unlimited.save(path)
    assert json.loads(path.read_text())["threshold"] is None
    assert HandPairAnnotation.load(path).threshold == np.inf


def test_save_is_atomic(tmp_path, monkeypatch, human):
    path = tmp_path / "pair.json"
    ann = _small_annotation(human)
    ann.save(path)
    before = path.read_bytes()
    moves = []

    def failing_replace(src, dst):
        moves.append((src, dst))
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", failing_replace)
    with pytest.raises(OSError, match="disk full"):
        dataclasses.replace(ann, threshold=1.0).save(path)
    monkeypatch.undo()
    # The new text went to a temporary file in the same folder (so the rename is atomic), which is gone.
    assert len(moves) == 1 and os.path.dirname(moves[0][0]) == str(tmp_path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pair.json"]


def test_load_refuses_the_annotation_of_another_hand(tmp_path, human, small_human, alien, to_alien):
    path = tmp_path / "pair.json"
    to_alien.save(path)
    witch = make_hand("witch")
    with pytest.raises(AnnotationError, match=r"target hand has 2338 vertices.*another hand"):
        HandPairAnnotation.load(path, human.mesh, witch.mesh)
    with pytest.raises(AnnotationError, match="source hand"):
        HandPairAnnotation.load(path, alien.mesh, alien.mesh)
    with pytest.raises(AnnotationError, match="another hand"):
        ContactTransfer(to_alien, human.mesh, witch.mesh)
    # Only the topology counts: the annotation holds for any pose or shape of the same triangles.
    moved = TriMesh(human.mesh.vertices * 1.1 + 0.3, human.mesh.faces)
    ContactTransfer(to_alien, moved, alien.mesh)


@pytest.mark.parametrize(
    "text, message",
    [
        ("{not json", "not valid JSON"),
        ('{"format": "contact-edit/hand-pair", "version": 1, "sour', "not valid JSON"),
        ("[1, 2, 3]", "must be a JSON object"),
        ('{"format": "contact-edit/contacts", "version": 1}', "format is 'contact-edit/contacts'"),
        ('{"format": "contact-edit/hand-pair", "version": 2}', "version 2"),
        ('{"format": "contact-edit/hand-pair", "version": true}', "version True"),
        ('{"format": "contact-edit/hand-pair", "version": 1.0}', "version 1.0"),
    ],
)
def test_load_refuses_files_that_are_not_annotations(tmp_path, text, message):
    path = tmp_path / "pair.json"
    path.write_text(text)
    with pytest.raises(AnnotationError, match=message):
        HandPairAnnotation.load(path)


def test_load_refuses_unreadable_files(tmp_path):
    with pytest.raises(AnnotationError, match="no annotation file"):
        HandPairAnnotation.load(tmp_path / "missing.json")
    with pytest.raises(AnnotationError, match="cannot read"):
        HandPairAnnotation.load(tmp_path)  # a directory
    (tmp_path / "latin1.json").write_bytes(b'{"format": "caf\xe9"}')
    with pytest.raises(AnnotationError, match="not valid JSON"):
        HandPairAnnotation.load(tmp_path / "latin1.json")


def _edited(ann, edit):
    data = json.loads(json.dumps(ann.to_dict()))
    edit(data)
    return data


@pytest.mark.parametrize(
    "edit, message",
    [
        (
            lambda d: d["curves"][0]["source"].update(faces=[10, 7488, 12]),
            r"curve 'a'\.source\.faces holds \[7488\]",
        ),
        (
            lambda d: d["curves"][0]["source"].update(faces=[10, -1, 12]),
            r"curve 'a'\.source\.faces holds \[-1\]",
        ),
        (
            lambda d: d["curves"][0]["target"]["start"].update(faces=[99999]),
            r"curve 'a'\.target\.start\.faces holds",
        ),
        (
            lambda d: d["markers"][1]["target"].update(faces=[4, 5, 8000]),
            r"marker 'many'\.target\.faces holds \[8000\]",
        ),
        (
            lambda d: d["curves"][0]["source"].update(faces=[10, 11.5, 12]),
            r"curve 'a'\.source\.faces must be",
        ),
        (
            lambda d: d["curves"][0]["source"].update(faces=[10, True, 12]),
            r"curve 'a'\.source\.faces must be",
        ),
        (
            lambda d: d["curves"][0]["source"].update(faces=[10, 2**70, 12]),
            r"curve 'a'\.source\.faces must be a list of integer indices",
        ),
        (
            lambda d: d["curves"][1]["source"]["bary"][1].__setitem__(0, float("nan")),
            r"curve 'b'\.source\.bary.*NaN",
        ),
        (
            lambda d: d["markers"][0]["target"].update(bary=[[0.5, 0.7, -0.2]]),
            r"marker 'single'\.target\.bary",
        ),
        (lambda d: d["markers"][0]["target"].update(bary=[[0.5, 0.5]]), r"marker 'single'\.target\.bary"),
        (lambda d: d["curves"][0]["target"].update(axis_scale=-1.0), "λ_A must be positive"),
        (
            lambda d: d["curves"][0]["target"].update(radial_scale=float("nan")),
            "radial_scale must be a number",
        ),
        (lambda d: d["curves"][0]["target"].update(direction=[0, 0]), "zero or non-finite target direction"),
        (
            lambda d: d["curves"][1]["source"].update(faces=[20], bary=[[1, 0, 0]]),
            "at least two source points",
        ),
        (lambda d: d["curves"][0].update(target=None), "no curve has a counterpart"),
        (lambda d: d["curves"][1].update(name="a"), "curve names repeat"),
        (lambda d: d.update(threshold=float("nan")), "threshold must be a number, got NaN"),
        (lambda d: d.update(threshold="1 cm"), "threshold must be a number"),
        (lambda d: d["source"].update(vertices=0), r"source\.vertices must be a positive integer"),
        (lambda d: d["target"].pop("topology"), r"target\.topology"),
        (
            lambda d: d["markers"][1]["source"].update(faces=[3, 3], bary=[[1, 0, 0], [0, 1, 0]]),
            "pairs 2 source points with 3 target points",
        ),
    ],
)
def test_from_dict_names_the_bad_field(human, edit, message):
    data = _edited(_small_annotation(human), edit)
    with pytest.raises(AnnotationError, match=message):
        HandPairAnnotation.from_dict(data)


def test_nan_barycentrics_in_a_file_are_refused(tmp_path, human):
    # json writes NaN as the (non-standard) literal NaN and reads it back: the loader must refuse it.
    data = _small_annotation(human).to_dict()
    data["markers"][1]["target"]["bary"][2][0] = float("nan")
    (tmp_path / "nan.json").write_text(json.dumps(data))
    with pytest.raises(AnnotationError, match=r"marker 'many'\.target\.bary: surface points 2 have NaN"):
        HandPairAnnotation.load(tmp_path / "nan.json")


def test_load_checks_points_against_the_meshes(tmp_path, human):
    # A face index inside the recorded face count but a hand of the recorded topology is required too.
    ann = _small_annotation(human)
    ann.save(tmp_path / "pair.json")
    back = HandPairAnnotation.load(tmp_path / "pair.json", human.mesh, human.mesh)
    _assert_same(back, ann)


@pytest.fixture(scope="module")
def small_text(human):
    return json.dumps(_small_annotation(human).to_dict())


@pytest.fixture(scope="module")
def fuzz_file(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz") / "pair.json"


@settings(derandomize=True, max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_fuzz_any_edit_of_a_file_loads_or_is_refused_cleanly(small_text, fuzz_file, data):
    """Garbage, truncations and arbitrary JSON values in any place: AnnotationError or a valid annotation
    (which then round-trips), never another exception."""
    how = data.draw(st.sampled_from(["truncate", "garbage", "replace", "delete"]))
    if how == "truncate":
        n = data.draw(st.integers(0, len(small_text) - 1))
        fuzz_file.write_text(small_text[:n])
    elif how == "garbage":
        fuzz_file.write_bytes(data.draw(st.binary(max_size=64)))
    else:
        doc = json.loads(small_text)
        mutate(doc, data, how)
        fuzz_file.write_text(json.dumps(doc))
    try:
        ann = HandPairAnnotation.load(fuzz_file)
    except AnnotationError as e:
        assert str(e)
        assert how != "truncate" or "not valid JSON" in str(e)
        return
    assert how in ("replace", "delete")
    assert HandPairAnnotation.from_dict(json.loads(json.dumps(ann.to_dict()))).to_dict() == ann.to_dict()


# ------------------------------------------------------------------------------------------ defaults


@pytest.mark.parametrize("kind, fingers, markers", [("human", 5, 19), ("witch", 5, 19), ("alien", 3, 13)])
def test_default_markers_follow_table_2(human, alien, same, to_alien, kind, fingers, markers):
    """Table 2: 19 virtual markers on the five-fingered hands, 13 on the three-fingered alien."""
    ann = {"human": same, "alien": to_alien}.get(kind) or annotate.default_annotation(human, make_hand(kind))
    assert len(ann.markers) == markers
    names = {m.name for m in ann.markers}
    target_fingers = [f for f in FINGERS if f"{f}_tip" in names]
    assert len(target_fingers) == fingers
    assert {"knuckle_radial", "knuckle_ulnar", "wrist_radial", "wrist_ulnar"} <= names
    for f in target_fingers:
        assert {f"{f}_joint1", f"{f}_joint2", f"{f}_tip"} <= names
    # The same kind gets 1:1 area markers, another kind the paper's single source point -> target area.
    kinds = {m.kind for m in ann.markers}
    assert kinds == ({"area"} if kind == "human" else {"many-to-one"})
    assert all(len(m.target) == annotate.MARKER_POINTS for m in ann.markers)


def test_default_curves_drop_the_fingers_the_target_lacks(to_alien, same):
    assert {c.name for c in same.curves} == {*FINGERS, "palm", "palm_across"}
    assert not any(c.dropped for c in same.curves)
    assert sorted(c.name for c in to_alien.curves if c.dropped) == ["pinky", "ring"]
    kept = {c.name for c in to_alien.curves if not c.dropped}
    assert kept == {"thumb", "index", "middle", "palm", "palm_across"}


@pytest.mark.parametrize("which, scale", [("same", 1.0), ("to_small", 0.75)])
def test_lambdas_are_the_scale_between_scaled_copies(request, which, scale):
    """λA (length ratio) and λS (girth ratio) of a hand and its copy at scale s are both exactly s."""
    ann = request.getfixturevalue(which)
    for c in ann.curves:
        assert c.axis_scale == pytest.approx(scale, rel=1e-12), c.name
        assert c.radial_scale == pytest.approx(scale, rel=1e-12), c.name
    assert ann.target.scale == pytest.approx(scale) and ann.source.scale == 1.0


def test_laid_out_curves_have_the_targets_lengths(human, alien, to_alien):
    """λA stretches each curve so that, laid out on the target, it is as long as the target's own curve."""
    transfer = ContactTransfer(to_alien, human.mesh, alien.mesh)
    target_curves = annotate.hand_curves(alien)
    for c in to_alien.curves:
        if c.dropped:
            assert c.name not in transfer.target_curves
            continue
        laid = transfer.target_curves[c.name]
        assert laid.length == pytest.approx(target_curves[c.name][0].length, rel=1e-6), c.name
        assert laid.length == pytest.approx(c.axis_scale * transfer.atlas.curves[c.name].length, rel=1e-9)


def test_same_kind_area_markers_sit_on_the_same_skin_spots(human, small_human, to_small):
    for m in to_small.markers:
        src = m.source.positions(human.mesh) * 0.75
        tgt = m.target.positions(small_human.mesh)
        assert np.abs(src - tgt).max() < 1e-4, m.name  # the nearest point on a re-triangulated copy


# ------------------------------------------------------------------------------------------ transfer


def _all_contacts(motion) -> SurfacePoints:
    return SurfacePoints(motion.hand_contacts.faces, motion.hand_contacts.bary)


def test_transfer_onto_the_same_hand_is_the_identity(human, same, motion):
    points = _all_contacts(motion)
    moved, kept = ContactTransfer(same, human.mesh, human.mesh).points(points)
    assert kept.all()
    err = np.linalg.norm(moved.positions(human.mesh) - points.positions(human.mesh), axis=1)
    # Exact but where the exact log map's shortest geodesic from a landmark passes a saddle vertex: the
    # exp map's straightest geodesic leaves such a vertex on one side (measured: 0.8% of the contacts,
    # at most 0.023 mm).
    assert np.mean(err < 1e-12) > 0.98
    assert err.max() < 5e-5


def test_transfer_onto_a_scaled_hand_scales_the_contacts(human, small_human, to_small, motion):
    points = _all_contacts(motion)
    moved, kept = ContactTransfer(to_small, human.mesh, small_human.mesh).points(points)
    assert kept.all()
    err = np.linalg.norm(moved.positions(small_human.mesh) - 0.75 * points.positions(human.mesh), axis=1)
    assert np.mean(err < 1e-12) > 0.98  # the rest: saddle vertices, as on the same hand
    assert err.max() < 0.75 * 5e-5


def test_transfer_to_the_alien_drops_ring_and_pinky(human, alien, to_alien, motion):
    points = _all_contacts(motion)
    transfer = ContactTransfer(to_alien, human.mesh, alien.mesh)
    moved, kept = transfer.points(points)
    chain = _chain(_owner_bone(human, points))
    lost = np.isin(chain, ["ring", "pinky"])
    assert lost.sum() > 1000 and (~lost).sum() > 1000  # both kinds are well represented
    np.testing.assert_array_equal(kept, ~lost)
    # The dropped ones are farther than ε_g from every remaining landmark, the kept ones nearer.
    coords = transfer.atlas.parameterize(points, list(transfer.target_curves))
    assert coords.distances[lost].min() > to_alien.threshold
    assert coords.distances[~lost].max() <= to_alien.threshold
    # Kept contacts land on the same finger (or the palm) of the alien.
    landed = _chain(_owner_bone(alien, moved))
    assert np.mean(landed == chain[kept]) > 0.95


def test_repeated_points_are_traced_once_and_each_frame_alone_agrees(human, alien, to_alien, motion):
    transfer = ContactTransfer(to_alien, human.mesh, alien.mesh)
    contacts = motion.hand_contacts
    bulk, kept = transfer.contacts(contacts)
    assert bulk.n_frames == contacts.n_frames
    for f in np.flatnonzero(contacts.count())[::5]:
        alone, kept_f = transfer.points(contacts.frame(f))
        np.testing.assert_array_equal(kept_f, kept[contacts.offsets[f] : contacts.offsets[f + 1]])
        np.testing.assert_array_equal(bulk.frame(f).faces, alone.faces)
        np.testing.assert_allclose(bulk.frame(f).bary, alone.bary, rtol=0, atol=1e-12)


def test_transfer_motion_keeps_object_contacts_paired(human, alien, to_alien, motion):
    calls = []
    out = transfer.transfer_motion(motion, to_alien, alien.mesh, progress=lambda *a: calls.append(a))
    assert calls == [(0, 1), (1, 1)]
    K = len(motion.hand_contacts)
    assert out.kept.shape == (K,) and out.kept.dtype == bool and 0 < out.kept.sum() < K
    np.testing.assert_array_equal(out.hand_contacts.offsets, out.object_contacts.offsets)
    frame = motion.hand_contacts.frame_index()
    np.testing.assert_array_equal(
        out.hand_contacts.count(), np.bincount(frame[out.kept], minlength=motion.n_frames)
    )
    np.testing.assert_array_equal(out.object_contacts.faces, motion.object_contacts.faces[out.kept])
    np.testing.assert_array_equal(out.object_contacts.bary, motion.object_contacts.bary[out.kept])
    # keep_rows is what pairs them, and refuses a mask of another length.
    with pytest.raises(AnnotationError, match="one flag per contact"):
        transfer.keep_rows(motion.object_contacts, out.kept[:-1])
    without = dataclasses.replace(motion, hand_contacts=None, object_contacts=None)
    with pytest.raises(AnnotationError, match="no hand contacts"):
        transfer.transfer_motion(without, to_alien, alien.mesh)


def test_empty_contacts_transfer_to_nothing(human, alien, to_alien):
    transfer = ContactTransfer(to_alien, human.mesh, alien.mesh)
    moved, kept = transfer.points(SurfacePoints(np.empty(0, np.int64), np.empty((0, 3))))
    assert len(moved) == 0 and kept.shape == (0,)
    moved, kept = transfer.contacts(Contacts([0, 0, 0], np.empty(0, np.int64), np.empty((0, 3))))
    assert moved.n_frames == 2 and len(moved) == 0


# ------------------------------------------------------------------------------------------ markers


def _marker_annotation(human) -> HandPairAnnotation:
    ref = HandRef.of(human.mesh, "human", 1.0)
    sp = SurfacePoints
    rng = np.random.default_rng(4)

    def random_points(k):
        return sp(rng.integers(0, human.mesh.n_faces, k), rng.dirichlet([1.0, 1.0, 1.0], k))

    return HandPairAnnotation(
        ref,
        ref,
        (CurveAnnotation("c", sp([0, 1], [[1, 0, 0], [1, 0, 0]]), sp([0], [[1, 0, 0]])),),
        (
            MarkerAnnotation("single", random_points(1), random_points(1)),
            MarkerAnnotation("many", random_points(1), random_points(4)),
            MarkerAnnotation("area", random_points(3), random_points(3)),
            MarkerAnnotation("centroid", random_points(3), random_points(1)),
        ),
    )


def _positions_by_hand(mesh_faces, V, points: SurfacePoints) -> np.ndarray:
    out = np.zeros((len(points), 3))
    for i in range(len(points)):
        for j in range(3):
            out[i] += points.bary[i, j] * V[mesh_faces[points.faces[i], j]]
    return out


def test_marker_targets_match_a_hand_computed_oracle(human):
    ann = _marker_annotation(human)
    assert [m.kind for m in ann.markers] == ["single", "many-to-one", "area", "one-to-many"]
    rng = np.random.default_rng(5)
    theta = human.rig.clip(human.rig.rest + rng.normal(scale=0.2, size=human.rig.n_dofs))
    V = human.posed_vertices(theta)
    pairs = ann.marker_pairs()
    assert pairs.names == ("single", "many", "area", "centroid")
    np.testing.assert_array_equal(pairs.marker, [0, 1, 1, 1, 1, 2, 2, 2, 3])
    S = [_positions_by_hand(human.mesh.faces, V, m.source) for m in ann.markers]
    expected = np.vstack([S[0], np.repeat(S[1], 4, axis=0), S[2], S[3].mean(0, keepdims=True)])
    got = pairs.targets(human.mesh, V)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-14)
    # Several frames at once give each frame's targets (one sparse product for all of them).
    frames = np.stack([V, human.posed_vertices(human.rig.rest), V[::-1]])
    batched = pairs.targets(human.mesh, frames)
    assert batched.shape == (3, *got.shape)
    for f in range(3):
        np.testing.assert_allclose(batched[f], pairs.targets(human.mesh, frames[f]), rtol=0, atol=1e-15)
    # A subset keeps its markers' rows, in the annotation's order, and its own source points only.
    sub = pairs.subset(["centroid", "many"])
    assert sub.names == ("centroid", "many") and len(sub.source) == 4
    np.testing.assert_array_equal(sub.marker, [1, 1, 1, 1, 0])
    np.testing.assert_allclose(sub.targets(human.mesh, V), expected[[1, 2, 3, 4, 8]], rtol=0, atol=1e-14)
    with pytest.raises(AnnotationError, match="no markers named thumb"):
        pairs.subset(["thumb"])
    with pytest.raises(AnnotationError, match=r"shape \(3746, 3\)"):
        pairs.targets(human.mesh, V[:-1])


def test_default_many_to_one_markers_track_one_source_vertex(human, to_alien, motion):
    pairs = to_alien.marker_pairs()
    V = motion.hand_vertices[20]
    got = pairs.targets(human.mesh, V)
    start = 0
    for m in to_alien.markers:
        (vertex,) = human.mesh.faces[m.source.faces[0]][m.source.bary[0] > 0.5]
        np.testing.assert_allclose(got[start : start + len(m.target)], np.tile(V[vertex], (len(m.target), 1)))
        start += len(m.target)
    assert start == len(got) == 13 * annotate.MARKER_POINTS


def test_the_procedural_hands_are_made_one_per_call_ahead_of_the_first_check(monkeypatch):
    """What procedural_kind compares with can be made ahead, one kind of hand per call (the add-on's
    timer ticks do it after start-up); made, a check makes no hand at all. Unmade, a check makes only the
    kinds it compares before it finds its own."""
    made = []

    def counted(kind, *args):
        made.append(kind)
        return make_hand(kind, *args)

    monkeypatch.setattr(annotate, "make_hand", counted)
    monkeypatch.setattr(annotate, "_TOPOLOGIES", {})
    human = make_hand("human").mesh
    assert annotate.procedural_kind(human) == "human" and made == ["human"]
    calls = []
    while not calls or calls[-1]:
        calls.append(annotate.make_next_procedural_topology())
    assert calls == [True] * (len(KINDS) - 2) + [False] and made == list(KINDS)
    assert annotate.procedural_kind(make_hand("tentacle").mesh) == "tentacle"
    assert annotate.procedural_kind(TriMesh(human.vertices, human.faces[:, ::-1])) is None
    assert made == list(KINDS) and annotate.make_next_procedural_topology() is False


@pytest.mark.parametrize("kind", ["human", "alien", "tentacle"])
def test_procedural_hand_knows_a_kind_by_its_topology_at_any_size(kind):
    """A procedural hand's mesh moved, turned and scaled (as a Blender scene holds it) is that kind, at
    its size; the same faces mirrored (reversed triangles) or any other mesh are none."""
    hand = make_hand(kind)
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    moved = TriMesh(1.7 * hand.mesh.vertices @ turn.T + [0.3, -2.0, 1.0], hand.mesh.faces)
    found = annotate.procedural_hand(moved)
    assert found.kind == annotate.procedural_kind(moved) == kind
    assert found.length == pytest.approx(1.7 * hand.length, rel=1e-12)
    assert found.mesh.topology_hash == hand.mesh.topology_hash
    assert annotate.procedural_hand(TriMesh(hand.mesh.vertices, hand.mesh.faces[:, ::-1])) is None
    assert annotate.procedural_hand(make_hand("witch" if kind == "human" else "human").mesh).kind != kind
