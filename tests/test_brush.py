"""Even surface samples and the area brush: exact counts per face, the same samples however the faces are
chosen, spacing better than random points, and dabs that cover exactly the connected, facing part of a
ball (checked against brute force and against the closed-form visible cap of a sphere)."""

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from geodesics import SurfacePoints, TriMesh
from geodesics.brush import Dab, erase, paint
from geodesics.primitives import grid_plane, icosphere
from geodesics.sampling import surface_samples

SETTINGS = settings(max_examples=40, deadline=None, derandomize=True, database=None)
FINE = grid_plane(40, 40, size=(1.0, 1.0), jitter=0.2, seed=2)
COARSE = TriMesh([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]])


@given(density=st.floats(1.0, 5000.0), seed=st.integers(0, 2**16))
@SETTINGS
def test_each_face_gets_its_area_times_the_density_rounded_one_way_or_the_other(density, seed):
    points, ids = surface_samples(FINE, density, seed=seed)
    counts = np.bincount(points.faces, minlength=FINE.n_faces)
    share = FINE.face_areas * density
    assert np.all((counts == np.floor(share)) | (counts == np.ceil(share)))
    assert abs(len(points) - FINE.face_areas.sum() * density) <= 1
    assert np.array_equal(ids, np.arange(len(points)))  # every id once, face by face


@given(seed=st.integers(0, 2**16), chosen=st.lists(st.integers(0, FINE.n_faces - 1), max_size=200))
@SETTINGS
def test_sampling_some_faces_gives_the_same_samples_as_the_whole_surface(seed, chosen):
    everything, all_ids = surface_samples(FINE, 800.0, seed=seed)
    some, ids = surface_samples(FINE, 800.0, faces=chosen, seed=seed)
    expected = np.isin(everything.faces, chosen)
    assert np.array_equal(ids, all_ids[expected])
    assert np.array_equal(some.faces, everything.faces[expected])
    assert np.array_equal(some.bary, everything.bary[expected])


@pytest.mark.parametrize("mesh", [FINE, COARSE], ids=["fine", "coarse"])
def test_samples_are_spread_more_evenly_than_random_points(mesh):
    density = 4000.0
    points, _ = surface_samples(mesh, density, seed=1)
    X = points.positions(mesh)[:, :2]
    nearest = cKDTree(X).query(X, k=2)[0][:, 1]
    # Uniform random points (a Poisson process) have a mean nearest-neighbour distance of 0.5/sqrt(ρ)
    # and pairs as close as you like; even samples keep their distance.
    assert nearest.mean() > 0.6 / np.sqrt(density)
    assert np.quantile(nearest, 0.01) > 0.1 / np.sqrt(density)
    grid = np.stack(np.meshgrid(np.linspace(0.05, 0.95, 60), np.linspace(0.05, 0.95, 60)), -1).reshape(-1, 2)
    assert cKDTree(X).query(grid)[0].max() < 1.6 / np.sqrt(density)  # no large holes


def test_bad_densities_and_faces_are_refused():
    for density in (0.0, -1.0, np.nan, np.inf):
        with pytest.raises(ValueError, match="density"):
            surface_samples(FINE, density)
    with pytest.raises(ValueError, match="face indices"):
        surface_samples(FINE, 10.0, faces=[FINE.n_faces])


def brute_force_region(mesh, centre, radius):
    """Faces whose closest point to ``centre`` is within ``radius`` (no connectivity)."""
    faces = np.arange(mesh.n_faces)
    closest = SurfacePoints.from_positions(mesh, faces, np.broadcast_to(centre, (faces.size, 3)))
    return faces[np.linalg.norm(closest.positions(mesh) - centre, axis=1) <= radius]


@given(x=st.floats(0.1, 0.9), y=st.floats(0.1, 0.9), radius=st.floats(0.01, 0.4))
@SETTINGS
def test_a_dab_on_a_plane_covers_the_faces_its_ball_meets(x, y, radius):
    centre = np.array([x, y, 0.0])
    face = int(SurfacePoints.nearest(FINE, centre).faces[0])
    region = Dab(face, tuple(centre), radius).region(FINE)
    assert np.array_equal(np.sort(region), brute_force_region(FINE, centre, radius))


def u_shape() -> TriMesh:
    """A strip folded into a U: two arms 0.1 apart, joined by a bend far from the arms' tips."""
    arm = grid_plane(20, 4, size=(1.0, 0.2))
    V = arm.vertices
    lower = V.copy()
    upper = V.copy()
    upper[:, 2] = 0.1
    n = len(V)
    faces = np.concatenate([arm.faces, arm.faces[:, ::-1] + n])
    # the bend: join the arms' x = 0 edges by a strip of quads
    left = np.flatnonzero(np.isclose(V[:, 0], 0.0))
    left = left[np.argsort(V[left, 1])]
    bend = []
    for a, b in itertools.pairwise(left):
        bend += [[a, b, b + n], [a, b + n, a + n]]
    return TriMesh(np.concatenate([lower, upper]), np.concatenate([faces, np.array(bend)]))


def test_a_dab_does_not_jump_the_gap_to_surface_it_reaches_only_through_the_air():
    mesh = u_shape()
    centre = np.array([0.9, 0.1, 0.0])  # the lower arm's tip; the upper arm is 0.1 above
    face = int(SurfacePoints.nearest(mesh, centre).faces[0])
    region = Dab(face, tuple(centre), 0.15).region(mesh)
    upper = mesh.vertices[mesh.faces[region]][:, :, 2].max(axis=1) > 0.05
    assert region.size and not upper.any()
    assert np.any(mesh.vertices[mesh.faces[brute_force_region(mesh, centre, 0.15)]][:, :, 2] > 0.05)


def test_a_dab_with_a_viewer_covers_only_the_cap_the_viewer_sees():
    sphere = icosphere(4)
    samples, _ = surface_samples(sphere, 2000.0, seed=3)
    height = 3.0
    top = int(SurfacePoints.nearest(sphere, [0, 0, 1.0]).faces[0])
    dab = Dab(top, (0.0, 0.0, 1.0), 2.5, eye=(0.0, 0.0, height))
    covered = dab.covers(sphere, samples)
    z = samples.positions(sphere)[:, 2]
    # A viewer on the axis at height h sees exactly the cap z > 1/h of the unit sphere; face normals
    # blur the rim by about a face's size.
    rim = np.abs(z - 1.0 / height) < 0.05
    assert np.array_equal(covered[~rim], (z > 1.0 / height)[~rim])
    orthographic = Dab(top, (0.0, 0.0, 1.0), 2.5, direction=(0.0, 0.0, -1.0)).covers(sphere, samples)
    assert np.array_equal(orthographic[np.abs(z) > 0.05], (z > 0)[np.abs(z) > 0.05])


def test_painting_collects_each_sample_once_at_the_chosen_density():
    density = 5000.0
    dab = Dab(int(SurfacePoints.nearest(FINE, [0.5, 0.5, 0]).faces[0]), (0.5, 0.5, 0.0), 0.2)
    points, ids = paint(FINE, [dab], density)
    again, again_ids = paint(FINE, [dab, dab, dab], density)
    assert np.array_equal(ids, again_ids) and np.array_equal(points.bary, again.bary)
    assert len(points) == pytest.approx(density * np.pi * 0.2**2, rel=0.03)
    assert np.all(np.linalg.norm(points.positions(FINE) - [0.5, 0.5, 0], axis=1) <= 0.2)
    second = Dab(int(SurfacePoints.nearest(FINE, [0.6, 0.5, 0]).faces[0]), (0.6, 0.5, 0.0), 0.2)
    _, both_ids = paint(FINE, [dab, second], density)
    _, second_ids = paint(FINE, [second], density)
    assert np.array_equal(both_ids, np.union1d(ids, second_ids))
    assert len(paint(FINE, [], density)[0]) == 0


def test_erasing_keeps_exactly_the_points_no_dab_covers():
    points, _ = surface_samples(FINE, 3000.0, seed=5)
    dabs = [
        Dab(int(SurfacePoints.nearest(FINE, [x, 0.5, 0]).faces[0]), (x, 0.5, 0.0), 0.1) for x in (0.3, 0.4)
    ]
    keep = erase(FINE, points, dabs)
    X = points.positions(FINE)
    inside = (np.linalg.norm(X - [0.3, 0.5, 0], axis=1) <= 0.1) | (
        np.linalg.norm(X - [0.4, 0.5, 0], axis=1) <= 0.1
    )
    assert np.array_equal(keep, ~inside)


def test_bad_dabs_are_refused():
    with pytest.raises(ValueError, match="radius"):
        Dab(0, (0.0, 0.0, 0.0), 0.0)
    with pytest.raises(ValueError, match="centre"):
        Dab(0, (np.nan, 0.0, 0.0), 1.0)
