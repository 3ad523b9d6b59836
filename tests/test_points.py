"""SurfacePoints: validation, snapping onto vertices and edges, construction from vertices and from 3D
positions (with clamping onto the triangle), face-frame coordinates, indexing and concatenation."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from geodesics.errors import MeshError
from geodesics.mesh import TriMesh
from geodesics.points import SNAP, SurfacePoints
from geodesics.primitives import icosphere, torus

SETTINGS = settings(max_examples=60, deadline=None, derandomize=True, database=None)
SPHERE = icosphere(2)


def random_points(mesh, k, seed):
    rng = np.random.default_rng(seed)
    faces = rng.integers(0, mesh.n_faces, k)
    bary = rng.dirichlet(np.ones(3), k)
    return faces, bary


def to3d(mesh, faces, z):
    axes = mesh.face_axes(faces)
    return mesh.vertices[mesh.faces[faces, 0]] + z.real[:, None] * axes[:, 0] + z.imag[:, None] * axes[:, 1]


def closest_point_on_triangle(x, A, B, C):
    """Independent 3D closest point: the projection if inside, else the closest point on an edge."""
    n = np.cross(B - A, C - A)
    n /= np.linalg.norm(n)
    p = x - n * np.dot(x - A, n)
    inside = all(np.dot(np.cross(Q - P, p - P), n) >= 0 for P, Q in [(A, B), (B, C), (C, A)])
    if inside:
        return p
    best = None
    for P, Q in [(A, B), (B, C), (C, A)]:
        t = np.clip(np.dot(x - P, Q - P) / np.dot(Q - P, Q - P), 0, 1)
        q = P + t * (Q - P)
        if best is None or np.linalg.norm(x - q) < np.linalg.norm(x - best):
            best = q
    return best


# ------------------------------------------------------------------------------------------ validation


@pytest.mark.parametrize(
    ("faces", "bary", "match"),
    [
        ([0, 1], [[0.2, 0.3, 0.5], [np.nan, 0.5, 0.5]], r"surface points 1 have NaN or infinite"),
        ([0], [[np.inf, 0, 0]], r"surface points 0 have NaN or infinite"),
        ([0, 1, 2], [[0.2, 0.3, 0.5], [0.5, 0.6, -0.1], [1, 0, 0]], r"points 1 have barycentric .* negative"),
        ([0, 1], [[0.5, 0.5, 0.5], [0.2, 0.3, 0.5]], r"points 0 .* do not sum to one \(e\.g\. \[0\.5, 0\.5"),
        ([0, 1], [[0.2, 0.3, 0.5]], r"need faces \(k,\) and bary \(k, 3\); got \(2,\) and \(1, 3\)"),
        ([0], [[0.5, 0.5]], r"need faces \(k,\) and bary \(k, 3\)"),
        ([0], [[[0.2, 0.3, 0.5]]], r"need faces \(k,\) and bary \(k, 3\)"),
    ],
)
def test_invalid_points(faces, bary, match):
    with pytest.raises(MeshError, match=match):
        SurfacePoints(faces, bary)


def test_faces_out_of_range():
    pts = SurfacePoints([3, SPHERE.n_faces, -1], np.full((3, 3), 1 / 3))  # constructing is fine
    for call in (pts.validate, pts.positions):
        m = SPHERE.n_faces
        match = rf"surface points 1, 2 refer to faces outside 0\.\.{m - 1} \(e\.g\. face {m}\)"
        with pytest.raises(MeshError, match=match):
            call(SPHERE)
    assert pts[[0]].validate(SPHERE) is not None


def test_single_point_shapes_and_copies():
    bary = np.array([0.2, 0.3, 0.5])
    p = SurfacePoints(4, bary)
    assert p.faces.shape == (1,) and p.bary.shape == (1, 3)
    bary[0] = 7.0
    assert p.bary[0, 0] == 0.2  # copied
    assert not p.bary.flags.writeable and not p.faces.flags.writeable


# -------------------------------------------------------------------------------------------- snapping


def test_snapping_onto_an_edge():
    p = SurfacePoints([5, 5], [[1e-13, 0.4, 0.6 - 1e-13], [-5e-10, 0.5, 0.5 + 5e-10]])
    assert p.bary[0, 0] == 0.0 and p.bary[1, 0] == 0.0
    np.testing.assert_allclose(p.bary.sum(1), 1.0, rtol=1e-15)
    np.testing.assert_array_equal(p.vertex_ids(SPHERE), [-1, -1])
    h = p.edge_halfedges(SPHERE)
    np.testing.assert_array_equal(h, [3 * 5 + 1, 3 * 5 + 1])  # the halfedge from corner 1 to corner 2
    assert SPHERE.halfedge_tail[h[0]] == SPHERE.faces[5, 1]
    assert SPHERE.halfedge_head[h[0]] == SPHERE.faces[5, 2]
    # Each point is on the segment between the edge's two vertices.
    A, B = SPHERE.vertices[SPHERE.faces[5, 1]], SPHERE.vertices[SPHERE.faces[5, 2]]
    np.testing.assert_allclose(p.positions(SPHERE), [A + 0.6 * (B - A), A + 0.5 * (B - A)], atol=1e-9)


@pytest.mark.parametrize("k", [0, 1, 2])
def test_edge_halfedges_for_each_zero_coordinate(k):
    bary = np.array([0.3, 0.3, 0.3])
    bary[k] = 0.0
    bary /= bary.sum()
    p = SurfacePoints([7], [bary])
    h = p.edge_halfedges(SPHERE)[0]
    assert h == 3 * 7 + (k + 1) % 3
    corners = {(k + 1) % 3, (k + 2) % 3}
    assert {SPHERE.halfedge_tail[h], SPHERE.halfedge_head[h]} == set(SPHERE.faces[7, list(corners)])


def test_snapping_onto_a_vertex():
    p = SurfacePoints([2, 2, 2], [[1 - 2e-13, 1e-13, 1e-13], [SNAP / 2, 1 - SNAP, SNAP / 2], [0.5, 0.5, 0]])
    np.testing.assert_array_equal(p.bary[:2], [[1, 0, 0], [0, 1, 0]])
    np.testing.assert_array_equal(p.vertex_ids(SPHERE), [SPHERE.faces[2, 0], SPHERE.faces[2, 1], -1])
    np.testing.assert_array_equal(p.edge_halfedges(SPHERE), [-1, -1, 6])
    np.testing.assert_array_equal(p.positions(SPHERE)[:2], SPHERE.vertices[SPHERE.faces[2, :2]])


def test_interior_points_are_on_no_vertex_or_edge():
    faces, bary = random_points(SPHERE, 50, seed=1)
    p = SurfacePoints(faces, bary)
    np.testing.assert_array_equal(p.vertex_ids(SPHERE), -1)
    np.testing.assert_array_equal(p.edge_halfedges(SPHERE), -1)
    np.testing.assert_allclose(p.bary, bary, rtol=1e-15)  # nothing to snap: unchanged up to renormalization


# --------------------------------------------------------------------------------------- from_vertices


def test_from_vertices_is_exact():
    mesh = torus(n_major=9, n_minor=6)
    v = np.array([0, 5, 53, 17, 17])
    p = SurfacePoints.from_vertices(mesh, v)
    np.testing.assert_array_equal(p.positions(mesh), mesh.vertices[v])
    np.testing.assert_array_equal(p.vertex_ids(mesh), v)
    assert np.all(np.any(mesh.faces[p.faces] == v[:, None], axis=1))
    p_all = SurfacePoints.from_vertices(mesh, np.arange(mesh.n_vertices))
    np.testing.assert_array_equal(p_all.positions(mesh), mesh.vertices)


def test_from_vertices_errors():
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]])
    with pytest.warns(UserWarning):
        mesh = TriMesh(V, [[0, 1, 2]])
    with pytest.raises(MeshError, match=r"vertices 3 belong to no face") as info:
        SurfacePoints.from_vertices(mesh, [0, 3])
    np.testing.assert_array_equal(info.value.vertices, [3])
    with pytest.raises(MeshError, match=r"vertex indices 4, 7 are out of range 0\.\.3"):
        SurfacePoints.from_vertices(mesh, [4, 1, 7])
    with pytest.raises(MeshError, match=r"vertex indices -1 are out of range"):
        SurfacePoints.from_vertices(mesh, [-1])


# -------------------------------------------------------------------------------------- from_positions


@pytest.mark.parametrize("mesh", [SPHERE, torus(n_major=10, n_minor=7)], ids=repr)
def test_from_positions_round_trip(mesh):
    faces, bary = random_points(mesh, 400, seed=2)
    X = SurfacePoints(faces, bary).positions(mesh)
    p = SurfacePoints.from_positions(mesh, faces, X)
    np.testing.assert_array_equal(p.faces, faces)
    np.testing.assert_allclose(p.bary, bary, atol=1e-12)
    np.testing.assert_allclose(p.positions(mesh), X, atol=1e-12)
    # Off the face along its normal: projected back onto the same point.
    lifted = X + 0.01 * mesh.face_normals[faces] * np.random.default_rng(3).normal(size=(len(X), 1))
    np.testing.assert_allclose(SurfacePoints.from_positions(mesh, faces, lifted).bary, bary, atol=1e-12)


def test_from_positions_clamps_to_the_nearest_point_of_the_triangle():
    mesh = SPHERE
    rng = np.random.default_rng(4)
    faces = rng.integers(0, mesh.n_faces, 300)
    # Barycentric coordinates well outside the triangle, plus a normal offset.
    bary = rng.normal(size=(300, 3)) * 1.5
    bary[:, 2] = 1 - bary[:, 0] - bary[:, 1]
    T = mesh.vertices[mesh.faces[faces]]
    X = np.einsum("kj,kjd->kd", bary, T) + 0.05 * mesh.face_normals[faces]
    p = SurfacePoints.from_positions(mesh, faces, X)
    assert np.all(p.bary >= 0)
    np.testing.assert_allclose(p.bary.sum(1), 1, rtol=1e-15)
    got = p.positions(mesh)
    expected = np.array([closest_point_on_triangle(x, *t) for x, t in zip(X, T, strict=True)])
    np.testing.assert_allclose(got, expected, atol=1e-12)
    outside = np.any(bary < 0, axis=1)
    assert np.count_nonzero(outside) > 200
    # The clamped points are on the triangle's boundary: on an edge or a vertex.
    on_boundary = (p.vertex_ids(mesh) >= 0) | (p.edge_halfedges(mesh) >= 0)
    assert np.all(on_boundary[outside])
    # Brute force: no sampled point of the triangle is closer.
    s = np.random.default_rng(5).dirichlet(np.ones(3), 2000)
    for i in np.flatnonzero(outside)[:20]:
        samples = s @ T[i]
        assert np.linalg.norm(X[i] - got[i]) <= np.linalg.norm(samples - X[i], axis=1).min() + 1e-12


def test_from_positions_errors():
    with pytest.raises(MeshError, match=r"got 2 faces but 3 positions"):
        SurfacePoints.from_positions(SPHERE, [0, 1], np.zeros((3, 3)))
    with pytest.raises(MeshError, match=r"refer to faces outside"):
        SurfacePoints.from_positions(SPHERE, [SPHERE.n_faces], np.zeros((1, 3)))


@SETTINGS
@given(
    face=st.integers(0, SPHERE.n_faces - 1),
    weights=st.tuples(*[st.floats(0.0, 1.0, allow_subnormal=False)] * 3).filter(lambda w: sum(w) > 1e-3),
)
def test_from_positions_round_trip_hypothesis(face, weights):
    bary = np.array(weights) / sum(weights)
    p = SurfacePoints([face], [bary])
    X = p.positions(SPHERE)
    q = SurfacePoints.from_positions(SPHERE, [face], X)
    np.testing.assert_allclose(q.positions(SPHERE), X, atol=1e-12)
    np.testing.assert_allclose(q.bary, p.bary, atol=1e-12)
    # The face-frame position maps to the same 3D point.
    np.testing.assert_allclose(to3d(SPHERE, p.faces, p.in_face_frame(SPHERE)), X, atol=1e-12)


# ------------------------------------------------------------------------------------------ face frame


def test_in_face_frame_matches_positions(bumpy):
    faces, bary = random_points(bumpy, 200, seed=6)
    p = SurfacePoints(faces, bary)
    z = p.in_face_frame(bumpy)
    np.testing.assert_allclose(to3d(bumpy, faces, z), p.positions(bumpy), atol=1e-13)
    corners = SurfacePoints(np.repeat(faces[:3], 3), np.tile(np.eye(3), (3, 1)))
    np.testing.assert_array_equal(corners.in_face_frame(bumpy), bumpy.face_points[faces[:3]].ravel())


# ------------------------------------------------------------------------------------------ containers


def test_indexing_len_and_concatenate():
    faces, bary = random_points(SPHERE, 5, seed=7)
    p = SurfacePoints(faces, bary)
    assert len(p) == 5 and repr(p) == "SurfacePoints(5 points)"
    for index, expected in [
        (2, [2]),
        (np.int64(3), [3]),
        (-1, [4]),
        ([0, 2], [0, 2]),
        (slice(1, 4), [1, 2, 3]),
        (np.array([True, False, True, False, True]), [0, 2, 4]),
    ]:
        q = p[index]
        assert isinstance(q, SurfacePoints) and len(q) == len(expected)
        np.testing.assert_array_equal(q.faces, faces[expected])
        np.testing.assert_allclose(q.bary, p.bary[expected], rtol=1e-15)
    both = SurfacePoints.concatenate([p[:2], p[3:], p[[2]]])
    np.testing.assert_array_equal(both.faces, faces[[0, 1, 3, 4, 2]])
    np.testing.assert_allclose(both.bary, p.bary[[0, 1, 3, 4, 2]], rtol=1e-15)
    empty = SurfacePoints.concatenate([])
    assert len(empty) == 0 and empty.bary.shape == (0, 3)
    assert SurfacePoints.concatenate(iter([p])).faces.tolist() == faces.tolist()
