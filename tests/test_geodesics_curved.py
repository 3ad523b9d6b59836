"""Exact geodesics on curved meshes, against Kirsanov's MMP implementation and Dijkstra, plus
sampling-agnostic behaviour and the failure modes."""

import gc
import weakref

import numpy as np
import pytest

from geodesics import (
    GeodesicError,
    GeodesicField,
    MeshError,
    SurfacePoints,
    TriMesh,
    closest_points,
    exp_map,
    geodesic_path,
    log_map,
)
from geodesics.primitives import grid_plane, icosphere, scan_like_sphere, scan_like_torus, torus

from .oracles import edge_path_distances, mmp_distances, random_points, with_points_as_vertices

CURVED = {
    "icosphere": lambda: icosphere(4),
    "torus": lambda: torus(n_major=48, n_minor=24),
    "scan_sphere": lambda: scan_like_sphere(3000, seed=1),
    "scan_torus": lambda: scan_like_torus(3000, seed=2),
}


@pytest.fixture(scope="module", params=sorted(CURVED))
def curved(request):
    return request.param, CURVED[request.param]()


def test_distances_equal_exact_mmp_between_surface_points(curved):
    name, mesh = curved
    rng = np.random.default_rng(20)
    points = random_points(mesh, 81, rng, distinct_faces=True)
    origin, targets = points[:1], points[1:]
    V, F, new = with_points_as_vertices(mesh, points)
    expected = mmp_distances(V, F, new[0], np.concatenate([new[1:], np.arange(mesh.n_vertices)]))
    got = np.abs(
        log_map(
            mesh,
            origin,
            SurfacePoints.concatenate(
                [targets, SurfacePoints.from_vertices(mesh, np.arange(mesh.n_vertices))]
            ),
        )
    )
    np.testing.assert_allclose(got, expected, rtol=1e-8, err_msg=name)


def test_stopping_once_nearby_targets_are_settled_changes_nothing(curved):
    """A field given targets stops as soon as they are settled (setting settled ones aside as it goes,
    queueing windows by a lower bound on their distance): it answers exactly what the whole field does."""
    name, mesh = curved
    rng = np.random.default_rng(21)
    origin, pool = random_points(mesh, 1, rng), random_points(mesh, 400, rng)
    whole = GeodesicField(mesh, origin)
    distance = whole.query(pool).distances
    # Single targets stop closest to the edge of what is settled; groups set targets aside as they go.
    groups = [np.array([i]) for i in np.argsort(distance)[::50]]
    groups += [np.flatnonzero(distance < share * distance.max()) for share in (0.1, 0.3, 0.6)]
    for group in groups:
        near = pool[group]
        early = GeodesicField(mesh, origin, near)
        assert early.W.size < whole.W.size, name  # it did stop early
        expected, got = whole.query(near), early.query(near)
        np.testing.assert_allclose(got.distances, expected.distances, rtol=1e-12, err_msg=name)
        np.testing.assert_allclose(got.initial_directions, expected.initial_directions, atol=1e-9)
        np.testing.assert_allclose(got.final_directions, expected.final_directions, atol=1e-9)


def test_a_window_is_queued_by_its_nearest_point_to_the_pseudosource():
    """The queue key is the distance from the pseudosource's image to the nearest point of the window's
    interval (either way round): never more, or the field could stop before a target is settled."""
    from geodesics.exact import _to_segment

    rng = np.random.default_rng(22)
    n = 500
    I, P0, P1 = (rng.normal(size=n) + 1j * rng.normal(size=n) for _ in range(3))
    t0, t1 = rng.uniform(-0.2, 1.2, (2, n))
    samples = np.linspace(t0, t1, 2001)  # (2001, n), both ends included
    nearest = np.abs(I - (P0 + samples * (P1 - P0))).min(axis=0)
    key = _to_segment(I, P0, P1, t0, t1)
    assert np.all(key <= nearest + 1e-12)
    np.testing.assert_allclose(key, nearest, atol=2e-3)  # and the sampling finds nothing nearer


def test_distances_never_exceed_edge_paths(curved):
    _, mesh = curved
    source = 7
    field = GeodesicField(mesh, SurfacePoints.from_vertices(mesh, [source]))
    dijkstra = edge_path_distances(mesh, source)
    assert np.all(field.vertex_distance <= dijkstra * (1 + 1e-12))
    assert np.mean(field.vertex_distance < dijkstra * (1 - 1e-6)) > 0.5  # and usually strictly shorter


def test_exp_of_log_from_spherical_vertices_returns_the_target():
    """Every icosphere vertex has angle sum below 2π; the log map's vertex basis and the exp map's
    vertex rule must be one convention for the round trip to close."""
    mesh = icosphere(3)
    assert np.all(mesh.angle_sums < 2 * np.pi - 1e-3)
    rng = np.random.default_rng(21)
    for v in (0, 17, 400):
        origin = SurfacePoints.from_vertices(mesh, [v])
        targets = SurfacePoints.concatenate(
            [random_points(mesh, 300, rng), SurfacePoints.from_vertices(mesh, np.arange(mesh.n_vertices))]
        )
        z = log_map(mesh, origin, targets)
        trace = exp_map(mesh, origin, z)
        np.testing.assert_allclose(
            trace.points.positions(mesh), targets.positions(mesh), atol=1e-9 * mesh.bounding_diagonal
        )


def test_final_direction_is_where_the_exp_map_arrives():
    mesh = icosphere(3)
    rng = np.random.default_rng(22)
    origin = random_points(mesh, 1, rng)
    targets = random_points(mesh, 200, rng)
    field = GeodesicField(mesh, origin, targets)
    q = field.query(targets)
    trace = exp_map(mesh, origin, q.distances * q.initial_directions)
    np.testing.assert_allclose(trace.directions, q.final_directions, atol=1e-7)


def test_paths_are_consistent_polylines(curved):
    _, mesh = curved
    rng = np.random.default_rng(23)
    a, b = random_points(mesh, 2, rng)[:1], random_points(mesh, 2, rng)[1:]
    path = geodesic_path(mesh, a, b)
    np.testing.assert_allclose(path.polyline[0], a.positions(mesh)[0], atol=1e-12)
    np.testing.assert_allclose(path.polyline[-1], b.positions(mesh)[0], atol=1e-12)
    length = np.linalg.norm(np.diff(path.polyline, axis=0), axis=1).sum()
    assert length == pytest.approx(path.length, rel=1e-10)
    inner = path.points[np.arange(1, len(path.points) - 1)]
    assert np.all(np.count_nonzero(inner.bary, axis=1) <= 2), "crossings lie on edges or vertices"
    assert path.length == pytest.approx(abs(log_map(mesh, a, b)[0]), rel=1e-12)


def test_paths_bend_only_around_saddle_vertices():
    mesh = torus(n_major=48, n_minor=24)
    rng = np.random.default_rng(24)
    bent = 0
    for _ in range(30):
        pts = random_points(mesh, 2, rng)
        path = geodesic_path(mesh, pts[:1], pts[1:])
        corners = path.points.vertex_ids(mesh)[1:-1]
        corners = corners[corners >= 0]
        assert np.all(mesh.angle_sums[corners] > 2 * np.pi)
        bent += corners.size > 0
    assert bent > 0, "some paths across the inner side of a torus bend around saddles"


def test_closest_points_agree_with_mmp():
    mesh = torus(n_major=40, n_minor=20)
    rng = np.random.default_rng(25)
    sources = rng.choice(mesh.n_vertices, 12, replace=False)
    targets = np.setdiff1d(np.arange(mesh.n_vertices), sources)
    got = closest_points(
        mesh, SurfacePoints.from_vertices(mesh, sources), SurfacePoints.from_vertices(mesh, targets)
    )
    per_source = np.stack([mmp_distances(mesh.vertices, mesh.faces, s, targets) for s in sources], 1)
    best = np.sort(per_source, axis=1)
    clear = best[:, 1] - best[:, 0] > 1e-9  # ignore exact ties
    np.testing.assert_array_equal(got[clear], np.argmin(per_source, axis=1)[clear])


def test_coarse_and_fine_samplings_of_one_plane_agree_exactly():
    """The same flat rectangle triangulated with ~100 and with ~100k faces is the same surface, so the
    exact log and exp maps must agree to rounding: nothing depends on the sampling."""
    coarse = grid_plane(7, 7, size=(1.0, 1.0), jitter=0.24, seed=30)
    fine = grid_plane(224, 224, size=(1.0, 1.0), jitter=0.24, seed=31)
    assert coarse.n_faces <= 100 and fine.n_faces >= 100_000
    rng = np.random.default_rng(32)
    xy = 0.5 + 0.25 * np.sqrt(rng.uniform(0, 1, 60))[:, None] * np.exp(
        1j * rng.uniform(0, 2 * np.pi, 60)
    ).view(float).reshape(-1, 2)
    xy[0] = 0.5
    pc, pf = _locate_in_plane(coarse, xy), _locate_in_plane(fine, xy)
    zc = log_map(coarse, pc[:1], pc[1:])
    zf = log_map(fine, pf[:1], pf[1:])
    # the two origins have different face frames: compare the same 3D vectors
    np.testing.assert_allclose(np.abs(zc), np.abs(zf), atol=1e-9)
    ends_c = exp_map(coarse, pc[:1], zc * 0.7).points.positions(coarse)
    ends_f = exp_map(fine, pf[:1], zf * 0.7).points.positions(fine)
    np.testing.assert_allclose(ends_c, ends_f, atol=1e-9)


@pytest.mark.slow
def test_coarse_and_fine_spheres_agree_up_to_discretization():
    coarse, fine = icosphere(2), icosphere(7)
    assert coarse.n_faces < 400 and fine.n_faces >= 100_000
    rng = np.random.default_rng(33)
    dirs = rng.normal(size=(40, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    exact = np.arccos(np.clip(dirs[1:] @ dirs[0], -1, 1))
    errors = {}
    for name, mesh in (("coarse", coarse), ("fine", fine)):
        pts = _locate_on_sphere(mesh, dirs)
        errors[name] = np.abs(np.abs(log_map(mesh, pts[:1], pts[1:])) - exact)
    assert errors["fine"].max() < 2e-3
    assert errors["coarse"].max() < 0.1
    assert errors["fine"].max() < errors["coarse"].max() / 10


def test_points_on_different_components_are_refused():
    a = grid_plane(4, 4, seed=1)
    V = np.vstack([a.vertices, a.vertices + np.array([5.0, 0, 0])])
    F = np.vstack([a.faces, a.faces + a.n_vertices])
    mesh = TriMesh(V, F)
    assert mesh.n_components == 2
    origin = SurfacePoints([0], [[0.2, 0.3, 0.5]])
    targets = SurfacePoints([1, a.n_faces + 3], [[0.2, 0.3, 0.5]] * 2)
    with pytest.raises(GeodesicError, match="component"):
        log_map(mesh, origin, targets)
    with pytest.raises(GeodesicError, match="component"):
        geodesic_path(mesh, origin, targets[1:])
    np.testing.assert_array_equal(closest_points(mesh, origin, targets), [0, -1])


def test_bad_queries_get_clear_errors():
    mesh = grid_plane(4, 4, seed=1)
    origin = SurfacePoints([0], [[0.2, 0.3, 0.5]])
    with pytest.raises(MeshError, match="NaN"):
        exp_map(mesh, origin, np.array([np.nan + 0j]))
    with pytest.raises(MeshError, match="2 origins but 3"):
        exp_map(mesh, SurfacePoints([0, 1], [[1, 0, 0]] * 2), np.ones(3))
    with pytest.raises(GeodesicError, match="single surface point"):
        log_map(mesh, SurfacePoints([0, 1], [[1, 0, 0]] * 2), origin)
    with pytest.raises(MeshError, match="faces outside"):
        log_map(mesh, SurfacePoints([999], [[1, 0, 0]]), origin)
    assert log_map(mesh, origin, origin)[0] == 0


def _locate_in_plane(mesh, xy):
    """Surface points at plane positions xy (z = 0), by brute-force point location."""
    P = mesh.vertices[mesh.faces][:, :, :2]
    faces, bary = [], []
    for x, y in xy:
        a, b, c = P[:, 0], P[:, 1], P[:, 2]
        det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
        l1 = ((x - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (y - a[:, 1])) / det
        l2 = ((b[:, 0] - a[:, 0]) * (y - a[:, 1]) - (x - a[:, 0]) * (b[:, 1] - a[:, 1])) / det
        inside = np.flatnonzero((l1 >= 0) & (l2 >= 0) & (l1 + l2 <= 1))
        f = inside[0]
        faces.append(f)
        bary.append([1 - l1[f] - l2[f], l1[f], l2[f]])
    return SurfacePoints(faces, bary)


def _locate_on_sphere(mesh, dirs):
    """Surface points where rays from the centre along ``dirs`` meet the mesh."""
    T = mesh.vertices[mesh.faces]
    centroid = T.mean(1) / np.linalg.norm(T.mean(1), axis=1, keepdims=True)
    faces, bary = [], []
    for d in dirs:
        near = np.flatnonzero(centroid @ d > np.cos(0.6))
        # Solve t d = a + u (b - a) + v (c - a) for nearby faces; keep the one with u, v in the triangle.
        Tn = T[near]
        M = np.stack([Tn[:, 1] - Tn[:, 0], Tn[:, 2] - Tn[:, 0], -np.broadcast_to(d, Tn[:, 0].shape)], axis=2)
        sol = np.linalg.solve(M, -Tn[:, 0][:, :, None])[:, :, 0]
        u, v, t = sol[:, 0], sol[:, 1], sol[:, 2]
        hit = np.flatnonzero((u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0))[0]
        faces.append(near[hit])
        bary.append([1 - u[hit] - v[hit], u[hit], v[hit]])
    return SurfacePoints(faces, bary)


def test_tracing_keeps_no_mesh_alive():
    """What exp_map precomputes per mesh is freed with the mesh: the add-on makes a mesh per operator
    call, and a cache holding them would grow all session."""
    mesh = icosphere(2)
    exp_map(mesh, random_points(mesh, 3, np.random.default_rng(0)), np.full(3, 0.1 + 0.05j))
    alive = weakref.ref(mesh)
    del mesh
    gc.collect()
    assert alive() is None
