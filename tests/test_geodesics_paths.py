"""Paths, transport and propagation limits, against closed forms on flat domains."""

import numpy as np
import pytest

from geodesics import (
    GeodesicField,
    SurfacePoints,
    TriMesh,
    geodesic_path,
    log_map,
    tangent_from_3d,
    tangent_to_3d,
    transport,
)
from geodesics.primitives import cylinder, grid_plane

from .oracles import random_points


def l_shape(n=12, seed=0):
    """The unit square minus its upper-right quarter (a grid with random diagonals): a non-convex flat
    domain whose reflex corner at (0.5, 0.5) is a boundary vertex with angle sum 3π/2."""
    square = grid_plane(n, n, size=(1.0, 1.0), jitter=0.0, seed=seed)
    centroid = square.vertices[square.faces].mean(1)
    keep = ~((centroid[:, 0] > 0.5) & (centroid[:, 1] > 0.5))
    used = np.unique(square.faces[keep])
    remap = np.full(square.n_vertices, -1)
    remap[used] = np.arange(used.size)
    return TriMesh(square.vertices[used], remap[square.faces[keep]])


def test_shortest_paths_wrap_around_a_reflex_boundary_corner():
    mesh = l_shape()
    corner = int(np.argmin(np.linalg.norm(mesh.vertices[:, :2] - 0.5, axis=1)))
    assert np.allclose(mesh.vertices[corner, :2], 0.5)
    assert mesh.is_boundary_vertex[corner]
    assert mesh.angle_sums[corner] == pytest.approx(1.5 * np.pi)
    rng = np.random.default_rng(40)
    points = random_points(mesh, 2000, rng)
    X = points.positions(mesh)[:, :2]
    a = np.flatnonzero((X[:, 0] > 0.6) & (X[:, 1] < 0.35))[:1]  # lower-right arm
    hidden = np.flatnonzero((X[:, 0] < 0.35) & (X[:, 1] > 0.65))  # upper-left arm, behind the corner
    origin, targets = points[a], points[hidden]
    o, c, t = X[a[0]], np.array([0.5, 0.5]), X[hidden]
    # The straight segment o -> t leaves x > 0.5 at s_x and enters y > 0.5 at s_y; it cuts through the
    # missing quarter (so the geodesic bends round the corner) when s_y < s_x.
    s_x = (o[0] - 0.5) / (o[0] - t[:, 0])
    s_y = (0.5 - o[1]) / (t[:, 1] - o[1])
    blocked = s_y < s_x
    assert 20 < blocked.sum() < len(blocked)
    around = np.linalg.norm(c - o) + np.linalg.norm(t - c, axis=1)
    expected = np.where(blocked, around, np.linalg.norm(t - o, axis=1))
    np.testing.assert_allclose(np.abs(log_map(mesh, origin, targets)), expected, atol=1e-12)
    path = geodesic_path(mesh, origin, targets[np.flatnonzero(blocked)[:1]])
    expected = expected[blocked]
    assert path.bends == 1
    assert path.points.vertex_ids(mesh)[1:-1].tolist().count(corner) == 1
    assert np.linalg.norm(np.diff(path.polyline, axis=0), axis=1).sum() == pytest.approx(expected[0])


def test_transport_on_the_plane_keeps_the_vector_in_space():
    mesh = grid_plane(20, 20, jitter=0.24, seed=41)
    rng = np.random.default_rng(42)
    pts = random_points(mesh, 40, rng)
    for i in range(0, 40, 2):
        path = geodesic_path(mesh, pts[[i]], pts[[i + 1]])
        z = np.exp(1j * rng.uniform(0, 2 * np.pi, 5)) * rng.uniform(0.1, 2, 5)
        a, b = pts[np.full(5, i)], pts[np.full(5, i + 1)]
        moved = transport(mesh, path, z)
        np.testing.assert_allclose(tangent_to_3d(mesh, b, moved), tangent_to_3d(mesh, a, z), atol=1e-12)


def test_transport_on_a_prism_is_the_identity_of_the_unrolling():
    """Across the prism's facets, vectors change in space but not in the unrolled plane; in particular a
    vector along the axis stays along the axis, and one along the circumference stays horizontal."""
    mesh = cylinder(radius=1.0, height=2.0, n_around=24, n_along=12, jitter=0.2, seed=43)
    rng = np.random.default_rng(44)
    pts = random_points(mesh, 200, rng)
    X = pts.positions(mesh)
    angle = np.arctan2(X[:, 1], X[:, 0])
    a = int(np.argmin(np.abs(angle)))  # near angle 0
    b = int(np.argmin(np.abs(angle - 1.5)))  # about a quarter turn round
    path = geodesic_path(mesh, pts[[a]], pts[[b]])
    assert len(path.points) > 5
    up = np.array([[0.0, 0.0, 1.0]])
    moved = transport(mesh, path, tangent_from_3d(mesh, pts[[a]], up))
    np.testing.assert_allclose(tangent_to_3d(mesh, pts[[b]], moved), up, atol=1e-12)
    around = np.cross(up, mesh.face_normals[pts.faces[[a]]])  # horizontal, in a's facet
    out = tangent_to_3d(mesh, pts[[b]], transport(mesh, path, tangent_from_3d(mesh, pts[[a]], around)))[0]
    assert abs(out[2]) < 1e-12
    assert np.linalg.norm(out) == pytest.approx(1.0)


def test_max_distance_stops_propagation():
    mesh = grid_plane(30, 30, jitter=0.2, seed=45)
    origin = SurfacePoints.from_vertices(mesh, [15 * 31 + 15])
    near = GeodesicField(mesh, origin, max_distance=0.2)
    full = GeodesicField(mesh, origin)
    reached = np.isfinite(near.vertex_distance)
    assert reached.sum() < 0.5 * mesh.n_vertices
    inside = full.vertex_distance < 0.2
    assert np.all(reached[inside])
    np.testing.assert_allclose(near.vertex_distance[inside], full.vertex_distance[inside], rtol=1e-14)
    assert near.W.size < full.W.size / 3


def test_several_sources_label_each_point_with_the_nearest():
    mesh = grid_plane(20, 20, jitter=0.2, seed=46)
    rng = np.random.default_rng(47)
    sources = random_points(mesh, 6, rng)
    targets = random_points(mesh, 500, rng)
    q = GeodesicField(mesh, sources, targets).query(targets)
    S, T = sources.positions(mesh)[:, :2], targets.positions(mesh)[:, :2]
    d = np.linalg.norm(T[:, None] - S[None], axis=2)
    np.testing.assert_allclose(q.distances, d.min(1), atol=1e-12)
    np.testing.assert_array_equal(q.sources, d.argmin(1))
