"""Axes and contact patches: parameterization, transfer, translate, rotate, bend (Algorithms 1-5)."""

import numpy as np
import pytest

from geodesics import (
    Axis,
    ContactError,
    ContactPatch,
    GeodesicField,
    SurfacePoints,
    TriMesh,
    farthest_pair_axis,
    tangent_from_3d,
    tangent_to_3d,
)
from geodesics.primitives import cone, cylinder, grid_plane, icosphere


def pool(mesh, n, seed):
    rng = np.random.default_rng(seed)
    points = SurfacePoints(rng.integers(0, mesh.n_faces, n), rng.dirichlet([2.0, 2.0, 2.0], n))
    return points, points.positions(mesh)


def nearest(mesh, xyz):
    return SurfacePoints.nearest(mesh, np.atleast_2d(xyz))


def disk_patch(mesh, centre, radius, n, seed=0, axis=None):
    """Random points of a planar mesh within a disk, with the farthest-pair axis unless given."""
    points, X = pool(mesh, 60 * n, seed)
    inside = np.flatnonzero(np.linalg.norm(X[:, :2] - centre, axis=1) < radius)[:n]
    points = points[inside]
    return ContactPatch(mesh, points, axis or farthest_pair_axis(mesh, points))


def relative_log_maps(patch):
    """Each point's exact log map from the axis point it is bound to, angle relative to the axis tangent
    there, computed afresh (one exact field per axis point in use)."""
    out = np.empty(len(patch), np.complex128)
    for j in np.unique(patch.binding):
        mine = np.flatnonzero(patch.binding == j)
        field = GeodesicField(patch.mesh, patch.axis.points[[j]], patch.points[mine])
        q = field.query(patch.points[mine])
        out[mine] = q.distances * q.initial_directions / patch.axis.tangents[j]
    return out


@pytest.fixture(scope="module")
def plane():
    return grid_plane(48, 48, size=(2.0, 2.0), jitter=0.2, seed=1)


@pytest.fixture(scope="module")
def patch(plane):
    return disk_patch(plane, [0.7, 0.8], 0.22, 600)


# ------------------------------------------------------------------------------------------ axes


def test_axis_between_is_the_straight_segment_with_every_edge_crossing(plane):
    a, b = nearest(plane, [0.3, 0.4, 0]), nearest(plane, [1.6, 1.1, 0])
    axis = Axis.between(plane, a, b)
    X = axis.points.positions(plane)
    assert axis.length == pytest.approx(np.linalg.norm(X[-1] - X[0]), rel=1e-12)
    cross = np.cross(X[-1] - X[0], X - X[0])
    assert np.abs(cross).max() < 1e-12  # all on the segment
    inner = axis.points[np.arange(1, len(axis) - 1)]
    assert np.all(np.count_nonzero(inner.bary, axis=1) <= 2)  # on edges
    assert len(axis) > 30
    np.testing.assert_allclose(axis.turning, 1, atol=1e-12)


def test_axis_records_turning_angles_of_a_polyline(plane):
    corners = np.array([[0.4, 0.4, 0], [1.0, 0.4, 0], [1.0, 1.2, 0], [0.6, 1.5, 0]])
    axis = Axis(plane, nearest(plane, corners))
    # On the plane: lengths are the side lengths, turning angles the exterior angles.
    np.testing.assert_allclose(axis.lengths, np.linalg.norm(np.diff(corners, axis=0), axis=1), rtol=1e-12)
    d = np.diff(corners[:, :2], axis=0) @ [1, 1j]
    np.testing.assert_allclose(np.angle(axis.turning[1:-1]), np.angle(d[1:] / d[:-1]), atol=1e-12)
    retraced = axis.trace(plane, axis.start, axis.direction)
    np.testing.assert_allclose(retraced.points.positions(plane), corners, atol=1e-12)


def test_axis_errors(plane):
    a = nearest(plane, [0.5, 0.5, 0])
    with pytest.raises(ContactError, match="at least two"):
        Axis(plane, a)
    with pytest.raises(ContactError, match="coincide"):
        Axis(plane, SurfacePoints.concatenate([a, nearest(plane, [1.0, 1, 0]), nearest(plane, [1.0, 1, 0])]))
    with pytest.raises(ContactError, match=r"boundary.*segment"):
        Axis.between(plane, a, nearest(plane, [1.5, 0.5, 0])).trace(plane, nearest(plane, [1.8, 1, 0]), 1.0)


# ------------------------------------------------------------------------------------------ patches


def test_parameterization_is_the_exact_log_map_from_the_closest_axis_point(patch):
    X = patch.positions()
    A = patch.axis.points.positions(patch.mesh)
    d = np.linalg.norm(X[:, None] - A[None], axis=2)
    np.testing.assert_allclose(np.abs(patch.coords), d.min(1), atol=1e-12)
    clear = np.sort(d, axis=1)[:, 1] - d.min(1) > 1e-9
    np.testing.assert_array_equal(patch.binding[clear], d.argmin(1)[clear])
    np.testing.assert_allclose(relative_log_maps(patch), patch.coords, atol=1e-12)


def test_translate_on_a_plane_is_a_rigid_translation_and_undoes(patch, plane):
    moved = patch.translate(nearest(plane, [1.3, 1.25, 0]))
    shift = moved.positions() - patch.positions()
    assert np.ptp(shift, axis=0).max() < 1e-12
    back = moved.translate(patch.axis.start)
    np.testing.assert_allclose(back.positions(), patch.positions(), atol=1e-12)


def test_rotate_about_the_first_axis_point(patch):
    o = patch.axis.start.positions(patch.mesh)[0]
    turned = patch.rotate(0.8)
    rel0 = (patch.positions() - o)[:, :2] @ [1, 1j]
    rel1 = (turned.positions() - o)[:, :2] @ [1, 1j]
    np.testing.assert_allclose(rel1, rel0 * np.exp(0.8j), atol=1e-12)
    np.testing.assert_allclose(turned.rotate(-0.8).positions(), patch.positions(), atol=1e-12)
    np.testing.assert_allclose(patch.rotate(2 * np.pi).positions(), patch.positions(), atol=1e-12)


def test_bend_moves_only_the_part_after_the_bend_rigidly(patch):
    i = len(patch.axis) // 2
    bent = patch.bend(i, 0.6)
    before = patch.binding < i
    np.testing.assert_array_equal(bent.positions()[before], patch.positions()[before])
    pivot = patch.axis.points[[i]].positions(patch.mesh)[0]
    rel0 = (patch.positions()[~before] - pivot)[:, :2] @ [1, 1j]
    rel1 = (bent.positions()[~before] - pivot)[:, :2] @ [1, 1j]
    np.testing.assert_allclose(rel1, rel0 * np.exp(0.6j), atol=1e-12)
    with pytest.raises(ContactError, match="bend at axis points"):
        patch.bend(0, 0.1)


def test_edits_leave_the_original_untouched(patch, plane):
    before = patch.positions().copy()
    patch.rotate(1.0)
    patch.translate(nearest(plane, [1.0, 1.0, 0]))
    with pytest.raises(ContactError):
        patch.translate(nearest(plane, [1.95, 1.95, 0]))  # would push the patch off the plane
    np.testing.assert_array_equal(patch.positions(), before)


def assert_mirrored_isometric(source, moved):
    """The transferred patch keeps every point's distance and (negated) angle to its axis point."""
    np.testing.assert_allclose(moved.axis.lengths, source.axis.lengths, rtol=1e-12)
    np.testing.assert_allclose(moved.axis.turning, np.conj(source.axis.turning), atol=1e-12)
    fresh = relative_log_maps(moved)
    np.testing.assert_allclose(np.abs(fresh), np.abs(source.coords), rtol=1e-9, atol=1e-12)
    far = np.abs(source.coords) > 1e-6
    np.testing.assert_allclose(np.angle(fresh[far] / np.conj(source.coords[far])), 0, atol=1e-9)


def test_transfer_plane_to_prism_is_mirrored_and_isometric(patch):
    prism = cylinder(radius=0.9, height=3.0, n_around=40, n_along=40, jitter=0.2, seed=3)
    start = nearest(prism, [0.9, 0.0, 1.5])
    moved = patch.transfer(prism, start, 1j)  # axis along the generator
    assert_mirrored_isometric(patch, moved)
    # mirrored: the orientation of the point set flips (signed areas change sign)
    a, b, c = (patch.positions()[i] for i in (0, 1, 2))
    a2, b2, c2 = (moved.positions()[i] for i in (0, 1, 2))
    n = np.cross(b - a, c - a) @ [0, 0, 1]
    outward = a2 / np.linalg.norm(a2[:2]) * [1, 1, 0]
    assert np.sign(np.cross(b2 - a2, c2 - a2) @ outward) == -np.sign(n)


def test_transfer_prism_to_pyramid_is_mirrored_and_isometric():
    prism = cylinder(radius=0.9, height=3.0, n_around=40, n_along=40, jitter=0.2, seed=3)
    points, X = pool(prism, 30000, 4)
    near = np.flatnonzero(np.linalg.norm(X - [0.9, 0, 1.5], axis=1) < 0.3)[:500]
    source = ContactPatch(prism, points[near], farthest_pair_axis(prism, points[near]))
    pyramid = cone(base_radius=1.5, height=3.0, top_radius=0.3, n_around=40, n_along=30, jitter=0.2, seed=5)
    moved = source.transfer(pyramid, nearest(pyramid, [0.0, -0.9, 1.2]), 0.6 + 0.8j)
    assert_mirrored_isometric(source, moved)


def test_transfer_is_sampling_agnostic_on_one_surface(patch):
    """The same prism triangulated coarsely and finely is one surface: the transfer lands on the same
    points. On two samplings of a sphere it agrees up to the discretization."""
    coarse = cylinder(radius=0.9, height=3.0, n_around=40, n_along=3, jitter=0.0, seed=6)
    fine = cylinder(radius=0.9, height=3.0, n_around=40, n_along=120, jitter=0.0, seed=7)
    ends = []
    middle = np.pi / 40  # inside a facet: on a generator edge the two facets' planes differ
    for mesh in (coarse, fine):
        start = nearest(mesh, [0.9 * np.cos(middle), 0.9 * np.sin(middle), 1.5])
        direction = tangent_from_3d(mesh, start, [[0.0, 0.6, 0.8]])[0]
        ends.append(patch.transfer(mesh, start, direction).positions())
    np.testing.assert_allclose(ends[0], ends[1], atol=1e-9)

    ends = []
    for mesh in (icosphere(3), icosphere(6)):
        start = nearest(mesh, [0.0, 0.0, 1.0])
        direction = tangent_from_3d(mesh, start, [[1.0, 0.0, 0.0]])[0]
        ends.append(patch.transfer(mesh, start, direction).positions())
    gap = np.linalg.norm(ends[0] - ends[1], axis=1)
    assert gap.max() < 0.02  # coarse edge length ~0.3, patch radius 0.22


def test_transfer_that_runs_off_the_boundary_says_how_far(patch):
    small = grid_plane(10, 10, size=(0.5, 0.5), jitter=0.2, seed=8)
    with pytest.raises(ContactError, match="boundary"):
        patch.transfer(small, nearest(small, [0.25, 0.25, 0]), 1.0)


def test_bad_patches_are_refused(plane):
    a, b = nearest(plane, [0.5, 0.5, 0]), nearest(plane, [0.8, 0.6, 0])
    axis = Axis.between(plane, a, b)
    with pytest.raises(ContactError, match="empty"):
        ContactPatch(plane, SurfacePoints(np.empty(0, int), np.empty((0, 3))), axis)
    other = grid_plane(4, 4, seed=9)
    with pytest.raises(ContactError, match="different mesh"):
        ContactPatch(other, SurfacePoints.from_vertices(other, [3]), axis)
    two = TriMesh(
        np.vstack([plane.vertices, plane.vertices + np.array([5.0, 0, 0])]),
        np.vstack([plane.faces, plane.faces + plane.n_vertices]),
    )
    axis2 = Axis.between(two, a, b)
    with pytest.raises(ContactError, match="component"):
        ContactPatch(two, SurfacePoints([0, plane.n_faces + 5], [[0.2, 0.3, 0.5]] * 2), axis2)


def test_patch_directions_match_3d_on_the_prism(patch):
    """The transferred axis's first direction is the one asked for, in space too."""
    prism = cylinder(radius=0.9, height=3.0, n_around=40, n_along=40, jitter=0.2, seed=3)
    start = nearest(prism, [0.9, 0.0, 1.5])
    direction = tangent_from_3d(prism, start, [[0.0, 0.0, 1.0]])[0]
    moved = patch.transfer(prism, start, direction)
    first = tangent_to_3d(prism, moved.axis.start, moved.axis.direction)
    np.testing.assert_allclose(first, [[0, 0, 1]], atol=1e-12)


def test_an_axis_bending_round_a_saddle_retraces_through_its_bend():
    """Across the inner side of a torus, shortest geodesics bend round saddle vertices: the axis then has
    several straight runs, and laying it out again must reproduce it."""
    from geodesics.primitives import torus

    mesh = torus(n_major=48, n_minor=24)
    a = nearest(mesh, [0.494, 1.12, -0.264])  # across the inside of the tube
    b = nearest(mesh, [-0.837, -0.2, -0.318])
    axis = Axis.between(mesh, a, b)
    assert np.any(np.abs(axis.turning[1:-1] - 1) > 1e-6), "the path should bend round a saddle"
    again = axis.trace(mesh, axis.start, axis.direction)
    np.testing.assert_allclose(again.points.positions(mesh), axis.points.positions(mesh), atol=1e-9)


def test_a_subset_keeps_its_points_exact_parameterization(patch):
    keep = np.arange(len(patch)) % 3 != 0
    part = patch.subset(keep)
    assert len(part) == keep.sum() and part.axis is patch.axis
    np.testing.assert_array_equal(part.positions(), patch.positions()[keep])
    np.testing.assert_allclose(part.coords, relative_log_maps(part), atol=1e-12)
    with pytest.raises(ContactError, match="without points"):
        patch.subset(np.zeros(len(patch), bool))


def test_a_grown_patch_mirrored_onto_its_transfers_edited_axis_extends_that_transfer(patch, plane):
    """Points added to a hand patch after its transfer land on the object where the transferred patch
    (moved and bent since) would have taken them, and the old points stay where they were."""
    prism = cylinder(radius=0.9, height=3.0, n_around=40, n_along=40, jitter=0.2, seed=3)
    edited = patch.transfer(prism, nearest(prism, [0.9, 0.0, 1.5]), 1j).rotate(0.3).bend(3, 0.2)
    grown = disk_patch(plane, [0.7, 0.8], 0.3, 900, seed=1, axis=patch.axis)
    both = ContactPatch(plane, SurfacePoints.concatenate([patch.points, grown.points]), patch.axis)
    mirrored = both.mirrored_onto(edited.axis)
    np.testing.assert_allclose(mirrored.positions()[: len(patch)], edited.positions(), atol=1e-9)
    fresh = both.transfer(prism, nearest(prism, [0.9, 0.0, 1.5]), 1j).rotate(0.3).bend(3, 0.2)
    np.testing.assert_allclose(mirrored.positions(), fresh.positions(), atol=1e-9)
    with pytest.raises(ContactError, match="not the axis"):
        both.mirrored_onto(Axis.between(prism, nearest(prism, [0.9, 0, 1.0]), nearest(prism, [0.9, 0, 1.1])))
