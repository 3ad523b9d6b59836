"""The solve a person's layout needs: the trust region on the energy as squares (its compressed system is
the full one), the narrow band that skips skin far from the object (the same penalty), and the global
start that reaches a grasp the hand must travel and turn to (where a local solve from rest does not), a
small edit that stays near, and the patches a pose leaves unreached, named."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from geodesics import SurfacePoints, TriMesh
from solver import ContactIK, MeshSDF, SolverError, hands, objects
from solver.grasp import grasp, in_palm
from solver.least_squares import compressed
from solver.sdf import NarrowBand

#: The pads a person would place for the grasp: the palm and the tips of the thumb and two fingers.
PADS = ("hand", "thumb_3", "index_3", "middle_3")


def test_the_compressed_system_has_the_full_systems_cost_gradient_and_model():
    rng = np.random.default_rng(0)
    J = rng.normal(size=(300, 12))
    J[:, 5] = 0.0  # a variable nothing depends on
    J[150:] = 0.0  # rows that are all zero, as a skin far from the object gives
    r = rng.normal(size=300)
    rc, Jc = compressed(r, J)
    assert rc.shape == (13,) and Jc.shape == (13, 12)
    assert rc @ rc == pytest.approx(r @ r, rel=1e-12)
    np.testing.assert_allclose(Jc.T @ rc, J.T @ r, atol=1e-10)
    for _ in range(3):
        step = rng.normal(size=12)
        model, full = rc + Jc @ step, r + J @ step
        assert model @ model == pytest.approx(full @ full, rel=1e-10)


def test_the_narrow_band_gives_the_bands_penetration_without_querying_far_skin():
    """Moving skin: inside within the band the distances and gradients are the solid's own, elsewhere
    (outside, or deeper than the band) positive, so the penetration a penalty sees is exactly the skin
    within the band inside; points far from the surface are not queried again."""
    hand = hands.make_hand("human")
    rng = np.random.default_rng(7)
    theta = rng.normal(size=hand.rig.n_dofs) * np.where(hand.rig.is_rotation, 0.2, 0.01)
    V = hand.posed_vertices(theta)
    sphere = objects.sphere(0.05)
    solid = MeshSDF(TriMesh(sphere.vertices + V.mean(0), sphere.faces))
    band = 0.006
    queried = []

    class Counting:
        def evaluate(self, x, b):
            queried.append(len(x))
            return solid.evaluate(x, b)

    tracked = NarrowBand(Counting(), band)
    for step in range(5):
        X = V + rng.normal(size=V.shape) * 2e-4 * step
        exact = solid(X)
        signed, gradient = tracked.evaluate(X)
        inside = (exact < 0) & (exact >= -band)
        np.testing.assert_allclose(signed[inside], exact[inside], rtol=0, atol=1e-15)
        np.testing.assert_allclose(gradient[inside], solid.evaluate(X[inside])[1], rtol=0, atol=1e-12)
        assert np.all(signed[~inside] > 0)
        assert np.all(gradient[exact < -band] == 0)
    assert queried[0] == len(V) and max(queried[1:]) < len(V) / 2


def _layout(angle_degrees: float, shift: float, seed: int = 0):
    """A grasp that exists (the fingers wrapped around a cylinder by flex-to-contact), its pads' closest
    points on the cylinder as targets, the cylinder and targets then carried away by a rigid motion."""
    hand = hands.make_hand("human")
    cylinder = in_palm(hand, objects.cylinder(0.03))
    grip = grasp(hand, cylinder, curl="in turn")
    patches = hand.contact_patches(30, seed=0)
    points = SurfacePoints.concatenate([patches[name] for name in PADS])
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    R = Rotation.from_rotvec(np.radians(angle_degrees) * axis / np.linalg.norm(axis)).as_matrix()
    t = shift * np.array([1.0, -0.5, 0.3])
    moved = TriMesh(cylinder.vertices @ R.T + t, cylinder.faces)
    solid = MeshSDF(moved)
    posed, _ = hand.posed_points(grip.theta, points)
    _, targets, faces = solid.query(posed @ R.T + t)
    patches_of = [(name, len(patches[name])) for name in PADS]
    return hand, points, targets, moved.face_normals[faces], solid, patches_of


@pytest.fixture(scope="module")
def far():
    """The cylinder turned 140° and moved 12 cm from the open hand."""
    return _layout(140.0, 0.12)


def test_a_global_start_reaches_the_grasp_the_hand_must_travel_and_turn_to(far):
    hand, points, targets, normals, solid, patches = far
    ik = ContactIK(hand, points, targets, normals, keep_out=solid, patches=patches)
    result = ik.solve()
    assert result.start == "global" and result.status == "converged"
    assert result.unreached == () and max(result.gaps.values()) < 0.002
    assert -solid(hand.posed_vertices(result.theta)).min() < 0.001  # no skin a millimetre inside
    local = ContactIK(hand, points, targets, normals, keep_out=solid, patches=patches, algorithm="slsqp")
    stuck = local.solve(start="local", max_evaluations=400)  # Contact Edit's solve, from the open hand
    assert len(stuck.unreached) >= 2 and stuck.energy > 5 * result.energy


def test_an_edit_of_a_solved_layout_starts_where_the_hand_is_and_stays_near(far):
    hand, points, targets, normals, solid, patches = far
    ik = ContactIK(hand, points, targets, normals, keep_out=solid, patches=patches)
    solved = ik.solve()
    # the index pad's targets slid 4 mm along the surface's tangent, as one patch moved by hand
    moved = targets.copy()
    index = slice(sum(n for _, n in patches[:2]), sum(n for _, n in patches[:3]))
    tangent = np.cross(normals[index].mean(0), [0.0, 0.0, 1.0])
    moved[index] += 0.004 * tangent / np.linalg.norm(tangent)
    moved[index] = solid.query(moved[index])[1]
    edit = ContactIK(hand, points, moved, normals, keep_out=solid, patches=patches).solve(solved.theta)
    assert edit.start == "local" and edit.unreached == ()
    turn = Rotation.from_matrix(
        hand.rig.root_transform(edit.theta)[:3, :3] @ hand.rig.root_transform(solved.theta)[:3, :3].T
    )
    assert np.degrees(turn.magnitude()) < 10
    assert (
        ContactIK(hand, points, moved, normals, patches=patches).solve(solved.theta, start="global").start
        == "global"
    )


def test_a_patch_the_hand_cannot_reach_is_named(far):
    hand, points, targets, normals, _, patches = far
    out_of_reach = targets.copy()
    thumb = slice(patches[0][1], patches[0][1] + patches[1][1])
    out_of_reach[thumb] += 0.25 * np.array([0.0, 0.0, 1.0])  # the thumb's targets 25 cm off the others
    result = ContactIK(hand, points, out_of_reach, normals, patches=patches).solve()
    assert len(result.unreached) > 1  # least squares spreads the miss over the patches
    assert result.out_of_reach == ("thumb_3",) and result.gaps["thumb_3"] > 0.02


def test_patches_and_starts_are_checked(far):
    hand, points, targets, normals, *_ = far
    with pytest.raises(SolverError, match="count its contacts"):
        ContactIK(hand, points, targets, normals, patches=[("a", 3)])
    with pytest.raises(SolverError, match="name each patch once"):
        ContactIK(hand, points, targets, normals, patches=[("a", len(points) - 1), ("a", 1)])
    ik = ContactIK(hand, points, targets, normals, algorithm="slsqp")
    with pytest.raises(SolverError, match="global start needs"):
        ik.solve(start="global")
    with pytest.raises(SolverError, match="start must be one of"):
        ik.solve(start="somewhere")
    with pytest.raises(SolverError, match="trust-region algorithm needs"):
        ContactIK(hand, points, targets, normals, algorithm="trust-region", norm="l2")
