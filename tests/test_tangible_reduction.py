"""Rig reduction: Eq. 1/7 by Gauss–Newton, greedy joints, the splitter integer program, instructions."""

import itertools
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from geodesics.rigid import kabsch
from tangible import SPLITTERS, Kit, Skeleton, reduce
from tangible import rotations as rot
from tangible.assembly import instructions_svg, instructions_text
from tangible.creatures import creature
from tangible.errors import RigError
from tangible.reachability import fit
from tangible.reduction import MAX_GATE_ERROR, SplitterProgram, branch_nodes, splitter_candidates
from tangible.skeleton import area_weights

KIT = Kit(6, {"T": 1, "cross": 1})


@pytest.fixture(scope="module")
def beast():
    return creature(62, n_poses=10, seed=2)


def device_pose(skeleton, samples, joints, rotations):
    """Full local rotations: fitted joints, sample roots, identity elsewhere (rigid)."""
    Q = np.broadcast_to(rot.IDENTITY, samples.shape).copy()
    Q[:, skeleton.roots] = samples[:, skeleton.roots]
    if len(joints):
        Q[:, joints] = rotations
    return Q


def energy(skeleton, samples, Q):
    e = skeleton.forward(Q).tails - skeleton.forward(samples).tails
    w = skeleton.weights
    return np.einsum("pmi,pmi,m->p", e, e, w) / (w.sum() * skeleton.size**2)


def test_every_bone_jointed_reaches_every_sample_exactly(beast):
    sk, samples = beast
    everything = [b for b in range(sk.n_bones) if sk.parents[b] >= 0]
    f = fit(sk, samples, [everything, []])
    assert f.energy[0] < 1e-20 and f.energy[1] > 0.05
    np.testing.assert_allclose(f.pose_energy[1], energy(sk, samples, device_pose(sk, samples, [], [])))


def test_fitted_energy_is_the_full_forward_kinematics_energy_and_a_local_minimum(beast):
    sk, samples = beast
    joints = [3, 9, 20, 33, 41]
    f = fit(sk, samples, [joints])
    Q = device_pose(sk, samples, joints, f.rotations[0])
    E = energy(sk, samples, Q)
    np.testing.assert_allclose(f.pose_energy[0], E, rtol=1e-10)
    rng = np.random.default_rng(0)
    for _ in range(20):
        P = Q.copy()
        P[:, joints] = rot.multiply(
            P[:, joints], rot.from_rotvec(rng.normal(scale=0.02, size=(len(samples), 5, 3)))
        )
        assert np.all(energy(sk, samples, P) >= E - 1e-5 * E - 1e-9)


def test_one_joint_reaches_the_weighted_kabsch_optimum(beast):
    """A single joint turns its whole subtree rigidly about its head: the best it can do is the weighted
    Kabsch rotation of the subtree's nodes onto the sample's, a closed-form oracle for Gauss–Newton."""
    sk, samples = beast
    j = sk.names.index("spine.02")  # carries wings and forelegs: a well-conditioned subtree
    f = fit(sk, samples, [[j]], max_iterations=200)
    Q0 = device_pose(sk, samples, [j], np.broadcast_to(rot.IDENTITY, (len(samples), 1, 4)))
    posed = sk.forward(Q0)
    target = sk.forward(samples).tails
    sub = sk.subtree[j]
    w = sk.weights
    for i in range(len(samples)):
        p = posed.heads[i, j]
        a, b = (posed.tails[i, sub] - p), (target[i, sub] - p)
        G = kabsch(a * np.sqrt(w[sub])[:, None], b * np.sqrt(w[sub])[:, None])
        x = posed.tails[i].copy()
        x[sub] = p + a @ G.T
        e = x - target[i]
        best = np.einsum("mi,mi,m->", e, e, w) / (w.sum() * sk.size**2)
        # Eq. 15 stops once a step gains less than 1e-6 (relative + absolute); Gauss–Newton converges
        # linearly here, so a few such steps' worth may remain.
        assert best - 1e-12 <= f.pose_energy[0, i] <= best * (1 + 1e-3)


def test_kabsch_recovers_a_rotation_and_never_reflects():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(50, 3))
    R = rot.to_matrix(rot.normalize(rng.normal(size=4)))
    np.testing.assert_allclose(kabsch(a, a @ R.T), R, atol=1e-12)
    mirrored = a * [1, 1, -1]
    assert np.linalg.det(kabsch(a, mirrored)) == pytest.approx(1.0)


def test_area_weights_split_each_face_by_its_skin_weights():
    V = np.array([[0, 0, 0], [2, 0, 0], [0, 1, 0], [2, 1, 0]], float)
    F = np.array([[0, 1, 2], [1, 3, 2]])
    W = np.array(
        [[1, 0], [1, 0], [0, 2], [0, 2]], float
    )  # bottom edge bone 0, top edge bone 1 (unnormalized)
    np.testing.assert_allclose(area_weights(V, F, W), [1.0 * 2 / 3 + 1.0 / 3, 1.0 / 3 + 1.0 * 2 / 3])


def tiny(angles_deg):
    """root (up) -> hub (up) -> one child per angle (degrees from straight, in the x-y plane)."""
    heads = [[0, 0, 0], [0, 1, 0]] + [[0, 2, 0]] * len(angles_deg)
    tails = [[0, 1, 0], [0, 2, 0]]
    for a in np.radians(angles_deg):
        tails.append([-np.sin(a), 2 + np.cos(a), 0])
    names = ["root", "hub"] + [f"out{i}" for i in range(len(angles_deg))]
    return Skeleton.from_heads_tails(names, [-1, 0] + [1] * len(angles_deg), heads, tails)


def test_candidates_align_matching_geometry_exactly_and_drop_what_is_60_degrees_off():
    node = branch_nodes(tiny([90, -90]))[1]
    cands = splitter_candidates(node, {"T": SPLITTERS["T"], "Y": SPLITTERS["Y"]})
    t = [c for c in cands if c.kind == "T"]
    assert {c.slots for c in t} == {(0, 1), (1, 0)}
    best = min(t, key=lambda c: c.errors.max())
    assert best.errors.max() < 1e-9 and best.slots == (0, 1)  # slot 0 (+90°) takes out0 (+90°)
    assert all(c.errors.max() <= MAX_GATE_ERROR for c in cands)
    # Straight outlets on a node whose children turn back by 170°: nothing fits, not even a phantom.
    back = branch_nodes(tiny([170, -170]))[1]
    assert splitter_candidates(back, {}) == []
    # At a root the inlet is free (the base is held in the hand), so a phantom fits any branch.
    fork = Skeleton.from_heads_tails(
        ["r", "a", "b"], [-1, 0, 0], [[0, 0, 0]] * 3, [[0, 1, 0], [0, -1, 0.1], [1, 0, 0]]
    )
    root_node = branch_nodes(fork)[0]
    assert {c.slots for c in splitter_candidates(root_node, {})} == {(0,), (1,)}


def check_assignment(r, kit):
    """The integer program's solution obeys Eq. 3-5, and the device is consistent with it."""
    assert r.program.violations(r.solution) == []
    chosen = [c for c, x in zip(r.program.candidates, r.solution, strict=True) if x]
    nodes = branch_nodes(r.skeleton)
    at = {}
    for c in chosen:
        assert c.node not in at  # Eq. 4
        at[c.node] = c
        assert c.errors.max() <= MAX_GATE_ERROR  # 60° filter
    for kind, count in kit.splitters.items():  # Eq. 3
        assert sum(c.kind == kind for c in chosen) <= count
    for c in chosen:  # Eq. 5
        parent = nodes[c.node].parent
        if parent in at:
            assert nodes[c.node].parent_outlet in at[parent].outlets
    # Device: at most the kit, every joint reachable, nothing in pruned branches.
    assert len(r.joints) <= kit.joints and len(r.device.splitters) <= sum(kit.splitters.values())
    assert not set(r.joints) & set(r.pruned)
    for pid in r.device.joints:
        b = r.bones[pid]
        for n, c in at.items():
            if r.skeleton.subtree[n, b] and n != b:
                kept = [nodes[n].outlets[m] for m in c.outlets]
                assert any(r.skeleton.subtree[k, b] for k in kept)
    assert len(r.device) == len(r.joints) + len(r.splitters)


@pytest.mark.parametrize("n_bones", [20, 62, 110])
def test_reduction_is_feasible_and_helps_on_rigs_of_20_to_110_bones(n_bones):
    sk, samples = creature(n_bones, n_poses=8, seed=n_bones)
    r = reduce(sk, samples, KIT)
    check_assignment(r, KIT)
    assert len(r.joints) == KIT.joints
    assert r.relative_error < 0.6
    # The device tree is what the assembly instructions show.
    text = instructions_text(r)
    for b in r.joints:
        assert repr(sk.names[b]) in text
    svg = ET.fromstring(instructions_svg(r))
    ns = "{http://www.w3.org/2000/svg}"
    assert len(svg.findall(f"{ns}circle")) == 2 * len(r.joints)
    assert len(svg.findall(f"{ns}rect")) == 1 + 1 + 2 * len(r.device.splitters)  # background, host


def test_error_falls_as_the_kit_grows_like_figure_7():
    sk, samples = creature(40, n_poses=8, seed=3)
    sizes = [0, 1, 2, 4, 6, 8, 10]
    errors = [reduce(sk, samples, Kit(n, {"T": 1, "cross": 1})).relative_error for n in sizes]
    assert errors[0] == pytest.approx(1.0)
    assert all(b <= a * 1.02 for a, b in itertools.pairwise(errors))
    assert errors[3] < 0.5 and errors[-1] < 0.2


def test_the_kit_is_used_and_splitters_keep_branches_that_matter():
    sk, samples = creature(29, n_poses=8, seed=0)
    bare = reduce(sk, samples, Kit(6))
    split = reduce(sk, samples, Kit(6, {"T": 1, "cross": 1}))
    assert split.energy < bare.energy
    assert bare.splitters == () and bare.device.splitters == ()
    assert len(split.device.splitters) >= 1
    check_assignment(split, Kit(6, {"T": 1, "cross": 1}))


def test_bad_input_is_named():
    sk, samples = creature(20, n_poses=3)
    with pytest.raises(RigError, match="unknown splitter kind"):
        Kit(3, {"Z": 1})
    with pytest.raises(RigError, match="root"):
        fit(sk, samples, [[0]])
    with pytest.raises(RigError, match="sample poses"):
        reduce(sk, samples[:, :5], KIT)
    with pytest.raises(RigError, match="head == tail"):
        Skeleton.from_heads_tails(["a"], [-1], [[0, 0, 0]], [[0, 0, 0]])


def test_a_program_without_candidates_places_nothing():
    """Every branching node's candidates can fail the gate filter: the program is then empty, not an
    error from reshaping nothing."""
    program = SplitterProgram.build([], {}, {}, set())
    assert program.A.shape == (0, 0) and program.solve().shape == (0,)
    assert program.violations(np.zeros(0)) == []
