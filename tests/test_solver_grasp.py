"""Signed distances (against brute force and winding numbers) and the 1988 flex-to-contact grasp."""

import numpy as np
import pytest

from geodesics import SurfacePoints, TriMesh
from geodesics.closest import closest_on_triangles
from solver import ContactIK, MeshSDF, SolverError, flex_to_contact, grasp, hands, objects
from solver.benchmark import cylinder_grasp
from solver.grasp import RELATIVE_TOLERANCE, in_palm
from solver.sdf import HalfSpace


def winding_numbers(mesh: TriMesh, X: np.ndarray) -> np.ndarray:
    """Generalized winding numbers (Van Oosterom-Strackee solid angles): 1 inside, 0 outside."""
    total = np.zeros(len(X))
    for start in range(0, mesh.n_faces, 256):
        T = mesh.vertices[mesh.faces[start : start + 256]]
        a, b, c = (T[None, :, k] - X[:, None] for k in range(3))
        la, lb, lc = (np.linalg.norm(v, axis=2) for v in (a, b, c))
        det = np.einsum("pfi,pfi->pf", a, np.cross(b, c))
        dot = lambda u, v: np.einsum("pfi,pfi->pf", u, v)  # noqa: E731
        denominator = la * lb * lc + dot(a, b) * lc + dot(a, c) * lb + dot(b, c) * la
        total += 2 * np.arctan2(det, denominator).sum(1)
    return total / (4 * np.pi)


def brute_force_distance(mesh: TriMesh, X: np.ndarray) -> np.ndarray:
    n, m = len(X), mesh.n_faces
    d = closest_on_triangles(np.repeat(X, m, axis=0), np.tile(mesh.vertices[mesh.faces], (n, 1, 1)))[0]
    return d.reshape(n, m).min(1)


@pytest.mark.parametrize("name", ["sphere", "mug", "plate", "scan-like plate"])
def test_signed_distance_is_exact_with_the_right_sign(name):
    mesh = (
        objects.scan_like(objects.plate(cells=5), seed=2)
        if name == "scan-like plate"
        else getattr(objects, name)()
    )
    rng = np.random.default_rng(0)
    lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
    X = rng.uniform(lo - 0.02, hi + 0.02, (150, 3))
    # Queries close to the surface too, where signs are hard.
    near = mesh.vertices[rng.integers(0, mesh.n_vertices, 100)] + rng.normal(scale=1e-3, size=(100, 3))
    X = np.concatenate([X, near])
    sdf = MeshSDF(mesh)
    d, closest, _ = sdf.query(X)
    assert np.abs(np.abs(d) - brute_force_distance(mesh, X)).max() < 1e-12
    inside = winding_numbers(mesh, X) > 0.5
    assert np.array_equal(d < 0, inside)
    assert inside.sum() > 10 and (~inside).sum() > 10
    assert np.allclose(np.linalg.norm(X - closest, axis=1), np.abs(d))
    # With max_distance, far points outside the box get a lower bound, exact ones stay exact.
    bounded = sdf(X, max_distance=0.005)
    exact = np.abs(d) <= 0.005
    assert np.array_equal(bounded[exact], d[exact])
    assert np.all(bounded[~exact & (d > 0)] <= d[~exact & (d > 0)] + 1e-15)  # lower bounds
    assert np.array_equal(bounded > 0.005, d > 0.005)


def test_signed_distance_refuses_open_meshes():
    from geodesics.primitives import cylinder

    with pytest.raises(SolverError, match="closed mesh"):
        MeshSDF(cylinder())


def test_half_space_distance():
    ground = HalfSpace(point=[0, 0, 1], normal=[0, 0, 2])
    d, g = ground.evaluate([[0, 0, 3], [5, 1, 0.5]])
    assert np.allclose(d, [2.0, -0.5]) and np.allclose(g, [[0, 0, 1]] * 2)


@pytest.fixture(scope="module")
def hand():
    return hands.make_hand("human")


def block_under(hand, finger: str, depth: float) -> TriMesh:
    """A box under a finger's distal half, its top ``depth`` below the finger's palm side."""
    tip = hand.rig.tails[hand.chains[finger][-1]]
    box = objects.box((0.03, 0.05, 0.02), cells=4)
    return TriMesh(box.vertices + np.array([tip[0], tip[1] - 0.01, -0.02 - depth]), box.faces)


def test_flex_to_contact_stops_on_the_surface(hand):
    obj = block_under(hand, "index", 0.012)
    sdf = MeshSDF(obj)
    tip = hand.chains["index"][-1]
    owner = np.argmax(hand.weights.toarray(), axis=1)
    candidates = np.flatnonzero(owner == tip)
    vertex = candidates[np.argmin(hand.mesh.vertices[candidates, 2] - hand.mesh.vertices[candidates, 1])]
    point = SurfacePoints.from_vertices(hand.mesh, [vertex])
    dofs = hand.flexion_dofs("index")
    result = flex_to_contact(hand, hand.rig.rest, dofs, point, obj, tolerance=1e-5)
    assert result.reached and 0 < result.curl < 1
    assert 0 <= result.distance <= 1e-5
    p, _ = hand.posed_points(result.theta, point)
    assert sdf(p)[0] == pytest.approx(result.distance, abs=1e-15)
    # It is the first contact: a little more curl goes inside.
    further = result.theta.copy()
    further[dofs] += 1e-3 * (hand.rig.upper[dofs] - hand.rig.rest[dofs])
    assert sdf(hand.posed_points(further, point)[0])[0] < 0
    others = np.setdiff1d(np.arange(hand.rig.n_dofs), dofs)
    assert np.array_equal(result.theta[others], hand.rig.rest[others])
    # A single joint, as in the 1988 paper; and an object out of reach.
    single = flex_to_contact(hand, hand.rig.rest, dofs[:1], point, obj, tolerance=1e-5)
    assert single.reached and single.theta[dofs[0]] > result.theta[dofs[0]]
    far = TriMesh(obj.vertices - [0, 0, 0.5], obj.faces)
    miss = flex_to_contact(hand, hand.rig.rest, dofs, point, far)
    assert not miss.reached and miss.curl == 1.0 and np.allclose(miss.theta[dofs], hand.rig.upper[dofs])
    # Curling the other way (rigs whose fingers flex by negative angles) lifts the finger off the block.
    away = flex_to_contact(hand, hand.rig.rest, dofs, point, obj, direction=-1)
    assert not away.reached and np.allclose(away.theta[dofs], hand.rig.lower[dofs])


def test_grasp_closes_every_finger_without_penetration():
    scene = cylinder_grasp()
    hand, sdf = scene.hand, scene.sdf
    result = grasp(hand, sdf)
    assert all(result.touching.values())
    d = sdf(hand.posed_vertices(result.theta))
    assert d.min() > -1e-5  # nothing inside (the palm rests on the surface at rest)
    owner = np.argmax(hand.weights.toarray(), axis=1)
    tolerance = 5e-4 * hand.size
    for name, bones in hand.chains.items():
        assert d[np.isin(owner, bones)].min() <= tolerance, name  # each finger touches
    rig = hand.rig
    curled = result.theta[[rig.rotation_dof(b, 0) for bones in hand.chains.values() for b in bones]]
    assert np.all(curled >= 0) and np.any(curled > 0.5)
    # The contacts of the grasp pose are its own: solving ContactIK from the grasp starts near zero error.
    ik = ContactIK(hand, scene.points, scene.targets, scene.normals)
    from_grasp = ik.solve(result.theta)
    from_rest = ik.solve()
    assert from_grasp.start_energy < 0.1 * from_rest.start_energy
    # (from the grasp, near its contacts, the solve stays near it: its energy holds the λk term too)
    assert ik.energy(from_grasp.theta)[0] <= 1.01 * from_rest.energy
    assert from_grasp.distances.mean() < 0.02 * hand.length  # targets are projections onto the cylinder


def test_grasp_and_flex_refuse_bad_input(hand):
    obj = objects.sphere()
    with pytest.raises(SolverError, match=r"needs a solver\.hands\.Hand"):
        grasp(hands.make_hand("human").vertex_skin(), obj)
    with pytest.raises(SolverError, match="no finger 'claw'"):
        grasp(hand, obj, chains=["claw"])
    with pytest.raises(SolverError, match="dofs must be"):
        flex_to_contact(hand, hand.rig.rest, [999], SurfacePoints.from_vertices(hand.mesh, [0]), obj)
    with pytest.raises(SolverError, match=r"one geodesics\.SurfacePoints point"):
        flex_to_contact(hand, hand.rig.rest, [9], SurfacePoints.from_vertices(hand.mesh, [0, 1]), obj)
    with pytest.raises(SolverError, match=r"direction must be \+1"):
        grasp(hand, obj, direction=0)
    with pytest.raises(SolverError, match="curl must be one of 'together', 'in turn'"):
        grasp(hand, obj, curl="claw")
    with pytest.raises(SolverError, match="closed TriMesh or a signed-distance callable"):
        flex_to_contact(hand, hand.rig.rest, [9], SurfacePoints.from_vertices(hand.mesh, [0]), "sphere")


def test_a_mug_in_the_palm_is_wrapped_joint_by_joint_and_touches_are_measured():
    """in_palm stands the mug its gap from the open hand's skin; curling the joints in turn wraps every
    finger on it without entering it, each finger's touch measured from its distance; curling them
    together from a hand already inside the mug leaves that finger as it is and says so."""
    hand = hands.make_hand("human")
    mug = in_palm(hand, objects.mug(), gap=0.003)
    solid = MeshSDF(mug)
    assert solid(hand.posed_vertices(hand.rig.rest)).min() == pytest.approx(0.003, abs=1e-9)
    tol = RELATIVE_TOLERANCE * hand.size
    wrapped = grasp(hand, mug, curl="in turn")
    assert all(wrapped.touching.values()) and all(0 <= d <= tol for d in wrapped.distance.values())
    assert solid(hand.posed_vertices(wrapped.theta)).min() >= 0
    # The wrap curls the knuckles first: they end more curled than when every joint curls at once.
    together = grasp(hand, mug)
    knuckles = [hand.rig.rotation_dof(bones[0], 0) for name, bones in hand.chains.items() if name != "thumb"]
    assert np.all(wrapped.theta[knuckles] > together.theta[knuckles])
    # Pushed 1 mm into the mug, the hand starts inside it: no finger is claimed to touch.
    inside = in_palm(hand, objects.mug(), gap=-0.001)
    pressed = grasp(hand, inside)
    assert min(pressed.distance.values()) < 0 and not all(pressed.touching.values())
    assert all(pressed.touching[n] == (0 <= d <= tol) for n, d in pressed.distance.items())
