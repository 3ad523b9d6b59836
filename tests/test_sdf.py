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
