"""Dense contact pairing by ray casting (§3.2, Fig. 3): closed forms and a brute-force oracle."""

import numpy as np
import pytest

from geodesics import SurfacePoints, TriMesh
from solver import SolverError, hands, objects
from solver.retarget.pairing import (
    INVERTED,
    NO_HIT,
    PAIRED,
    TOO_FAR,
    RayCaster,
    face_normals,
    pair_frame,
    pair_rays,
)


def _brute_hits(V, F, o, d):
    """Every t where the line o + t d meets a triangle: plane intersection, then same-side tests (an
    independent formula from the caster's Möller–Trumbore)."""
    T = V[F]
    n = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    with np.errstate(all="ignore"):
        t = np.einsum("ij,ij->i", n, T[:, 0] - o) / (n @ d)
    X = o + t[:, None] * d
    inside = np.ones(len(F), bool)
    for i in range(3):
        a, b = T[:, i], T[:, (i + 1) % 3]
        inside &= np.einsum("ij,ij->i", np.cross(b - a, X - a), n) >= 0
    return np.sort(t[inside & np.isfinite(t)])


def test_caster_finds_exactly_the_brute_force_hits_on_a_hand():
    hand = hands.make_hand("human")
    V, F = hand.posed_vertices(hand.rig.rest), hand.mesh.faces
    rng = np.random.default_rng(0)
    O = V[rng.integers(0, len(V), 300)] + rng.normal(scale=0.01, size=(300, 3))
    D = rng.normal(size=(300, 3))
    ray, _, t, bary = RayCaster(V, F).intersect(O, D)
    assert np.all(bary >= 0) and np.allclose(bary.sum(1), 1)
    total = 0
    for i in range(len(O)):
        expected = _brute_hits(V, F, O[i], D[i])
        got = t[ray == i]
        assert got.shape == expected.shape, i
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
        total += got.size
    assert total > 300  # most lines pass through the hand, many through two fingers


def test_a_line_through_a_vertex_or_edge_counts_once():
    # Two triangles sharing the edge x = y; a line through the edge's midpoint and one through a vertex.
    V = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    caster = RayCaster(V, F)
    ray, _, t, _ = caster.intersect([[0.5, 0.5, 1.0], [0.0, 0.0, 1.0]], [[0, 0, -1.0], [0, 0, -1.0]])
    np.testing.assert_array_equal(ray, [0, 1])
    np.testing.assert_allclose(t, [1.0, 1.0])


def test_plane_pairs_straight_across_and_inverts_when_penetrating():
    # Source contacts on the plane z = 0 facing +z; the opposite mesh a 2 cm slab.
    rng = np.random.default_rng(1)
    xy = rng.uniform(-0.02, 0.02, (50, 2))
    origins = np.column_stack([xy, np.zeros(50)])
    normals = np.tile([0.0, 0.0, 1.0], (50, 1))
    slab = objects.box((0.1, 0.1, 0.02), cells=4)
    for gap in (0.004, 0.0):  # the slab 4 mm above, and touching
        V = slab.vertices + np.array([0.0, 0.0, 0.01 + gap])
        pairing = pair_rays(origins, normals, RayCaster(V, slab.faces), cutoff=0.01)
        assert np.all(pairing.status == PAIRED)
        np.testing.assert_allclose(pairing.distance, gap, atol=1e-12)
        np.testing.assert_allclose(pairing.positions, origins + np.array([0, 0, gap]), atol=1e-12)
        hit = SurfacePoints(pairing.faces, pairing.bary).positions(TriMesh(V, slab.faces))
        np.testing.assert_allclose(hit, pairing.positions, atol=1e-12)
    # The slab sunk 3 mm into the plane: one hit ahead (its top), so the ray turns and finds its bottom.
    V = slab.vertices + np.array([0.0, 0.0, 0.01 - 0.003])
    pairing = pair_rays(origins, normals, RayCaster(V, slab.faces), cutoff=0.01)
    assert np.all(pairing.status == INVERTED)
    np.testing.assert_allclose(pairing.distance, 0.003, atol=1e-12)
    np.testing.assert_allclose(pairing.positions[:, 2], -0.003, atol=1e-12)
    # The cutoff discards what lies farther: the slab 15 mm above.
    V = slab.vertices + np.array([0.0, 0.0, 0.025])
    pairing = pair_rays(origins, normals, RayCaster(V, slab.faces), cutoff=0.01)
    assert np.all(pairing.status == TOO_FAR) and not pairing.kept.any()
    np.testing.assert_allclose(pairing.distance, 0.015, atol=1e-12)
    # Facing away: nothing is hit.
    pairing = pair_rays(origins, -normals, RayCaster(V, slab.faces), cutoff=0.01)
    assert np.all(pairing.status == NO_HIT) and np.all(pairing.faces == -1)
    assert np.all(np.isnan(pairing.distance))


def _line_sphere(o, d, c, r):
    """Closed form: t of the two intersections of unit-direction lines with a sphere (NaN: miss)."""
    oc = o - c
    b = np.einsum("ij,ij->i", oc, d)
    disc = b**2 - (np.einsum("ij,ij->i", oc, oc) - r**2)
    s = np.sqrt(np.where(disc >= 0, disc, np.nan))
    return -b - s, -b + s, disc


def test_sphere_outside_sphere_matches_the_closed_form():
    r1, r2, centre = 0.03, 0.035, np.array([0.072, 0.0, 0.0])
    source = objects.sphere(r1, subdivisions=4)
    target = TriMesh(objects.sphere(r2, subdivisions=5).vertices + centre, objects.sphere(r2, 5).faces)
    rng = np.random.default_rng(2)
    faces = rng.integers(0, source.n_faces, 4000)
    points = SurfacePoints(faces, rng.dirichlet([1, 1, 1], faces.size))
    pairing = pair_frame(source, source.vertices, points, target, target.vertices, cutoff=0.02)
    o = points.positions(source)
    n = face_normals(source.vertices, source.faces, faces)
    near, _, disc = _line_sphere(o, n, centre, r2)
    # The target is a convex polyhedron between its sphere and the sphere its faces' planes touch
    # (radius r_in): a ray from outside meets it between the closed forms for the two spheres.
    fn = face_normals(target.vertices, target.faces, np.arange(target.n_faces))
    r_in = np.min(np.einsum("ij,ij->i", fn, target.vertices[target.faces[:, 0]] - centre))
    assert 0.999 * r2 < r_in < r2
    near_in, _, disc_in = _line_sphere(o, n, centre, r_in)
    clear = disc_in > (0.2 * r2) ** 2  # away from grazing lines
    hit = clear & (near > 0)
    miss = (disc < 0) | (near < -0.01)
    assert hit.sum() > 100 and miss.sum() > 1000
    decided = hit & ((near_in < 0.02) | (near > 0.02))  # clearly on one side of the cutoff
    expected = np.where(near[decided] > 0.02, TOO_FAR, PAIRED)
    np.testing.assert_array_equal(pairing.status[decided], expected)
    assert np.count_nonzero(expected == TOO_FAR) > 20 and np.count_nonzero(expected == PAIRED) > 20
    assert np.all(pairing.distance[hit] >= near[hit] - 1e-12)
    assert np.all(pairing.distance[hit] <= near_in[hit] + 1e-12)
    assert np.all(pairing.status[miss] == NO_HIT)
    kept = pairing.kept
    radius = np.linalg.norm(pairing.positions[kept] - centre, axis=1)
    assert np.all((radius >= r_in - 1e-12) & (radius <= r2 + 1e-12))
    np.testing.assert_allclose(pairing.points.positions(target), pairing.positions[kept], atol=1e-12)


def test_sphere_inside_sphere_inverts_to_the_far_side():
    # Every contact of a small sphere is inside a concentric larger one: one hit ahead, so the ray is
    # inverted, passes the centre and meets the large sphere at distance r1 + r2 behind.
    r1, r2 = 0.01, 0.03
    source, target = objects.sphere(r1, 3), objects.sphere(r2, 4)
    rng = np.random.default_rng(3)
    faces = rng.integers(0, source.n_faces, 500)
    points = SurfacePoints(faces, rng.dirichlet([1, 1, 1], faces.size))
    far = pair_frame(source, source.vertices, points, target, target.vertices, cutoff=0.05)
    assert np.all(far.status == INVERTED)
    o = points.positions(source)
    n = face_normals(source.vertices, source.faces, faces)
    # Behind the contact the ray meets the polyhedron between the sphere r2 and the sphere its faces'
    # planes touch.
    fn = face_normals(target.vertices, target.faces, np.arange(target.n_faces))
    r_in = np.min(np.einsum("ij,ij->i", fn, target.vertices[target.faces[:, 0]]))
    near, _, _ = _line_sphere(o, n, np.zeros(3), r2)
    near_in, _, _ = _line_sphere(o, n, np.zeros(3), r_in)
    assert np.all((far.distance <= -near + 1e-12) & (far.distance >= -near_in - 1e-12))
    assert np.all(np.abs(far.distance - (r1 + r2)) < 0.02 * r1)
    close = pair_frame(source, source.vertices, points, target, target.vertices, cutoff=0.02)
    assert np.all(close.status == TOO_FAR) and close.counts()["too far"] == 500


def test_three_hits_ahead_still_means_inside():
    # A contact inside one slab, with a second slab beyond: three hits ahead (odd), so inverted.
    slab = objects.box((0.1, 0.1, 0.01), cells=2)
    V = np.concatenate([slab.vertices + np.array([0, 0, 0.003]), slab.vertices + np.array([0, 0, 0.03])])
    F = np.concatenate([slab.faces, slab.faces + len(slab.vertices)])
    pairing = pair_rays([[0.0, 0.0, 0.0]], [[0.0, 0.0, 1.0]], RayCaster(V, F), cutoff=0.01)
    assert pairing.status[0] == INVERTED
    np.testing.assert_allclose(pairing.distance, 0.002, atol=1e-12)


def test_hand_contacts_pair_back_onto_the_hand_from_an_offset_object():
    # Object contacts taken as points just off the hand along its normals; pairing them back must find
    # the hand points they came from (paired at the offset, or inverted when pushed inside).
    hand = hands.make_hand("human")
    points = SurfacePoints.concatenate(hand.contact_patches(30, seed=1).values())
    V = hand.posed_vertices(hand.rig.rest)
    p, n = hand.posed_points(hand.rig.rest, points)
    rng = np.random.default_rng(4)
    offset = rng.uniform(-0.0015, 0.0015, len(points))
    origins = p + offset[:, None] * n
    pairing = pair_rays(origins, -n, RayCaster(V, hand.mesh.faces), cutoff=0.01)
    assert pairing.kept.mean() > 0.97
    ok = pairing.kept
    assert np.all(pairing.status[ok & (offset > 0)] == PAIRED)
    assert np.all(pairing.status[ok & (offset < 0)] == INVERTED)
    np.testing.assert_allclose(pairing.distance[ok], np.abs(offset[ok]), atol=2e-4)
    assert np.median(np.linalg.norm(pairing.positions[ok] - p[ok], axis=1)) < 2e-4


def test_bad_input_is_refused():
    slab = objects.box((0.1, 0.1, 0.01), cells=1)
    caster = RayCaster(slab.vertices, slab.faces)
    with pytest.raises(SolverError, match="zero normals"):
        pair_rays([[0.0, 0, 0]], [[0.0, 0, 0]], caster)
    with pytest.raises(SolverError, match="cutoff"):
        pair_rays([[0.0, 0, 0]], [[0.0, 0, 1]], caster, cutoff=0.0)
    with pytest.raises(SolverError, match="shape"):
        pair_frame(slab, slab.vertices[:3], SurfacePoints([0], [[1, 0, 0]]), slab, slab.vertices)
