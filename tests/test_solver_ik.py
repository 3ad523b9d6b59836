"""Contact IK: every term's gradient against central differences, staged solves, scale invariance,
cancellation, and bad input."""

import numpy as np
import pytest

from geodesics import SurfacePoints, TriMesh
from solver import Box, ContactIK, HalfSpace, Markers, MeshSDF, SolverError, Weights, hands, objects
from solver.ik import L2_SMOOTHING, minimize
from solver.rotations import euler_to_matrix


@pytest.fixture(scope="module")
def hand():
    return hands.make_hand("human")


def problem(hand, per_patch=12, seed=0):
    """The hand's own patch points at a random pose with opposed normals: (points, P, N, pose)."""
    rng = np.random.default_rng(seed)
    rig = hand.rig
    points = SurfacePoints.concatenate(hand.contact_patches(per_patch, seed=seed).values())
    truth = np.zeros(rig.n_dofs)
    joints = rig.dof_bone != 0
    truth[joints] = 0.5 * rng.uniform(rig.lower[joints], rig.upper[joints])
    truth[:3] = [0.01, -0.02, 0.015]
    truth[3:6] = [0.2, -0.1, 0.3]
    P, N = hand.posed_points(truth, points)
    return points, P, -N, truth


def central_gradient(ik, theta, h=1e-6):
    g = np.empty_like(theta)
    for j in range(theta.size):
        step = np.zeros_like(theta)
        step[j] = h
        g[j] = (ik.energy(theta + step)[0] - ik.energy(theta - step)[0]) / (2 * h)
    return g


ONLY = {
    name: Weights(**{w: (value if w == key else 0.0) for w in "dnpmtko"})
    for name, key, value in [
        ("distance", "d", 1.0),
        ("normal", "n", 1.0),
        ("prior", "p", 10.0),
        ("marker", "m", 1.0),
        ("table", "t", 1.0),
        ("keyed", "k", 10.0),
        ("penetration", "o", 100.0),
    ]
}


@pytest.mark.parametrize(("term", "obstacle"), [(term, "half-space") for term in ONLY] + [("table", "box")])
def test_every_term_has_the_exact_gradient(hand, term, obstacle):
    points, P, N, truth = problem(hand)
    rng = np.random.default_rng(7)
    table = (
        HalfSpace(point=[0, 0, -0.01], normal=[0.1, 0.2, 1.0])
        if obstacle == "half-space"
        else Box(
            center=hand.posed_vertices(truth).mean(0),
            half_extents=[0.07, 0.06, 0.05],
            rotation=euler_to_matrix([0.1, 0.2, 0.3]),
        )
    )
    sphere = objects.sphere(0.05)  # a ball around the hand's middle: some of its skin is inside
    ball = TriMesh(sphere.vertices + hand.posed_vertices(truth).mean(0), sphere.faces)
    ik = ContactIK(
        hand,
        points,
        P,
        N,
        ONLY[term],
        prior=0.1 * truth,
        markers=Markers(points[::7], P[::7] + 0.01),
        obstacle=table,
        keep_out=MeshSDF(ball),
        keyed=truth,
        contact_weights=np.random.default_rng(3).uniform(0.2, 3.0, len(points)),  # some matter more
    )
    for trial in range(3):
        noise = rng.normal(size=truth.size) * np.where(hand.rig.is_rotation, 0.2, 0.01)
        theta = np.clip(truth + noise, hand.rig.lower, hand.rig.upper)
        energy, terms, grad = ik.energy_and_gradient(theta)
        assert terms[term] > 0 and energy == pytest.approx(terms[term])
        numeric = central_gradient(ik, theta)
        assert np.abs(grad - numeric).max() < 1e-5 * np.abs(numeric).max(), (term, trial)


@pytest.mark.parametrize("term", list(ONLY))
def test_residuals_are_the_energy_as_a_sum_of_squares(hand, term):
    """The trust region's view of the energy: Σ r² is the energy (the normals' 1 + n·m is |n + m|² / 2),
    2 Jᵀr its gradient over the DOFs asked for, and without the solids their terms are left out."""
    points, P, N, truth = problem(hand)
    sphere = objects.sphere(0.05)
    ball = TriMesh(sphere.vertices + hand.posed_vertices(truth).mean(0), sphere.faces)
    ik = ContactIK(
        hand, points, P, N, ONLY[term], prior=0.1 * truth, markers=Markers(points[::7], P[::7] + 0.01),
        obstacle=HalfSpace(point=[0, 0, -0.01], normal=[0.1, 0.2, 1.0]), keep_out=MeshSDF(ball), keyed=truth,
        contact_weights=np.random.default_rng(3).uniform(0.2, 3.0, len(points)),
    )  # fmt: skip
    rng = np.random.default_rng(7)  # the pose of the gradient test's first trial: some skin in the ball
    noise = rng.normal(size=truth.size) * np.where(hand.rig.is_rotation, 0.2, 0.01)
    theta = np.clip(truth + noise, hand.rig.lower, hand.rig.upper)
    dofs = np.flatnonzero(np.random.default_rng(11).random(truth.size) < 0.6)
    energy, terms, grad = ik.energy_and_gradient(theta)
    r, J, total, parts = ik.residuals(theta, dofs)
    assert terms[term] > 0 and J.shape == (r.size, dofs.size)
    assert r @ r == pytest.approx(energy, rel=1e-12) and total == pytest.approx(energy, rel=1e-12)
    assert parts == pytest.approx(terms, rel=1e-12)
    np.testing.assert_allclose(2 * J.T @ r, grad[dofs], rtol=0, atol=1e-9 * np.abs(grad).max())
    _, _, without, parts = ik.residuals(theta, dofs, solids=False)
    assert "table" not in parts and "penetration" not in parts
    assert without == pytest.approx(energy - terms["table"] - terms["penetration"], rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("term", ["distance", "marker"])
def test_l2_norm_terms_have_the_exact_gradient_and_value(hand, term):
    """The retargeting paper's plain distances (Eq. 4-5): value against the closed form, gradient against
    central differences, also where some points sit exactly on their targets (the smoothed kink)."""
    points, P, N, truth = problem(hand)
    targets = P.copy()
    targets[::2] += 0.004  # half the points 4 mm off, half exactly on target at the truth
    markers = Markers(points[::3], targets[::3])
    ik = ContactIK(hand, points, targets, N, ONLY[term], markers=markers, norm="l2")
    _, terms = ik.energy(truth)
    a, b = (points, targets) if term == "distance" else (markers.points, markers.targets)
    d = np.linalg.norm(hand.posed_points(truth, a)[0] - b, axis=1) / ik.unit
    delta = L2_SMOOTHING
    assert terms[term] == pytest.approx(np.sum(np.sqrt(d**2 + delta**2) - delta), rel=1e-12)
    rng = np.random.default_rng(3)
    for theta in (truth, np.clip(truth + rng.normal(size=truth.size) * 0.05, hand.rig.lower, hand.rig.upper)):
        _, _, grad = ik.energy_and_gradient(theta)
        numeric = central_gradient(ik, theta)
        assert np.abs(grad - numeric).max() < 1e-5 * np.abs(numeric).max()
    with pytest.raises(SolverError, match="norm must be one of"):
        ContactIK(hand, points, targets, N, norm="l1")


def test_l2_norm_keeps_reachable_contacts_on_target_when_others_cannot_be_met(hand):
    """Why the retargeting paper sums plain distances: with some contacts unreachable, least squares
    spreads the error over all of them, while the L2 sum leaves the reachable ones nearly exact."""
    points, P, N, truth = problem(hand)
    targets = P.copy()
    far = np.arange(len(P)) % 5 == 0
    targets[far] += 0.02  # a fifth of the contacts 2 cm off where the hand cannot follow
    free = hand.rig.dof_bone == 0  # the root alone: the rigid hand cannot meet the displaced fifth
    near = {}
    for norm in ("squared", "l2"):
        ik = ContactIK(hand, points, targets, N, Weights(n=0.0, p=0.0), norm=norm)
        result = ik.solve(truth, free)
        near[norm] = np.median(result.distances[~far])
    assert near["l2"] < 0.25 * near["squared"]


def test_solve_recovers_a_pose_and_reports_consistently(hand):
    points, P, N, truth = problem(hand, per_patch=40)
    ik = ContactIK(hand, points, P, N)
    start = truth.copy()
    start[6:] = 0.0
    result = ik.solve(start)
    assert result.status == "converged"
    assert result.energy < 0.01 * result.start_energy
    assert result.distances.mean() < 0.01 * hand.length
    assert result.energy == pytest.approx(sum(result.terms.values()))
    assert np.allclose(result.distances, ik.distances(result.theta))
    assert set(result.terms) == {"distance", "normal", "prior"}
    assert np.all(result.theta >= hand.rig.lower) and np.all(result.theta <= hand.rig.upper)
    assert result.iterations > 0 and result.seconds > 0


def test_root_only_stage_leaves_the_fingers_alone(hand):
    """Staged solve (Contact Edit §5.6): with only the root free, no finger DOF changes at all."""
    points, P, N, truth = problem(hand)
    rig = hand.rig
    start = np.where(rig.dof_bone == 0, 0.0, 0.3 * truth)
    root = rig.dof_bone == 0
    result = ContactIK(hand, points, P, N).solve(start, free=root)
    assert np.array_equal(result.theta[~root], start[~root])
    assert np.abs(result.theta[root] - start[root]).max() > 1e-3
    assert result.energy < result.start_energy
    # Then unlock everything, from the staged result.
    final = ContactIK(hand, points, P, N).solve(result.theta)
    assert final.energy < result.energy


def test_locked_dofs_never_move(hand):
    points, P, N, _ = problem(hand)
    rig = hand.rig
    locked = np.zeros(rig.n_dofs, bool)
    locked[rig.bone_dofs("index_2")] = True
    locked_rig = type(rig)(
        rig.names, rig.parents, rig.matrix_local, rig.lengths, rig.lower, rig.upper, locked
    )
    skin = type(hand)(hand.mesh, locked_rig, hand.weights, hand.kind, hand.length, hand.chains)
    result = ContactIK(skin, points, P, N).solve()
    assert np.all(result.theta[locked] == 0.0)


def test_scale_invariance(hand):
    """A hand and its targets scaled by 100: the same joint angles, locations scaled by 100."""
    points, P, N, truth = problem(hand, per_patch=10)
    big = hands.make_hand("human", scale=100.0)
    start = truth.copy()
    start[6:] = 0.0
    small_result = ContactIK(hand, points, P, N).solve(start)
    big_start = start.copy()
    big_start[:3] *= 100
    big_result = ContactIK(big, points, 100 * P, N).solve(big_start)
    rotation = hand.rig.is_rotation
    assert np.abs(big_result.theta[rotation] - small_result.theta[rotation]).max() < 1e-5
    assert np.abs(big_result.theta[:3] / 100 - small_result.theta[:3]).max() < 1e-5 * hand.length
    assert big_result.energy == pytest.approx(small_result.energy, rel=1e-6)


def test_cancel_from_progress_returns_the_best_pose(hand):
    points, P, N, _ = problem(hand)
    seen = []

    def progress(info):
        seen.append((info.energy, info.theta, dict(info.terms), info.iteration))
        return info.iteration == 12

    result = ContactIK(hand, points, P, N).solve(progress=progress)
    assert result.status == "cancelled"
    assert result.iterations == 12 == len(seen)
    best = min(seen, key=lambda s: s[0])
    assert result.energy == best[0] and np.array_equal(result.theta, best[1])
    assert [s[3] for s in seen] == list(range(1, 13))
    assert set(seen[0][2]) == {"distance", "normal", "prior"}


def test_never_returns_nan(hand):
    points, P, N, _ = problem(hand)

    class Broken:
        def evaluate(self, x):
            return np.full(len(x), np.nan), np.zeros((len(x), 3))

    result = ContactIK(hand, points, P, N, obstacle=Broken()).solve()
    assert result.status == "stopped"
    assert np.all(np.isfinite(result.theta)) and np.array_equal(result.theta, hand.rig.rest)


def test_an_optimizer_failure_ends_the_solve_at_its_best_pose():
    """L-BFGS on a finite energy whose gradient is NaN: NLopt gives up with its generic failure, which
    NLopt releases raise differently (2.9's wheels, which the extension bundles, as ``nlopt.runtime_error``;
    tests/test_wheels.py runs this there)."""
    theta = np.array([1.0, 2.0])
    rig = type("Bounds", (), {"lower": np.full(2, -10.0), "upper": np.full(2, 10.0)})
    final, energy, _, _, status = minimize(
        lambda t: (float(t @ t), {}), lambda t: (float(t @ t), {}, np.full(2, np.nan)), theta, np.arange(2),
        np.ones(2), rig, "lbfgs",
    )  # fmt: skip
    assert status == "stopped" and np.array_equal(final, theta) and energy == 5.0


def test_keyed_prior_and_algorithms(hand):
    points, P, N, truth = problem(hand)
    keyed = 0.5 * truth
    free_result = ContactIK(hand, points, P, N, Weights(p=0.0)).solve()
    keyed_result = ContactIK(hand, points, P, N, Weights(p=0.0, k=1000.0), keyed=keyed).solve()
    assert np.abs(keyed_result.theta - keyed).max() < np.abs(free_result.theta - keyed).max()
    fd = ContactIK(hand, points, P, N, gradient="finite-difference").solve(max_evaluations=60)
    exact = ContactIK(hand, points, P, N, algorithm="slsqp").solve(max_evaluations=60)
    assert fd.status == exact.status == "max evaluations"
    for algorithm in ("lbfgs", "mma", "ccsaq"):
        result = ContactIK(hand, points, P, N, algorithm=algorithm).solve(max_evaluations=40)
        assert result.energy < result.start_energy


def test_bad_input_names_what_and_where(hand):
    points, P, N, _ = problem(hand)
    k = len(points)
    with pytest.raises(SolverError, match="no contacts"):
        ContactIK(hand, SurfacePoints(np.empty(0, int), np.empty((0, 3))), P[:0], N[:0])
    bad = P.copy()
    bad[[4, 11]] = np.nan
    with pytest.raises(SolverError, match="target points of contacts 4, 11 are NaN") as err:
        ContactIK(hand, points, bad, N)
    assert err.value.contacts.tolist() == [4, 11]
    with pytest.raises(SolverError, match=f"got {k} hand points but {k - 1} target points"):
        ContactIK(hand, points, P[1:], N)
    zero = N.copy()
    zero[3] = 0
    with pytest.raises(SolverError, match="target normals of contacts 3 are zero"):
        ContactIK(hand, points, P, zero)
    with pytest.raises(SolverError, match="weight λp must be finite and non-negative"):
        Weights(p=-1.0)
    with pytest.raises(SolverError, match="weight λd must be finite"):
        Weights(d=float("nan"))
    with pytest.raises(SolverError, match="prior needs 54 values"):
        ContactIK(hand, points, P, N, prior=np.zeros(3))
    with pytest.raises(SolverError, match="unknown algorithm 'newton'"):
        ContactIK(hand, points, P, N, algorithm="newton")
    with pytest.raises(SolverError, match="SkinnedMesh"):
        ContactIK(hand.mesh, points, P, N)
    with pytest.raises(SolverError, match="do not lie on the hand mesh"):
        ContactIK(hand, SurfacePoints([hand.mesh.n_faces], [[1, 0, 0]]), P[:1], N[:1])
    ik = ContactIK(hand, points, P, N)
    with pytest.raises(SolverError, match=r"theta0 is not finite at DOFs 6 \(hand.rotation.x\)"):
        ik.solve(np.where(np.arange(54) == 6, np.nan, 0.0))
    with pytest.raises(SolverError, match="free needs 54 flags"):
        ik.solve(free=[True, False])
    with pytest.raises(SolverError, match="marker"):
        ContactIK(hand, points, P, N, markers=Markers(points[:3], P[:2]))


def test_a_solve_that_frees_or_moves_nothing_never_claims_convergence(hand):
    points, P, N, truth = problem(hand)
    ik = ContactIK(hand, points, P, N)
    nothing = ik.solve(truth, free=np.zeros(hand.rig.n_dofs, bool))
    assert nothing.status == "no free DOFs" and nothing.iterations == 0
    assert np.array_equal(nothing.theta, hand.rig.clip(truth))
    locked = hand.rig.locked.copy()
    at_optimum = ContactIK(hand, points, P, N, Weights(p=0.0)).solve(truth)  # already where it should be
    assert at_optimum.status == "unchanged" and np.abs(at_optimum.theta - hand.rig.clip(truth)).max() < 1e-6
    assert np.array_equal(locked, hand.rig.locked)


def test_keep_out_rests_a_round_pad_on_the_object_instead_of_sinking_it(hand):
    """Eq. 2 alone pulls every point of a round fingertip pad onto its closest points of a ball: the pad
    flattens by sinking into it. With the object kept out (λo), the skin stays out of the ball (to
    0.1 mm) at the cost of a slightly larger contact distance."""
    rig = hand.rig
    pad = hand.contact_patches(60, seed=1)["index_3"]
    P, N = hand.posed_points(rig.rest, pad)
    normal = N.mean(0) / np.linalg.norm(N.mean(0))
    sphere = objects.sphere(0.05, subdivisions=4)
    ball = TriMesh(sphere.vertices + P.mean(0) + 0.05 * normal, sphere.faces)  # touching the pad's middle
    solid = MeshSDF(ball)
    _, targets, faces = solid.query(P)
    deepest, mean = {}, {}
    for name, keep_out in (("eq2", None), ("kept out", solid)):
        r = ContactIK(hand, pad, targets, ball.face_normals[faces], keep_out=keep_out).solve(rig.rest)
        deepest[name] = -solid(hand.posed_vertices(r.theta)).min()
        mean[name] = r.distances.mean()
    assert deepest["eq2"] > 1e-3 > 1e-4 > deepest["kept out"]  # measured 1.9 mm and 0.02 mm
    assert mean["eq2"] < mean["kept out"] < 2 * mean["eq2"]
