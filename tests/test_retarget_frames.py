"""Per-frame pose estimation (§3.4.1–3.4.2): the rigid fit, the root DOFs of a transform, and frames of a
synthetic grasp retargeted onto the same hand, whose ground truth (``source_theta``) is the answer."""

import pickle
from dataclasses import replace

import numpy as np
import pytest

from geodesics import SurfacePoints
from geodesics.rigid import rigid_fit
from solver import SolverError
from solver.retarget import annotate, synthetic
from solver.retarget import frames as fr
from solver.rotations import euler_to_matrix

#: Frames of the 120-frame cylinder grasp: approach (no contacts), grasp, hold (contacts), release.
FRAMES = [12, 36, 60, 112]
SPEC = fr.HandSpec("human", 1.0)


# ------------------------------------------------------------------------------------------ fixtures


@pytest.fixture(scope="module")
def hand():
    return SPEC.build()


@pytest.fixture(scope="module")
def motion():
    return synthetic.generate("cylinder", frames=120, seed=0)


@pytest.fixture(scope="module")
def clip(motion):
    return motion.select(FRAMES)


@pytest.fixture(scope="module")
def annotation(hand):
    return annotate.default_annotation(hand, hand)


@pytest.fixture(scope="module")
def tasks(clip, annotation):
    return fr.build_tasks(clip, SPEC, annotation)


@pytest.fixture(scope="module")
def estimated(clip, annotation):
    calls = []
    roots, fulls = fr.estimate(clip, SPEC, annotation, progress=lambda *a: calls.append(a))
    return roots, fulls, calls


def _root_transform(rig, theta) -> np.ndarray:
    """World transform of the rest shape applied by the root at θ."""
    return rig.pose_matrices(theta)[0] @ np.linalg.inv(rig.matrix_local[0])


def _root_error(rig, theta, truth) -> tuple[float, float]:
    """(degrees, metres): the root's rotation error and the wrist's (the palm bone head's) position error."""
    A, B = _root_transform(rig, theta), _root_transform(rig, truth)
    R = A[:3, :3].T @ B[:3, :3]
    angle = np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)))
    wrist = rig.heads[rig.bone_index("hand")]
    return float(angle), float(np.linalg.norm(A[:3, :3] @ wrist + A[:3, 3] - B[:3, :3] @ wrist - B[:3, 3]))


def _palm_angle(rig, theta, truth) -> float:
    """Degrees between the palm bone's world frames at two poses. The root is the forearm, which only the
    wrist markers pin, so it trades off against the wrist; the palm's frame does not."""
    b = rig.bone_index("hand")
    A, B = rig.pose_matrices(theta)[b], rig.pose_matrices(truth)[b]
    R = A[:3, :3].T @ B[:3, :3]
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))


def _random_rigid(rng) -> np.ndarray:
    Q, R = np.linalg.qr(rng.normal(size=(3, 3)))
    Q = Q * np.sign(np.diag(R))
    if np.linalg.det(Q) < 0:
        Q[:, 0] = -Q[:, 0]
    G = np.eye(4)
    G[:3, :3] = Q
    G[:3, 3] = rng.normal(scale=0.3, size=3)
    return G


# ------------------------------------------------------------------------------------------ tasks


def _points(k):
    return SurfacePoints(np.arange(k), np.tile([1.0, 0.0, 0.0], (k, 1)))


def _task(target, **kw):
    base = dict(
        frame=7,
        stage="root",
        hand=SPEC,
        seed=target.rig.rest.copy(),
        contact_points=_points(2),
        contact_targets=np.zeros((2, 3)),
        contact_normals=np.tile([0.0, 0.0, 1.0], (2, 1)),
        marker_points=_points(3),
        marker_targets=np.zeros((3, 3)),
    )
    base.update(kw)
    return fr.FrameTask(**base)


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(stage="middle"), "stage must be one of root, full"),
        (dict(contact_targets=np.zeros((3, 3))), r"frame 7: contact_targets must have shape \(2, 3\)"),
        (dict(contact_normals=np.zeros(6)), r"frame 7: contact_normals must have shape \(2, 3\)"),
        (dict(marker_targets=np.zeros((3, 2))), r"frame 7: marker_targets must have shape \(3, 3\)"),
        (
            dict(
                contact_points=_points(0),
                contact_targets=np.zeros((0, 3)),
                contact_normals=np.zeros((0, 3)),
                marker_points=_points(0),
                marker_targets=np.zeros((0, 3)),
            ),
            "frame 7 has neither contacts nor markers",
        ),
    ],
)
def test_frame_task_refuses_malformed_data(hand, change, message):
    with pytest.raises(SolverError, match=message):
        _task(hand, **change)


def test_solve_frame_refuses_a_bad_hand_or_seed(hand):
    with pytest.raises(SolverError, match="HandSpec or a SkinnedMesh, got str"):
        fr.solve_frame(_task(hand, hand="human"))
    with pytest.raises(SolverError, match=f"seed needs {hand.rig.n_dofs} values"):
        fr.solve_frame(_task(hand, seed=np.zeros(5)))
    with pytest.raises(SolverError, match="λj must be a finite non-negative number"):
        fr.RetargetWeights(j=-1.0)


def test_weights_map_onto_the_solvers():
    w = fr.RetargetWeights(m=2.0, c=3.0, cd=5.0, cn=7.0, t=11.0, j=13.0).solver_weights()
    assert (w.d, w.n, w.m, w.t, w.p, w.k) == (15.0, 21.0, 2.0, 11.0, 13.0, 0.0)
    assert fr.RetargetWeights.paper().j == 50.0


# ------------------------------------------------------------------------------------------ rigid fit


def test_rigid_fit_recovers_a_rigid_transform_exactly():
    rng = np.random.default_rng(0)
    for _ in range(20):
        G = _random_rigid(rng)
        P = rng.normal(scale=0.1, size=(12, 3))
        Q = P @ G[:3, :3].T + G[:3, 3]
        np.testing.assert_allclose(rigid_fit(P, Q), G, rtol=0, atol=1e-12)


def test_rigid_fit_ignores_zero_weights_and_never_reflects():
    rng = np.random.default_rng(1)
    G = _random_rigid(rng)
    P = rng.normal(scale=0.1, size=(10, 3))
    Q = P @ G[:3, :3].T + G[:3, 3]
    Q[7:] += rng.normal(scale=0.5, size=(3, 3))  # outliers, weighted out
    w = np.r_[rng.uniform(0.5, 2.0, 7), np.zeros(3)]
    np.testing.assert_allclose(rigid_fit(P, Q, w), G, rtol=0, atol=1e-12)
    # A mirror image has no rigid fit: the best rotation is still a rotation.
    M = rigid_fit(P, P * [-1.0, 1.0, 1.0])
    assert np.linalg.det(M[:3, :3]) == pytest.approx(1.0)


def test_root_dofs_round_trip_through_forward_kinematics(hand):
    rig = hand.rig
    rng = np.random.default_rng(2)
    for _ in range(10):
        G = _random_rigid(rng)
        theta = rig.rest.copy()
        theta[:6] = rig.root_dofs(G)
        np.testing.assert_allclose(rig.pose_matrices(theta)[0], G @ rig.matrix_local[0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(_root_transform(rig, theta), G, rtol=0, atol=1e-12)
        np.testing.assert_allclose(rig.root_transform(theta), G, rtol=0, atol=1e-12)
    # ``compatible`` picks the Euler solution nearest to it (no 2π jumps between frames).
    shifted = rig.root_dofs(G, compatible=theta[3:6] + 2 * np.pi)
    np.testing.assert_allclose(shifted[3:], theta[3:6] + 2 * np.pi, atol=1e-9)
    R = euler_to_matrix(shifted[3:], rig.rotation_modes[0])
    np.testing.assert_allclose(R, euler_to_matrix(theta[3:6], rig.rotation_modes[0]), atol=1e-12)


# ------------------------------------------------------------------------------------------ tasks of a motion


def test_build_tasks_pose_the_frames_data(hand, clip, tasks):
    """At the ground truth the markers sit on their targets exactly (the same hand: same skin spots) and
    the contacts within the synthetic contact tolerance of their object points."""
    assert [t.frame for t in tasks] == list(range(len(FRAMES)))
    assert all(t.stage == "root" and t.align_root for t in tasks)
    counts = [len(t.contact_points) for t in tasks]
    assert counts[0] == counts[-1] == 0 and min(counts[1:3]) > 50
    np.testing.assert_array_equal(counts, clip.hand_contacts.count())
    for t, truth in zip(tasks, clip.source_theta, strict=True):
        markers, _ = hand.posed_points(truth, t.marker_points)
        np.testing.assert_allclose(markers, t.marker_targets, rtol=0, atol=1e-9)
        if len(t.contact_points):
            q, _ = hand.posed_points(truth, t.contact_points)
            gap = np.linalg.norm(q - t.contact_targets, axis=1)
            assert gap.max() <= synthetic.CONTACT_TOLERANCE + 1e-9
            # Outward object normals point at the hand: the hand point is outside the object.
            assert np.mean(np.einsum("ij,ij->i", q - t.contact_targets, t.contact_normals) > -1e-9) > 0.95


# ------------------------------------------------------------------------------------------ solving


def test_full_pass_recovers_the_ground_truth(hand, clip, tasks, estimated):
    _, fulls, _ = estimated
    rig = hand.rig
    for t, full, truth in zip(tasks, fulls, clip.source_theta, strict=True):
        # The solves' optimum, not their stopping point: from seeds perturbed by 1e-12 to 1e-6, or with
        # ftol_rel down to 1e-11, frame 60 ends within 0.03° and 0.01 mm of these figures.
        angle, wrist = _root_error(rig, full.theta, truth)
        assert angle < 3.5 and wrist < 1.5e-3, (t.frame, angle, wrist)  # measured ≤ 2.51°, 0.89 mm
        assert _palm_angle(rig, full.theta, truth) < 1.0, t.frame  # measured ≤ 0.62°
        vertices = np.linalg.norm(hand.posed_vertices(full.theta) - hand.posed_vertices(truth), axis=1)
        assert vertices.max() < 2.5e-3, t.frame  # measured ≤ 2.03 mm
        assert full.marker_distance < 2e-4  # measured ≤ 0.12 mm
        if len(t.contact_points):
            q, _ = hand.posed_points(truth, t.contact_points)
            ideal = np.linalg.norm(q - t.contact_targets, axis=1).mean()  # the data's own gap (≈ 1 mm)
            assert full.contact_distance <= ideal + 1e-4, (t.frame, full.contact_distance, ideal)
            np.testing.assert_allclose(full.contact_distances.mean(), full.contact_distance)
        assert full.status in ("converged", "max_evaluations")


def test_root_pass_is_near_the_truth_before_the_fingers_close(hand, clip, estimated):
    roots, _, _ = estimated
    for i in (0, len(FRAMES) - 1):  # approach and release: the fingers are near their rest pose
        angle, wrist = _root_error(hand.rig, roots[i].theta, clip.source_theta[i])
        assert angle < 10 and wrist < 6e-3, (FRAMES[i], angle, wrist)  # measured ≤ 4.0°, 4 mm
        np.testing.assert_array_equal(roots[i].theta[6:], hand.rig.rest[6:])  # only the root moved


def test_root_pass_recovers_the_root_on_grasp_frames(hand, clip, estimated):
    roots, _, _ = estimated
    for i in (1, 2):
        angle, wrist = _root_error(hand.rig, roots[i].theta, clip.source_theta[i])
        assert angle < 10 and wrist < 1e-2, (FRAMES[i], angle, wrist)


def test_markers_only_frames_are_solved_on_markers(estimated):
    roots, fulls, _ = estimated
    for r in (roots[0], fulls[0], fulls[-1]):
        assert r.contact_distances.shape == (0,) and np.isnan(r.contact_distance)
        assert "distance" not in r.terms and "normal" not in r.terms and "marker" in r.terms
        assert r.marker_distances.shape == (19 * annotate.MARKER_POINTS,)
    assert fulls[0].marker_distance < 1e-4  # measured 0.02 mm
    assert set(fulls[1].terms) >= {"distance", "normal", "marker", "prior"}


def test_estimate_feeds_each_root_into_its_full_task(hand, clip, annotation, tasks, estimated):
    roots, fulls, calls = estimated
    n = len(FRAMES)
    assert calls == [("root", k, n) for k in range(1, n + 1)] + [("full", k, n) for k in range(1, n + 1)]
    assert [r.stage for r in roots] == ["root"] * n and [r.stage for r in fulls] == ["full"] * n
    full = fr.full_tasks(tasks, roots[::-1])  # matched by frame, not by position
    for t, f, r in zip(tasks, full, roots, strict=True):
        assert f.stage == "full" and not f.align_root and f.frame == t.frame
        np.testing.assert_array_equal(f.seed[:6], r.theta[:6])
        np.testing.assert_array_equal(f.seed[6:], t.seed[6:])
        assert f.contact_points is t.contact_points and f.marker_targets is t.marker_targets
    with pytest.raises(SolverError, match="no root result for frame 3"):
        fr.full_tasks(tasks, roots[:3])
    # The full pass that estimate ran is this one, frame by frame (one frame re-solved alone).
    again = fr.solve_frame(full[2])
    np.testing.assert_array_equal(again.theta, fulls[2].theta)
    assert again.energy == fulls[2].energy


def test_frames_are_independent_of_each_other_and_of_order(tasks, estimated):
    roots, _, _ = estimated
    backwards = fr.solve_frames(tasks[::-1])
    for r, b in zip(roots, backwards[::-1], strict=True):
        assert r.frame == b.frame
        np.testing.assert_array_equal(r.theta, b.theta)
    alone = fr.solve_frame(tasks[1])
    np.testing.assert_array_equal(alone.theta, roots[1].theta)
    np.testing.assert_array_equal(alone.contact_distances, roots[1].contact_distances)


def test_tasks_and_results_pickle(tasks, estimated):
    roots, fulls, _ = estimated
    task = pickle.loads(pickle.dumps(tasks[2]))
    assert task.hand == SPEC and task.table is not None
    np.testing.assert_array_equal(task.contact_points.bary, tasks[2].contact_points.bary)
    np.testing.assert_array_equal(fr.solve_frame(task).theta, roots[2].theta)
    result = pickle.loads(pickle.dumps(fulls[1]))
    np.testing.assert_array_equal(result.theta, fulls[1].theta)
    assert result.terms == fulls[1].terms and result.status == fulls[1].status
    assert len(pickle.dumps(tasks[2])) < 200_000  # a HandSpec, not the hand, travels


def test_table_term_keeps_the_hand_out_of_the_table(hand, motion, annotation):
    """Raise the table to 0.5 mm under the hand's lowest vertex at a hold frame: the root pass (whose
    fingers are open) would sink 2 cm into it without the term; with it, it sinks far less, and the full
    pose stays out of it."""
    f = 60
    box = fr.table_box(motion.table, motion.table_size)
    table = motion.table.copy()
    table[2, 3] += box.evaluate(motion.hand_vertices[f])[0].min() - 5e-4
    raised = fr.table_box(table, motion.table_size)
    task = replace(fr.build_tasks(motion.select([f]), SPEC, annotation)[0], table=raised)

    def depth(theta):
        return -raised.evaluate(hand.posed_vertices(theta))[0].min()

    free = fr.solve_frame(replace(task, table=None))
    root = fr.solve_frame(task)
    full = fr.solve_frame(fr.full_tasks([task], [root])[0])
    assert depth(free.theta) > 0.01  # measured 14 mm
    assert depth(root.theta) < 0.3 * depth(free.theta)  # measured 4.2 mm
    assert root.terms["table"] > 0
    assert depth(full.theta) < 1e-4  # measured 0.5 mm above the table
