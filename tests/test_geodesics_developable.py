"""Exact geodesics on developable meshes, against their closed-form unrollings.

A jittered plane, a prism ("cylinder") and a pyramid ("cone") whose vertices all lie on generator
lines are intrinsically flat, so each unrolls isometrically onto the plane: geodesics are straight
segments there, log maps are plain vector differences, and exp maps are straight rays.
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from geodesics import SurfacePoints, exp_map, log_map, tangent_axes
from geodesics.primitives import cone, cylinder, grid_plane

from .oracles import random_points

ANGLE_TOL = 1e-7


def unrolled(mesh, points, vertex_uv):
    """(k,) complex unrolled coordinates of surface points, from per-vertex unrolled coordinates."""
    return (points.bary * vertex_uv[mesh.faces[points.faces]]).sum(1)


def frame_in_plane(mesh, points, vertex_uv):
    """(k,) unit complex: each point's basis x-axis in unrolled coordinates (face points only)."""
    F = mesh.faces[points.faces]
    e = vertex_uv[F[:, 1]] - vertex_uv[F[:, 0]]
    return e / np.abs(e)


def generator_columns(mesh, seam_angle):
    """Each vertex's generator line (column index, counted counter-clockwise from ``seam_angle``) and the
    sorted column angles. Vertices on the axis (a cone apex) get column -1."""
    V = mesh.vertices
    on_axis = np.hypot(V[:, 0], V[:, 1]) < 1e-12
    phi = np.mod(np.arctan2(V[:, 1], V[:, 0]) - seam_angle, 2 * np.pi)
    angles, column = np.unique(np.round(phi[~on_axis], 9), return_inverse=True)
    columns = np.full(len(V), -1)
    columns[~on_axis] = column
    return columns, angles


def across_seam(mesh, columns):
    """Faces that join the last and first columns (their unrolling would wrap around)."""
    F = columns[mesh.faces]
    last = columns.max()
    return np.any(F == 0, axis=1) & np.any(last == F, axis=1)


def prism_unrolling(mesh, radius, seam_angle):
    """Unrolled coordinates of a prism's vertices: arc length along the polygon from the seam (chords
    between the actual generator lines), and height. Also each vertex's column."""
    columns, angles = generator_columns(mesh, seam_angle)
    x = np.concatenate([[0.0], np.cumsum(2 * radius * np.sin(np.diff(angles) / 2))])
    return x[columns] + 1j * mesh.vertices[:, 2], columns


def pyramid_unrolling(mesh, base_radius, height, seam_angle):
    """Unrolled coordinates of a pyramid's vertices: slant distance from the apex times e^{iψ}, ψ the sum
    of the apex angles of the strips between the seam and the vertex's generator. Also the columns."""
    columns, angles = generator_columns(mesh, seam_angle)
    g = np.stack(
        [base_radius * np.cos(angles), base_radius * np.sin(angles), -height * np.ones_like(angles)], 1
    )
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    psi = np.concatenate([[0.0], np.cumsum(np.arccos(np.clip((g[1:] * g[:-1]).sum(1), -1, 1)))])
    s = np.linalg.norm(mesh.vertices - [0.0, 0.0, height], axis=1)
    return np.where(columns >= 0, s * np.exp(1j * psi[np.maximum(columns, 0)]), 0), columns


def assert_log_matches(mesh, origin, targets, uv, diameter):
    z = log_map(mesh, origin, targets)
    delta = unrolled(mesh, targets, uv) - unrolled(mesh, origin, uv)
    expected = delta / frame_in_plane(mesh, origin, uv)
    np.testing.assert_allclose(np.abs(z), np.abs(delta), rtol=0, atol=1e-9 * diameter)
    far = np.abs(delta) > 1e-6 * diameter
    assert np.max(np.abs(np.angle(z[far] / expected[far]))) < ANGLE_TOL
    return z


# ---------------------------------------------------------------------------------------------- plane


@pytest.fixture(scope="module")
def plane():
    return grid_plane(24, 18, size=(2.0, 1.5), jitter=0.24, seed=3)


def plane_uv(mesh):
    return mesh.vertices[:, 0] + 1j * mesh.vertices[:, 1]


def test_plane_log_map_is_the_vector_difference(plane):
    rng = np.random.default_rng(0)
    origin = random_points(plane, 1, rng)
    targets = SurfacePoints.concatenate(
        [random_points(plane, 400, rng), SurfacePoints.from_vertices(plane, np.arange(plane.n_vertices))]
    )
    assert_log_matches(plane, origin, targets, plane_uv(plane), plane.bounding_diagonal)


def test_plane_log_map_from_a_vertex_uses_the_vertex_basis(plane):
    rng = np.random.default_rng(1)
    v = int(np.flatnonzero(~plane.is_boundary_vertex)[40])
    origin = SurfacePoints.from_vertices(plane, [v])
    targets = random_points(plane, 300, rng)
    z = log_map(plane, origin, targets)
    uv = plane_uv(plane)
    delta = unrolled(plane, targets, uv) - uv[v]
    ref = uv[plane.halfedge_head[plane.vertex_halfedge[v]]] - uv[v]  # the reference halfedge is angle 0
    np.testing.assert_allclose(np.abs(z), np.abs(delta), atol=1e-9 * plane.bounding_diagonal)
    assert np.max(np.abs(np.angle(z / (delta / (ref / abs(ref)))))) < ANGLE_TOL


def test_plane_log_map_from_an_edge_point(plane):
    rng = np.random.default_rng(2)
    f = 100
    origin = SurfacePoints([f], [[0.3, 0.7, 0.0]])  # on the edge opposite corner 2
    assert origin.edge_halfedges(plane)[0] >= 0
    assert_log_matches(
        plane, origin, random_points(plane, 300, rng), plane_uv(plane), plane.bounding_diagonal
    )


def test_plane_exp_log_round_trips(plane):
    rng = np.random.default_rng(4)
    diameter = plane.bounding_diagonal
    origin = random_points(plane, 1, rng)
    targets = random_points(plane, 500, rng)
    z = log_map(plane, origin, targets)
    trace = exp_map(plane, origin, z)
    assert not trace.hit_boundary.any()
    np.testing.assert_allclose(trace.points.positions(plane), targets.positions(plane), atol=1e-9 * diameter)
    # and log(exp(z)) == z for fresh rays
    inner = np.abs(z) < 0.3
    z2 = z[inner] * np.exp(1j * rng.uniform(-0.2, 0.2, inner.sum()))
    back = log_map(plane, origin, exp_map(plane, origin, z2).points)
    np.testing.assert_allclose(back, z2, atol=1e-9 * diameter)


def test_plane_rays_through_vertices_and_along_edges():
    """On a regular grid, rays along the axes run along edges and diagonal rays pass through vertices."""
    mesh = grid_plane(16, 16, size=(1.0, 1.0), jitter=0.0, seed=5)  # random diagonals, exact grid
    diameter = mesh.bounding_diagonal
    h = 1 / 16
    v = 8 * 17 + 4  # grid vertex (x = 4h, y = 8h)
    origin = SurfacePoints.from_vertices(mesh, [v])
    axes = tangent_axes(mesh, origin)[0]
    directions_3d = np.array(
        [[1, 0], [0, 1], [-1, 0], [0, -1], [1, 1], [1, -1], [-1, 1], [2, 1], [1, 2]], float
    )
    lengths = np.array([7.3, 5.1, 3.7, 6.2, 4.4, 3.6, 2.9, 3.3, 2.1]) * h
    d = directions_3d / np.linalg.norm(directions_3d, axis=1, keepdims=True)
    z = lengths * ((d @ axes[0, :2]) + 1j * (d @ axes[1, :2]))
    trace = exp_map(mesh, origin, z)
    assert not trace.hit_boundary.any()
    expected = mesh.vertices[v, :2] + d * lengths[:, None]
    np.testing.assert_allclose(trace.points.positions(mesh)[:, :2], expected, atol=1e-12)
    np.testing.assert_allclose(log_map(mesh, origin, trace.points), z, atol=1e-9 * diameter)
    # rays that end exactly on a vertex come back on the vertex, in its basis
    on_vertex = exp_map(mesh, origin, np.array([4 * h * (axes[0, 0] + 1j * axes[1, 0])]))
    assert on_vertex.points.vertex_ids(mesh)[0] == v + 4


def test_plane_rays_stop_at_the_boundary(plane):
    rng = np.random.default_rng(6)
    origin = random_points(plane, 1, rng)
    o = unrolled(plane, origin, plane_uv(plane))[0]
    theta = rng.uniform(0, 2 * np.pi, 200)
    frame = frame_in_plane(plane, origin, plane_uv(plane))[0]
    trace = exp_map(plane, origin, 5.0 * np.exp(1j * theta))  # longer than the rectangle
    assert trace.hit_boundary.all()
    d = frame * np.exp(1j * theta)
    # distance to the rectangle [0, 2] x [0, 1.5] along d
    with np.errstate(divide="ignore"):
        tx = np.where(d.real > 0, (2.0 - o.real) / d.real, -o.real / d.real)
        ty = np.where(d.imag > 0, (1.5 - o.imag) / d.imag, -o.imag / d.imag)
    exit_length = np.minimum(np.abs(tx), np.abs(ty))
    np.testing.assert_allclose(trace.lengths, exit_length, atol=1e-9)
    end = unrolled(plane, trace.points, plane_uv(plane))
    np.testing.assert_allclose(end, o + exit_length * d, atol=1e-9)
    assert np.all(np.abs(trace.directions) > 0.999)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(
    st.integers(0, 1000),
    st.floats(0.05, 0.95),
    st.floats(0.05, 0.95),
    st.floats(-np.pi, np.pi),
    st.floats(0.01, 0.6),
)
def test_plane_log_of_exp_is_identity(plane, face, a, b, angle, length):
    bary = np.array([a, b * (1 - a), (1 - a) * (1 - b)])
    origin = SurfacePoints([face % plane.n_faces], [bary / bary.sum()])
    z = np.array([length * np.exp(1j * angle)])
    trace = exp_map(plane, origin, z)
    if trace.hit_boundary[0]:
        return
    np.testing.assert_allclose(log_map(plane, origin, trace.points), z, atol=1e-9 * plane.bounding_diagonal)


# ---------------------------------------------------------------------------------------------- prism


@pytest.fixture(scope="module")
def prism():
    return cylinder(radius=0.8, height=2.0, n_around=24, n_along=14, jitter=0.24, seed=7)


def test_prism_is_flat(prism):
    interior = ~prism.is_boundary_vertex
    np.testing.assert_allclose(prism.angle_sums[interior], 2 * np.pi, atol=1e-12)


def test_prism_log_and_exp_match_the_unrolling(prism):
    rng = np.random.default_rng(8)
    diameter = prism.bounding_diagonal
    uv, columns = prism_unrolling(prism, 0.8, np.pi)  # the cut is opposite the +x side
    candidates = random_points(prism, 3000, rng)
    col = columns[prism.faces[candidates.faces]]
    safe = np.all((col >= 3) & (col <= 20), axis=1)  # well away from the cut, so the strip is convex
    points = candidates[np.flatnonzero(safe)]
    origin, targets = points[:1], points[1:600]
    z = assert_log_matches(prism, origin, targets, uv, diameter)
    trace = exp_map(prism, origin, z)
    np.testing.assert_allclose(trace.points.positions(prism), targets.positions(prism), atol=1e-9 * diameter)


# ---------------------------------------------------------------------------------------------- pyramid


def test_truncated_pyramid_matches_its_unrolled_annulus():
    mesh = cone(base_radius=1.0, height=1.5, top_radius=0.25, n_around=20, n_along=12, jitter=0.24, seed=9)
    interior = ~mesh.is_boundary_vertex
    np.testing.assert_allclose(mesh.angle_sums[interior], 2 * np.pi, atol=1e-12)
    uv, columns = pyramid_unrolling(mesh, 1.0, 1.5, np.pi)
    rng = np.random.default_rng(10)
    candidates = random_points(mesh, 4000, rng)
    col = columns[mesh.faces[candidates.faces]]
    inner_slant = np.hypot(0.25, 1.5 * 0.25 / 1.0)
    # a band narrower than half the sector, so the direct copy is shorter than going round the other way
    points = candidates[np.flatnonzero(np.all((col >= 5) & (col <= 12), axis=1))]
    origin, targets = points[:1], points[1:]
    o = unrolled(mesh, origin, uv)[0]
    t = unrolled(mesh, targets, uv)
    # keep pairs whose straight segment in the unrolling avoids the hole around the apex
    d = t - o
    s = np.clip(-(np.conj(d) * o).real / np.abs(d) ** 2, 0, 1)
    clear = np.abs(o + s * d) > inner_slant * 1.02
    assert clear.sum() > 300
    targets = targets[np.flatnonzero(clear)]
    z = assert_log_matches(mesh, origin, targets, uv, mesh.bounding_diagonal)
    trace = exp_map(mesh, origin, z)
    np.testing.assert_allclose(
        trace.points.positions(mesh), targets.positions(mesh), atol=1e-9 * mesh.bounding_diagonal
    )


def test_pyramid_apex_round_trips_in_the_vertex_basis():
    """The apex has angle sum below 2π; log from it and exp back must use the same rescaled basis."""
    mesh = cone(base_radius=1.0, height=1.2, top_radius=0.0, n_around=16, n_along=10, jitter=0.2, seed=11)
    apex = int(np.argmax(mesh.vertices[:, 2]))
    theta = mesh.angle_sums[apex]
    assert theta < 2 * np.pi - 0.5
    rng = np.random.default_rng(12)
    origin = SurfacePoints.from_vertices(mesh, [apex])
    targets = random_points(mesh, 400, rng)
    z = log_map(mesh, origin, targets)
    slant = np.linalg.norm(targets.positions(mesh) - mesh.vertices[apex], axis=1)
    np.testing.assert_allclose(np.abs(z), slant, atol=1e-9 * mesh.bounding_diagonal)
    trace = exp_map(mesh, origin, z)
    np.testing.assert_allclose(
        trace.points.positions(mesh), targets.positions(mesh), atol=1e-9 * mesh.bounding_diagonal
    )
    # the angle in the apex basis is the unrolled angle from the reference generator, scaled by 2π/θ
    uv, columns = pyramid_unrolling(mesh, 1.0, 1.2, 0.0)
    ref_head = mesh.halfedge_head[mesh.vertex_halfedge[apex]]
    psi = np.mod(np.angle(unrolled(mesh, targets, uv)), 2 * np.pi)  # in [0, θ), and θ < 2π
    unrolled_angle = np.mod(psi - np.mod(np.angle(uv[ref_head]), 2 * np.pi), theta)
    straddle = across_seam(mesh, columns)[targets.faces]  # their unrolled angles would wrap around
    expected = unrolled_angle * 2 * np.pi / theta
    got = np.mod(np.angle(z), 2 * np.pi)
    diff = np.angle(np.exp(1j * (got - expected)))
    assert np.max(np.abs(diff[~straddle])) < ANGLE_TOL
