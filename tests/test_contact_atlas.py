"""The contact atlas (retargeting paper §3.3.2): charts around axial curves, λ_A, λ_S, dropped curves,
the distance filter."""

import numpy as np
import pytest

from geodesics import Axis, ContactAtlas, ContactError, SurfacePoints, TriMesh, tangent_from_3d, tangent_to_3d
from geodesics.primitives import grid_plane

ROTATION = np.array([[np.cos(0.7), -np.sin(0.7), 0], [np.sin(0.7), np.cos(0.7), 0], [0, 0, 1]])
SHIFT = np.array([3.0, -1.0, 0.0])


def nearest(mesh, xyz):
    return SurfacePoints.nearest(mesh, np.atleast_2d(xyz))


@pytest.fixture(scope="module")
def setting():
    """A source plane with three axial curves ("fingers"), and a rigidly moved, differently meshed copy."""
    source = grid_plane(50, 50, size=(2.0, 2.0), jitter=0.2, seed=21)
    moved = grid_plane(43, 47, size=(2.0, 2.0), jitter=0.2, seed=22)
    target = TriMesh(moved.vertices @ ROTATION.T + SHIFT, moved.faces)
    ends = {
        "thumb": ([0.4, 0.5], [0.6, 1.3]),
        "index": ([0.9, 0.5], [1.0, 1.5]),
        "middle": ([1.4, 0.5], [1.5, 1.5]),
    }
    curves = {
        name: Axis.between(source, nearest(source, [*a, 0]), nearest(source, [*b, 0]))
        for name, (a, b) in ends.items()
    }
    rng = np.random.default_rng(23)
    contacts = SurfacePoints(rng.integers(0, source.n_faces, 30000), rng.dirichlet([2.0, 2.0, 2.0], 30000))
    X = contacts.positions(source)
    contacts = contacts[np.flatnonzero((X[:, 0] > 0.2) & (X[:, 0] < 1.8) & (X[:, 1] > 0.3) & (X[:, 1] < 1.7))]
    return source, target, ContactAtlas(source, curves), contacts


def placements(atlas, target):
    """Each curve's start and direction at the image of its source start and direction."""
    out = {}
    for name, axis in atlas.curves.items():
        start = nearest(target, axis.start.positions(atlas.mesh) @ ROTATION.T + SHIFT)
        direction = tangent_to_3d(atlas.mesh, axis.start, axis.direction) @ ROTATION.T
        out[name] = (start, tangent_from_3d(target, start, direction)[0])
    return out


def test_isometric_surfaces_move_contacts_by_the_isometry(setting):
    source, target, atlas, contacts = setting
    laid = atlas.lay_out(target, placements(atlas, target))
    points, kept = atlas.transfer(contacts, laid)
    assert kept.all()
    expected = contacts.positions(source) @ ROTATION.T + SHIFT
    np.testing.assert_allclose(points.positions(target), expected, atol=1e-9)


def test_each_contact_is_bound_to_its_nearest_landmark(setting):
    source, _, atlas, contacts = setting
    coords = atlas.parameterize(contacts[np.arange(2000)])
    X = contacts[np.arange(2000)].positions(source)
    landmarks = [atlas.curves[n].points.positions(source) for n in coords.curves]
    d = np.concatenate([np.linalg.norm(X[:, None] - L[None], axis=2) for L in landmarks], axis=1)
    np.testing.assert_allclose(coords.distances, d.min(1), atol=1e-12)


def test_scaling_stretches_axes_and_distances(setting):
    _, target, atlas, contacts = setting
    laid = atlas.lay_out(target, placements(atlas, target), axis_scale={"index": 1.3})
    assert laid["index"].length == pytest.approx(1.3 * atlas.curves["index"].length, rel=1e-12)
    assert laid["thumb"].length == pytest.approx(atlas.curves["thumb"].length, rel=1e-12)
    sample = contacts[np.arange(3000)]
    coords = atlas.parameterize(sample)
    points, kept = atlas.transfer(sample, laid, radial_scale={"index": 1.5})
    index = coords.curve[kept] == coords.curves.index("index")
    axis = laid["index"]
    landmark = axis.points[coords.landmark[kept][index]].positions(target)
    got = np.linalg.norm(points.positions(target)[index] - landmark, axis=1)
    np.testing.assert_allclose(got, 1.5 * coords.distances[kept][index], atol=1e-9)


def test_dropping_a_curve_removes_only_its_contacts(setting):
    _, target, atlas, contacts = setting
    laid = atlas.lay_out(target, placements(atlas, target))
    all_coords = atlas.parameterize(contacts)
    bound_to_middle = all_coords.curve == all_coords.curves.index("middle")
    three, kept3 = atlas.transfer(contacts, laid)
    fewer = {k: v for k, v in laid.items() if k != "middle"}
    threshold = 0.2
    two, kept2 = atlas.transfer(contacts, fewer, threshold=threshold)
    # contacts of the remaining curves within the threshold land exactly where they did
    others = ~bound_to_middle & (all_coords.distances <= threshold)
    assert np.all(kept2[others])
    index3, index2 = np.cumsum(kept3) - 1, np.cumsum(kept2) - 1
    np.testing.assert_allclose(
        two[index2[others]].positions(target), three[index3[others]].positions(target), atol=1e-12
    )
    # the middle finger's contacts went to the index curve's chart and the far ones were filtered out
    assert np.mean(kept2[bound_to_middle]) < 0.6
    rebound = atlas.parameterize(contacts, ["thumb", "index"])
    np.testing.assert_array_equal(kept2, rebound.distances <= threshold)


def test_atlas_errors(setting):
    source, target, atlas, contacts = setting
    with pytest.raises(ContactError, match="at least one"):
        ContactAtlas(source, {})
    with pytest.raises(ContactError, match="no axial curve named 'pinky'"):
        atlas.lay_out(target, {"pinky": (nearest(target, SHIFT), 1.0)})
    with pytest.raises(ContactError, match="no target curves"):
        atlas.transfer(contacts, {})
    a, b = nearest(target, SHIFT + np.array([0.5, 0.5, 0])), nearest(target, SHIFT + np.array([0.6, 0.6, 0]))
    short = Axis.between(target, a, b)
    with pytest.raises(ContactError, match="target curve 'thumb' has"):
        atlas.transfer(contacts, {"thumb": short})
