"""Contact sets: hierarchy (§4.3.4), hierarchical transfer, pairing, and the JSON contact file."""

import json

import numpy as np
import pytest

from geodesics import (
    ContactError,
    ContactPatch,
    ContactSet,
    SurfacePoints,
    TriMesh,
    directed_axis,
    farthest_pair_axis,
    log_map,
    medial_axis,
)
from geodesics.default_axes import _boundary_vertices, _graph_sweeps
from geodesics.primitives import cylinder, grid_plane


def nearest(mesh, xyz):
    return SurfacePoints.nearest(mesh, np.atleast_2d(xyz))


def disk(mesh, centre, radius, n, seed):
    rng = np.random.default_rng(seed)
    points = SurfacePoints(rng.integers(0, mesh.n_faces, 80 * n), rng.dirichlet([2.0, 2.0, 2.0], 80 * n))
    X = points.positions(mesh)
    return points[np.flatnonzero(np.linalg.norm(X[:, :2] - centre, axis=1) < radius)[:n]]


@pytest.fixture(scope="module")
def plane():
    return grid_plane(40, 40, size=(2.0, 2.0), jitter=0.2, seed=11)


@pytest.fixture(scope="module")
def hand(plane):
    """A palm with two finger-tip patches parented to it, and a nail patch under one tip."""
    s = ContactSet(plane)
    for name, centre, radius in (
        ("palm", [0.8, 0.8], 0.2),
        ("index", [1.15, 0.7], 0.07),
        ("thumb", [0.6, 1.1], 0.07),
    ):
        points = disk(plane, centre, radius, 300, seed=len(name))
        s = s.add(name, ContactPatch(plane, points, farthest_pair_axis(plane, points)))
    points = disk(plane, [1.25, 0.75], 0.03, 60, seed=99)
    s = s.add("nail", ContactPatch(plane, points, farthest_pair_axis(plane, points)))
    return s.parent("index", "palm").parent("thumb", "palm").parent("nail", "index")


def test_editing_a_parent_carries_its_children_rigidly_on_a_plane(hand, plane):
    moved = hand.translate("palm", nearest(plane, [1.0, 1.05, 0]))
    shift = moved["palm"].positions() - hand["palm"].positions()
    for name in ("index", "thumb", "nail"):
        delta = moved[name].positions() - hand[name].positions()
        np.testing.assert_allclose(delta, np.broadcast_to(shift[0], delta.shape), atol=1e-12)
    turned = hand.rotate("palm", 0.5)
    o = hand["palm"].axis.start.positions(plane)[0]
    for name in ("palm", "index", "nail"):
        rel0 = (hand[name].positions() - o)[:, :2] @ [1, 1j]
        rel1 = (turned[name].positions() - o)[:, :2] @ [1, 1j]
        np.testing.assert_allclose(rel1, rel0 * np.exp(0.5j), atol=1e-12)


def test_links_keep_their_geodesic_length(hand):
    edited = hand.rotate("palm", 1.1).bend("index", 2, 0.3)
    for child, link in hand.links.items():
        start_parent, start_child = edited[link.parent].axis.start, edited[child].axis.start
        assert abs(log_map(edited.mesh, start_parent, start_child)[0]) == pytest.approx(
            link.length, rel=1e-12
        )


def test_editing_a_child_leaves_parent_and_siblings(hand):
    edited = hand.rotate("index", 0.7)
    for name in ("palm", "thumb"):
        np.testing.assert_array_equal(edited[name].positions(), hand[name].positions())
    assert not np.allclose(edited["nail"].positions(), hand["nail"].positions())


def test_hierarchy_rules(hand):
    with pytest.raises(ContactError, match="cycle"):
        hand.parent("palm", "nail")
    with pytest.raises(ContactError, match="already exists"):
        hand.add("palm", hand["palm"])
    with pytest.raises(ContactError, match="no patch named 'ring'"):
        hand.rotate("ring", 0.1)
    without = hand.remove("index")
    assert "nail" in without and "nail" not in without.links  # children stay, unlinked
    assert hand.descendants("palm") == ["index", "nail", "thumb"]
    assert set(hand.unparent("thumb").links) == {"index", "nail"}


def test_hierarchical_transfer_pairs_and_keeps_the_arrangement(hand):
    prism = cylinder(radius=0.9, height=3.0, n_around=40, n_along=40, jitter=0.2, seed=3)
    start = nearest(prism, [0.9 * np.cos(0.05), 0.9 * np.sin(0.05), 1.5])
    source, target = hand.transfer("palm", ContactSet(prism), start, 1j, rename=lambda n: f"{n}@mug")
    assert set(target) == {"palm@mug", "index@mug", "thumb@mug", "nail@mug"}
    assert source.pairs["index"] == "index@mug" and target.pairs["index@mug"] == "index"
    assert target.links["nail@mug"].parent == "index@mug"
    for child, link in hand.links.items():
        parent_start = target[f"{link.parent}@mug"].axis.start
        got = abs(log_map(prism, parent_start, target[f"{child}@mug"].axis.start)[0])
        assert got == pytest.approx(link.length, rel=1e-9)  # the prism is developable
    # editing the transferred tree carries its children there too
    moved = target.rotate("palm@mug", 0.3)
    assert not np.allclose(moved["nail@mug"].positions(), target["nail@mug"].positions())
    with pytest.raises(ContactError, match="already has"):
        hand.transfer("palm", target, start, 1j, rename=lambda n: f"{n}@mug")


@pytest.mark.parametrize("mirror", [True, False])
def test_a_transfer_between_units_keeps_true_size_and_chosen_handedness(hand, plane, mirror):
    """Onto the same plane in other units (three target lengths per hand length, as a hand in metres
    onto a prop in other units), the whole hierarchy lands as the hand's layout scaled by exactly 3:
    mirrored (w = c z̄ + t) by default, unmirrored (w = c z + t) with ``mirror=False``, |c| = 3."""
    big = TriMesh(plane.vertices * 3.0, plane.faces)
    start = nearest(big, 3.0 * hand["palm"].axis.start.positions(plane)[0])
    _, target = hand.transfer("palm", ContactSet(big), start, 1.0, scale=3.0, mirror=mirror)
    names = ["palm", "index", "thumb", "nail"]
    z = np.concatenate([hand[n].positions()[:, :2] @ [1, 1j] for n in names])
    w = np.concatenate([target[n].positions()[:, :2] @ [1, 1j] for n in names])
    A = np.c_[np.conj(z) if mirror else z, np.ones_like(z)]
    fit = np.linalg.lstsq(A, w, rcond=None)[0]
    np.testing.assert_allclose(A @ fit, w, atol=1e-9)
    assert abs(fit[0]) == pytest.approx(3.0, rel=1e-9)
    for child, link in target.links.items():
        got = abs(log_map(big, target[link.parent].axis.start, target[child].axis.start)[0])
        assert got == pytest.approx(3.0 * hand.links[child].length, rel=1e-9)
    with pytest.raises(ContactError, match="scale"):
        hand.transfer("palm", ContactSet(big), start, 1.0, scale=0.0)


def test_rename_keeps_order_links_pairs_and_edits(hand):
    """Renamed, a patch keeps its place in the order, its children follow it under the new name, its pair
    stays; the renamed set edits as the old one did; a clash or an empty name is refused, naming it."""
    paired = hand.pair("palm", "palm@mug")
    renamed = paired.rename("palm", "heel")
    assert list(renamed) == ["heel" if n == "palm" else n for n in paired]
    assert {c: link.parent for c, link in renamed.links.items()} == {
        c: ("heel" if link.parent == "palm" else link.parent) for c, link in paired.links.items()
    }
    assert dict(renamed.pairs) == {"heel": "palm@mug"}
    np.testing.assert_array_equal(
        renamed.rotate("heel", 0.4)["nail"].positions(), paired.rotate("palm", 0.4)["nail"].positions()
    )
    with pytest.raises(ContactError, match="a patch named 'nail' already exists"):
        paired.rename("palm", "nail")
    with pytest.raises(ContactError, match="non-empty"):
        paired.rename("palm", "")
    assert list(paired.rename("palm", "palm")) == list(paired)


def test_file_round_trip(hand, tmp_path):
    path = tmp_path / "hand.json"
    paired = hand.pair("palm", "palm@mug")
    paired.save(path)
    loaded = ContactSet.load(path, hand.mesh)
    assert list(loaded) == list(paired) and dict(loaded.pairs) == dict(paired.pairs)
    for name in paired:
        np.testing.assert_array_equal(loaded[name].points.faces, paired[name].points.faces)
        np.testing.assert_allclose(loaded[name].positions(), paired[name].positions(), atol=1e-15)
        np.testing.assert_allclose(loaded[name].coords, paired[name].coords, atol=1e-15)
    np.testing.assert_allclose(
        loaded.rotate("palm", 0.4)["nail"].positions(),
        paired.rotate("palm", 0.4)["nail"].positions(),
        atol=1e-12,
    )
    assert [p.name for p in tmp_path.iterdir()] == ["hand.json"]  # no temporary file left behind


def test_files_for_another_mesh_are_refused_unless_remapped(hand, tmp_path):
    path = tmp_path / "hand.json"
    hand.save(path)
    other = grid_plane(37, 33, size=(2.0, 2.0), jitter=0.2, seed=12)  # the same plane, meshed differently
    with pytest.raises(ContactError, match=r"another mesh.*remap"):
        ContactSet.load(path, other)
    remapped = ContactSet.load(path, other, remap=True)
    for name in hand:
        np.testing.assert_allclose(remapped[name].positions(), hand[name].positions(), atol=1e-12)
    assert remapped.links["nail"].length == pytest.approx(hand.links["nail"].length, rel=1e-9)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d.update(format="something else"), "not a contact file"),
        (lambda d: d.update(version=99), "version 99 is not supported"),
        (lambda d: d.pop("patches"), "patches is missing"),
        (
            lambda d: d["patches"][0].update(points={"faces": [10**9], "bary": [[1, 0, 0]]}),
            "patch 'palm'.*faces",
        ),
        (
            lambda d: d["patches"][0].update(points={"faces": [0], "bary": [[0.5, 0.6, 0.1]]}),
            "patch 'palm'.*sum",
        ),
        (lambda d: d["patches"][0]["axis"].update(lengths=[-1.0]), "patch 'palm'.*lengths"),
        (lambda d: d["patches"][0].update(binding=[0] * 3), "patch 'palm'.*binding"),
        (lambda d: d["patches"][1].update(parent="wrist"), "parent 'wrist'"),
        (lambda d: d["patches"][1].update(name="palm"), "used twice"),
        (lambda d: d["patches"][0]["axis"].update(turning=[[2.0, 0.0]]), "patch 'palm'"),
        (lambda d: d["patches"][1].update(link={"length": "far"}), "link.length"),
        # A float or a boolean where an index or the version belongs is an error, not truncated.
        (lambda d: d.update(version=True), "version True is not supported"),
        (
            lambda d: d["patches"][0].update(points={"faces": [1.5], "bary": [[1, 0, 0]]}),
            "patch 'palm'.*points.faces must be a list of integer indices",
        ),
        (
            lambda d: d["patches"][0].update(points={"faces": [True], "bary": [[1, 0, 0]]}),
            "points.faces must be a list of integer indices",
        ),
        (lambda d: d["patches"][0].update(binding=[0.5] * 3), "binding must be a list of integer indices"),
        (lambda d: d["patches"][0].pop("binding"), "patch 'palm'.binding is missing"),
    ],
)
def test_malformed_files_get_clear_errors(hand, tmp_path, change, message):
    data = hand.to_dict()
    change(data)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ContactError, match=message):
        ContactSet.load(path, hand.mesh)


def test_unreadable_files_get_clear_errors(hand, tmp_path):
    with pytest.raises(ContactError, match="cannot read"):
        ContactSet.load(tmp_path / "missing.json", hand.mesh)
    garbage = tmp_path / "garbage.json"
    garbage.write_bytes(b"\x00\xff{not json")
    with pytest.raises(ContactError, match="cannot read"):
        ContactSet.load(garbage, hand.mesh)


# ------------------------------------------------------------------------------------------ default axes


def test_farthest_pair_axis_joins_the_diameter(plane):
    rng = np.random.default_rng(5)
    pool = SurfacePoints(rng.integers(0, plane.n_faces, 40000), rng.dirichlet([2.0, 2.0, 2.0], 40000))
    X = pool.positions(plane)
    ellipse = ((X[:, 0] - 1.0) / 0.45) ** 2 + ((X[:, 1] - 1.0) / 0.12) ** 2 < 1  # a well-defined diameter
    for inside, tolerance in ((ellipse, 1e-12), (np.linalg.norm(X[:, :2] - 1.0, axis=1) < 0.3, 0.02)):
        points = pool[np.flatnonzero(inside)[:400]]
        P = points.positions(plane)
        diameter = np.linalg.norm(P[:, None] - P[None], axis=2).max()
        axis = farthest_pair_axis(plane, points)
        assert axis.length == pytest.approx(diameter, rel=tolerance)  # near-diametral on a disk
        ends = axis.points[[0, len(axis) - 1]].positions(plane)
        assert np.min(np.linalg.norm(P[:, None] - ends[None], axis=2), axis=0).max() < 1e-12


def test_the_farthest_pair_estimate_bounds_the_geodesic_distance(plane):
    """The edge-graph sweep the farthest-pair search runs on is never shorter than the geodesic (here the
    straight line: the plane is flat), and not far over it."""
    rng = np.random.default_rng(6)
    points = SurfacePoints(rng.integers(0, plane.n_faces, 300), rng.dirichlet([1.0, 1.0, 1.0], 300))
    estimate = _graph_sweeps(plane, points)([0, 5])
    P = points.positions(plane)
    straight = np.linalg.norm(P[[0, 5]][:, None] - P[None], axis=2)
    assert np.all(estimate >= straight - 1e-12)
    ratio = estimate[straight > 0.1] / straight[straight > 0.1]
    assert np.median(ratio) < 1.15 and ratio.max() < 1.5  # measured 1.08 and 1.33 on this jittered grid


def test_sweeps_stopped_at_twice_the_farthest_distance_from_one_point_miss_no_pair(plane):
    """The farthest-pair search stops its later sweeps at twice the farthest distance from patch point 0
    (every pair is joined through point 0 within it): every pair's distance is the unstopped sweep's, on
    a patch a fraction of the mesh, where the stopped sweeps skip most of it."""
    rng = np.random.default_rng(7)
    pool = SurfacePoints(rng.integers(0, plane.n_faces, 20000), rng.dirichlet([1.0, 1.0, 1.0], 20000))
    X = pool.positions(plane)
    points = pool[np.flatnonzero(np.linalg.norm(X[:, :2] - [0.6, 1.3], axis=1) < 0.25)[:300]]
    sweep = _graph_sweeps(plane, points)
    everything = sweep(np.arange(len(points)))
    limit = 2 * everything[0].max() * (1 + 1e-9)
    np.testing.assert_array_equal(sweep(np.arange(len(points)), limit), everything)
    assert np.isinf(sweep(np.arange(len(points)), limit / 2)).any()  # half of it loses pairs


@pytest.mark.parametrize("seed", range(11, 17))
def test_medial_axis_of_a_strip_runs_along_its_middle(seed):
    """The 1.4 × 0.4 strip's medial axis is the segment y = 1, 0.5 ≤ x ≤ 1.5 (plus spurs to its corners,
    which the smoothing removes): the axis lies on it, covers most of it, and passes along it once."""
    plane = grid_plane(40, 40, size=(2.0, 2.0), jitter=0.2, seed=seed)
    V = plane.vertices
    strip = np.flatnonzero((V[:, 0] > 0.3) & (V[:, 0] < 1.7) & (V[:, 1] > 0.8) & (V[:, 1] < 1.2))
    axis = medial_axis(plane, SurfacePoints.from_vertices(plane, strip))
    X = axis.points.positions(plane)
    assert np.abs(X[:, 1] - 1.0).max() < 1.5 * plane.mean_edge_length  # measured ≤ 0.057 = 1.1 edges
    assert 0.45 < X[:, 0].min() < 0.62 and 1.38 < X[:, 0].max() < 1.55  # measured 0.505..0.597, 1.407..1.508
    assert np.all(np.diff(X[:, 0]) > 0) or np.all(np.diff(X[:, 0]) < 0)  # one pass along the strip


@pytest.fixture(scope="module")
def human():
    from solver.hands import make_hand

    return make_hand("human")


def pad(human, *bones):
    """The vertices of the palm-side faces of the given bones, as patch points."""
    faces = np.concatenate([human.palmar_faces(human.rig.names.index(b)) for b in bones])
    return SurfacePoints.from_vertices(human.mesh, np.unique(human.mesh.faces[faces]))


def test_medial_axis_of_a_fingertip_pad_is_its_short_middle_not_the_farthest_pair(human):
    """A fingertip pad (78 vertices, about 18 × 16 mm) is nearly round, so its medial axis is short and
    central (a disc's is its centre); it used to fall back to the 25 mm farthest pair."""
    points = pad(human, "index_3")
    axis, farthest = medial_axis(human.mesh, points), farthest_pair_axis(human.mesh, points)
    assert len(axis) >= 2 and axis.length < 0.4 * farthest.length  # measured 4.3 against 24.9 mm
    X = axis.points.positions(human.mesh)
    region = human.mesh.faces[human.palmar_faces(human.rig.names.index("index_3"))]
    rim = human.mesh.vertices[np.unique(_boundary_vertices(region))]
    from_rim = np.linalg.norm(X[:, None] - rim[None], axis=2).min(1)
    assert from_rim.min() > 0.15 * farthest.length  # inside, a pad edge or more from the rim: measured 4.9 mm


def test_medial_axis_of_a_two_phalanx_pad_runs_along_the_finger(human):
    points = pad(human, "index_2", "index_3")
    axis, farthest = medial_axis(human.mesh, points), farthest_pair_axis(human.mesh, points)
    X = axis.points.positions(human.mesh)
    along = human.rig.matrix_local[human.rig.names.index("index_3"), :3, 1]  # the bone's length axis
    chord = X[-1] - X[0]
    assert abs(chord @ along) > 0.95 * np.linalg.norm(chord)  # measured 0.99
    assert 0.25 * farthest.length < axis.length < 0.75 * farthest.length  # measured 18.9 of 45.3 mm


def test_a_directed_axis_runs_through_the_centroid_across_the_patchs_extent(plane):
    """On the plane the geodesic is the straight segment through the patch's centroid along the direction,
    from its lowest extent along it to its highest, whatever the patch's own diameter (here the
    ellipse's, across the direction)."""
    rng = np.random.default_rng(8)
    pool = SurfacePoints(rng.integers(0, plane.n_faces, 40000), rng.dirichlet([2.0, 2.0, 2.0], 40000))
    X = pool.positions(plane)
    points = pool[np.flatnonzero(((X[:, 0] - 1.0) / 0.12) ** 2 + ((X[:, 1] - 1.0) / 0.45) ** 2 < 1)[:400]]
    P = points.positions(plane)
    axis = directed_axis(plane, points, [1.0, 0.0, 0.7])  # its part along the plane's normal is dropped
    ends = axis.points[[0, len(axis) - 1]].positions(plane)
    centre = P.mean(axis=0)
    np.testing.assert_allclose(
        ends, [[P[:, 0].min(), centre[1], 0], [P[:, 0].max(), centre[1], 0]], atol=1e-12
    )
    assert axis.length == pytest.approx(np.linalg.norm(ends[1] - ends[0]), rel=1e-12)
    assert axis.length < 0.4 * farthest_pair_axis(plane, points).length  # across the ellipse, not along


def test_a_fingertip_pads_axis_along_its_bone_runs_along_the_finger(human):
    """A fingertip pad is nearly round, so its farthest pair lies anywhere around its rim; along the
    bone its axis runs from the pad's back to the tip."""
    points = pad(human, "middle_3")
    along = human.rig.matrix_local[human.rig.names.index("middle_3"), :3, 1]
    X = directed_axis(human.mesh, points, along).points.positions(human.mesh)
    chord = X[-1] - X[0]
    assert chord @ along > 0.95 * np.linalg.norm(chord)


@pytest.mark.parametrize(
    "direction, message",
    [
        ([0.0, 0.0, 0.0], "must be a finite, non-zero 3-vector"),
        ([np.nan, 1.0, 0.0], "must be a finite, non-zero 3-vector"),
        ([1.0, 0.0], "must be a finite, non-zero 3-vector"),
        ([0.0, 0.0, -2.0], "is the patch's normal"),
    ],
)
def test_a_directed_axis_needs_a_direction_along_the_patch(plane, direction, message):
    points = disk(plane, [1.0, 1.0], 0.1, 50, seed=3)
    with pytest.raises(ContactError, match=message):
        directed_axis(plane, points, direction)


def test_transfer_without_the_hierarchy_moves_one_patch(hand):
    prism = cylinder(radius=0.9, height=3.0, n_around=40, n_along=40, jitter=0.2, seed=3)
    start = nearest(prism, [0.9 * np.cos(0.05), 0.9 * np.sin(0.05), 1.5])
    source, target = hand.transfer("palm", ContactSet(prism), start, 1j, hierarchy=False)
    assert list(target) == ["palm"] and dict(source.pairs) == {"palm": "palm"}
    assert dict(source.links) == dict(hand.links)
