"""Procedural surfaces: sizes, boundaries, vertices on the analytic surface, outward orientation, closed-form
areas and volumes, determinism, irregularity of the scan-like meshes, parameter checks and speed."""

import time

import numpy as np
import pytest
from scipy.spatial import Delaunay

from geodesics.primitives import (
    cone,
    cylinder,
    grid_plane,
    icosphere,
    scan_like_sphere,
    scan_like_torus,
    torus,
)


def boundary_loops(mesh):
    """Boundary loops as lists of vertices, following boundary halfedges head to tail."""
    b = np.flatnonzero(mesh.twin < 0)
    after = {int(mesh.halfedge_tail[h]): int(h) for h in b}
    assert len(after) == b.size  # one outgoing boundary halfedge per boundary vertex
    seen, loops = set(), []
    for h in b:
        if h in seen:
            continue
        loop, cur = [], int(h)
        while cur not in seen:
            seen.add(cur)
            loop.append(int(mesh.halfedge_tail[cur]))
            cur = after[int(mesh.halfedge_head[cur])]
        assert cur == h
        loops.append(loop)
    return loops


def signed_volume(mesh):
    T = mesh.vertices[mesh.faces]
    return np.einsum("ij,ij->i", T[:, 0], np.cross(T[:, 1], T[:, 2])).sum() / 6


def centroids(mesh):
    return mesh.vertices[mesh.faces].mean(1)


def torus_outward(c, major):
    """Unit outward normal of the torus at the point nearest to each c."""
    rho = np.hypot(c[:, 0], c[:, 1])
    core = np.stack([c[:, 0] / rho * major, c[:, 1] / rho * major, 0 * rho], 1)
    d = c - core
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def trapezoid_band_area(rho, z, n):
    """Area of the planar isosceles trapezoids between consecutive rings (radii rho, heights z), n sectors."""
    a = 2 * rho * np.sin(np.pi / n)
    h = np.hypot((rho[1:] - rho[:-1]) * np.cos(np.pi / n), z[1:] - z[:-1])
    return n * np.sum(0.5 * (a[1:] + a[:-1]) * h)


def valences(mesh):
    return np.bincount(mesh.faces.ravel(), minlength=mesh.n_vertices)


# ------------------------------------------------------------------------------------------ grid_plane


@pytest.mark.parametrize(("nx", "ny", "size", "jitter"), [(1, 1, (1.0, 1.0), 0.0), (7, 4, (2.0, 0.5), 0.24)])
def test_grid_plane(nx, ny, size, jitter):
    m = grid_plane(nx, ny, size=size, jitter=jitter, seed=2)
    assert (m.n_vertices, m.n_faces) == ((nx + 1) * (ny + 1), 2 * nx * ny)
    V = m.vertices
    np.testing.assert_array_equal(V[:, 2], 0.0)
    i, j = np.arange(m.n_vertices) % (nx + 1), np.arange(m.n_vertices) // (nx + 1)
    dx, dy = size[0] / nx, size[1] / ny
    assert np.all(np.abs(V[:, 0] - i * dx) <= jitter * dx + 1e-15)
    assert np.all(np.abs(V[:, 1] - j * dy) <= jitter * dy + 1e-15)
    # Sides stay on their lines, corners are fixed, everything stays inside the rectangle.
    np.testing.assert_array_equal(V[i == 0, 0], 0.0)
    np.testing.assert_array_equal(V[i == nx, 0], size[0])
    np.testing.assert_array_equal(V[j == 0, 1], 0.0)
    np.testing.assert_array_equal(V[j == ny, 1], size[1])
    corners = [0, nx, ny * (nx + 1), m.n_vertices - 1]
    np.testing.assert_array_equal(V[corners, :2], [[0, 0], [size[0], 0], [0, size[1]], list(size)])
    assert np.all((V[:, 0] >= 0) & (V[:, 0] <= size[0]) & (V[:, 1] >= 0) & (V[:, 1] <= size[1]))
    # One counter-clockwise boundary loop around the rectangle; all faces face +z and tile it.
    (loop,) = boundary_loops(m)
    assert len(loop) == 2 * (nx + ny)
    x, y = V[loop, 0], V[loop, 1]
    loop_area = 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
    assert loop_area == pytest.approx(size[0] * size[1], rel=1e-14)
    np.testing.assert_allclose(m.face_normals[:, 2], 1.0, atol=1e-15)
    assert m.face_areas.sum() == pytest.approx(size[0] * size[1], rel=1e-14)
    # Jitter < 1/4 keeps every triangle at least (1 - 4 jitter) / 2 cell areas.
    assert m.face_areas.min() >= (1 - 4 * jitter) / 2 * dx * dy * (1 - 1e-12)


def test_grid_plane_diagonals():
    regular = grid_plane(2, 1, seed=None)
    np.testing.assert_array_equal(regular.faces, [[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]])
    inner = ~grid_plane(6, 6, seed=None).is_boundary_vertex
    assert np.all(valences(grid_plane(6, 6, seed=None))[inner] == 6)
    random = grid_plane(6, 6, seed=1)
    assert len(np.unique(valences(random)[inner])) >= 3  # 4 .. 8
    # Each cell is split along one of its two diagonals.
    cells = random.faces.reshape(-1, 6)
    for c in cells:
        assert len(set(c)) == 4
    # The diagonals do not depend on the jitter (drawn first).
    np.testing.assert_array_equal(grid_plane(6, 6, jitter=0.2, seed=1).faces, random.faces)


# -------------------------------------------------------------------------------------------- cylinder


@pytest.mark.parametrize("jitter", [0.0, 0.2])
def test_cylinder(jitter):
    r, H, n, k = 0.7, 2.5, 13, 5
    m = cylinder(radius=r, height=H, n_around=n, n_along=k, jitter=jitter, seed=3)
    assert (m.n_vertices, m.n_faces) == (n * (k + 1), 2 * n * k)
    V = m.vertices
    np.testing.assert_allclose(np.hypot(V[:, 0], V[:, 1]), r, rtol=1e-15)
    loops = sorted(boundary_loops(m), key=lambda lp: V[lp[0], 2])
    assert [len(lp) for lp in loops] == [n, n]
    np.testing.assert_array_equal(V[loops[0], 2], 0.0)
    np.testing.assert_array_equal(V[loops[1], 2], H)
    assert np.all((V[:, 2] >= 0) & (V[:, 2] <= H))
    assert np.all(np.abs(V[:, 2] - np.repeat(np.arange(k + 1), n) * H / k) <= jitter * H / k + 1e-15)
    angle = np.angle(V[:, 0] + 1j * V[:, 1]) - 2 * np.pi * np.tile(np.arange(n), k + 1) / n
    assert np.all(np.abs(np.angle(np.exp(1j * angle))) <= jitter * 2 * np.pi / n + 1e-12)
    # Each column of vertices keeps one angle (a generator line), so the mesh stays developable.
    columns = (V[:, 0] + 1j * V[:, 1]).reshape(k + 1, n)
    np.testing.assert_allclose(
        columns / np.abs(columns), np.broadcast_to(columns[0] / r, columns.shape), atol=1e-15
    )
    np.testing.assert_allclose(m.angle_sums[~m.is_boundary_vertex], 2 * np.pi, atol=1e-12)
    # Outward: normals point away from the axis.
    c = centroids(m)
    assert np.all(np.einsum("ij,ij->i", m.face_normals[:, :2], c[:, :2]) > 0)
    if jitter == 0:  # planar rectangles
        assert m.face_areas.sum() == pytest.approx(n * 2 * r * np.sin(np.pi / n) * H, rel=1e-13)


# ------------------------------------------------------------------------------------------------ cone


@pytest.mark.parametrize("top_radius", [0.0, 0.3])
@pytest.mark.parametrize("jitter", [0.0, 0.2])
def test_cone(top_radius, jitter):
    R, H, n, k = 1.5, 2.0, 11, 4
    m = cone(base_radius=R, height=H, top_radius=top_radius, n_around=n, n_along=k, jitter=jitter, seed=4)
    V = m.vertices
    np.testing.assert_allclose(np.hypot(V[:, 0], V[:, 1]), R * (1 - V[:, 2] / H), atol=1e-15 * R)
    loops = sorted(boundary_loops(m), key=lambda lp: V[lp[0], 2])
    np.testing.assert_array_equal(V[loops[0], 2], 0.0)
    if top_radius > 0:
        z_top = H * (1 - top_radius / R)
        assert (m.n_vertices, m.n_faces) == (n * (k + 1), 2 * n * k)
        assert [len(lp) for lp in loops] == [n, n]
        np.testing.assert_array_equal(V[loops[1], 2], z_top)
        np.testing.assert_allclose(np.hypot(V[loops[1], 0], V[loops[1], 1]), top_radius, rtol=1e-14)
        assert np.all(V[:, 2] <= z_top)
    else:
        assert (m.n_vertices, m.n_faces) == (n * k + 1, n * (2 * k - 1))
        assert [len(lp) for lp in loops] == [n]
        np.testing.assert_array_equal(V[-1], [0, 0, H])
        assert valences(m)[-1] == n
        fan = m.faces[-n:]
        np.testing.assert_array_equal(fan[:, 2], m.n_vertices - 1)
        assert np.all(V[:-1, 2] < H)
    # Generator lines: all vertices of a column share their angle; heights move by at most jitter cells.
    rings = k + 1 if top_radius > 0 else k
    columns = (V[: rings * n, 0] + 1j * V[: rings * n, 1]).reshape(rings, n)
    directions = columns / np.abs(columns)
    np.testing.assert_allclose(directions, np.broadcast_to(directions[:1], columns.shape), atol=1e-15)
    dz = (H * (1 - top_radius / R) if top_radius > 0 else H) / k
    assert np.all(np.abs(V[: rings * n, 2] - np.repeat(np.arange(rings), n) * dz) <= jitter * dz + 1e-15)
    # Outward: away from the axis and up.
    c = centroids(m)
    assert np.all(np.einsum("ij,ij->i", m.face_normals[:, :2], c[:, :2]) > 0)
    assert np.all(m.face_normals[:, 2] > 0)
    if jitter == 0:  # the bands are planar trapezoids (the fan: triangles)
        z = V[::n, 2][:rings]
        rho = R * (1 - z / H)
        area = trapezoid_band_area(rho, z, n)
        if top_radius == 0:
            slant = np.hypot(rho[-1] * np.cos(np.pi / n), H - z[-1])  # apex to the middle of a chord
            area += n * rho[-1] * np.sin(np.pi / n) * slant
        assert m.face_areas.sum() == pytest.approx(area, rel=1e-13)


# ------------------------------------------------------------------------------------- closed surfaces


@pytest.mark.parametrize("s", [0, 1, 3])
def test_icosphere(s):
    r = 1.7
    m = icosphere(s, radius=r)
    assert (m.n_vertices, m.n_faces) == (10 * 4**s + 2, 20 * 4**s)
    assert np.all(m.twin >= 0) and m.n_components == 1
    np.testing.assert_allclose(np.linalg.norm(m.vertices, axis=1), r, rtol=1e-15)
    assert np.all(np.einsum("ij,ij->i", m.face_normals, centroids(m)) > 0)
    assert sorted(np.unique(valences(m)).tolist()) == ([5] if s == 0 else [5, 6])
    assert np.count_nonzero(valences(m) == 5) == 12
    volume = signed_volume(m)
    assert 0 < volume < 4 / 3 * np.pi * r**3
    if s == 0:
        a = r * 4 / np.sqrt(10 + 2 * np.sqrt(5))
        assert volume == pytest.approx(5 / 12 * (3 + np.sqrt(5)) * a**3, rel=1e-14)
    else:
        assert volume > (0.85 if s == 1 else 0.99) * 4 / 3 * np.pi * r**3


@pytest.mark.parametrize(("R", "r", "N", "M"), [(1.0, 0.35, 48, 24), (3.0, 1.0, 7, 5)])
def test_torus(R, r, N, M):
    m = torus(major=R, minor=r, n_major=N, n_minor=M)
    assert (m.n_vertices, m.n_faces) == (N * M, 2 * N * M)
    assert np.all(m.twin >= 0) and m.n_components == 1
    V = m.vertices
    implicit = (np.hypot(V[:, 0], V[:, 1]) - R) ** 2 + V[:, 2] ** 2
    np.testing.assert_allclose(implicit, r**2, atol=1e-14 * R**2)
    assert np.all(np.einsum("ij,ij->i", m.face_normals, torus_outward(centroids(m), R)) > 0)
    assert 0 < signed_volume(m) < 2 * np.pi**2 * R * r**2
    if N > 10:
        assert signed_volume(m) == pytest.approx(2 * np.pi**2 * R * r**2, rel=0.02)
    # The cells are planar isosceles trapezoids between rings of the tube.
    b = 2 * np.pi * np.arange(M + 1) / M
    area = trapezoid_band_area(R + r * np.cos(b), r * np.sin(b), N)
    assert m.face_areas.sum() == pytest.approx(area, rel=1e-13)
    np.testing.assert_array_equal(valences(m), 6)


def test_big_torus_is_fast():
    start = time.perf_counter()
    m = torus(n_major=1000, n_minor=500)
    elapsed = time.perf_counter() - start
    assert m.n_faces == 1_000_000 and np.all(m.twin >= 0)
    assert elapsed < 15.0, f"1,000,000-face torus took {elapsed:.1f} s"


# ------------------------------------------------------------------------------------------- scan-like


def test_scan_like_sphere():
    n, r = 400, 2.0
    m = scan_like_sphere(n, radius=r, seed=5)
    assert (m.n_vertices, m.n_faces) == (n, 2 * n - 4)
    assert np.all(m.twin >= 0) and m.n_components == 1 and m.isolated_vertices.size == 0
    np.testing.assert_allclose(np.linalg.norm(m.vertices, axis=1), r, rtol=1e-15)
    # Outward, and convex: every vertex is on the inner side of every face's plane.
    assert np.all(np.einsum("ij,ij->i", m.face_normals, centroids(m)) > 0)
    offsets = m.vertices[None, :, :] - m.vertices[m.faces[:, 0]][:, None, :]
    heights = np.einsum("fvd,fd->fv", offsets, m.face_normals)
    assert heights.max() < 1e-12
    assert signed_volume(m) > 0
    # Irregular, with skinny triangles.
    assert len(np.unique(valences(m))) > 4
    assert m.corner_angles.min() < 0.2 * icosphere(3).corner_angles.min()


def test_scan_like_torus():
    n, R, r = 500, 1.2, 0.4
    m = scan_like_torus(n, major=R, minor=r, seed=6)
    assert (m.n_vertices, m.n_faces) == (n, 2 * n)
    assert np.all(m.twin >= 0) and m.n_components == 1
    assert m.n_vertices - m.n_edges + m.n_faces == 0
    V = m.vertices
    implicit = (np.hypot(V[:, 0], V[:, 1]) - R) ** 2 + V[:, 2] ** 2
    np.testing.assert_allclose(implicit, r**2, atol=1e-14)
    assert np.all(np.einsum("ij,ij->i", m.face_normals, torus_outward(centroids(m), R)) > 0)
    assert signed_volume(m) == pytest.approx(2 * np.pi**2 * R * r**2, rel=0.1)
    assert len(np.unique(valences(m))) > 4
    assert m.corner_angles.min() < 0.2 * torus(R, r).corner_angles.min()


def canonical(faces):
    """Faces as a set of tuples rotated to start at their smallest index (orientation kept)."""
    k = np.argmin(faces, axis=1)
    rolled = np.stack([np.roll(f, -i) for f, i in zip(faces, k, strict=True)])
    return set(map(tuple, rolled.tolist()))


@pytest.mark.parametrize("seed", [0, 1])
def test_scan_like_torus_is_the_periodic_delaunay_triangulation(seed):
    # Independent construction: all 9 tiles, scaled like the torus, keep the triangles with centroid in the
    # unit square, orient counter-clockwise.
    n, R, r = 300, 1.0, 0.35
    m = scan_like_torus(n, major=R, minor=r, seed=seed)
    uv = np.random.default_rng(seed).random((n, 2))  # the first draw (no redraw happens for these seeds)
    a, b = 2 * np.pi * uv[:, 0], 2 * np.pi * uv[:, 1]
    np.testing.assert_allclose(m.vertices[:, 2], r * np.sin(b), atol=1e-15)
    azimuth = np.arctan2(m.vertices[:, 1], m.vertices[:, 0])
    np.testing.assert_allclose(np.exp(1j * azimuth), np.exp(1j * a), atol=1e-12)
    offsets = np.array([[i, j] for i in (-1, 0, 1) for j in (-1, 0, 1)], float)
    tiled = (uv[None] + offsets[:, None]).reshape(-1, 2)
    T = Delaunay(tiled * [R, r]).simplices
    c = tiled[T].mean(1)
    T = T[np.all((c >= 0) & (c < 1), axis=1)]
    P = tiled[T]
    d1, d2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    ccw = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    T[ccw < 0] = T[ccw < 0][:, ::-1]
    assert canonical(T % n) == canonical(m.faces)


def test_scan_like_torus_is_valid_for_many_seeds():
    for seed in range(12):
        for n in (100, 200):
            m = scan_like_torus(n, seed=seed)
            assert m.n_faces == 2 * n and np.all(m.twin >= 0) and m.n_components == 1
            assert np.all(np.einsum("ij,ij->i", m.face_normals, torus_outward(centroids(m), 1.0)) > 0)
        m = scan_like_torus(300, minor=0.1, seed=seed)  # a thin tube needs a few hundred points
        assert np.all(np.einsum("ij,ij->i", m.face_normals, torus_outward(centroids(m), 1.0)) > 0)


def test_scan_like_sphere_small():
    m = scan_like_sphere(4, seed=0)
    assert m.n_faces == 4 and signed_volume(m) > 0


# ----------------------------------------------------------------------------------------- determinism


@pytest.mark.parametrize(
    "make",
    [
        lambda seed: grid_plane(6, 5, jitter=0.2, seed=seed),
        lambda seed: cylinder(n_around=9, n_along=3, jitter=0.2, seed=seed),
        lambda seed: cone(top_radius=0.0, n_around=9, n_along=3, jitter=0.2, seed=seed),
        lambda seed: scan_like_sphere(200, seed=seed),
        lambda seed: scan_like_torus(200, seed=seed),
    ],
    ids=["grid_plane", "cylinder", "cone", "scan_like_sphere", "scan_like_torus"],
)
def test_determinism(make):
    a, b, c = make(7), make(7), make(8)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    assert not np.array_equal(a.vertices, c.vertices)


def test_regular_ones_are_deterministic():
    makers = (lambda: icosphere(2), lambda: torus(n_major=10, n_minor=6), lambda: grid_plane(3, 3, seed=None))
    for make in makers:
        a, b = make(), make()
        np.testing.assert_array_equal(a.vertices, b.vertices)
        np.testing.assert_array_equal(a.faces, b.faces)


# -------------------------------------------------------------------------------------- bad parameters


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: grid_plane(0, 3), "nx must be an integer >= 1"),
        (lambda: grid_plane(2.5, 3), "nx must be an integer"),
        (lambda: grid_plane(2, 3, size=(1.0, -1.0)), "size must be a positive"),
        (lambda: grid_plane(2, 3, jitter=0.25), r"jitter must be in \[0, 0.25\)"),
        (lambda: grid_plane(2, 3, jitter=-0.1), r"jitter must be in"),
        (lambda: grid_plane(2, 3, jitter=0.1, seed=None), "jitter needs a seed"),
        (lambda: cylinder(n_around=2), "n_around must be an integer >= 3"),
        (lambda: cylinder(radius=0.0), "radius must be a positive"),
        (lambda: cone(top_radius=1.0), r"top_radius must be in \[0, base_radius"),
        (lambda: cone(top_radius=-0.1), "top_radius must be in"),
        (lambda: cone(n_along=0), "n_along must be an integer >= 1"),
        (lambda: icosphere(-1), "subdivisions must be an integer >= 0"),
        (lambda: torus(1.0, 1.0), "minor radius 1.0 must be smaller than major radius 1.0"),
        (lambda: torus(n_minor=2), "n_minor must be an integer >= 3"),
        (lambda: scan_like_sphere(3), "n_points must be an integer >= 4"),
        (lambda: scan_like_torus(99), "n_points must be an integer >= 100"),
        (lambda: scan_like_torus(200, major=0.3, minor=0.5), "must be smaller than major"),
    ],
)
def test_bad_parameters(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_too_few_points_for_a_thin_tube():
    with pytest.raises(RuntimeError, match="use more points"):
        scan_like_torus(100, minor=0.05, seed=0)
