"""MeshSDF's bounds (max_distance outside the bounding box, band everywhere) and evaluate's gradients,
against its own unbounded distances (which tests/test_solver_grasp.py checks against brute force and
winding numbers, and tests/test_trimesh_oracle.py against trimesh)."""

import numpy as np
import pytest

from geodesics import ClosestPoints, SurfacePoints
from solver import MeshSDF, objects

MESHES = {"mug": objects.mug(), "sphere": objects.sphere(), "box": objects.box()}


def queries(mesh, seed: int, k: int = 400) -> np.ndarray:
    """Points near the surface on both sides (1e-6 to 3e-2 of the mesh's size) and anywhere in a box
    twice the mesh's size."""
    rng = np.random.default_rng(seed)
    diag = mesh.bounding_diagonal
    faces = rng.integers(0, mesh.n_faces, k)
    on = SurfacePoints(faces, rng.dirichlet([1.0, 1.0, 1.0], k)).positions(mesh)
    offset = diag * 10.0 ** rng.uniform(-6, np.log10(0.03), k) * rng.choice([-1.0, 1.0], k)
    lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
    return np.vstack(
        [on + offset[:, None] * mesh.face_normals[faces], rng.uniform(lo - diag / 2, hi + diag / 2, (k, 3))]
    )


@pytest.mark.parametrize("name", MESHES)
def test_band_bounds_far_points_inside_and_outside(name):
    mesh = MESHES[name]
    sdf = MeshSDF(mesh)
    X = queries(mesh, seed=1)
    exact, closest, _ = sdf.query(X)
    band = 0.01 * mesh.bounding_diagonal
    signed, near_closest, near_faces = sdf.query(X, band=band)
    kept = near_faces >= 0
    assert np.all(kept[np.abs(exact) <= band])
    np.testing.assert_array_equal(signed[kept], exact[kept])
    np.testing.assert_allclose(near_closest[kept], closest[kept], rtol=0, atol=1e-15)
    # Bounded: positive lower bounds beyond the band, inside as well as outside.
    assert np.all(signed[~kept] > band) and np.all(signed[~kept] <= np.abs(exact[~kept]))
    assert np.any(~kept & (exact > 0))
    assert name == "mug" or np.any(~kept & (exact < 0))  # the mug's walls are thinner than its faces
    assert np.all(np.isnan(near_closest[~kept])) and np.all(near_faces[~kept] == -1)
    # max_distance bounds only outside the bounding box; with both, the smaller applies there.
    both, _, both_faces = sdf.query(X, 0.0, band)
    outside = ClosestPoints.of(mesh).box_gap(X) > 0
    assert np.all(both_faces[outside] == -1) and np.all(both[outside] > 0)
    np.testing.assert_array_equal(both[~outside], signed[~outside])


@pytest.mark.parametrize("name", MESHES)
def test_evaluate_is_the_banded_query_with_unit_gradients(name):
    mesh = MESHES[name]
    sdf = MeshSDF(mesh)
    X = queries(mesh, seed=2)
    band = 0.01 * mesh.bounding_diagonal
    exact, _, _ = sdf.query(X)
    signed, gradient = sdf.evaluate(X, band)
    query, closest, faces = sdf.query(X, 0.0, band)
    np.testing.assert_array_equal(signed, query)
    found = faces >= 0
    np.testing.assert_allclose(gradient[found], (X[found] - closest[found]) / signed[found, None], rtol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(gradient[found], axis=1), 1, rtol=1e-12)
    assert np.all(gradient[~found] == 0)
    # The penetration it reports is exact: every point inside within the band, and inside the box.
    inside = (exact < 0) & (exact >= -band)
    np.testing.assert_array_equal(signed[inside], exact[inside])
    assert np.all(exact[signed < 0] < 0) and inside.sum() > 20
    # Finite differences along the gradient at points off the surface and within the band.
    rows = np.flatnonzero(found & (np.abs(signed) > 1e-4 * mesh.bounding_diagonal))[:50]
    h = 1e-7 * mesh.bounding_diagonal
    ahead = sdf(X[rows] + h * gradient[rows])
    np.testing.assert_allclose((ahead - signed[rows]) / h, 1, atol=1e-6)


def test_evaluate_refuses_non_finite_points():
    from solver import SolverError

    with pytest.raises(SolverError, match="finite"):
        MeshSDF(MESHES["sphere"]).evaluate([[0.0, np.nan, 0.0]], 0.01)


def test_the_deepest_point_of_faces_is_found_where_no_vertex_is_inside():
    """A triangle on the plane x + y = 1.9 whose corners are all outside the cube [-1, 1]³ cuts its edge
    x = y = 1: the midpoint of its first side, (0.95, 0.95, 0), is 0.05 inside (min(1 - x, 1 - y)), the
    deepest of the plane's points there, and a grid point (an edge midpoint). The same by the exact mesh
    distance and by the analytic box; a face far off is left out, and none inside gives 0."""
    from solver.sdf import Box, deepest_in_faces

    cube = objects.box(size=(2.0, 2.0, 2.0))
    assert np.allclose(cube.vertices.min(0), -1) and np.allclose(cube.vertices.max(0), 1)
    V = np.array([[1.9, 0.0, 0.0], [0.0, 1.9, 0.0], [0.95, 0.95, 3.0]])
    far = V + 10.0
    for solid in (MeshSDF(cube), Box(np.zeros(3), np.ones(3))):
        assert solid.evaluate(V)[0].min() > 0.89  # every corner well outside
        assert deepest_in_faces(solid, V, [[0, 1, 2]]) == pytest.approx(0.05, abs=1e-12)
        both = np.vstack([V, far])
        assert deepest_in_faces(solid, both, [[0, 1, 2], [3, 4, 5]]) == pytest.approx(0.05, abs=1e-12)
        assert deepest_in_faces(solid, far, [[0, 1, 2]]) == 0.0
        assert deepest_in_faces(solid, V, [[0, 1, 2]], steps=1) == 0.0  # the corners alone miss it
