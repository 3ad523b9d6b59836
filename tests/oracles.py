"""Independent references for the geodesic tests: closed-form unrollings, Kirsanov's exact MMP
(pygeodesic), Dijkstra on the edge graph."""

from __future__ import annotations

import numpy as np
import pygeodesic.geodesic as pygeodesic
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from geodesics import SurfacePoints, TriMesh


def random_points(mesh: TriMesh, k: int, rng, distinct_faces: bool = False) -> SurfacePoints:
    """k points strictly inside random faces (optionally all in different faces)."""
    if distinct_faces:
        faces = rng.choice(mesh.n_faces, size=k, replace=False)
    else:
        faces = rng.integers(0, mesh.n_faces, k)
    bary = rng.dirichlet([2.0, 2.0, 2.0], k)
    return SurfacePoints(faces, bary)


def with_points_as_vertices(
    mesh: TriMesh, points: SurfacePoints
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split each point's face into three at the point (faces must be distinct, points interior).

    The surface is unchanged (the new faces are coplanar with the old), so exact geodesic distances
    between the new vertices equal those between the points. Returns (V, F, new vertex ids).
    """
    assert np.unique(points.faces).size == len(points), "one point per face"
    V = np.vstack([mesh.vertices, points.positions(mesh)])
    new = mesh.n_vertices + np.arange(len(points))
    keep = np.ones(mesh.n_faces, bool)
    keep[points.faces] = False
    a, b, c = mesh.faces[points.faces].T
    split = np.concatenate([np.stack([a, b, new], 1), np.stack([b, c, new], 1), np.stack([c, a, new], 1)])
    return V, np.vstack([mesh.faces[keep], split]), new


def mmp_distances(V: np.ndarray, F: np.ndarray, source: int, targets: np.ndarray) -> np.ndarray:
    """Exact polyhedral distances from one vertex by Kirsanov's MMP implementation."""
    solver = pygeodesic.PyGeodesicAlgorithmExact(
        np.ascontiguousarray(V, float), np.ascontiguousarray(F, np.int32)
    )
    distances, _ = solver.geodesicDistances(np.array([source]), np.asarray(targets))
    return np.asarray(distances)


def edge_path_distances(mesh: TriMesh, source: int) -> np.ndarray:
    """Dijkstra distances along mesh edges from one vertex (an upper bound on geodesic distance)."""
    t, h = mesh.halfedge_tail, mesh.halfedge_head
    w = np.linalg.norm(mesh.vertices[t] - mesh.vertices[h], axis=1)
    graph = coo_matrix((w, (t, h)), shape=(mesh.n_vertices,) * 2).tocsr()
    return dijkstra(graph, directed=False, indices=source)


def plane_coordinates(mesh: TriMesh, points: SurfacePoints) -> np.ndarray:
    """(k,) complex x + iy of points on a mesh lying in the z = 0 plane."""
    X = points.positions(mesh)
    return X[:, 0] + 1j * X[:, 1]
