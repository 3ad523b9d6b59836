"""Rigs: Blender's rotation conventions, forward kinematics against hand-written matrices, bad input."""

import numpy as np
import pytest

from solver import Rig, SolverError
from solver.hands import make_hand
from solver.rig import into_limits
from solver.rotations import (
    EULER_ORDERS,
    axis_angle_to_matrix,
    euler_to_matrix,
    matrix_to_axis_angle,
    matrix_to_euler,
    matrix_to_quaternion,
    quaternion_to_axis_angle,
    quaternion_to_matrix,
)


def Rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def Ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def Rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def homogeneous(R=None, t=(0.0, 0.0, 0.0)):
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = np.eye(3) if R is None else R, t
    return M


# ----------------------------------------------------------------------------------------- rotations


def test_euler_orders_match_blender():
    """Blender's order "ABC" applies A first: Euler((x, y, z), 'XYZ').to_matrix() == Rz Ry Rx.

    The reference matrix is mathutils' own output for (0.3, 0.5, 0.7) in 'XYZ' (printed by Blender 5.0).
    """
    blender_xyz = np.array([[0.6712, -0.5071, 0.5407], [0.5654, 0.8220, 0.0690], [-0.4794, 0.2593, 0.8384]])
    assert np.allclose(euler_to_matrix([0.3, 0.5, 0.7], "XYZ"), blender_xyz, atol=1e-4)
    x, y, z = 0.3, -1.1, 2.0
    R = {"X": Rx(x), "Y": Ry(y), "Z": Rz(z)}
    for order in EULER_ORDERS:
        expected = R[order[2]] @ R[order[1]] @ R[order[0]]
        assert np.allclose(euler_to_matrix([x, y, z], order), expected, atol=1e-15)


def test_matrix_to_euler_round_trips_in_every_order():
    rng = np.random.default_rng(0)
    for order in EULER_ORDERS:
        angles = rng.uniform(-np.pi, np.pi, (200, 3))
        middle = "XYZ".index(order[1])
        angles[:, middle] = rng.uniform(-1.5, 1.5, 200)
        back = matrix_to_euler(euler_to_matrix(angles, order), order)
        assert np.abs(back - angles).max() < 1e-12
        # Gimbal lock: only the matrix is defined, and it must be reproduced.
        locked = angles[:5].copy()
        locked[:, middle] = np.pi / 2
        R = euler_to_matrix(locked, order)
        assert np.abs(euler_to_matrix(matrix_to_euler(R, order), order) - R).max() < 1e-12


def test_compatible_euler_avoids_jumps():
    angles = np.array([3.0, 0.2, -3.1])
    R = euler_to_matrix(angles + np.array([0.2, 0.0, -0.2]))  # crosses ±π on x and z
    plain = matrix_to_euler(R)
    near = matrix_to_euler(R, compatible=angles)
    assert np.allclose(euler_to_matrix(near), R, atol=1e-12)
    assert np.allclose(near, angles + np.array([0.2, 0.0, -0.2]), atol=1e-12)
    assert np.abs(plain - angles).max() > 6.0  # the principal angles wrapped around


def test_quaternion_and_axis_angle_conversions():
    rng = np.random.default_rng(1)
    q = rng.normal(size=(100, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 0] < 0] *= -1
    R = quaternion_to_matrix(q)
    assert np.abs(R.transpose(0, 2, 1) @ R - np.eye(3)).max() < 1e-14
    assert np.abs(matrix_to_quaternion(R) - q).max() < 1e-12
    # A quarter turn about z: (w, x, y, z) = (cos 45°, 0, 0, sin 45°); axis-angle (π/2, 0, 0, 1).
    quarter = quaternion_to_matrix([np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)])
    assert np.allclose(quarter, Rz(np.pi / 2), atol=1e-15)
    assert np.allclose(axis_angle_to_matrix([np.pi / 2, 0, 0, 2.0]), quarter, atol=1e-15)
    assert np.allclose(matrix_to_axis_angle(quarter), [np.pi / 2, 0, 0, 1], atol=1e-14)
    assert np.allclose(matrix_to_axis_angle(np.eye(3)), [0, 0, 1, 0])
    # -q is the same rotation, read as the turn the other way round: angle 2π - θ about the same axis
    # (Blender's Quaternion.to_axis_angle), so a sign-continuous curve of quaternions stays continuous.
    turned = quaternion_to_axis_angle(-3.0 * q)  # normalized first
    assert np.allclose(axis_angle_to_matrix(turned), R, atol=1e-12)
    assert np.allclose(turned[:, 0], 2 * np.pi - matrix_to_axis_angle(R)[:, 0], atol=1e-12)
    assert np.all((turned[:, 0] >= np.pi) & (turned[:, 0] <= 2 * np.pi))
    with pytest.raises(SolverError):
        quaternion_to_matrix([0, 0, 0, 0])


# --------------------------------------------------------------------------------- forward kinematics


def chain():
    """Three bones with rolled, non-axis-aligned rest frames (like a Blender finger)."""
    rest0 = homogeneous(Rz(0.4) @ Rx(0.2), (0.1, -0.2, 0.3))
    rest1 = rest0 @ homogeneous(Ry(0.3) @ Rx(-0.5), (0.0, 1.5, 0.0))
    rest2 = rest1 @ homogeneous(Rz(-0.6), (0.02, 1.0, 0.01))
    rig = Rig(
        ["a", "b", "c"],
        [-1, 0, 1],
        [rest0, rest1, rest2],
        [1.5, 1.0, 0.7],
        rotation_modes=["XYZ", "ZXY", "YZX"],
    )
    return rig, (rest0, rest1, rest2)


def test_forward_kinematics_matches_handwritten_blender_matrices():
    rig, (M0, M1, M2) = chain()
    theta = np.array([0.05, -0.1, 0.2, 0.3, -0.4, 0.5, 0.6, 0.1, -0.7, -0.2, 0.9, 0.35])
    basis0 = homogeneous(Rz(0.5) @ Ry(-0.4) @ Rx(0.3), (0.05, -0.1, 0.2))  # 'XYZ', with the location
    basis1 = homogeneous(Ry(0.1) @ Rx(0.6) @ Rz(-0.7))  # 'ZXY' applies z, then x, then y
    basis2 = homogeneous(Rx(-0.2) @ Rz(0.35) @ Ry(0.9))  # 'YZX' applies y, then z, then x
    pose0 = M0 @ basis0
    pose1 = pose0 @ np.linalg.inv(M0) @ M1 @ basis1
    pose2 = pose1 @ np.linalg.inv(M1) @ M2 @ basis2
    P = rig.pose_matrices(theta)
    assert np.abs(P - np.stack([pose0, pose1, pose2])).max() < 1e-14
    assert np.abs(rig.basis(theta) - np.stack([basis0, basis1, basis2])).max() < 1e-15
    assert np.allclose(rig.pose_matrices(rig.rest), np.stack([M0, M1, M2]), atol=1e-15)
    # The DOF vector comes back from the local transforms (Blender's matrix_basis).
    assert np.abs(rig.theta_from_basis(rig.basis(theta)) - theta).max() < 1e-13


def test_dof_layout_names_and_subtree():
    rig, _ = chain()
    assert rig.n_dofs == 12
    assert rig.dof_names[:4] == ("a.location.x", "a.location.y", "a.location.z", "a.rotation.x")
    assert rig.dof_names[6] == "b.rotation.x" and rig.rotation_dof(2, 1) == 10
    assert rig.bone_dofs("a").tolist() == [0, 1, 2, 3, 4, 5] and rig.bone_dofs(2).tolist() == [9, 10, 11]
    assert rig.subtree.tolist() == [[True, False, False], [True, True, False], [True, True, True]]
    assert np.allclose(rig.tails[1], rig.heads[1] + rig.lengths[1] * rig.matrix_local[1, :3, 1])


def test_from_bones_builds_bone_frames():
    rig = Rig.from_bones(
        ["root", "tip"], [-1, 0], [[0, 0, 0], [0, 2, 0]], [[0, 2, 0], [1, 3, 0]], [[0, 0, 1]] * 2
    )
    M = rig.matrix_local
    assert np.allclose(M[0, :3, :3], np.eye(3))  # y along the bone, z as hinted, x = y × z
    assert np.allclose(M[1, :3, 1], [np.sqrt(0.5), np.sqrt(0.5), 0]) and np.allclose(M[1, :3, 2], [0, 0, 1])
    assert np.allclose(rig.lengths, [2.0, np.sqrt(2.0)])
    # A positive x rotation turns the bone's y axis towards its z axis (the curl convention of hands).
    theta = rig.rest
    theta[rig.rotation_dof(1, 0)] = np.pi / 2
    assert np.allclose(rig.pose_matrices(theta)[1, :3, 1], [0, 0, 1], atol=1e-15)


# ----------------------------------------------------------------------------------------- bad input


def test_bad_rigs_are_refused_with_what_and_where():
    M = np.stack([np.eye(4)] * 3)
    with pytest.raises(SolverError, match=r"bones 1 'b'.*zero, negative or non-finite length") as err:
        Rig(["a", "b", "c"], [-1, 0, 1], M, [1.0, 0.0, 1.0])
    assert err.value.bones.tolist() == [1]
    with pytest.raises(SolverError, match="zero length") as err:
        Rig.from_bones(["a", "b"], [-1, 0], [[0, 0, 0], [0, 1, 0]], [[0, 1, 0], [0, 1, 0]], [[0, 0, 1]] * 2)
    assert err.value.bones.tolist() == [1]
    lower, upper = np.full(12, -1.0), np.full(12, 1.0)
    lower[7], upper[7] = 0.5, 0.2
    with pytest.raises(SolverError, match=r"DOFs 7 \(b.rotation.y\) are inverted") as err:
        Rig(["a", "b", "c"], [-1, 0, 1], M, [1, 1, 1], lower=lower, upper=upper)
    assert err.value.dofs.tolist() == [7] and err.value.bones.tolist() == [1]
    with pytest.raises(SolverError, match="NaN"):
        Rig(["a", "b", "c"], [-1, 0, 1], M, [1, 1, 1], lower=np.full(12, np.nan))
    with pytest.raises(SolverError, match="parent listed before them") as err:
        Rig(["a", "b", "c"], [-1, 2, 0], M, [1, 1, 1])
    assert err.value.bones.tolist() == [1]
    with pytest.raises(SolverError, match="must be the root"):
        Rig(["a", "b"], [1, -1], M[:2], [1, 1])
    with pytest.raises(SolverError, match="unique"):
        Rig(["a", "a"], [-1, 0], M[:2], [1, 1])
    scaled = M.copy()
    scaled[2, :3, :3] *= 2
    with pytest.raises(SolverError, match=r"bones 2 'c' are not rigid"):
        Rig(["a", "b", "c"], [-1, 0, 1], scaled, [1, 1, 1])
    with pytest.raises(SolverError, match="rotation mode 'QUATERNION'"):
        Rig(["a"], [-1], M[:1], [1], rotation_modes=["QUATERNION"])
    rig = Rig(["a", "b", "c"], [-1, 0, 1], M, [1, 1, 1])
    with pytest.raises(SolverError, match=r"not finite at DOFs 4 \(a.rotation.y\)"):
        rig.pose_matrices(np.where(np.arange(12) == 4, np.nan, 0.0))
    with pytest.raises(SolverError, match="needs 12 values"):
        rig.pose_matrices(np.zeros(5))
    moved = rig.basis(rig.rest)
    moved[1, :3, 3] = [0, 0.5, 0]
    with pytest.raises(SolverError, match="only the root translates"):
        rig.theta_from_basis(moved)


def test_into_limits_keeps_the_pose():
    """Unwrapped Euler angles past the rig's bounds come back by whole turns (the same rotation);
    what no turn can bring back is clipped; translations are only clipped."""
    from scipy.spatial.transform import Rotation

    lower = np.array([-1.0, -2 * np.pi, -2 * np.pi, -2 * np.pi, -1.3])
    upper = np.array([1.0, 2 * np.pi, 2 * np.pi, 2 * np.pi, 1.4])
    rot = np.array([False, True, True, True, True])
    theta = np.array(
        [
            [0.5, 8.06, 0.97, -8.43, 0.2],  # a root that turned past 2π (the cyclic retarget's last frames)
            [1.5, -13.0, 1.0, 20.0, 1.5],  # two and three turns out; a joint just past its limit
            [-3.0, 1.0, -1.0, 0.5, -7.0],  # inside; a joint 2π below, which a turn brings back to -0.72
        ]
    )
    out = into_limits(theta, rot, lower, upper)
    assert np.all((out >= lower) & (out <= upper))
    np.testing.assert_allclose(
        Rotation.from_euler("xyz", out[:, 1:4]).as_matrix(),
        Rotation.from_euler("xyz", theta[:, 1:4]).as_matrix(),
        atol=1e-12,
    )
    np.testing.assert_allclose(out[0], [0.5, 8.06 - 2 * np.pi, 0.97, -8.43 + 2 * np.pi, 0.2])
    assert out[1, 0] == 1.0 and out[2, 0] == -1.0  # translations clipped
    assert out[1, 4] == 1.4  # 0.1 past the limit: 2π away is farther out, so it is clipped
    np.testing.assert_allclose(out[2, 4], -7.0 + 2 * np.pi)
    np.testing.assert_array_equal(into_limits(out, rot, lower, upper), out)  # idempotent
    # Rig.clip does the same to one pose or to many.
    rig = make_hand("human").rig
    poses = np.tile(rig.rest, (2, 1))
    poses[:, 3] = [8.06, -8.43]
    np.testing.assert_allclose(rig.clip(poses)[:, 3], [8.06 - 2 * np.pi, -8.43 + 2 * np.pi])
    np.testing.assert_array_equal(rig.clip(poses[1]), rig.clip(poses)[1])
    with pytest.raises(SolverError, match="poses must be finite"):
        rig.clip(np.full((2, rig.n_dofs), np.nan))
