"""The retargeting authors' surface-point strings (``v``/``e``/``f``) in geometry-central's numbering:
edge numbers equal potpourri3d's (geometry-central's own) edge list, hand-worked golden strings on an
octahedron, exact round trips, the authors' six-decimal output, and errors naming the entry."""

import numpy as np
import potpourri3d as pp3d
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from geodesics import MeshError, SurfacePoints, TriMesh
from geodesics.point_strings import GeometryCentralIndex, format_points, parse_points
from geodesics.primitives import cylinder, grid_plane, icosphere, torus
from solver import objects
from solver.hands import make_hand

#: +x, +y, -x, -y, +z, -z; faces counter-clockwise seen from outside.
OCTA_VERTICES = np.array([[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
OCTA_FACES = np.array(
    [[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4], [1, 0, 5], [2, 1, 5], [3, 2, 5], [0, 3, 5]]
)
#: Edges in the order geometry-central creates them from OCTA_FACES, worked by hand: each face's
#: halfedges in turn, a new edge whenever the reverse halfedge has not been met.
OCTA_EDGES = [(0, 1), (1, 4), (4, 0), (1, 2), (2, 4), (2, 3), (3, 4), (3, 0), (0, 5), (5, 1), (5, 2), (5, 3)]


@pytest.fixture(scope="module")
def octa():
    return TriMesh(OCTA_VERTICES, OCTA_FACES)


@pytest.mark.parametrize(
    "make",
    [
        lambda: TriMesh(OCTA_VERTICES, OCTA_FACES),
        lambda: torus(n_major=12, n_minor=8),
        lambda: icosphere(2),
        lambda: grid_plane(5, 4, jitter=0.2, seed=3),  # boundary edges
        lambda: cylinder(n_around=10, n_along=3),  # open tube: two boundary loops
        lambda: objects.mug(),
        lambda: make_hand("human").mesh,
    ],
)
def test_edge_numbering_is_geometry_centrals(make):
    mesh = make()
    index = GeometryCentralIndex(mesh)
    assert np.array_equal(index.edges, pp3d.edges(mesh.vertices, mesh.faces))
    assert index.n_edges == mesh.n_edges


def test_octahedron_edges_worked_by_hand(octa):
    assert GeometryCentralIndex(octa).edges.tolist() == [list(e) for e in OCTA_EDGES]


def test_golden_strings_on_the_octahedron(octa):
    points = parse_points(octa, ["v 4", "e 3 0.25", "e 11 0", "f 6 0.2 0.3 0.5", "e 0 0.5"])
    expected = [
        [0, 0, 1],
        0.75 * OCTA_VERTICES[1] + 0.25 * OCTA_VERTICES[2],  # edge 3 runs from vertex 1 to 2
        OCTA_VERTICES[5],  # edge 11 starts at vertex 5
        0.2 * OCTA_VERTICES[3] + 0.3 * OCTA_VERTICES[2] + 0.5 * OCTA_VERTICES[5],
        [0.5, 0.5, 0],
    ]
    np.testing.assert_allclose(points.positions(octa), expected, atol=1e-15)
    assert format_points(octa, points) == ["v 4", "e 3 0.25", "v 5", "f 6 0.2 0.3 0.5", "e 0 0.5"]


def test_edge_points_written_from_either_face(octa):
    """A point on edge 1 (1 → 4) expressed in face 0 (where it runs 1 → 4) and in face 1 (4 → 1)."""
    points = SurfacePoints([0, 1], [[0, 0.7, 0.3], [0.7, 0, 0.3]])  # 0.7·v1 + 0.3·v4 both times
    assert format_points(octa, points) == ["e 1 0.3", "e 1 0.3"]


def test_stripped_vertices_shift_later_indices():
    """geometry-central strips vertices no face uses, so later vertices move down (the plugin's
    loadMeshFromExplicitGeometry calls stripUnusedVertices)."""
    V = np.vstack([OCTA_VERTICES[:2], [[9, 9, 9]], OCTA_VERTICES[2:]])
    F = np.where(OCTA_FACES >= 2, OCTA_FACES + 1, OCTA_FACES)
    with pytest.warns(Warning):
        mesh = TriMesh(V, F)
    index = GeometryCentralIndex(mesh)
    assert index.vertex.tolist() == [0, 1, -1, 2, 3, 4, 5]
    assert index.edges.tolist() == [list(e) for e in OCTA_EDGES]
    assert format_points(mesh, SurfacePoints.from_vertices(mesh, [6])) == ["v 5"]
    np.testing.assert_array_equal(parse_points(mesh, ["v 5"]).positions(mesh), [[0, 0, -1]])


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), kind=st.sampled_from(["vertex", "edge", "face"]))
def test_round_trip_is_exact(seed, kind):
    mesh = torus(n_major=12, n_minor=8)
    rng = np.random.default_rng(seed)
    k = 20
    faces = rng.integers(0, mesh.n_faces, k)
    bary = rng.dirichlet([1, 1, 1], k)
    if kind == "vertex":
        bary = np.eye(3)[rng.integers(0, 3, k)]
    elif kind == "edge":
        bary[np.arange(k), rng.integers(0, 3, k)] = 0
        bary /= bary.sum(1, keepdims=True)
    points = SurfacePoints(faces, bary)
    strings = format_points(mesh, points)
    assert {s[0] for s in strings} == {kind[0]}
    back = parse_points(mesh, strings)
    np.testing.assert_allclose(back.positions(mesh), points.positions(mesh), rtol=0, atol=1e-15)
    if kind == "face":
        assert np.array_equal(back.faces, points.faces) and np.array_equal(back.bary, points.bary)
    assert format_points(mesh, back) == strings


def test_the_authors_six_decimals_are_read_and_renormalized(octa):
    p = parse_points(octa, ["f 2 0.333333 0.333333 0.333333", "e 4 0.123457"])
    assert np.allclose(p.bary.sum(1), 1, atol=1e-15)
    np.testing.assert_allclose(p.bary[0], [1 / 3] * 3)


@pytest.mark.parametrize(
    "entry, message",
    [
        ("x 1", "should start with 'v', 'e' or 'f'"),
        ("", "should start with"),
        ("v", "should be 'v' and 1 number"),
        ("v 1 2", "should be 'v' and 1 number"),
        ("f 1 0.5 0.5", "should be 'f' and 4 numbers"),
        ("e 1 half", "should be 'e' and 2 numbers"),
        ("v 1.5", "not an integer"),
        ("v -1", "a vertex the mesh does not have (it has 6 vertices)"),
        ("e 12 0.5", "an edge the mesh does not have (it has 12 edges)"),
        ("f 8 0.2 0.3 0.5", "a face the mesh does not have (it has 8 faces)"),
        ("e 1 1.5", "t outside [0, 1]"),
        ("e 1 nan", "t outside [0, 1]"),
        ("f 1 0.5 0.5 0.5", "not summing to one"),
        ("f 1 -0.5 0.5 1.0", "below zero"),
        ("vx 1", "should be 'v' and 1 number"),
    ],
)
def test_bad_strings_name_the_entry(octa, entry, message):
    with pytest.raises(MeshError, match="frame 3's contacts: entry 1") as err:
        parse_points(octa, ["v 0", entry, "v 2"], where="frame 3's contacts")
    assert message in str(err.value)


def test_a_non_string_entry_is_named(octa):
    with pytest.raises(MeshError, match="entry 0 is int 3, not a point string"):
        parse_points(octa, [3])


@settings(max_examples=200, deadline=None)
@given(st.lists(st.text(alphabet="vef 0123456789.-e+naix", max_size=14), max_size=6))
def test_parser_raises_only_its_own_error(strings):
    mesh = TriMesh(OCTA_VERTICES, OCTA_FACES)
    try:
        points = parse_points(mesh, strings)
    except MeshError:
        return
    assert len(points) == len(strings)
