"""geodesics.ClosestPoints (exact closest points of a mesh to points in space) and closest_on_triangles,
against closed-form answers, a brute force over every face written independently (projection onto each
face's plane, else the nearest of its three edges), and trimesh.proximity; SurfacePoints.nearest is the
solver's answer, with the solver built once per mesh."""

import gc
import weakref

import numpy as np
import pytest

from geodesics import ClosestPoints, MeshError, SurfacePoints, TriMesh
from geodesics.closest import closest_on_triangles
from geodesics.primitives import cylinder, grid_plane, icosphere, scan_like_sphere, torus
from solver import objects

MESHES = {
    "icosphere": icosphere(2),
    "torus": torus(n_major=24, n_minor=12),
    "scan-like sphere": scan_like_sphere(400, seed=2),
    "mug": objects.mug(),
    "plate": objects.plate(),
    "jittered grid (open)": grid_plane(8, 7, jitter=0.2, seed=4),
    "cylinder (open)": cylinder(n_around=12, n_along=4, jitter=0.2, seed=1),
}


def brute_force(mesh: TriMesh, X: np.ndarray, chunk: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """(k,) distances and (k, 3) closest points, by testing every face: the projection onto the face's
    plane where it falls inside the face, else the closest point of the nearest edge."""
    A, B, C = (mesh.vertices[mesh.faces[:, c]] for c in range(3))
    n = np.cross(B - A, C - A)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    distances, points = [], []
    for start in range(0, len(X), chunk):
        x = X[start : start + chunk, None]  # (c, 1, 3) against (m, 3)
        p = x - n * np.einsum("cmj,mj->cm", x - A, n)[..., None]
        inside = np.ones(p.shape[:2], bool)
        for P, Q in ((A, B), (B, C), (C, A)):
            inside &= np.einsum("cmj,mj->cm", np.cross(Q - P, p - P), n) >= 0
        best = np.where(inside[..., None], p, np.nan)
        best_d = np.where(inside, np.linalg.norm(x - p, axis=2), np.inf)
        for P, Q in ((A, B), (B, C), (C, A)):
            t = np.clip(np.einsum("cmj,mj->cm", x - P, Q - P) / np.einsum("mj,mj->m", Q - P, Q - P), 0, 1)
            q = P + t[..., None] * (Q - P)
            d = np.linalg.norm(x - q, axis=2)
            closer = d < best_d
            best[closer], best_d[closer] = q[closer], d[closer]
        face = np.argmin(best_d, axis=1)
        rows = np.arange(len(face))
        distances.append(best_d[rows, face])
        points.append(best[rows, face])
    return np.concatenate(distances), np.concatenate(points)


def queries(mesh: TriMesh, seed: int, k: int = 60) -> np.ndarray:
    """Points on random faces, on edges, on vertices, off the surface along its normals (both sides,
    1e-7 to 1e-1 of the mesh's size) and anywhere in a box three times the mesh's size."""
    rng = np.random.default_rng(seed)
    diag = mesh.bounding_diagonal
    faces = rng.integers(0, mesh.n_faces, k)
    bary = rng.dirichlet([1.0, 1.0, 1.0], k)
    on_face = SurfacePoints(faces, bary).positions(mesh)
    bary[:, rng.integers(0, 3)] = 0.0
    on_edge = SurfacePoints(faces, bary / bary.sum(1, keepdims=True)).positions(mesh)
    on_vertex = mesh.vertices[np.unique(mesh.faces[faces, 0])]
    offset = diag * 10.0 ** rng.uniform(-7, -1, k) * rng.choice([-1.0, 1.0], k)
    off = on_face + offset[:, None] * mesh.face_normals[faces]
    lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
    far = rng.uniform(lo - diag, hi + diag, (k, 3))
    return np.vstack([on_face, on_edge, on_vertex, off, far])


@pytest.mark.parametrize("name", MESHES)
def test_closest_points_match_brute_force(name):
    mesh = MESHES[name]
    X = queries(mesh, seed=1)
    found = ClosestPoints(mesh).query(X)
    distances, points = brute_force(mesh, X)
    diag = mesh.bounding_diagonal
    np.testing.assert_allclose(found.distances, distances, rtol=1e-12, atol=1e-14 * diag)
    np.testing.assert_allclose(found.points, points, rtol=0, atol=1e-9 * diag)
    # What it says it found is so: the point is in its face, at its coordinates, at that distance.
    corners = mesh.vertices[mesh.faces[found.faces]]
    np.testing.assert_allclose(np.einsum("kc,kcd->kd", found.bary, corners), found.points, atol=1e-14 * diag)
    np.testing.assert_allclose(np.linalg.norm(X - found.points, axis=1), found.distances, atol=1e-15 * diag)
    assert np.all(found.bary >= -1e-15) and np.allclose(found.bary.sum(1), 1, rtol=0, atol=1e-15)
    zeros = np.count_nonzero(found.bary == 0, axis=1)
    assert np.array_equal(zeros == 2, found.features < 3)  # on a corner: one coordinate
    on_edge = (found.features >= 3) & (found.features < 6)
    assert np.all(zeros[on_edge] >= 1)  # on an edge: the opposite corner's coordinate is zero
    assert np.all(found.bary[on_edge, (found.features[on_edge] - 1) % 3] == 0)


@pytest.mark.parametrize("name", ["mug", "jittered grid (open)"])
def test_max_distance_bounds_far_points_and_keeps_near_ones_exact(name):
    mesh = MESHES[name]
    X = queries(mesh, seed=2)
    solver = ClosestPoints(mesh)
    exact = solver.query(X)
    for limit in (0.0, 1e-3 * mesh.bounding_diagonal, 0.05 * mesh.bounding_diagonal):
        bounded = solver.query(X, limit)
        kept = bounded.faces >= 0
        assert np.all(kept[exact.distances <= limit])  # nothing within reach is bounded
        # The same distances; where faces tie (a point closest to an edge or a corner), either face.
        np.testing.assert_array_equal(bounded.distances[kept], exact.distances[kept])
        np.testing.assert_allclose(bounded.points[kept], exact.points[kept], rtol=0, atol=1e-15)
        assert np.all(bounded.distances[~kept] > limit)  # a lower bound, beyond the limit
        assert np.all(bounded.distances[~kept] <= exact.distances[~kept])
        assert np.all(np.isnan(bounded.points[~kept])) and np.all(np.isnan(bounded.bary[~kept]))
        assert np.all(bounded.features[~kept] == -1)
        assert 0 < np.count_nonzero(~kept) < len(X)
    # One limit per point: none for the first half, zero for the others.
    half = len(X) // 2
    mixed = solver.query(X, np.where(np.arange(len(X)) < half, np.inf, 0.0))
    np.testing.assert_array_equal(mixed.distances[:half], exact.distances[:half])
    np.testing.assert_array_equal(mixed.distances[half:], solver.query(X[half:], 0.0).distances)


@pytest.mark.parametrize("name", ["mug", "scan-like sphere", "cylinder (open)"])
def test_closest_points_match_trimesh_proximity(name):
    """trimesh on the mesh scaled to a 1e6 diagonal, where its absolute tolerances are negligible (see
    tests/test_trimesh_oracle.py)."""
    trimesh = pytest.importorskip("trimesh")
    mesh = MESHES[name]
    mesh = TriMesh(mesh.vertices * (1e6 / mesh.bounding_diagonal), mesh.faces)
    X = queries(mesh, seed=3)
    found = ClosestPoints(mesh).query(X)
    theirs, distance, _ = trimesh.proximity.closest_point(
        trimesh.Trimesh(mesh.vertices, mesh.faces, process=False), X
    )
    np.testing.assert_allclose(found.distances, distance, rtol=1e-9, atol=1e-8)
    np.testing.assert_allclose(found.points, theirs, rtol=0, atol=1e-3)


def test_closest_on_triangles_in_every_region():
    """The unit right triangle in z = 0 and a point in each of its seven regions, answers by hand."""
    T = np.tile(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), (7, 1, 1))
    P = np.array(
        [
            [-1.0, -2.0, 0.5],  # corner 0
            [3.0, -1.0, 0.0],  # corner 1
            [-0.5, 2.0, -2.0],  # corner 2
            [0.25, -1.0, 1.0],  # edge 0-1
            [1.0, 1.0, 0.0],  # edge 1-2
            [-2.0, 0.75, 0.0],  # edge 2-0
            [0.2, 0.3, -4.0],  # interior
        ]
    )
    d, points, bary, features = closest_on_triangles(P, T)
    np.testing.assert_array_equal(features, np.arange(7))
    expected = np.array(
        [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.25, 0, 0], [0.5, 0.5, 0], [0, 0.75, 0], [0.2, 0.3, 0]]
    )
    np.testing.assert_allclose(points, expected, atol=1e-15)
    np.testing.assert_allclose(d, np.linalg.norm(P - expected, axis=1), rtol=1e-15)
    np.testing.assert_array_equal(bary[:3], np.eye(3))
    np.testing.assert_allclose(bary[3:], [[0.75, 0.25, 0], [0, 0.5, 0.5], [0.25, 0, 0.75], [0.5, 0.2, 0.3]])
    assert bary[3, 2] == 0 and bary[4, 0] == 0 and bary[5, 1] == 0


def test_nearest_is_the_solvers_answer_and_the_solver_is_built_once():
    mesh = icosphere(3)
    X = queries(mesh, seed=4)
    nearest = SurfacePoints.nearest(mesh, X)
    found = ClosestPoints.of(mesh).query(X)
    np.testing.assert_array_equal(nearest.faces, found.faces)
    np.testing.assert_allclose(nearest.bary, found.bary, rtol=0, atol=1e-15)
    assert ClosestPoints.of(mesh) is ClosestPoints.of(mesh)
    assert ClosestPoints.of(icosphere(3)) is not ClosestPoints.of(mesh)  # a different (equal) mesh
    # Points on vertices come back on those vertices.
    ids = np.arange(0, mesh.n_vertices, 7)
    np.testing.assert_array_equal(SurfacePoints.nearest(mesh, mesh.vertices[ids]).vertex_ids(mesh), ids)
    # The solver lives as long as its mesh, no longer.
    alive = weakref.ref(ClosestPoints.of(mesh))
    del mesh
    gc.collect()
    assert alive() is None


def test_query_errors_and_shapes():
    solver = ClosestPoints(icosphere(1))
    with pytest.raises(MeshError, match=r"shape \(k, 3\), got \(2, 2\)"):
        solver.query(np.zeros((2, 2)))
    with pytest.raises(MeshError, match="NaN or infinite"):
        solver.query([[0.0, np.inf, 0.0]])
    with pytest.raises(MeshError, match="max_distance must not be NaN"):
        solver.query(np.zeros((2, 3)), np.nan)
    with pytest.raises(MeshError, match=r"one per query point \(2\), got shape \(3,\)"):
        solver.query(np.zeros((2, 3)), [1.0, 2.0, 3.0])
    one = solver.query([0.0, 0.0, 2.0])
    assert one.distances.shape == (1,) and one.points.shape == (1, 3) and one.bary.shape == (1, 3)
    empty = solver.query(np.zeros((0, 3)))
    assert empty.distances.shape == (0,) and empty.faces.shape == (0,)
    with pytest.raises(MeshError, match="NaN or infinite"):
        SurfacePoints.nearest(icosphere(1), [[np.nan, 0.0, 0.0]])
