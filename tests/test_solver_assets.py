"""Procedural hands and objects: valid closed manifolds of the right genus, rigs, skin weights."""

import warnings

import numpy as np
import pytest

from solver import SolverError, hands, objects
from solver.retarget import synthetic
from solver.subdivision import Cage, catmull_clark


def euler_characteristic(mesh) -> int:
    return mesh.n_vertices - mesh.n_edges + mesh.n_faces


EXPECTED = {"human": (54, 5), "witch": (54, 5), "alien": (42, 3), "tentacle": (45, 1)}


@pytest.fixture(scope="module", params=hands.KINDS)
def hand(request):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no MeshWarning: every vertex is on a face
        return hands.make_hand(request.param)


def test_hands_are_closed_genus_zero_and_rigged(hand):
    mesh = hand.mesh
    assert np.all(mesh.twin >= 0) and mesh.n_components == 1
    assert mesh.isolated_vertices.size == 0
    assert euler_characteristic(mesh) == 2
    n_dofs, n_chains = EXPECTED[hand.kind]
    assert hand.rig.n_dofs == n_dofs and len(hand.chains) == n_chains
    assert 2000 <= mesh.n_faces <= 10000
    # Outward orientation: the enclosed volume is positive.
    T = mesh.vertices[mesh.faces]
    assert np.einsum("ij,ij->i", T[:, 0], np.cross(T[:, 1], T[:, 2])).sum() > 0
    assert np.all(hand.rig.lower <= hand.rig.rest) and np.all(hand.rig.rest <= hand.rig.upper)


def test_human_hand_proportions():
    hand = hands.make_hand("human")
    assert hand.length == pytest.approx(0.186, abs=0.01)  # wrist to middle fingertip
    assert set(hand.chains) == {"thumb", "index", "middle", "ring", "pinky"}
    assert all(len(c) == 3 for c in hand.chains.values())
    witch = hands.make_hand("witch")
    finger = witch.rig.lengths[list(witch.chains["middle"])].sum()
    assert finger > 1.4 * hand.rig.lengths[list(hand.chains["middle"])].sum()


def test_skin_weights_are_normalized_sparse_and_smooth(hand):
    W = hand.weights
    assert np.allclose(np.asarray(W.sum(axis=1)).ravel(), 1.0)
    assert W.nnz < 4 * hand.mesh.n_vertices and W.data.min() > 0
    # Smooth across joints: along every edge the weights change by at most a third.
    dense = W.toarray()
    a, b = hand.mesh.halfedge_tail, hand.mesh.halfedge_head
    assert np.abs(dense[a] - dense[b]).max() < 1 / 3
    # Every bone but the forearm carries skin, and each finger bone dominates somewhere.
    dominant = np.unique(np.argmax(dense, axis=1))
    assert set(dominant) >= set(range(1, hand.rig.n_bones))


def test_curling_a_finger_moves_only_that_finger():
    hand = hands.make_hand("human")
    theta = hand.rig.rest
    theta[hand.flexion_dofs("index")] = np.radians([60, 70, 40])
    moved = np.linalg.norm(hand.posed_vertices(theta) - hand.mesh.vertices, axis=1) > 1e-12
    index = list(hand.chains["index"])
    W = hand.weights.toarray()
    assert np.array_equal(moved, W[:, index].sum(1) > 0)  # the finger and the webs beside it
    owner = np.argmax(W, axis=1)
    # Curling brings the fingertip towards the palm side (-z) and back towards the wrist.
    tip = np.argmax(np.where(owner == index[-1], hand.mesh.vertices[:, 1], -np.inf))
    assert hand.posed_vertices(theta)[tip, 2] < hand.mesh.vertices[tip, 2] - 0.03


def test_hands_are_deterministic_and_scale():
    a, b = hands.make_hand("alien"), hands.make_hand("alien")
    assert np.array_equal(a.mesh.vertices, b.mesh.vertices) and np.array_equal(a.mesh.faces, b.mesh.faces)
    assert (a.weights != b.weights).nnz == 0
    big = hands.make_hand("alien", scale=10.0)
    assert np.allclose(big.mesh.vertices, 10 * a.mesh.vertices)
    assert np.allclose(big.rig.matrix_local[:, :3, 3], 10 * a.rig.matrix_local[:, :3, 3])
    assert big.length == pytest.approx(10 * a.length)
    # The same triangles at every size (near-tied quad diagonals once split differently after scaling,
    # so a child-size hand refused the files made for the life-size one).
    for kind in ("human", "witch", "alien"):
        life = hands.make_hand(kind).mesh
        for scale in (0.75, 1.25, 0.01):
            assert hands.make_hand(kind, scale).mesh.topology_hash == life.topology_hash, (kind, scale)
    with pytest.raises(SolverError, match="unknown hand kind 'robot'"):
        hands.make_hand("robot")
    with pytest.raises(SolverError, match="scale"):
        hands.make_hand("human", scale=0)


def test_left_hands_are_mirror_images_of_right_ones():
    right, left = hands.make_hand("human", 1.5), hands.make_hand("human", 1.5, side="left")
    S = np.diag([-1.0, 1.0, 1.0, 1.0])
    assert left.mesh.vertices.tobytes() == (right.mesh.vertices * [-1.0, 1.0, 1.0]).tobytes()
    assert left.mesh.faces.tobytes() == right.mesh.faces[:, ::-1].tobytes()
    assert left.rig.matrix_local.tobytes() == (S @ right.rig.matrix_local @ S).tobytes()
    signs = hands.mirror_theta(right.rig, np.ones(right.rig.n_dofs))
    assert np.array_equal(np.where(signs < 0, -right.rig.upper, right.rig.lower), left.rig.lower)
    # By kind string (a motion's source_kind), and under the name the synthetic motions gave it.
    for name, hand in (("human", right), ("human-left", left)):
        for built in (hands.hand_from_kind(name, 1.5), synthetic.source_hand(name, 1.5)):
            assert built.mesh.vertices.tobytes() == hand.mesh.vertices.tobytes()
            assert built.rig.matrix_local.tobytes() == hand.rig.matrix_local.tobytes()
    with pytest.raises(SolverError, match="unknown side 'middle'"):
        hands.make_hand("human", side="middle")


def test_contact_patches_lie_on_the_palm_side():
    hand = hands.make_hand("human")
    patches = hand.contact_patches(20, seed=3)
    assert len(patches) == 16 and all(len(p) == 20 for p in patches.values())
    for name, points in patches.items():
        bone = hand.rig.bone_index(name)
        z = hand.rig.matrix_local[bone, :3, 2]
        assert np.all(hand.mesh.face_normals[points.faces] @ z > 0.5)


@pytest.mark.parametrize(
    ("name", "genus"), [("sphere", 0), ("cylinder", 0), ("box", 0), ("mug", 1), ("plate", 2)]
)
def test_objects_are_closed_with_the_right_genus(name, genus):
    mesh = getattr(objects, name)()
    assert np.all(mesh.twin >= 0) and mesh.n_components == 1 and mesh.isolated_vertices.size == 0
    assert euler_characteristic(mesh) == 2 - 2 * genus
    T = mesh.vertices[mesh.faces]
    volume = np.einsum("ij,ij->i", T[:, 0], np.cross(T[:, 1], T[:, 2])).sum() / 6
    assert volume > 0
    scan = objects.scan_like(mesh, seed=4, noise=0.05)
    assert euler_characteristic(scan) == 2 - 2 * genus and np.all(scan.twin >= 0)
    valence = np.bincount(scan.faces.ravel())
    assert valence.min() <= 4 and valence.max() >= 9  # irregular, like a scan
    again = objects.scan_like(mesh, seed=4, noise=0.05)
    assert np.array_equal(scan.vertices, again.vertices) and np.array_equal(scan.faces, again.faces)


def test_object_sizes_and_scan_preserves_the_surface():
    box = objects.box((0.06, 0.06, 0.12))
    assert np.allclose(box.vertices.min(0), [-0.03, -0.03, -0.06]) and np.allclose(
        box.vertices.max(0), [0.03, 0.03, 0.06]
    )
    assert box.face_areas.sum() == pytest.approx(2 * (0.06 * 0.06 + 2 * 0.06 * 0.12))
    cylinder = objects.cylinder(radius=0.03, height=0.15)
    assert np.allclose(np.ptp(cylinder.vertices, axis=0), [0.06, 0.06, 0.15], atol=1e-3)
    scan = objects.scan_like(box, seed=1)  # splits and coplanar flips only: the same surface
    assert scan.face_areas.sum() == pytest.approx(box.face_areas.sum(), rel=1e-12)
    mug = objects.mug()
    assert mug.vertices[:, 0].max() > 0.06  # the handle sticks out on +x


def test_catmull_clark_on_a_cube():
    """Subdividing a cube cage: 24 quads, the known valence-3 vertex rule, weights still sum to one."""
    cage = Cage(2)
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    ids = cage.add_vertices(corners, [[1, 0]] * 4 + [[0, 1]] * 4)
    for axis in range(3):
        for side in (0, 1):
            quad = [i for i in ids if corners[i, axis] == side]
            quad = [quad[0], quad[1], quad[3], quad[2]]  # around the face
            out = np.zeros(3)
            out[axis] = 1 if side else -1
            cage.add_face(quad, out)
    P, Q, A = catmull_clark(cage.points, cage.faces, cage.attributes, 1)
    assert Q.shape == (24, 4) and len(P) == 8 + 12 + 6
    # Original corner (0, 0, 0): (Q + 2R + (n - 3) P) / n with n = 3, Q = mean face point, R = mean midpoint.
    Qmean = np.array([1 / 3, 1 / 3, 1 / 3])
    R = np.array([1 / 6, 1 / 6, 1 / 6])
    assert np.allclose(P[0], (Qmean + 2 * R) / 3)
    assert np.allclose(A.sum(1), 1.0) and A.min() >= 0
