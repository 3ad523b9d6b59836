"""The twist-universal-twist joint: the firmware's angles ↔ rotation, the authors' host composition in our
frame, and no gimbal lock inside the joint's range."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tangible import rotations as rot
from tangible.joint import (
    ANGLES,
    THEIR_AXES,
    bend_angle,
    from_theirs,
    joint_angles,
    joint_rotation,
    to_theirs,
)
from tangible.protocol import ANGLE_LSB as LSB
from tangible.protocol import BEND_OFFSET

Y = np.array([0.0, 1.0, 0.0])
MAX_BEND = np.radians(89.0)
HINGE = np.nextafter(np.pi / 2, 0)  # the hinges' open range (−90°, 90°)


# ---------------------------------------------------------------- the authors' host code, written literally


def AngleAxisd(angle, axis):
    """Eigen::AngleAxisd(angle, axis) as a matrix (Rodrigues)."""
    k = np.asarray(axis, dtype=np.float64)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


UnitX, UnitY, UnitZ = np.eye(3)
M_PI = np.pi


def rot4(angle1, angle2, angle3, angle4, ninety=90.0):
    """``Software/RigReducer/puppet_things.h`` line 95 (degrees, bone along x)."""
    return (
        AngleAxisd((angle1 * M_PI) / 180.0, UnitX)
        @ AngleAxisd(((ninety - angle2) * M_PI) / 180.0, UnitZ)
        @ AngleAxisd(((angle3 - ninety) * M_PI) / 180.0, UnitY)
        @ AngleAxisd((angle4 * M_PI) / 180.0, UnitX)
    )


def decode(raw):
    """What the protocol decoder hands the joint model: radians, record order, bend offsets removed,
    wrapped to (−π, π]."""
    a = np.asarray(raw, dtype=np.float64).copy()
    a[1:3] -= BEND_OFFSET
    a = np.mod(a * LSB + np.pi, 2 * np.pi) - np.pi
    return np.where(a == -np.pi, np.pi, a)


def random_records(n, seed):
    """Raw 14-bit records as the firmware sends them: twists anywhere, bends within ±80° of the offset."""
    rng = np.random.default_rng(seed)
    raw = rng.integers(0, 0x4000, (n, 4))
    raw[:, 1:3] = BEND_OFFSET + rng.integers(-3640, 3641, (n, 2))
    return raw


def test_our_rotation_is_the_host_composition_in_our_frame():
    """At random records: the host's ROT4 (degrees = raw · 360/16384, as the firmware's comments
    convert) taken to our frame is our rotation up to the firmware's one-LSB bend offset, and exactly
    ours once the host's 90° is the firmware's 0x0FFF LSB."""
    raw = random_records(2000, seed=0)
    ours = joint_rotation(np.array([decode(r) for r in raw]))
    degrees = raw * 360.0 / 16384
    theirs = np.array([THEIR_AXES @ rot4(*d) @ THEIR_AXES.T for d in degrees])
    assert rot.angle(ours, rot.from_matrix(theirs)).max() < np.sqrt(2) * LSB + 1e-12
    exact = np.array(
        [THEIR_AXES @ rot4(*d, ninety=BEND_OFFSET * 360.0 / 16384) @ THEIR_AXES.T for d in degrees]
    )
    assert rot.angle(ours, rot.from_matrix(exact)).max() < 1e-12
    # The same through the quaternion helpers, and back.
    theirs_q = rot.from_matrix([rot4(*d, ninety=BEND_OFFSET * 360.0 / 16384) for d in degrees])
    assert rot.angle(from_theirs(theirs_q), ours).max() < 1e-12
    assert rot.angle(to_theirs(ours), theirs_q).max() < 1e-12
    # The host's straight joint is one LSB off ours on each hinge.
    host_straight = rot.from_matrix(
        THEIR_AXES @ rot4(0, BEND_OFFSET * 360 / 16384, BEND_OFFSET * 360 / 16384, 0) @ THEIR_AXES.T
    )
    assert rot.angle(host_straight, joint_rotation([0, 0, 0, 0])) == pytest.approx(
        np.hypot(LSB, LSB), rel=1e-3
    )


def test_the_frame_mapping_sends_their_bone_axis_to_ours():
    np.testing.assert_array_equal(THEIR_AXES @ [1, 0, 0], Y)  # their x (the bone) is our y
    np.testing.assert_array_equal(THEIR_AXES @ [0, 1, 0], [0, 0, 1])  # their y is our z
    np.testing.assert_array_equal(THEIR_AXES @ [0, 0, 1], [1, 0, 0])  # their z is our x
    assert np.linalg.det(THEIR_AXES) == 1.0


def test_single_angles_are_the_documented_axes():
    assert ANGLES == ("twist_proximal", "bend_a", "bend_b", "twist_distal")
    a = 0.7
    np.testing.assert_allclose(joint_rotation([a, 0, 0, 0]), rot.from_axis_angle(Y, a), atol=1e-15)
    np.testing.assert_allclose(joint_rotation([0, a, 0, 0]), rot.from_axis_angle([1, 0, 0], -a), atol=1e-15)
    np.testing.assert_allclose(joint_rotation([0, 0, a, 0]), rot.from_axis_angle([0, 0, 1], a), atol=1e-15)
    np.testing.assert_allclose(joint_rotation([0, 0, 0, a]), rot.from_axis_angle(Y, a), atol=1e-15)
    np.testing.assert_allclose(joint_rotation([0, 0, 0, 0]), rot.IDENTITY, atol=0)
    # Shaft direction formula of the module docstring.
    tp, al, be = 1.1, 0.3, -0.5
    d = rot.rotate(joint_rotation([tp, al, be, 2.0]), Y)
    expect = rot.rotate(
        rot.from_axis_angle(Y, tp), [-np.sin(be), np.cos(al) * np.cos(be), -np.sin(al) * np.cos(be)]
    )
    np.testing.assert_allclose(d, expect, atol=1e-15)


def test_polarity_is_the_joint_seen_half_way_round_its_shaft():
    """The firmware's polarity 1 mirrors both bends: the rotation conjugated by a half turn about y."""
    a = np.random.default_rng(4).uniform(-1.4, 1.4, (100, 4))
    flipped = a * [1, -1, -1, 1]
    half = rot.from_axis_angle(Y, np.pi)
    expect = rot.multiply(rot.multiply(half, joint_rotation(a)), rot.conjugate(half))
    assert rot.angle(joint_rotation(flipped), expect).max() < 1e-12


def random_rotations(n, seed, max_bend=MAX_BEND):
    """Rotations with bends uniform in [0, max_bend] in every direction and any twist."""
    rng = np.random.default_rng(seed)
    tp, td = rng.uniform(-np.pi, np.pi, (2, n))
    phi = rng.uniform(-np.pi, np.pi, n)
    bend = rng.uniform(0, max_bend, n)
    axis = np.stack([np.cos(phi), np.zeros(n), np.sin(phi)], axis=1)
    swing = rot.from_axis_angle(axis, bend)
    return rot.multiply(rot.multiply(rot.from_axis_angle(Y, tp), swing), rot.from_axis_angle(Y, td)), tp


def test_rotation_to_angles_and_back_is_exact_for_bends_up_to_89_degrees():
    q, tp = random_rotations(20000, seed=1)
    a = joint_angles(q, tp)
    assert np.all(bend_angle(a) <= MAX_BEND + 1e-12)
    assert np.all(np.abs(a[:, 1:3]) < np.pi / 2)
    assert rot.angle(joint_rotation(a), q).max() < 1e-12
    np.testing.assert_array_equal(a[:, 0], tp)


@given(
    st.floats(-np.pi + 1e-9, np.pi),
    st.floats(-HINGE, HINGE),
    st.floats(-HINGE, HINGE),
    st.floats(-np.pi + 1e-9, np.pi),
)
@settings(max_examples=500, deadline=None)
def test_angles_to_rotation_and_back_within_the_range(tp, alpha, beta, td):
    """Within the hinges' range both round trips hold: the rotation to 1e-12 rad, and the angles up to
    the conditioning of the hinges near the edge (ε / cos β)."""
    a = np.array([tp, alpha, beta, td])
    q = joint_rotation(a)
    back = joint_angles(q, tp)
    assert rot.angle(joint_rotation(back), q) < 1e-12
    d = np.angle(np.exp(1j * (back - a)))
    assert np.abs(d).max() < 1e-12 + 1e-15 / np.cos(beta)
    assert back[0] == tp and np.abs(back[1:3]).max() <= np.pi / 2 + 1e-12


finite = st.floats(-10.0, 10.0)


@given(st.floats(-np.pi, np.pi), st.tuples(finite, finite, finite))
@settings(max_examples=300, deadline=None)
def test_any_rotation_gets_finite_angles_that_reproduce_it(tp, rotvec):
    """Outside the range too (bends up to 180°, the singular line included): finite angles that
    reproduce the rotation."""
    q = rot.from_rotvec(np.array(rotvec))
    a = joint_angles(q, tp)
    assert np.all(np.isfinite(a)) and np.all(np.abs(a) <= np.pi)
    assert rot.angle(joint_rotation(a), q) < 1e-12


@pytest.mark.parametrize("beta", [np.pi / 2, -np.pi / 2])
@pytest.mark.parametrize("alpha", [0.0, 0.4, -1.0])
def test_the_singular_edge_puts_the_first_hinge_on_the_distal_ring(alpha, beta):
    """With the second hinge folded flat, α and τd turn about the same axis: α = 0 and τd takes it."""
    q = joint_rotation([0.3, alpha, beta, 0.2])
    a = joint_angles(q, 0.3)
    assert a[1] == 0.0 and a[2] == pytest.approx(beta, abs=1e-7)
    assert rot.angle(joint_rotation(a), q) < 1e-7
    # ... and just inside the edge the hinges are still found, to the conditioning ε / cos β.
    inside = beta * (1 - 1e-6)
    a = joint_angles(joint_rotation([0.3, alpha, inside, 0.2]), 0.3)
    np.testing.assert_allclose(a, [0.3, alpha, inside, 0.2], atol=1e-8)


def test_the_bend_does_not_depend_on_the_twists():
    rng = np.random.default_rng(2)
    a = rng.uniform(-1.2, 1.2, (1000, 4))
    a[:, [0, 3]] = rng.uniform(-np.pi, np.pi, (1000, 2))
    d = rot.rotate(joint_rotation(a), Y)
    np.testing.assert_allclose(np.arccos(np.clip(d[:, 1], -1, 1)), bend_angle(a), atol=1e-9)


def test_the_twist_split_is_a_free_choice_that_reproduces_the_rotation():
    q, _ = random_rotations(500, seed=3)
    for tp in (-2.0, 0.0, 0.4):
        assert rot.angle(joint_rotation(joint_angles(q, tp)), q).max() < 1e-12


@pytest.mark.parametrize("direction", [0.0, 0.5, 1.0, 1.5707963, 2.6, -1.2])
def test_no_gimbal_lock_tracing_a_great_circle_to_the_edge_of_the_range(direction):
    """Moving the shaft along a great circle (Fig. 4) moves the hinge angles smoothly: the angles' speed
    stays bounded by 1/cos(bend) ≤ 1/cos(89°) ≈ 57 everywhere in the range, in every direction."""
    axis = np.array([np.cos(direction), 0.0, np.sin(direction)])
    bends = np.linspace(0, MAX_BEND, 4000)
    a = joint_angles(rot.from_axis_angle(axis, bends))
    speed = np.linalg.norm(np.diff(a, axis=0), axis=1) / np.diff(bends)
    assert np.all(speed <= 1.0 / np.cos(bends[1:]) + 1e-6)
    # ... and the hinge angles are continuous (no wrap-around jumps).
    assert np.abs(np.diff(a[:, 1:3], axis=0)).max() < 0.05


def test_batches_and_bad_shapes():
    a = np.random.default_rng(5).uniform(-1, 1, (3, 5, 4))
    assert joint_rotation(a).shape == (3, 5, 4)
    assert joint_angles(joint_rotation(a), a[..., 0]).shape == (3, 5, 4)
    with pytest.raises(ValueError, match=r"\(\.\.\., 4\)"):
        joint_rotation([1.0, 2.0, 3.0])
