"""TriMesh: validation (errors name the offending elements), halfedges, face frames, vertex fans and the
intrinsic geometry (angles, Gauss–Bonnet, unfolding across edges)."""

import warnings

import numpy as np
import pytest

from geodesics.errors import MeshError, MeshWarning
from geodesics.mesh import TriMesh
from geodesics.primitives import (
    cone,
    cylinder,
    grid_plane,
    icosphere,
    scan_like_sphere,
    scan_like_torus,
    torus,
)

SQUARE_V = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
SQUARE_F = np.array([[0, 1, 2], [0, 2, 3]])
TETRA_V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
TETRA_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])  # outward

MESHES = [
    grid_plane(5, 4, jitter=0.2, seed=1),
    cylinder(n_around=10, n_along=3, jitter=0.2, seed=2),
    cone(top_radius=0.0, n_around=9, n_along=3, jitter=0.2, seed=3),
    cone(top_radius=0.3, n_around=9, n_along=3, jitter=0.2, seed=3),
    icosphere(2),
    torus(n_major=12, n_minor=8),
    scan_like_sphere(300, seed=4),
    scan_like_torus(300, seed=5),
]


def raises(match: str, **kwargs) -> MeshError:
    """Build a TriMesh that must fail with a message matching ``match``; return the error."""
    with pytest.raises(MeshError, match=match) as info:
        TriMesh(**kwargs)
    return info.value


def assert_ids(err: MeshError, vertices=(), faces=(), edges=None):
    np.testing.assert_array_equal(err.vertices, np.asarray(vertices, np.int64))
    np.testing.assert_array_equal(err.faces, np.asarray(faces, np.int64))
    if edges is not None:
        np.testing.assert_array_equal(err.edges, np.asarray(edges, np.int64).reshape(-1, 2))


def to3d(z, axes):
    """Complex face-frame vectors (k,) to 3D with the frames' axes (k, 2, 3)."""
    return z.real[:, None] * axes[:, 0] + z.imag[:, None] * axes[:, 1]


# ------------------------------------------------------------------------------------------------- validation


def test_valid_square():
    m = TriMesh(SQUARE_V, SQUARE_F)
    assert (m.n_vertices, m.n_faces, m.n_edges, m.n_components) == (4, 2, 5, 1)
    assert m.isolated_vertices.size == 0
    assert m.faces.dtype == np.int64 and not m.faces.flags.writeable and not m.vertices.flags.writeable
    np.testing.assert_allclose(m.face_areas, [0.5, 0.5], rtol=1e-15)
    np.testing.assert_allclose(m.face_normals, [[0, 0, 1], [0, 0, 1]], atol=1e-15)


def test_input_is_copied():
    V, F = SQUARE_V.copy(), SQUARE_F.copy()
    m = TriMesh(V, F)
    V[0, 0] = 5.0
    F[0, 0] = 3
    assert m.vertices[0, 0] == 0.0 and m.faces[0, 0] == 0


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_vertex(bad):
    V = SQUARE_V.copy()
    V[2, 1] = bad
    err = raises(r"vertices 2 have NaN or infinite coordinates", vertices=V, faces=SQUARE_F)
    assert_ids(err, vertices=[2])


def test_non_finite_vertices_are_all_named():
    V = np.vstack([SQUARE_V, [[np.nan, 0, 0]]])
    V[1, 2] = np.inf
    err = raises(r"vertices 1, 4 have NaN", vertices=V, faces=SQUARE_F)  # even the unused vertex 4
    assert_ids(err, vertices=[1, 4])


def test_index_out_of_range():
    F = [[0, 1, 2], [0, 2, 7]]
    err = raises(r"faces 1 use vertex indices outside 0\.\.3", vertices=SQUARE_V, faces=F)
    assert_ids(err, faces=[1])


def test_negative_index():
    F = [[-1, 1, 2], [0, 2, 3]]
    err = raises(r"faces 0 use vertex indices outside 0\.\.3", vertices=SQUARE_V, faces=F)
    assert_ids(err, faces=[0])


def test_many_bad_faces_are_summarized_but_all_kept():
    F = np.tile([0, 1, 9], (12, 1))
    err = raises(r"faces 0, 1, .*, 9, … \(12 in all\)", vertices=SQUARE_V, faces=F)
    assert_ids(err, faces=np.arange(12))


def test_repeated_vertex_in_face():
    F = [[0, 1, 2], [2, 3, 2]]
    err = raises(r"faces 1 are degenerate: they repeat a vertex", vertices=SQUARE_V, faces=F)
    assert_ids(err, faces=[1])


def test_collinear_face():
    V = np.vstack([SQUARE_V, [[1.0, 2.0, 0.0]]])  # (1,0), (1,1), (1,2) are collinear
    err = raises(r"faces 2 are degenerate \(zero area", vertices=V, faces=[[0, 1, 2], [0, 2, 3], [2, 1, 4]])
    assert_ids(err, faces=[2])


def test_coincident_vertices_face():
    V = np.vstack([SQUARE_V, [[1.0, 1.0, 0.0]]])  # vertex 4 sits on vertex 2
    err = raises(r"faces 2 are degenerate", vertices=V, faces=[[0, 1, 2], [0, 2, 3], [2, 4, 3]])
    assert_ids(err, faces=[2])


def test_degeneracy_threshold_is_relative():
    # A triangle of base 1 and height h: rejected below 1e-12 (relative to its longest edge), accepted above.
    for scale in [1e-6, 1.0, 1e6]:
        for h, ok in [(1e-13, False), (1e-10, True)]:
            V = scale * np.array([[0.0, 0, 0], [1, 0, 0], [0.5, h, 0]])
            if ok:
                assert TriMesh(V, [[0, 1, 2]]).face_areas[0] == pytest.approx(0.5 * h * scale**2, rel=1e-6)
            else:
                assert_ids(raises("degenerate", vertices=V, faces=[[0, 1, 2]]), faces=[0])


def test_non_manifold_edge():
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -1, 0], [0.5, 0, 1]])
    F = [[0, 1, 2], [1, 0, 3], [1, 0, 4]]
    err = raises(r"1 edges are non-manifold .* edge \(0, 1\), used by faces 0, 1, 2", vertices=V, faces=F)
    assert_ids(err, faces=[0, 1, 2], edges=[[0, 1]])


def two_cones(apex: int, n: int = 5):
    """Two open cones (fans closed around their apex) touching only at the apex vertex ``apex``."""
    ring = np.exp(2j * np.pi * np.arange(n) / n)
    up = np.stack([ring.real, ring.imag, np.ones(n)], 1)
    down = np.stack([ring.real, ring.imag, -np.ones(n)], 1)
    V = np.insert(np.concatenate([up, down]), apex, [0.0, 0.0, 0.0], axis=0)
    idx = np.delete(np.arange(2 * n + 1), apex)  # vertex index of the k-th ring point
    a, b = idx[:n], idx[n:]
    F = [[apex, a[k], a[(k + 1) % n]] for k in range(n)] + [[apex, b[(k + 1) % n], b[k]] for k in range(n)]
    return V, np.array(F)


def test_bowtie_interior_vertex():
    V, F = two_cones(apex=3)
    # Every edge has one or two faces, but vertex 3 has two separate closed fans.
    err = raises(r"vertices 3 are non-manifold \(their faces form more than one fan", vertices=V, faces=F)
    assert_ids(err, vertices=[3])


def test_bowtie_boundary_vertex():
    V = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [2, 1, 0], [2, 2, 0]])
    F = [[0, 1, 2], [2, 3, 4]]  # two triangles touching at vertex 2
    err = raises(r"vertices 2 are non-manifold \(several boundary fans meet there\)", vertices=V, faces=F)
    assert_ids(err, vertices=[2])


def test_boundary_fan_plus_closed_fan():
    V, F = two_cones(apex=0)
    V = np.vstack([V, [[3.0, 0, 0], [3, 1, 0]]])
    F = np.vstack([F, [[0, 11, 12]]])  # a lone triangle also touches the apex: one boundary fan, two closed
    err = raises(r"vertices 0 are non-manifold", vertices=V, faces=F)
    assert_ids(err, vertices=[0])


def test_inconsistent_orientation():
    V = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [1, 1, 0], [2, 1, 0]])
    F = [[0, 1, 4], [0, 4, 3], [1, 5, 2], [1, 5, 4]]  # face 2 should be [1, 2, 5]
    match = r"faces 2, 3 are oriented inconsistently .*edge \(1, 5\) runs the same way"
    err = raises(match, vertices=V, faces=F)
    assert_ids(err, faces=[2, 3], edges=[[1, 5]])


def test_flipped_tetrahedron_face():
    F = TETRA_F.copy()
    F[3] = F[3, ::-1]
    err = raises("oriented inconsistently", vertices=TETRA_V, faces=F)
    assert 3 in err.faces and len(err.edges) >= 1


@pytest.mark.parametrize(
    ("vertices", "faces", "match"),
    [
        (SQUARE_V[:, :2], SQUARE_F, r"vertices must have shape \(n, 3\), got \(4, 2\)"),
        (SQUARE_V.ravel(), SQUARE_F, r"vertices must have shape \(n, 3\), got \(12,\)"),
        (SQUARE_V, [[0, 1, 2, 3]], r"faces must have shape \(m, 3\), got \(1, 4\); use TriMesh\.from_poly"),
        (SQUARE_V, [0, 1, 2], r"faces must have shape \(m, 3\), got \(3,\)"),
        (SQUARE_V, [[0, 1, 2.5]], r"face indices must be integers"),
        (SQUARE_V, [[0, 1, np.nan]], r"face indices must be integers"),
        (SQUARE_V, np.empty((0, 3), np.int64), r"the mesh has no faces"),
        (SQUARE_V, [], r"the mesh has no faces"),
    ],
)
def test_bad_shapes(vertices, faces, match):
    raises(match, vertices=vertices, faces=faces)


def test_integral_float_faces_are_accepted():
    m = TriMesh(SQUARE_V, SQUARE_F.astype(float))
    np.testing.assert_array_equal(m.faces, SQUARE_F)


def test_isolated_vertices_warn_and_keep_indices():
    V = np.vstack([SQUARE_V[:2], [[7.0, 7, 7]], SQUARE_V[2:], [[9.0, 9, 9]]])  # vertices 2 and 5 unused
    F = [[0, 1, 3], [0, 3, 4]]
    with pytest.warns(MeshWarning, match=r"2 vertices are used by no face and are ignored: 2, 5"):
        m = TriMesh(V, F)
    np.testing.assert_array_equal(m.isolated_vertices, [2, 5])
    np.testing.assert_array_equal(m.faces, F)
    assert m.n_vertices == 6
    np.testing.assert_array_equal(m.vertex_components, [0, 0, -1, 0, 0, -1])
    np.testing.assert_array_equal(m.vertex_halfedge[[2, 5]], [-1, -1])
    np.testing.assert_array_equal(m.angle_sums[[2, 5]], [0, 0])
    assert m.ring_start[3] == m.ring_start[2]
    np.testing.assert_array_equal(m.vertex_normals[[2, 5]], 0.0)
    assert m.bounding_diagonal == pytest.approx(np.sqrt(2))  # only used vertices count


def test_no_warning_without_isolated_vertices():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        TriMesh(SQUARE_V, SQUARE_F)


def test_components_and_boundaries():
    # A square (one boundary loop), a closed tetrahedron and a lone triangle, with faces interleaved.
    V = np.vstack([TETRA_V + 5, SQUARE_V, [[0.0, 0, 3], [1, 0, 3], [0, 1, 3]]])
    parts = [SQUARE_F + 4, TETRA_F, np.array([[8, 9, 10]])]
    F = np.vstack([parts[0][0], parts[1][0], parts[2][0], parts[1][1:], parts[0][1]])
    part_of_face = np.array([0, 1, 2, 1, 1, 1, 0])
    m = TriMesh(V, F)
    assert m.n_components == 3
    labels = m.face_components
    for part in range(3):
        assert np.unique(labels[part_of_face == part]).size == 1
    assert np.unique(labels[[0, 1, 2]]).size == 3
    np.testing.assert_array_equal(m.vertex_components[:4], labels[1])
    np.testing.assert_array_equal(m.vertex_components[4:8], labels[0])
    np.testing.assert_array_equal(m.vertex_components[8:], labels[2])
    # Boundary: 4 edges of the square, 3 of the triangle, none of the tetrahedron.
    assert np.count_nonzero(m.twin < 0) == 7
    np.testing.assert_array_equal(m.is_boundary_vertex, [False] * 4 + [True] * 7)
    assert m.n_edges == 5 + 6 + 3
    assert repr(m) == "TriMesh(11 vertices, 7 faces, 3 components, 7 boundary edges)"


# -------------------------------------------------------------------------------------------------- halfedges


@pytest.mark.parametrize("m", MESHES, ids=repr)
def test_halfedge_conventions(m):
    h = np.arange(3 * m.n_faces)
    f, k = h // 3, h % 3
    np.testing.assert_array_equal(m.halfedge_tail, m.faces[f, k])
    np.testing.assert_array_equal(m.halfedge_head, m.faces[f, (k + 1) % 3])
    inner = m.twin >= 0
    t = m.twin[inner]
    np.testing.assert_array_equal(m.twin[t], h[inner])
    np.testing.assert_array_equal(m.halfedge_tail[t], m.halfedge_head[inner])
    np.testing.assert_array_equal(m.halfedge_head[t], m.halfedge_tail[inner])
    assert np.all(t // 3 != f[inner])
    np.testing.assert_array_equal(m.halfedge_edge[t], m.halfedge_edge[inner])
    # Independent edge count: each undirected edge once.
    pairs = np.unique(np.sort(np.stack([m.halfedge_tail, m.halfedge_head], 1), axis=1), axis=0)
    assert m.n_edges == len(pairs) == np.unique(m.halfedge_edge).size
    # A boundary halfedge has no reverse anywhere in the mesh.
    directed = set(zip(m.halfedge_tail.tolist(), m.halfedge_head.tolist(), strict=True))
    for b in np.flatnonzero(~inner):
        assert (m.halfedge_head[b], m.halfedge_tail[b]) not in directed


@pytest.mark.parametrize(("nx", "ny"), [(1, 1), (5, 4), (7, 2)])
def test_grid_boundary_and_edge_counts(nx, ny):
    m = grid_plane(nx, ny, jitter=0.1, seed=nx)
    assert np.count_nonzero(m.twin < 0) == 2 * (nx + ny)
    assert m.n_edges == nx * (ny + 1) + ny * (nx + 1) + nx * ny
    corners = [0, nx, ny * (nx + 1), (nx + 1) * (ny + 1) - 1]
    assert np.count_nonzero(m.is_boundary_vertex) == 2 * (nx + ny)
    assert np.all(m.is_boundary_vertex[corners])


@pytest.mark.parametrize("m", MESHES, ids=repr)
def test_rings_are_the_counter_clockwise_fans(m):
    h = np.arange(3 * m.n_faces)
    prev = h - h % 3 + (h + 2) % 3
    counts = np.bincount(m.halfedge_tail, minlength=m.n_vertices)
    np.testing.assert_array_equal(np.diff(m.ring_start), counts)
    for v in range(m.n_vertices):
        ring = m.ring[m.ring_start[v] : m.ring_start[v + 1]]
        assert np.all(m.halfedge_tail[ring] == v)
        assert ring[0] == m.vertex_halfedge[v]
        np.testing.assert_array_equal(m.twin[prev[ring[:-1]]], ring[1:])  # next counter-clockwise
        if m.is_boundary_vertex[v]:
            assert m.twin[ring[0]] == -1 and m.twin[prev[ring[-1]]] == -1
        else:
            assert m.twin[prev[ring[-1]]] == ring[0]


# ------------------------------------------------------------------------------------------------ face frames


@pytest.mark.parametrize("m", MESHES, ids=repr)
def test_face_frames_reproduce_the_triangles(m):
    P = m.face_points
    assert np.all(P[:, 0] == 0) and np.all(P[:, 1].imag == 0) and np.all(P[:, 1].real > 0)
    assert np.all(P[:, 2].imag > 0)
    axes = m.face_axes(np.arange(m.n_faces))
    gram = np.einsum("fij,fkj->fik", axes, axes)
    np.testing.assert_allclose(gram, np.broadcast_to(np.eye(2), gram.shape), atol=1e-14)
    np.testing.assert_allclose(np.cross(axes[:, 0], axes[:, 1]), m.face_normals, atol=1e-14)
    V = m.vertices[m.faces]
    back = V[:, :1] + P.real[..., None] * axes[:, None, 0] + P.imag[..., None] * axes[:, None, 1]
    np.testing.assert_allclose(back, V, atol=1e-13 * m.bounding_diagonal)
    # Areas and corner angles from the 3D positions, independently.
    e1, e2 = V[:, 1] - V[:, 0], V[:, 2] - V[:, 0]
    np.testing.assert_allclose(m.face_areas, 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1), rtol=1e-12)
    for k in range(3):
        a, b = V[:, (k + 1) % 3] - V[:, k], V[:, (k + 2) % 3] - V[:, k]
        angle = np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b))
        np.testing.assert_allclose(m.corner_angles[:, k], angle, atol=1e-13)
    np.testing.assert_allclose(m.corner_angles.sum(1), np.pi, atol=1e-13)
    lengths = np.linalg.norm(m.vertices[m.halfedge_head] - m.vertices[m.halfedge_tail], axis=1)
    np.testing.assert_allclose(m.halfedge_lengths, lengths, rtol=1e-13)
    assert m.mean_edge_length == pytest.approx(lengths.mean(), rel=1e-13)


def test_icosahedron_closed_form():
    m = icosphere(0, radius=2.0)
    a = 2.0 * 4 / np.sqrt(10 + 2 * np.sqrt(5))  # edge of the icosahedron inscribed in radius 2
    np.testing.assert_allclose(m.halfedge_lengths, a, rtol=1e-14)
    np.testing.assert_allclose(m.face_areas, np.sqrt(3) / 4 * a**2, rtol=1e-14)
    np.testing.assert_allclose(m.angle_sums, 5 * np.pi / 3, rtol=1e-14)
    np.testing.assert_allclose(m.vertex_normals, m.vertices / 2, atol=1e-14)  # symmetric fans: radial


def test_grid_areas_and_normals(flat_grid):
    m = flat_grid
    assert m.face_areas.sum() == pytest.approx(1.2, rel=1e-13)
    np.testing.assert_allclose(m.face_normals, np.broadcast_to([0, 0, 1.0], (m.n_faces, 3)), atol=1e-15)
    np.testing.assert_allclose(m.vertex_normals, np.broadcast_to([0, 0, 1.0], (m.n_vertices, 3)), atol=1e-15)
    assert m.bounding_diagonal == pytest.approx(np.hypot(1.2, 1.0), rel=1e-15)


# ----------------------------------------------------------------------------------------- intrinsic geometry


def euler_characteristic(m):
    return m.n_vertices - m.n_edges + m.n_faces


@pytest.mark.parametrize(
    ("m", "chi"),
    [
        (icosphere(3), 2),
        (torus(), 0),
        (torus(3.0, 1.0, 7, 5), 0),
        (scan_like_sphere(2000, seed=1), 2),
        (scan_like_torus(2000, seed=2), 0),
    ],
    ids=repr,
)
def test_gauss_bonnet_closed(m, chi):
    assert np.all(m.twin >= 0)
    assert euler_characteristic(m) == chi
    assert np.sum(2 * np.pi - m.angle_sums) == pytest.approx(2 * np.pi * chi, abs=1e-10)


@pytest.mark.parametrize(
    ("m", "chi"),
    [
        (grid_plane(7, 5, jitter=0.24, seed=1), 1),
        (cylinder(n_around=11, n_along=4, jitter=0.2, seed=2), 0),
        (cone(top_radius=0.4, jitter=0.2, seed=3), 0),
        (cone(top_radius=0.0, jitter=0.2, seed=3), 1),
    ],
    ids=repr,
)
def test_gauss_bonnet_with_boundary(m, chi):
    # Σ_interior (2π − θ) + Σ_boundary (π − θ) = 2π χ
    assert euler_characteristic(m) == chi
    inside = ~m.is_boundary_vertex
    total = np.sum(2 * np.pi - m.angle_sums[inside]) + np.sum(np.pi - m.angle_sums[~inside])
    assert total == pytest.approx(2 * np.pi * chi, abs=1e-11)


def test_gauss_bonnet_bumpy(bumpy):
    inside = ~bumpy.is_boundary_vertex
    total = np.sum(2 * np.pi - bumpy.angle_sums[inside]) + np.sum(np.pi - bumpy.angle_sums[~inside])
    assert total == pytest.approx(2 * np.pi, abs=1e-11)
    assert np.ptp(bumpy.angle_sums[inside]) > 1.0  # really not flat


def test_flat_angle_sums(flat_grid):
    # grid_plane(6, 5): corners are vertices 0, 6, 35, 41; other boundary vertices lie on straight sides.
    m = flat_grid
    inside = ~m.is_boundary_vertex
    np.testing.assert_allclose(m.angle_sums[inside], 2 * np.pi, atol=1e-12)
    corners = [0, 6, 35, 41]
    sides = m.is_boundary_vertex.copy()
    sides[corners] = False
    assert np.count_nonzero(sides) == 2 * (6 + 5) - 4
    np.testing.assert_allclose(m.angle_sums[corners], np.pi / 2, atol=1e-12)
    np.testing.assert_allclose(m.angle_sums[sides], np.pi, atol=1e-12)
    np.testing.assert_allclose(m.vertex_angle_scale[inside | sides], 1.0, atol=1e-12)
    np.testing.assert_allclose(m.vertex_angle_scale[corners], 2.0, atol=1e-12)


@pytest.mark.parametrize("jitter", [0.0, 0.24])
def test_cylinder_angle_sums_are_flat(jitter):
    # Each strip between two neighbouring generator lines is planar (jitter moves whole generators around
    # the axis, vertices only along them): the surface is developable, every interior vertex has exactly
    # 2π and every boundary vertex π.
    m = cylinder(radius=0.7, height=2.0, n_around=13, n_along=6, jitter=jitter, seed=4)
    inside = ~m.is_boundary_vertex
    assert np.count_nonzero(inside) == 13 * 5
    np.testing.assert_allclose(m.angle_sums[inside], 2 * np.pi, atol=1e-12)
    np.testing.assert_allclose(m.angle_sums[~inside], np.pi, atol=1e-12)


@pytest.mark.parametrize("top_radius", [0.0, 0.3])
@pytest.mark.parametrize("jitter", [0.0, 0.24])
def test_cone_angle_sums_are_flat_away_from_the_apex(top_radius, jitter):
    m = cone(1.2, 0.9, top_radius, n_around=10, n_along=5, jitter=jitter, seed=6)
    inside = ~m.is_boundary_vertex
    if top_radius == 0:
        inside[-1] = False  # the apex
    assert np.count_nonzero(inside) == 10 * 4
    np.testing.assert_allclose(m.angle_sums[inside], 2 * np.pi, atol=1e-12)


@pytest.mark.parametrize(("radius", "height", "n"), [(1.0, 1.0, 32), (1.0, 4.0, 16), (2.0, 0.5, 64)])
def test_cone_apex_angle_sum(radius, height, n):
    m = cone(base_radius=radius, height=height, top_radius=0.0, n_around=n, n_along=3, seed=1)
    apex = m.n_vertices - 1
    np.testing.assert_array_equal(m.vertices[apex], [0, 0, height])
    # Independent: the angle at the apex between two consecutive vertices of the last ring, from 3D positions.
    ring = m.vertices[2 * n : 3 * n] - m.vertices[apex]
    a, b = ring, np.roll(ring, -1, axis=0)
    corner = np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b))
    np.testing.assert_allclose(corner, corner[0], rtol=1e-12)  # all the fan's corners are equal
    assert m.angle_sums[apex] == pytest.approx(n * corner[0], rel=1e-13)
    # ... and close to the smooth cone's 2π sin(half-angle), up to the polygon's discretization.
    smooth = 2 * np.pi * np.sin(np.arctan(radius / height))
    assert m.angle_sums[apex] < smooth
    assert m.angle_sums[apex] == pytest.approx(smooth, rel=(np.pi / n) ** 2 / 6 + 1e-12)
    assert not m.is_boundary_vertex[apex]
    assert m.vertex_angle_scale[apex] == pytest.approx(2 * np.pi / m.angle_sums[apex], rel=1e-15)


@pytest.mark.parametrize("m", [*MESHES, "bumpy"], ids=repr)
def test_halfedge_angles(m, bumpy):
    m = bumpy if isinstance(m, str) else m
    corner = m.corner_angles.ravel()
    for v in range(m.n_vertices):
        ring = m.ring[m.ring_start[v] : m.ring_start[v + 1]]
        angles = m.halfedge_angle[ring]
        assert angles[0] == 0.0
        assert np.all(np.diff(angles) > 0)
        np.testing.assert_allclose(np.diff(angles), corner[ring[:-1]], atol=1e-13)
        assert angles[-1] + corner[ring[-1]] == pytest.approx(m.angle_sums[v], abs=1e-13)
    scale = np.where(m.is_boundary_vertex, np.pi, 2 * np.pi) / m.angle_sums
    np.testing.assert_allclose(m.vertex_angle_scale, scale, rtol=1e-15)


def test_halfedge_angles_are_counter_clockwise_in_the_plane(flat_grid):
    # On a flat grid seen from +z, the angle of each outgoing halfedge from the reference one is the
    # polar angle difference of the 3D edge vectors, measured counter-clockwise.
    m = flat_grid
    d = m.vertices[m.halfedge_head] - m.vertices[m.halfedge_tail]
    polar = np.arctan2(d[:, 1], d[:, 0])
    ref = m.vertex_halfedge[m.halfedge_tail]
    expected = np.mod(polar - polar[ref], 2 * np.pi)
    expected[np.isclose(expected, 2 * np.pi)] = 0.0
    np.testing.assert_allclose(m.halfedge_angle, expected, atol=1e-12)


@pytest.mark.parametrize("m", MESHES, ids=repr)
def test_halfedge_rotation_and_offset(m):
    h = np.flatnonzero(m.twin >= 0)
    t = m.twin[h]
    f, g = h // 3, t // 3
    k, kt = h % 3, t % 3
    P = m.face_points
    rot, off = m.halfedge_rotation[h], m.halfedge_offset[h]
    np.testing.assert_allclose(np.abs(rot), 1.0, rtol=1e-14)
    assert np.all(np.isnan(m.halfedge_rotation[m.twin < 0]))
    assert np.all(np.isnan(m.halfedge_offset[m.twin < 0]))
    axes_f, axes_g = m.face_axes(f), m.face_axes(g)
    # The edge's direction in face f, rotated, is the same 3D direction seen in face g.
    e = P[f, (k + 1) % 3] - P[f, k]
    e /= np.abs(e)
    edge3d = m.vertices[m.halfedge_head[h]] - m.vertices[m.halfedge_tail[h]]
    edge3d /= np.linalg.norm(edge3d, axis=1, keepdims=True)
    np.testing.assert_allclose(to3d(e, axes_f), edge3d, atol=1e-13)
    np.testing.assert_allclose(to3d(rot * e, axes_g), edge3d, atol=1e-13)
    # The edge's inward normal in f points, in g's frame, away from g's third vertex (the unfolding).
    inward_g = to3d(rot * 1j * e, axes_g)
    third = m.vertices[m.faces[g, (kt + 2) % 3]] - m.vertices[m.halfedge_tail[h]]
    assert np.all(np.einsum("ij,ij->i", inward_g, third) < 0)
    np.testing.assert_allclose(np.einsum("ij,ij->i", inward_g, edge3d), 0, atol=1e-13)
    # Both endpoints of the shared edge land on their own positions in g's frame.
    scale = m.bounding_diagonal
    np.testing.assert_allclose(off + rot * P[f, k], P[g, (kt + 1) % 3], atol=1e-13 * scale)
    np.testing.assert_allclose(off + rot * P[f, (k + 1) % 3], P[g, kt], atol=1e-13 * scale)
    # Composing with the twin's map is the identity.
    np.testing.assert_allclose(m.halfedge_rotation[t] * rot, 1.0, atol=1e-14)
    np.testing.assert_allclose(m.halfedge_offset[t] + m.halfedge_rotation[t] * off, 0, atol=1e-13 * scale)


def test_unfolding_is_exact_on_a_flat_grid(flat_grid):
    # On a plane, a point's position in face f mapped to g's frame is the same 3D point.
    m = flat_grid
    h = np.flatnonzero(m.twin >= 0)
    f, g = h // 3, m.twin[h] // 3
    z = m.face_points[f].mean(1)  # f's centroid
    zg = m.halfedge_offset[h] + m.halfedge_rotation[h] * z
    x = m.vertices[m.faces[g, 0]] + to3d(zg, m.face_axes(g))
    np.testing.assert_allclose(x, m.vertices[m.faces[f]].mean(1), atol=1e-13)


def test_errors_from_polygons_name_the_polygons():
    """A Blender user sees polygons, not our triangles: errors from from_polygons point at polygons."""
    V = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 1], [0.5, 0.5, -1]])
    # polygon 2 repeats the quad's edge 0-1 a third time: a non-manifold edge
    polygons = [[0, 1, 2, 3], [0, 4, 1], [1, 0, 5], [0, 1, 4]]
    with pytest.raises(MeshError, match="polygons") as caught:
        TriMesh.from_polygons(V, polygons)
    assert set(caught.value.faces.tolist()) <= {0, 1, 2, 3}
    assert caught.value.faces.size > 0
    assert caught.value.faces.max() < len(polygons)


def test_signed_volume_is_positive_outside_in_negative_inside_out():
    """A unit corner tetrahedron encloses 1/6, wherever it is; turned inside out, -1/6."""
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]) + np.array([3.0, -2.0, 5.0])
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    assert TriMesh(V, F).signed_volume == pytest.approx(1 / 6, rel=1e-12)
    assert TriMesh(V, F[:, ::-1]).signed_volume == pytest.approx(-1 / 6, rel=1e-12)
