"""Tangent bases: the vertex basis convention (geometry-central's), conversions between vertex bases and
face frames, rotations across edges, change_basis, and the 3D axes of each basis."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from geodesics.errors import MeshError
from geodesics.mesh import TriMesh
from geodesics.points import SurfacePoints
from geodesics.primitives import cone, scan_like_sphere
from geodesics.tangent import (
    change_basis,
    corner_halfedges,
    face_rotation,
    face_to_vertex,
    from_face_frame,
    tangent_axes,
    tangent_from_3d,
    tangent_to_3d,
    to_face_frame,
    vertex_to_face,
)

SETTINGS = settings(max_examples=60, deadline=None, derandomize=True, database=None)


def edge_dir(mesh, h):
    """Unit direction of halfedges in their faces' frames."""
    P = mesh.face_points
    f, k = h // 3, h % 3
    e = P[f, (k + 1) % 3] - P[f, k]
    return e / np.abs(e)


def dir3d(mesh, faces, z):
    axes = mesh.face_axes(faces)
    return z.real[:, None] * axes[:, 0] + z.imag[:, None] * axes[:, 1]


def unit(x):
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def ring_of(mesh, v):
    return mesh.ring[mesh.ring_start[v] : mesh.ring_start[v + 1]]


def centroids(faces):
    faces = np.atleast_1d(faces)
    return SurfacePoints(faces, np.full((faces.size, 3), 1 / 3))


def independent_vertex_angles(mesh, v):
    """Outgoing halfedges of v counter-clockwise, the angle sum of the corners before each, and the total,
    from the face list and 3D positions only (an interior vertex starts at the mesh's reference halfedge)."""
    F, V = mesh.faces, mesh.vertices
    corners = {}
    for f, k in zip(*np.nonzero(v == F), strict=True):
        a, b = F[f, (k + 1) % 3], F[f, (k + 2) % 3]
        u, w = V[a] - V[v], V[b] - V[v]
        corners[a] = (3 * f + k, b, np.arctan2(np.linalg.norm(np.cross(u, w)), np.dot(u, w)))
    second = {c[1] for c in corners.values()}
    starts = [a for a in corners if a not in second]  # edge v->a with no face on its right: boundary
    assert len(starts) <= 1
    a = starts[0] if starts else mesh.halfedge_head[mesh.vertex_halfedge[v]]
    order, before, total = [], [], 0.0
    for _ in range(len(corners)):
        h, a, angle = corners[a]
        order.append(h)
        before.append(total)
        total += angle
    return np.array(order), np.array(before), total, bool(starts)


def random_vertex_directions(mesh, vertices, per_vertex, seed, boundary_half=True):
    """Random directions (complex, random length) at each vertex; within [0, π] at boundary vertices."""
    rng = np.random.default_rng(seed)
    v = np.repeat(vertices, per_vertex)
    phi = rng.uniform(0, 2 * np.pi, v.size)
    if boundary_half:
        phi = np.where(mesh.is_boundary_vertex[v], phi / 2, phi)
    return v, rng.uniform(0.1, 3.0, v.size) * np.exp(1j * phi)


# ------------------------------------------------------------------------------------------- vertex basis


@pytest.mark.parametrize("name", ["bumpy", "sharp_cone", "scan"])
def test_vertex_basis_convention(name, request):
    mesh = scan_like_sphere(60, seed=9) if name == "scan" else request.getfixturevalue(name)
    for v in range(mesh.n_vertices):
        order, before, total, boundary = independent_vertex_angles(mesh, v)
        assert boundary == mesh.is_boundary_vertex[v]
        np.testing.assert_array_equal(ring_of(mesh, v), order)
        assert mesh.vertex_halfedge[v] == order[0]
        assert mesh.angle_sums[v] == pytest.approx(total, abs=1e-12)
        np.testing.assert_allclose(mesh.halfedge_angle[order], before, atol=1e-12)
        # geometry-central: the k-th outgoing halfedge is at (angle before it) * 2π/θ, * π/θ on the boundary.
        expected = before * (np.pi if boundary else 2 * np.pi) / total
        got = face_to_vertex(mesh, order, edge_dir(mesh, order))
        np.testing.assert_allclose(got, np.exp(1j * expected), atol=1e-12)
        # ... and back: that vertex direction points along the edge in 3D.
        h, zf = vertex_to_face(mesh, np.full(order.size, v), np.exp(1j * expected))
        assert np.all(mesh.halfedge_tail[h] == v)
        edges3d = unit(mesh.vertices[mesh.halfedge_head[order]] - mesh.vertices[v])
        np.testing.assert_allclose(dir3d(mesh, h // 3, zf), edges3d, atol=1e-12)


def test_vertex_to_face_then_back_is_identity(bumpy, sharp_cone):
    for mesh in (bumpy, sharp_cone):
        v, z = random_vertex_directions(mesh, np.arange(mesh.n_vertices), 40, seed=1)
        h, zf = vertex_to_face(mesh, v, z)
        np.testing.assert_array_equal(mesh.halfedge_tail[h], v)
        np.testing.assert_allclose(np.abs(zf), np.abs(z), rtol=1e-14)
        # The face direction lies inside the corner of h.
        local = np.angle(zf / edge_dir(mesh, h))
        assert np.all(local >= -1e-12) and np.all(local <= mesh.corner_angles.ravel()[h] + 1e-12)
        np.testing.assert_allclose(face_to_vertex(mesh, h, zf), z, atol=1e-12)


def test_face_to_vertex_then_back_for_directions_inside_the_corner(bumpy):
    rng = np.random.default_rng(2)
    h = rng.integers(0, 3 * bumpy.n_faces, 3000)
    local = rng.uniform(0, 1, h.size) * bumpy.corner_angles.ravel()[h]
    z = 0.7 * edge_dir(bumpy, h) * np.exp(1j * local)
    zv = face_to_vertex(bumpy, h, z)
    h2, z2 = vertex_to_face(bumpy, bumpy.halfedge_tail[h], zv)
    np.testing.assert_array_equal(h2, h)
    np.testing.assert_allclose(z2, z, atol=1e-12)


@SETTINGS
@given(data=st.data())
def test_round_trip_at_the_cone_apex_hypothesis(data, sharp_cone):
    apex = sharp_cone.n_vertices - 1
    phi = data.draw(st.floats(0, 2 * np.pi, exclude_max=True))
    r = data.draw(st.floats(1e-3, 1e3))
    z = np.array([r * np.exp(1j * phi)])
    h, zf = vertex_to_face(sharp_cone, np.array([apex]), z)
    assert sharp_cone.halfedge_tail[h[0]] == apex
    np.testing.assert_allclose(face_to_vertex(sharp_cone, h, zf), z, rtol=1e-12, atol=1e-12 * r)
    # The apex direction's surface angle is φ θ / 2π from the reference halfedge.
    theta = sharp_cone.angle_sums[apex]
    surface = sharp_cone.halfedge_angle[h[0]] + np.angle(zf[0] / edge_dir(sharp_cone, h)[0])
    assert surface == pytest.approx(phi * theta / (2 * np.pi), abs=1e-12)


@SETTINGS
@given(data=st.data())
def test_round_trip_at_boundary_vertices_hypothesis(data, bumpy):
    boundary = np.flatnonzero(bumpy.is_boundary_vertex)
    v = boundary[data.draw(st.integers(0, boundary.size - 1))]
    phi = data.draw(st.floats(0, np.pi))
    z = np.array([np.exp(1j * phi)])
    h, zf = vertex_to_face(bumpy, np.array([v]), z)
    np.testing.assert_allclose(face_to_vertex(bumpy, h, zf), z, atol=1e-12)


def test_off_surface_directions_at_boundary_vertices_go_to_the_nearer_edge(bumpy):
    m = bumpy
    boundary = np.flatnonzero(m.is_boundary_vertex)
    h = np.arange(3 * m.n_faces)
    prev = h - h % 3 + (h + 2) % 3
    for v in boundary:
        out_edge = m.vertices[m.halfedge_head[m.vertex_halfedge[v]]] - m.vertices[v]
        incoming = prev[(m.twin[prev] < 0) & (m.halfedge_head[prev] == v)][0]  # the boundary edge into v
        back_edge = m.vertices[m.halfedge_tail[incoming]] - m.vertices[v]
        cases = [(1.01, back_edge), (1.49, back_edge), (1.51, out_edge), (1.99, out_edge)]
        cases += [(1, back_edge), (0, out_edge)]
        for turns, expected in cases:
            phi = turns * np.pi
            hv, zf = vertex_to_face(m, np.array([v]), np.array([2.0 * np.exp(1j * phi)]))
            np.testing.assert_allclose(dir3d(m, hv // 3, zf)[0], 2.0 * unit(expected), atol=1e-12)
            snapped = np.pi if phi >= np.pi and phi < 1.5 * np.pi else 0.0
            np.testing.assert_allclose(face_to_vertex(m, hv, zf), 2.0 * np.exp(1j * snapped), atol=1e-12)


def test_flat_vertex_bases_are_rotated_face_frames(flat_grid):
    m = flat_grid
    rng = np.random.default_rng(3)
    straight = ~m.is_boundary_vertex | np.isclose(m.angle_sums, np.pi)  # interior or on a straight side
    for v in np.flatnonzero(straight):
        ring = ring_of(m, v)
        vp = SurfacePoints.from_vertices(m, [v])
        for hA in ring:
            corner = m.corner_angles.ravel()[hA]
            local = rng.uniform(0, corner) if m.is_boundary_vertex[v] else rng.uniform(-3, 3)
            z = rng.uniform(0.5, 2) * edge_dir(m, np.array([hA])) * np.exp(1j * local)
            want = dir3d(m, [hA // 3], z)
            zv = face_to_vertex(m, np.array([hA]), z)
            # The vertex basis's 3D axes (reference edge, normal x reference edge) give the same vector ...
            np.testing.assert_allclose(tangent_to_3d(m, vp, zv), want, atol=1e-12)
            # ... as does the face the direction points into ...
            h, zf = vertex_to_face(m, [v], zv)
            np.testing.assert_allclose(dir3d(m, h // 3, zf), want, atol=1e-12)
            # ... and every other face around the vertex, through change_basis.
            if m.is_boundary_vertex[v]:
                continue
            faces = ring // 3
            zB = change_basis(
                m, np.repeat(zv, faces.size), SurfacePoints.concatenate([vp] * faces.size), centroids(faces)
            )
            np.testing.assert_allclose(dir3d(m, faces, zB), np.repeat(want, faces.size, axis=0), atol=1e-12)
            # From the face A's centroid to the vertex: the same vertex direction.
            np.testing.assert_allclose(change_basis(m, z, centroids(hA // 3), vp), zv, atol=1e-12)


# ------------------------------------------------------------------------------------------ face rotation


def test_face_rotation(bumpy):
    m = bumpy
    h = np.flatnonzero(m.twin >= 0)
    f, g = h // 3, m.twin[h] // 3
    r = face_rotation(m, f, g)
    np.testing.assert_allclose(r, m.halfedge_rotation[h], rtol=1e-15)
    # The edge direction in f, rotated, is the reversed twin direction in g, and the same 3D vector.
    np.testing.assert_allclose(r * edge_dir(m, h), -edge_dir(m, m.twin[h]), atol=1e-14)
    e3 = unit(m.vertices[m.halfedge_head[h]] - m.vertices[m.halfedge_tail[h]])
    np.testing.assert_allclose(dir3d(m, g, r * edge_dir(m, h)), e3, atol=1e-13)
    np.testing.assert_allclose(face_rotation(m, g, f) * r, 1.0, atol=1e-14)
    np.testing.assert_array_equal(face_rotation(m, f, f), 1.0)
    far = np.flatnonzero(~np.isin(np.arange(m.n_faces), m.twin[3 * 0 + np.arange(3)] // 3))[1:3]
    with pytest.raises(MeshError, match=rf"faces 0 and {far[0]} share no edge"):
        face_rotation(m, [0, 0], [0, far[0]])


# ------------------------------------------------------------------------------------------ change_basis


def test_change_basis_between_the_faces_of_an_edge(bumpy):
    m = bumpy
    rng = np.random.default_rng(4)
    h = np.flatnonzero(m.twin >= 0)
    t = m.twin[h]
    f, g = h // 3, t // 3
    s = rng.uniform(0.05, 0.95, h.size)
    # The same edge point expressed in f (corners k, k+1) and in g (corners kt+1, kt).
    bf, bg = np.zeros((h.size, 3)), np.zeros((h.size, 3))
    idx = np.arange(h.size)
    bf[idx, h % 3], bf[idx, (h + 1) % 3] = 1 - s, s
    bg[idx, (t + 1) % 3], bg[idx, t % 3] = 1 - s, s
    pf, pg = SurfacePoints(f, bf), SurfacePoints(g, bg)
    np.testing.assert_allclose(pf.positions(m), pg.positions(m), atol=1e-15)
    e = edge_dir(m, h)
    z = np.exp(1j * rng.uniform(-np.pi, np.pi, h.size)) * rng.uniform(0.5, 2, h.size)
    w = change_basis(m, z, pf, pg)
    np.testing.assert_allclose(w, z * m.halfedge_rotation[h], atol=1e-14)
    np.testing.assert_allclose(np.abs(w), np.abs(z), rtol=1e-14)
    # Independent 3D checks: the edge direction is the same 3D vector; the inward normal of f points away
    # from g's third vertex.
    e3 = unit(m.vertices[m.halfedge_head[h]] - m.vertices[m.halfedge_tail[h]])
    np.testing.assert_allclose(dir3d(m, g, change_basis(m, e, pf, pg)), e3, atol=1e-13)
    across = dir3d(m, g, change_basis(m, 1j * e, pf, pg))
    third = m.vertices[m.faces[g, (t + 2) % 3]] - pg.positions(m)
    assert np.all(np.einsum("ij,ij->i", across, third) < 0)
    np.testing.assert_allclose(change_basis(m, w, pg, pf), z, atol=1e-13)


def test_change_basis_face_and_vertex(bumpy):
    m = bumpy
    rng = np.random.default_rng(5)
    f = rng.integers(0, m.n_faces, 400)
    k = rng.integers(0, 3, f.size)
    v = m.faces[f, k]
    fp = SurfacePoints(f, rng.dirichlet(np.ones(3), f.size))
    vp = SurfacePoints.from_vertices(m, v)
    z = np.exp(1j * rng.uniform(-np.pi, np.pi, f.size))
    zv = change_basis(m, z, fp, vp)
    np.testing.assert_allclose(zv, face_to_vertex(m, 3 * f + k, z), atol=1e-14)
    np.testing.assert_array_equal(corner_halfedges(m, f, v), 3 * f + k)
    # Back from the vertex to the face: the identity whenever the face direction is one the vertex has: on
    # the boundary, within the fan; inside, (for θ <= 2π) within θ/2 of the middle of the corner, as a face
    # frame holds 2π of directions but the vertex only θ.
    back = change_basis(m, zv, vp, fp)
    local = np.angle(z / edge_dir(m, 3 * f + k))
    a = m.halfedge_angle[3 * f + k] + local
    theta, middle = m.angle_sums[v], 0.5 * m.corner_angles.ravel()[3 * f + k]
    boundary = m.is_boundary_vertex[v]
    fan = (a >= 0) & (a <= theta)
    exists = np.where(boundary, fan, (theta <= 2 * np.pi) & (np.abs(local - middle) < theta / 2))
    assert np.count_nonzero(exists) > 100 and np.count_nonzero(~exists) > 20
    np.testing.assert_allclose(back[exists], z[exists], atol=1e-12)
    # In any case the result, seen from the vertex again, is the same vertex direction.
    in_range = exists | ~boundary & (theta <= 2 * np.pi)
    np.testing.assert_allclose(change_basis(m, back, fp, vp)[in_range], zv[in_range], atol=1e-12)


def test_change_basis_vertex_to_any_face_of_it(bumpy, sharp_cone):
    # Every face of a vertex gets the vertex direction; directions pointing into that face stay inside it.
    for m in (bumpy, sharp_cone):
        rng = np.random.default_rng(6)
        for v in range(m.n_vertices):
            theta = m.angle_sums[v]
            if not m.is_boundary_vertex[v] and theta > 2 * np.pi:
                continue  # a saddle has directions no face frame can hold
            ring = ring_of(m, v)
            faces = ring // 3
            zv = np.exp(1j * rng.uniform(0, np.pi if m.is_boundary_vertex[v] else 2 * np.pi, faces.size))
            vp = SurfacePoints.concatenate([SurfacePoints.from_vertices(m, [v])] * faces.size)
            zf = change_basis(m, zv, vp, centroids(faces))
            local = np.angle(zf / edge_dir(m, ring))
            fits = (np.abs(local) < np.pi) if m.is_boundary_vertex[v] else np.ones(ring.size, bool)
            np.testing.assert_allclose(face_to_vertex(m, ring, zf)[fits], zv[fits], atol=1e-12)
            # Directions inside the face's own corner are returned inside it.
            scale = m.vertex_angle_scale[v]
            inside = np.exp(1j * (m.halfedge_angle[ring] + 0.5 * m.corner_angles.ravel()[ring]) * scale)
            zin = change_basis(m, inside, vp, centroids(faces))
            expected = edge_dir(m, ring) * np.exp(0.5j * m.corner_angles.ravel()[ring])
            np.testing.assert_allclose(zin, expected, atol=1e-12)


def test_change_basis_vertex_to_face_round_trip_at_a_valence_3_cone():
    # A low pyramid's apex: three corners of about 2 rad, angle sum just below 2π. A direction in one face
    # is more than π from the neighbouring face's corner edge on one side, less than π on the other.
    ring = np.exp(2j * np.pi * np.arange(3) / 3)
    V = np.vstack([np.column_stack([ring.real, ring.imag, np.zeros(3)]), [[0.0, 0.0, 0.2]]])
    m = TriMesh(V, [[3, 0, 1], [3, 1, 2], [3, 2, 0]])
    assert 5.5 < m.angle_sums[3] < 2 * np.pi
    phi = np.linspace(0, 2 * np.pi, 90, endpoint=False)
    apex = SurfacePoints.concatenate([SurfacePoints.from_vertices(m, [3])] * phi.size)
    for f in range(3):
        zf = change_basis(m, np.exp(1j * phi), apex, centroids(np.full(phi.size, f)))
        h = corner_halfedges(m, np.full(phi.size, f), np.full(phi.size, 3))
        np.testing.assert_allclose(face_to_vertex(m, h, zf), np.exp(1j * phi), atol=1e-12)
        back = change_basis(m, zf, centroids(np.full(phi.size, f)), apex)
        np.testing.assert_allclose(back, np.exp(1j * phi), atol=1e-12)


def test_change_basis_between_vertices_on_a_flat_grid(flat_grid):
    m = flat_grid
    rng = np.random.default_rng(7)
    h = np.arange(3 * m.n_faces)
    a, b = m.halfedge_tail[h], m.halfedge_head[h]
    inner = ~m.is_boundary_vertex[a] & ~m.is_boundary_vertex[b]
    a, b = a[inner], b[inner]
    z = np.exp(1j * rng.uniform(0, 2 * np.pi, a.size))
    pa, pb = SurfacePoints.from_vertices(m, a), SurfacePoints.from_vertices(m, b)
    w = change_basis(m, z, pa, pb)
    np.testing.assert_allclose(tangent_to_3d(m, pb, w), tangent_to_3d(m, pa, z), atol=1e-12)
    np.testing.assert_allclose(change_basis(m, w, pb, pa), z, atol=1e-12)


def test_change_basis_errors(bumpy):
    m = bumpy
    with pytest.raises(MeshError, match="got 2 source points but 1 target points"):
        change_basis(m, [1, 1], centroids([0, 1]), centroids([0]))
    far = next(f for f in range(m.n_faces) if not set(m.faces[f]) & set(m.faces[0]))
    with pytest.raises(MeshError, match="point pairs 1 share no face"):
        change_basis(m, [1, 1], centroids([0, 0]), centroids([0, far]))
    v_far = next(v for v in range(m.n_vertices) if v not in m.faces[0])
    with pytest.raises(MeshError, match="point pairs 0 share no face"):
        change_basis(m, [1], centroids([0]), SurfacePoints.from_vertices(m, [v_far]))
    with pytest.raises(MeshError, match="are not corners of faces"):
        corner_halfedges(m, np.array([0]), np.array([v_far]))


def test_to_and_from_face_frame(bumpy):
    m = bumpy
    rng = np.random.default_rng(8)
    fp = SurfacePoints(rng.integers(0, m.n_faces, 20), rng.dirichlet(np.ones(3), 20))
    vp = SurfacePoints.from_vertices(m, rng.integers(0, m.n_vertices, 20))
    pts = SurfacePoints.concatenate([fp, vp])
    z = np.exp(1j * rng.uniform(0, np.pi, 40))
    faces, zf = to_face_frame(m, pts, z)
    np.testing.assert_array_equal(faces[:20], fp.faces)
    np.testing.assert_array_equal(zf[:20], z[:20])
    h, zv = vertex_to_face(m, vp.vertex_ids(m), z[20:])
    np.testing.assert_array_equal(faces[20:], h // 3)
    np.testing.assert_array_equal(zf[20:], zv)
    np.testing.assert_allclose(from_face_frame(m, pts, faces, zf), z, atol=1e-12)
    np.testing.assert_allclose(to_face_frame(m, fp, 2.0)[1], 2.0)  # a scalar broadcasts


# ------------------------------------------------------------------------------------------ tangent axes


def test_tangent_axes_and_3d_round_trip(bumpy):
    m = bumpy
    rng = np.random.default_rng(9)
    k = 60
    face_pts = SurfacePoints(rng.integers(0, m.n_faces, k), rng.dirichlet(np.ones(3), k))
    eb = rng.dirichlet(np.ones(2), k)
    edge_pts = SurfacePoints(rng.integers(0, m.n_faces, k), np.column_stack([eb, np.zeros(k)]))
    vert_pts = SurfacePoints.from_vertices(m, np.arange(m.n_vertices))
    pts = SurfacePoints.concatenate([face_pts, edge_pts, vert_pts])
    axes = tangent_axes(m, pts)
    gram = np.einsum("kij,klj->kil", axes, axes)
    np.testing.assert_allclose(gram, np.broadcast_to(np.eye(2), gram.shape), atol=1e-13)
    normal = np.concatenate([m.face_normals[pts.faces[: 2 * k]], m.vertex_normals])
    np.testing.assert_allclose(np.cross(axes[:, 0], axes[:, 1]), normal, atol=1e-13)
    # Vertex points: x is the reference edge projected onto the vertex's tangent plane.
    ref = m.vertices[m.halfedge_head[m.vertex_halfedge]] - m.vertices
    ref -= m.vertex_normals * np.einsum("ij,ij->i", ref, m.vertex_normals)[:, None]
    np.testing.assert_allclose(axes[2 * k :, 0], unit(ref), atol=1e-13)
    np.testing.assert_allclose(axes[: 2 * k], m.face_axes(pts.faces[: 2 * k]), atol=0)
    # Round trips.
    z = rng.normal(size=len(pts)) + 1j * rng.normal(size=len(pts))
    X = tangent_to_3d(m, pts, z)
    np.testing.assert_allclose(np.einsum("ij,ij->i", X, normal), 0, atol=1e-13)
    np.testing.assert_allclose(tangent_from_3d(m, pts, X), z, atol=1e-13)
    Y = rng.normal(size=(len(pts), 3))
    Yt = Y - normal * np.einsum("ij,ij->i", Y, normal)[:, None]
    np.testing.assert_allclose(tangent_to_3d(m, pts, tangent_from_3d(m, pts, Y)), Yt, atol=1e-13)


def test_tangent_axes_on_a_regular_cone_apex():
    m = cone(top_radius=0.0, n_around=12, n_along=2, seed=None)
    apex = SurfacePoints.from_vertices(m, [m.n_vertices - 1])
    axes = tangent_axes(m, apex)[0]
    np.testing.assert_allclose(m.vertex_normals[-1], [0, 0, 1], atol=1e-14)  # symmetric fan
    ref = m.vertices[m.halfedge_head[m.vertex_halfedge[-1]]]
    np.testing.assert_allclose(axes[0], unit(ref * [1, 1, 0]), atol=1e-14)
    np.testing.assert_allclose(axes[1], np.cross([0, 0, 1], axes[0]), atol=1e-14)
