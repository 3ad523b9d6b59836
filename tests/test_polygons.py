"""TriMesh.from_polygons / triangulate_polygons: quads split like Blender, ngons ear-clipped (areas and
coverage checked against the polygons), provenance of every triangle, and errors naming bad polygons."""

import numpy as np
import pytest

from geodesics.errors import MeshError
from geodesics.mesh import TriMesh
from geodesics.polygons import triangulate_polygons

L_HEXAGON = np.array([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], float)  # concave at (1, 1), area 3


def star(n=5, outer=1.0, inner=0.4):
    """A star-shaped polygon with ``2n`` corners, counter-clockwise, starting at an outer tip."""
    a = np.pi / 2 + np.pi * np.arange(2 * n) / n
    r = np.where(np.arange(2 * n) % 2 == 0, outer, inner)
    return np.stack([r * np.cos(a), r * np.sin(a)], 1)


def comb():
    """A comb: a bar with three teeth pointing up (12 corners, many reflex), area 2*1 + 3*0.5*1.5."""
    return np.array(
        [[0, 0], [4, 0], [4, 2.5], [3.5, 2.5], [3.5, 1], [2.25, 1], [2.25, 2.5], [1.75, 2.5], [1.75, 1],
         [0.5, 1], [0.5, 2.5], [0, 2.5]], float,
    )  # fmt: skip


def cross2(a, b):
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def shoelace(q):
    x, y = q[:, 0], q[:, 1]
    return 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)


def inside_polygon(points, q):
    """Even-odd ray casting, independent of the triangulation."""
    x, y = points[:, 0:1], points[:, 1:2]
    x0, y0 = q[:, 0], q[:, 1]
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    crosses = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xc = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return np.count_nonzero(crosses & (x < xc), axis=1) % 2 == 1


def in_triangles(points, T):
    """(k, t) whether each point lies strictly inside each 2D triangle (t, 3, 2)."""

    def side(a, b):
        return (b[:, 0] - a[:, 0]) * (points[:, None, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (
            points[:, None, 0] - a[:, 0]
        )

    a, b, c = T[:, 0], T[:, 1], T[:, 2]
    return (side(a, b) > 0) & (side(b, c) > 0) & (side(c, a) > 0)


def lift(q, rotation=None, offset=(0.0, 0.0, 0.0)):
    """2D points to 3D in z = 0, optionally rotated and moved."""
    P = np.column_stack([q, np.zeros(len(q))])
    return P @ (np.eye(3) if rotation is None else rotation).T + offset


def rotation_matrix(seed):
    Q, R = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    Q = Q * np.sign(np.diag(R))
    return Q if np.linalg.det(Q) > 0 else -Q


def check_tiling(q, tris2d):
    """The triangles tile the polygon: same area, positively oriented, and every sample point of the
    bounding box is in exactly one triangle if it is in the polygon, in none otherwise."""
    areas = 0.5 * cross2(tris2d[:, 1] - tris2d[:, 0], tris2d[:, 2] - tris2d[:, 0])
    assert np.all(areas > 0)
    assert areas.sum() == pytest.approx(shoelace(q), rel=1e-12)
    rng = np.random.default_rng(0)
    lo, hi = q.min(0), q.max(0)
    pts = lo + (hi - lo) * rng.random((4000, 2))
    count = in_triangles(pts, tris2d).sum(1)
    inside = inside_polygon(pts, q)
    np.testing.assert_array_equal(count, inside.astype(int))


@pytest.mark.parametrize("name", ["L_hexagon", "star", "comb", "convex_octagon"])
@pytest.mark.parametrize("tilted", [False, True])
def test_ngon_triangulation_tiles_the_polygon(name, tilted):
    q = {
        "L_hexagon": L_HEXAGON,
        "star": star(),
        "comb": comb(),
        "convex_octagon": np.stack([np.cos(np.arange(8) * np.pi / 4), np.sin(np.arange(8) * np.pi / 4)], 1),
    }[name]
    R = rotation_matrix(3) if tilted else np.eye(3)
    offset = np.array([0.3, -2.0, 5.0]) if tilted else np.zeros(3)
    for shift in range(len(q)):  # every choice of first corner
        poly = np.roll(np.arange(len(q)), -shift)
        mesh = TriMesh.from_polygons(lift(q, R, offset), [poly])
        assert mesh.n_faces == len(q) - 2
        np.testing.assert_array_equal(mesh.triangle_polygon, 0)
        np.testing.assert_array_equal(poly[mesh.triangle_corners], mesh.faces)
        np.testing.assert_allclose(mesh.face_normals, np.broadcast_to(R[:, 2], (mesh.n_faces, 3)), atol=1e-12)
        check_tiling(q, q[mesh.faces])
    assert mesh.face_areas.sum() == pytest.approx(abs(shoelace(q)), rel=1e-12)


def test_known_areas():
    assert shoelace(L_HEXAGON) == 3.0
    # comb: the 4 x 2.5 box minus the two gaps between the teeth (1.25 x 1.5 each)
    assert shoelace(comb()) == pytest.approx(4 * 2.5 - 2 * 1.25 * 1.5, rel=1e-15)
    s = star(5, 1.0, 0.4)
    assert shoelace(s) == pytest.approx(10 * 0.5 * 1.0 * 0.4 * np.sin(np.pi / 5), rel=1e-14)


def test_convex_quad_is_split_along_0_2():
    V = lift(np.array([[0, 0], [2, 0], [2.5, 1.5], [0, 1]], float))
    mesh = TriMesh.from_polygons(V, [[0, 1, 2, 3]])
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [0, 2, 3]])
    np.testing.assert_array_equal(mesh.triangle_corners, [[0, 1, 2], [0, 2, 3]])


DART = np.array([[0, 0], [2, 1], [0, 2], [0.5, 1]], float)  # reflex corner 3: the 0-2 diagonal lies outside


@pytest.mark.parametrize(
    ("reflex", "expected"),
    [
        (3, [[0, 1, 3], [1, 2, 3]]),
        (1, [[0, 1, 3], [1, 2, 3]]),
        (0, [[0, 1, 2], [0, 2, 3]]),
        (2, [[0, 1, 2], [0, 2, 3]]),
    ],
)
def test_concave_quad_split_avoids_the_fold(reflex, expected):
    q = np.roll(DART, reflex - 3, axis=0)  # corner `reflex` is the dart's reflex corner
    mesh = TriMesh.from_polygons(lift(q), [[0, 1, 2, 3]])
    np.testing.assert_array_equal(mesh.faces, expected)
    np.testing.assert_array_equal(mesh.triangle_corners, expected)
    check_tiling(q, q[mesh.faces])
    assert mesh.face_areas.sum() == pytest.approx(1.5, rel=1e-14)


def test_mixed_polygons_keep_their_provenance():
    # A triangle, a quad, a pentagon, the L hexagon and the star, side by side, listed in a shuffled order.
    shapes = [
        np.array([[0, 0], [1, 0], [0, 1]], float),
        np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float),
        np.stack([np.cos(np.arange(5) * 2 * np.pi / 5), np.sin(np.arange(5) * 2 * np.pi / 5)], 1),
        L_HEXAGON,
        star(),
    ]
    order = [3, 0, 4, 1, 2]
    V, polygons, offset = [], [], 0
    for k, i in enumerate(order):
        q = shapes[i] + [3.0 * k, 0]
        V.append(lift(q))
        idx = offset + np.arange(len(q))
        polygons.append(list(np.roll(idx, k)))  # also start at different corners
        offset += len(q)
    V = np.concatenate(V)
    mesh = TriMesh.from_polygons(V, polygons)
    sizes = np.array([len(shapes[i]) for i in order])
    assert mesh.n_faces == np.sum(sizes - 2)
    np.testing.assert_array_equal(mesh.triangle_polygon, np.repeat(np.arange(5), sizes - 2))
    for t in range(mesh.n_faces):
        p = mesh.triangle_polygon[t]
        np.testing.assert_array_equal(np.asarray(polygons[p])[mesh.triangle_corners[t]], mesh.faces[t])
    area = np.bincount(mesh.triangle_polygon, weights=mesh.face_areas)
    np.testing.assert_allclose(area, [shoelace(shapes[i]) for i in order], rtol=1e-12)
    assert mesh.n_components == 5
    np.testing.assert_allclose(mesh.face_normals[:, 2], 1.0, atol=1e-12)
    assert not mesh.triangle_polygon.flags.writeable and not mesh.triangle_corners.flags.writeable


def test_plain_trimesh_has_no_provenance():
    mesh = TriMesh(lift(np.array([[0, 0], [1, 0], [0, 1]], float)), [[0, 1, 2]])
    assert mesh.triangle_polygon is None and mesh.triangle_corners is None


def test_quad_grid_array_and_closed_cube():
    # A (p, 4) array of quads: a 3 x 2 grid.
    nx, ny = 3, 2
    i, j = np.meshgrid(np.arange(nx), np.arange(ny))
    a = (j * (nx + 1) + i).ravel()
    quads = np.stack([a, a + 1, a + nx + 2, a + nx + 1], 1)
    gx, gy = np.meshgrid(np.arange(nx + 1) * 0.5, np.arange(ny + 1) * 0.25)
    V = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    mesh = TriMesh.from_polygons(V, quads)
    assert mesh.n_faces == 2 * nx * ny
    np.testing.assert_array_equal(mesh.triangle_polygon, np.repeat(np.arange(nx * ny), 2))
    np.testing.assert_array_equal(mesh.faces[0::2], quads[:, [0, 1, 2]])
    np.testing.assert_array_equal(mesh.faces[1::2], quads[:, [0, 2, 3]])
    assert mesh.face_areas.sum() == pytest.approx(1.5 * 0.5, rel=1e-14)
    # The unit cube from six outward quads: closed, volume 1, Gauss–Bonnet with χ = 2.
    C = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], float)
    cube = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]
    mesh = TriMesh.from_polygons(C, cube)
    assert np.all(mesh.twin >= 0) and mesh.n_faces == 12
    T = mesh.vertices[mesh.faces]
    volume = np.einsum("ij,ij->i", T[:, 0], np.cross(T[:, 1], T[:, 2])).sum() / 6
    assert volume == pytest.approx(1.0, rel=1e-14)
    np.testing.assert_allclose(mesh.angle_sums, 1.5 * np.pi, rtol=1e-14)
    assert np.sum(2 * np.pi - mesh.angle_sums) == pytest.approx(4 * np.pi, rel=1e-14)


def test_non_planar_quad_uses_0_2():
    V = np.array([[0, 0, 0], [1, 0, 0.3], [1, 1, 0], [0, 1, 0.3]], float)
    mesh = TriMesh.from_polygons(V, [[0, 1, 2, 3]])
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [0, 2, 3]])


@pytest.mark.parametrize(
    ("polygons", "match", "bad"),
    [
        ([[0, 1, 2], [0, 1]], r"polygons 1 have fewer than three corners", [1]),
        ([[0, 1], [0, 1, 2], [3], [0, 1, 2, 3]], r"polygons 0, 2 have fewer than three corners", [0, 2]),
        ([[0, 1, 2], [0, 2, 3, 9]], r"polygons 1 use vertex indices outside 0\.\.4", [1]),
        ([[0, 1, 2, 3, 4], [0, -1, 3], [5, 1, 2]], r"polygons 1, 2 use vertex indices outside 0\.\.", [1, 2]),
        (np.array([[0, 1, 2, 3], [0, 1, 2, 7]]), r"polygons 1 use vertex indices outside", [1]),
    ],
)
def test_bad_polygons(polygons, match, bad):
    V = lift(np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 2]], float))
    with pytest.raises(MeshError, match=match) as info:
        TriMesh.from_polygons(V, polygons)
    np.testing.assert_array_equal(info.value.faces, bad)


def test_no_or_garbage_polygons():
    V = lift(np.array([[0, 0], [1, 0], [0, 1]], float))
    with pytest.raises(MeshError, match="the mesh has no faces"):
        TriMesh.from_polygons(V, [])
    with pytest.raises(MeshError, match="polygons must be sequences of vertex indices"):
        TriMesh.from_polygons(V, [[0, 1, "two"]])


def test_triangulate_polygons_directly():
    V = lift(L_HEXAGON)
    faces, polygon, corners = triangulate_polygons(V, [np.arange(6), [0, 1, 2]])
    assert faces.dtype == polygon.dtype == corners.dtype == np.int64
    np.testing.assert_array_equal(polygon, [0, 0, 0, 0, 1])
    np.testing.assert_array_equal(faces[-1], [0, 1, 2])
    check_tiling(L_HEXAGON, L_HEXAGON[faces[:4]])


def test_blender_flat_layout_matches_the_list_layout():
    """Blender stores polygons as one flat array of corner vertices and a corner count per polygon."""
    rng = np.random.default_rng(12)
    V = rng.random((20, 3))
    V[:, 2] = 0.0
    polygons = [[0, 1, 2], [3, 4, 5, 6], [7, 8, 9, 10, 11], [12, 13, 14]]
    flat = np.concatenate(polygons)
    sizes = np.array([len(p) for p in polygons])
    a = triangulate_polygons(V, polygons)
    b = triangulate_polygons(V, (flat, sizes))
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    with pytest.raises(MeshError, match="add up to 15 corners, but 14"):
        triangulate_polygons(V, (flat[:-1], sizes))
