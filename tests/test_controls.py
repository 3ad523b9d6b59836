"""Production rigs posed through their controls (solver.rig.controls), without Blender: a plain rig described
as an armature must pose exactly as solver.Rig does, derivatives must match finite differences, and the
analysis must find the wrist, the root control and the finger controls of a Rigify-like mechanism, and name
what it cannot reproduce."""

from dataclasses import replace

import numpy as np
import pytest

from solver import ContactIK, SkinnedMesh, SolverError
from solver.hands import make_hand
from solver.ik import movable_vertices
from solver.rig.bones import Bone
from solver.rig.constraints import Constraint, Target
from solver.rig.control_rig import ControlRig, rotation_vector_matrix
from solver.rig.controls import Armature, PoseBone
from solver.rotations import euler_to_matrix


def plain_armature(rig, theta0) -> Armature:
    """A solver.Rig as Blender would hold it: every bone a deforming XYZ-Euler control at pose θ0."""
    P = rig.pose_matrices(theta0)
    bones = []
    for b, name in enumerate(rig.names):
        dofs = slice(3 + 3 * b, 6 + 3 * b)
        bones.append(
            PoseBone(
                bone=Bone(
                    name,
                    rig.matrix_local[b],
                    rig.lengths[b],
                    parent=rig.names[rig.parents[b]] if b else None,
                    rotation_mode="XYZ",
                ),
                matrix=P[b],
                location=theta0[:3] if b == 0 else np.zeros(3),
                rotation=theta0[dofs],
                deform=True,
                lower=rig.lower[dofs],
                upper=rig.upper[dofs],
            )
        )
    return Armature(bones, name="plain")


@pytest.fixture(scope="module")
def human():
    hand = make_hand("human")
    rng = np.random.default_rng(0)
    theta0 = hand.rig.clip(hand.rig.rest + rng.normal(0, 0.2, hand.rig.n_dofs))
    armature = plain_armature(hand.rig, theta0)
    plan = armature.plan(hand.rig.names, contact_bones=[n for n in hand.rig.names if n != "forearm"])
    return hand, theta0, SkinnedMesh(hand.mesh, ControlRig(plan), hand.weights)


def rig_pose(hand, theta0, control_rig, theta) -> np.ndarray:
    """The solver.Rig pose θ that a control rig pose θ stands for."""
    rig = hand.rig
    out = theta0.copy()
    out[6:] = theta[6:]
    moved = control_rig.root_transform(theta) @ rig.pose_matrices(theta0)[0]
    basis = np.linalg.inv(rig.matrix_local[0]) @ moved
    R = basis[:3, :3]
    out[:6] = rig.theta_from_basis(
        np.concatenate([basis[None], np.tile(np.eye(4), (rig.n_bones - 1, 1, 1))]), compatible=theta0
    )[:6]
    assert np.allclose(euler_to_matrix(out[3:6]), R, atol=1e-12)
    return out


def test_the_wrist_root_control_and_finger_controls_of_a_plain_hand(human):
    hand, theta0, skin = human
    rig = skin.rig
    assert rig.plan.hand_root == "hand"  # where the fingers branch
    assert rig.plan.root == "forearm"  # the forearm stub deforms the skin too, so it carries the hand
    assert rig.names == hand.rig.names and rig.n_dofs == hand.rig.n_dofs
    assert not rig.locked.any() and rig.plan.ok
    assert np.allclose(rig.start[6:], theta0[6:]) and not rig.start[:6].any()


def test_a_forearm_hanging_from_an_arm_keeps_its_pose():
    """On a plain rig whose forearm hangs from an upper arm (every body rig; the mesh weighted to the
    forearm too, as a character's one mesh is), the hand bone is the root control: moving the forearm
    would open the elbow. A forearm stub at the top of the armature (the procedural hands) still carries
    the hand, as above."""
    hand = make_hand("human")
    plain = plain_armature(hand.rig, hand.rig.rest)
    forearm = plain["forearm"]
    above = np.eye(4)
    above[:3, 3] = forearm.bone.matrix_local[:3, 3] - forearm.bone.matrix_local[:3, 1] * 0.25
    upper = PoseBone(bone=Bone("upper_arm", above, 0.25, rotation_mode="XYZ"), matrix=above, deform=True)
    hung = replace(forearm, bone=Bone("forearm", forearm.bone.matrix_local, forearm.bone.length,
                                      parent="upper_arm", rotation_mode="XYZ"))  # fmt: skip
    armature = Armature([upper, hung, *[plain[n] for n in hand.rig.names[1:]]], name="body")
    plan = armature.plan(hand.rig.names, contact_bones=["index_3", "thumb_3"])
    assert (plan.hand_root, plan.root) == ("hand", "hand")
    assert "forearm" not in plan.controls and "forearm" not in plan.needed
    # Its skin stays where Blender has it, so keep-out leaves out exactly the vertices weighted to it alone.
    W = hand.weights.toarray()
    forearm_only = (W[:, 0] > 0) & (W[:, 1:].sum(axis=1) == 0)
    assert 0 < forearm_only.sum() < len(W)
    skin = SkinnedMesh(hand.mesh, ControlRig(plan), hand.weights)
    np.testing.assert_array_equal(movable_vertices(skin), np.flatnonzero(~forearm_only))


def test_a_plain_rig_poses_exactly_as_solver_rig(human):
    hand, theta0, skin = human
    rig = skin.rig
    rng = np.random.default_rng(1)
    for _ in range(3):
        theta = rig.start + rng.normal(0, 0.3, rig.n_dofs)
        theta[:3] = rng.normal(0, 0.02, 3)
        ours = skin.posed_vertices(theta)
        theirs = hand.posed_vertices(rig_pose(hand, theta0, rig, theta))
        assert np.abs(ours - theirs).max() < 1e-12


def test_derivatives_match_central_differences(human):
    hand, _, skin = human
    rig = skin.rig
    rng = np.random.default_rng(2)
    points = hand.contact_patches(20, seed=3)["index_3"]
    theta = rig.start + rng.normal(0, 0.2, rig.n_dofs)
    targets, normals = skin.posed_points(theta + rng.normal(0, 0.05, rig.n_dofs), points)
    ik = ContactIK(skin, points, targets, -normals)
    _, _, grad = ik.energy_and_gradient(theta)
    h = 1e-6
    for j in (0, 4, 9, 12, 30, rig.n_dofs - 1):
        step = np.zeros(rig.n_dofs)
        step[j] = h
        numeric = (ik.energy(theta + step)[0] - ik.energy(theta - step)[0]) / (2 * h)
        assert abs(grad[j] - numeric) <= 1e-6 * max(1.0, abs(numeric))
    r, J, energy, _ = ik.residuals(theta)  # the trust region's forward derivatives: the same gradient
    assert r @ r == pytest.approx(energy, rel=1e-12)
    np.testing.assert_allclose(2 * J.T @ r, grad, rtol=0, atol=1e-9 * np.abs(grad).max())


def test_the_root_turns_about_the_root_controls_head():
    assert np.allclose(rotation_vector_matrix(np.zeros((1, 3))), np.eye(3))
    w = np.array([[0.3, -0.2, 0.5]])
    R = rotation_vector_matrix(w)[0]
    assert np.allclose(R @ w[0], w[0]) and np.allclose(R.T @ R, np.eye(3))
    assert np.isclose(np.arccos((np.trace(R) - 1) / 2), np.linalg.norm(w))


def test_root_dofs_invert_root_transform(human):
    """ControlRig.root_dofs is the inverse of root_transform (the retargeting's root alignment), and with
    ``compatible`` it picks, of the rotation vectors a whole turn apart, the one nearest to it."""
    _, _, skin = human
    rig = skin.rig
    rng = np.random.default_rng(4)
    for _ in range(10):
        theta = rig.start.copy()
        theta[:3] = rng.normal(0, 0.05, 3)
        theta[3:6] = rng.normal(0, 1.0, 3)
        G = rig.root_transform(theta)
        theta[:6] = rig.root_dofs(G)
        np.testing.assert_allclose(rig.root_transform(theta), G, rtol=0, atol=1e-12)
        assert np.linalg.norm(theta[3:6]) <= np.pi + 1e-12
    turn = theta[3:6] / np.linalg.norm(theta[3:6])
    shifted = rig.root_dofs(G, compatible=theta[3:6] + 2 * np.pi * turn)
    np.testing.assert_allclose(shifted[3:6], theta[3:6] + 2 * np.pi * turn, atol=1e-12)
    np.testing.assert_allclose(shifted[:3], theta[:3], atol=1e-12)
    moved = theta.copy()
    moved[:6] = shifted
    np.testing.assert_allclose(rig.root_transform(moved), G, rtol=0, atol=1e-12)


# ------------------------------------------------------------------ a Rigify-like mechanism


def mechanism(extra_constraint=None) -> Armature:
    """A forearm, a wrist and two two-bone fingers where, as in Rigify, deform bones copy locked mechanism
    bones that copy the controls; a finger master rotates the finger's first control."""
    y = np.eye(4)

    def at(x, y0, z=0.0):
        M = np.eye(4)
        M[:3, 3] = (x, y0, z)
        return M

    bones, constraints = {}, {}

    def add(name, parent, M, length, *, deform=False, control=False, cons=()):
        bones[name] = (Bone(name, M, length, parent=parent, rotation_mode="QUATERNION"), deform, control)
        constraints[name] = tuple(cons)

    def copy(target):
        return Constraint("COPY_TRANSFORMS", name="Copy Transforms", targets=(Target(subtarget=target),))

    add("forearm_ctrl", None, at(0, -0.2), 0.2, control=True)
    add("DEF-forearm", "forearm_ctrl", at(0, -0.2), 0.2, deform=True)
    add("hand_ctrl", "forearm_ctrl", at(0, 0), 0.08, control=True)
    add("DEF-hand", "DEF-forearm", at(0, 0), 0.08, deform=True, cons=[copy("hand_ctrl")])
    for f, x in (("a", -0.02), ("b", 0.02)):
        add(f"master_{f}", "DEF-hand", at(x, 0.08), 0.06, control=True)
        add(f"{f}.01", "DEF-hand", at(x, 0.08), 0.03, control=True)
        add(f"{f}.02", f"{f}.01", at(x, 0.11), 0.03, control=True)
        for k in ("01", "02"):
            add(f"MCH-{f}.{k}", "DEF-hand", at(x, 0.08 if k == "01" else 0.11), 0.03, cons=[copy(f"{f}.{k}")])
            add(
                f"DEF-{f}.{k}",
                "DEF-hand",
                at(x, 0.08 if k == "01" else 0.11),
                0.03,
                deform=True,
                cons=[copy(f"MCH-{f}.{k}")],
            )
    if extra_constraint is not None:
        name, con = extra_constraint
        constraints[name] = constraints[name] + (con,)
    pose_bones = []
    for name, (bone, deform, control) in bones.items():
        parent = bone.parent
        pose_bones.append(
            PoseBone(
                bone=bone,
                matrix=bone.matrix_local,
                constraints=constraints[name],
                deform=deform,
                lock_rotation=(not control,) * 3,
                lock_location=(not control,) * 3,
            )
        )
        del parent
    del y
    return Armature(pose_bones, name="mechanism")


DEFORM = ("DEF-forearm", "DEF-hand", "DEF-a.01", "DEF-a.02", "DEF-b.01", "DEF-b.02")


def test_the_analysis_finds_wrist_root_control_and_finger_controls():
    arm = mechanism()
    assert arm.hand_root(["DEF-a.01", "DEF-b.02"]) == "DEF-hand"  # where the fingers branch
    assert arm.hand_root(["DEF-a.02"]) == "DEF-hand"  # one finger: up to where it branches
    assert arm.hand_root(DEFORM) == "DEF-hand"  # a forearm stub above the wrist: down to it
    plan = arm.plan(DEFORM, contact_bones=["DEF-a.02", "DEF-b.02"])
    assert plan.root == "hand_ctrl"  # the control the wrist's deform bone copies
    assert set(plan.controls) == {"a.01", "a.02", "b.01", "b.02"}  # not the masters, nothing locked
    assert plan.ok and "forearm_ctrl" not in plan.needed


def test_what_cannot_be_reproduced_is_named_with_its_bone():
    ik = Constraint("IK", name="IK", targets=(Target(subtarget="b.02"),))
    arm = mechanism(("MCH-a.02", ik))
    plan = arm.plan(DEFORM, contact_bones=["DEF-a.02"])
    assert [b.bone for b in plan.blockers] == ["MCH-a.02"]
    assert "IK" in plan.blockers[0].reason
    with pytest.raises(SolverError, match=r"MCH-a\.02"):
        ControlRig(plan)


def test_a_mechanism_rig_follows_its_controls():
    arm = mechanism()
    rig = ControlRig(arm.plan(DEFORM, contact_bones=["DEF-a.02", "DEF-b.02"]))
    theta = rig.start.copy()
    a1 = rig.bone_index("a.01")
    theta[rig.rotation_dof(a1, 0)] = 0.4
    S = rig.kinematics(theta, derivatives=False).skinning
    column = {n: i for i, n in enumerate(rig.deform_bones)}
    # DEF-a.01 copies MCH-a.01, which copies the control a.01: it turns by 0.4 about its x axis.
    turned = S[column["DEF-a.01"]]
    head = arm["a.01"].bone.matrix_local[:3, 3]
    assert np.allclose(turned[:, :3], euler_to_matrix([0.4, 0, 0], "XYZ"), atol=1e-12)
    assert np.allclose(turned[:, :3] @ head + turned[:, 3], head, atol=1e-12)
    # a.02 is a child of a.01: it swings with it.
    assert not np.allclose(S[column["DEF-a.02"]], np.eye(4)[:3], atol=1e-6)
    assert np.allclose(S[column["DEF-b.02"]], np.eye(4)[:3], atol=1e-12)


def test_control_rig_clips_poses_as_solver_rig(human):
    """A control rig stands in for a solver.Rig (the retarget clips its spline's (F, d) poses)."""
    hand, _, skin = human
    rig = skin.rig
    rng = np.random.default_rng(2)
    poses = rig.start + rng.normal(0, 2.0, (4, rig.n_dofs))
    clipped = rig.clip(poses)
    assert clipped.shape == poses.shape
    np.testing.assert_array_equal(clipped, np.stack([rig.clip(p) for p in poses]))
    # The fingers' DOFs are the hand's own (the root's are the root control's, with its own limits).
    np.testing.assert_array_equal(clipped[:, 6:], hand.rig.clip(poses)[:, 6:])
    with pytest.raises(SolverError, match=r"shape \(F, 54\)"):
        rig.clip(poses[:, :-1])
