"""trimesh as an independent oracle: our closest points (SurfacePoints.nearest, MeshSDF), signed distances
(MeshSDF) and ray hits (RayCaster) against trimesh's, on the solver's objects and the geodesics
primitives, with seeded query points near the surface (on both sides) and far from it.

trimesh's proximity queries use absolute tolerances: ``trimesh.triangles.closest_point`` decides a
point's region of a triangle with ``tol.zero`` (1e-13) on products of squared lengths, and
``trimesh.proximity.closest_point`` (and ``signed_distance``, built on it) settles between its two best
faces by their normals whenever their squared distances differ by less than ``tol.merge`` (1e-8). On a
mug in metres, a tenth of a millimetre from its surface, both then return points several percent too far.
So trimesh is compared on the meshes scaled to a 1e6 diagonal, where its tolerances are negligible, and
ours are checked to be scale-invariant, which carries the comparison back to the objects' own scale.
Rays are compared at the objects' own scale: trimesh's ray test counts hits up to 1e-6 behind a ray's
origin and merges hits within 1e-8 of each other, and these rays start at least 1e-3 of the mesh's size
from it.
"""

import numpy as np
import pytest
import trimesh
from trimesh.ray.ray_triangle import RayMeshIntersector

from geodesics import SurfacePoints, TriMesh
from geodesics.primitives import cylinder, grid_plane, icosphere, scan_like_sphere, torus
from solver import objects
from solver.retarget.pairing import RayCaster
from solver.sdf import MeshSDF

CLOSED = {
    "mug": objects.mug(),
    "box": objects.box(),
    "icosphere": icosphere(3),
    "torus": torus(n_major=24, n_minor=12),
    "scan-like sphere": scan_like_sphere(400, seed=2),
}
OPEN = {
    "jittered grid": grid_plane(8, 7, jitter=0.2, seed=4),
    "cylinder": cylinder(n_around=12, n_along=4, jitter=0.2, seed=1),
}
#: Distances agree to this relative error (plus a floor far below any real discrepancy).
RTOL = 1e-9


def as_trimesh(mesh: TriMesh) -> trimesh.Trimesh:
    return trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)


def queries(mesh: TriMesh, seed: int, k: int = 300, closest: float = 1e-5) -> np.ndarray:
    """k points off random surface points along their face normals (both sides, at 1e-5 to 1e-1 of the
    mesh's size, at least ``closest`` of it) and k points in a box three times the mesh's size."""
    rng = np.random.default_rng(seed)
    diag = mesh.bounding_diagonal
    faces = rng.integers(0, mesh.n_faces, k)
    on = SurfacePoints(faces, rng.dirichlet([1.0, 1.0, 1.0], k)).positions(mesh)
    offset = diag * 10.0 ** rng.uniform(np.log10(closest), -1, k) * rng.choice([-1.0, 1.0], k)
    near = on + offset[:, None] * mesh.face_normals[faces]
    lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
    far = rng.uniform(lo - diag, hi + diag, (k, 3))
    return np.vstack([near, far])


def scaled(mesh: TriMesh) -> TriMesh:
    """The mesh scaled to a bounding diagonal of 1e6 (see the module docstring)."""
    return TriMesh(mesh.vertices * (1e6 / mesh.bounding_diagonal), mesh.faces)


@pytest.mark.parametrize("name", CLOSED)
def test_signed_distances_and_closest_points_match_trimesh_proximity(name):
    mesh = scaled(CLOSED[name])
    X = queries(mesh, seed=1)
    ours, closest, _ = MeshSDF(mesh).query(X)
    theirs_closest, theirs_distance, _ = trimesh.proximity.closest_point(as_trimesh(mesh), X)
    diag = mesh.bounding_diagonal
    np.testing.assert_allclose(np.abs(ours), theirs_distance, rtol=RTOL, atol=1e-14 * diag)
    np.testing.assert_allclose(closest, theirs_closest, rtol=0, atol=RTOL * diag)
    # trimesh's sign convention is the opposite of ours: positive inside.
    theirs_signed = trimesh.proximity.signed_distance(as_trimesh(mesh), X)
    np.testing.assert_allclose(-ours, theirs_signed, rtol=RTOL, atol=1e-14 * diag)
    assert np.any(ours < 0) and np.any(ours > 0)


@pytest.mark.parametrize("name", [*CLOSED, *OPEN])
def test_nearest_surface_points_match_trimesh_proximity(name):
    mesh = scaled({**CLOSED, **OPEN}[name])
    X = queries(mesh, seed=2)
    ours = SurfacePoints.nearest(mesh, X).positions(mesh)
    theirs, distance, _ = trimesh.proximity.closest_point(as_trimesh(mesh), X)
    diag = mesh.bounding_diagonal
    np.testing.assert_allclose(np.linalg.norm(X - ours, axis=1), distance, rtol=RTOL, atol=1e-14 * diag)
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=RTOL * diag)


@pytest.mark.parametrize("name", ["mug", "box", "jittered grid"])
def test_ours_are_scale_invariant(name):
    """At the objects' own scale (metres), our answers are those checked against trimesh, scaled back."""
    mesh = {**CLOSED, **OPEN}[name]
    big = scaled(mesh)
    factor = big.bounding_diagonal / mesh.bounding_diagonal
    X = queries(mesh, seed=5)
    nearest = SurfacePoints.nearest(mesh, X)
    nearest_big = SurfacePoints.nearest(big, X * factor)
    diag = mesh.bounding_diagonal
    np.testing.assert_allclose(
        nearest.positions(mesh), nearest_big.positions(big) / factor, rtol=0, atol=1e-12 * diag
    )
    if name in CLOSED:
        ours, closest, _ = MeshSDF(mesh).query(X)
        ours_big, closest_big, _ = MeshSDF(big).query(X * factor)
        np.testing.assert_allclose(ours, ours_big / factor, rtol=1e-12, atol=1e-15 * diag)
        np.testing.assert_allclose(closest, closest_big / factor, rtol=0, atol=1e-12 * diag)


def rays(mesh: TriMesh, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Origins near the surface (not closer than 1e-3 of its size: trimesh counts hits up to 1e-6 behind
    a ray's origin) and far from it, with random directions of random lengths."""
    rng = np.random.default_rng(seed)
    O = queries(mesh, seed, k=200, closest=1e-3)
    D = rng.normal(size=O.shape) * rng.uniform(0.5, 2.0, (len(O), 1))
    far = len(O) // 2
    # Half the far rays aim at points inside random faces, so that most of them hit the mesh.
    target = SurfacePoints(rng.integers(0, mesh.n_faces, len(O)), rng.dirichlet([1.0, 1.0, 1.0], len(O)))
    D[far::2] = (target.positions(mesh) - O)[far::2]
    return O, D


def hits_sorted(ray, face, t):
    order = np.lexsort((t, ray))
    return ray[order], face[order], t[order]


@pytest.mark.parametrize("name", [*CLOSED, *OPEN])
def test_ray_hits_match_trimesh(name):
    mesh = {**CLOSED, **OPEN}[name]
    O, D = rays(mesh, seed=3)
    ray, face, t, bary = RayCaster(mesh.vertices, mesh.faces).intersect(O, D, t_min=0.0)
    where, their_ray, their_face = RayMeshIntersector(as_trimesh(mesh)).intersects_location(
        O, D, multiple_hits=True
    )
    their_t = np.einsum("ij,ij->i", where - O[their_ray], D[their_ray]) / np.einsum(
        "ij,ij->i", D[their_ray], D[their_ray]
    )
    their_ray, their_face, their_t = hits_sorted(their_ray, their_face, their_t)
    assert ray.size > len(O) // 3
    assert np.array_equal(ray, their_ray)
    assert np.array_equal(face, their_face)
    diag = mesh.bounding_diagonal
    scale = np.linalg.norm(D[ray], axis=1)
    np.testing.assert_allclose(t * scale, their_t * scale, rtol=0, atol=RTOL * diag)
    position = np.einsum("hc,hcj->hj", bary, mesh.vertices[mesh.faces[face]])
    np.testing.assert_allclose(position, O[ray] + t[:, None] * D[ray], rtol=0, atol=RTOL * diag)


@pytest.mark.parametrize("name", CLOSED)
def test_line_hits_are_trimesh_rays_both_ways_and_parity_tells_inside(name):
    """Our lines (t unbounded) are trimesh's rays forwards and backwards; on a closed mesh a point is
    inside exactly when its ray meets the surface an odd number of times."""
    mesh = CLOSED[name]
    O, D = rays(mesh, seed=4)
    ray, face, t, _ = RayCaster(mesh.vertices, mesh.faces).intersect(O, D)
    caster = RayMeshIntersector(as_trimesh(mesh))
    parts = []
    for sign in (1.0, -1.0):
        where, r, f = caster.intersects_location(O, sign * D, multiple_hits=True)
        parts.append((r, f, np.einsum("ij,ij->i", where - O[r], D[r]) / (D[r] ** 2).sum(1)))
    their_ray, their_face, their_t = hits_sorted(*(np.concatenate(p) for p in zip(*parts, strict=True)))
    assert np.array_equal(ray, their_ray)
    assert np.array_equal(face, their_face)
    diag = mesh.bounding_diagonal
    np.testing.assert_allclose(
        t * np.linalg.norm(D[ray], axis=1), their_t * np.linalg.norm(D[ray], axis=1), rtol=0, atol=RTOL * diag
    )
    ahead = np.bincount(ray[t > 0], minlength=len(O))
    inside = MeshSDF(mesh)(O) < 0
    assert np.array_equal(ahead % 2 == 1, inside)
    assert np.array_equal(inside, trimesh.proximity.signed_distance(as_trimesh(mesh), O) > 0)


@pytest.mark.parametrize("name", CLOSED)
def test_rays_through_vertices_and_edges_count_each_crossing_once(name):
    """Rays aimed exactly at vertices and at points of edges meet two or more faces there: both casters
    report the crossing once (trimesh merges hits at one location), so hit counts and parities agree."""
    mesh = CLOSED[name]
    rng = np.random.default_rng(6)
    diag = mesh.bounding_diagonal
    lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
    O = rng.uniform(lo - diag, hi + diag, (200, 3))
    face, corner = rng.integers(0, mesh.n_faces, len(O)), rng.integers(0, 3, len(O))
    a = mesh.vertices[mesh.faces[face, corner]]
    b = mesh.vertices[mesh.faces[face, (corner + 1) % 3]]
    along = np.where(rng.random(len(O)) < 0.5, 0.0, rng.random(len(O)))
    D = a + along[:, None] * (b - a) - O
    ray, _, t, _ = RayCaster(mesh.vertices, mesh.faces).intersect(O, D, t_min=0.0)
    where, their_ray, _ = RayMeshIntersector(as_trimesh(mesh)).intersects_location(O, D, multiple_hits=True)
    their_t = np.einsum("ij,ij->i", where - O[their_ray], D[their_ray]) / (D[their_ray] ** 2).sum(1)
    order = np.lexsort((their_t, their_ray))
    assert np.array_equal(ray, their_ray[order])
    np.testing.assert_allclose(t, their_t[order], rtol=0, atol=RTOL)
    assert np.all(np.isin(np.arange(len(O)), ray))  # every ray meets its target
