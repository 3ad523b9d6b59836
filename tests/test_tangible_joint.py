"""The two-ring universal joint: angles ↔ rotation, with no gimbal lock inside the bend range."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tangible import rotations as rot
from tangible.joint import bend_angle, joint_angles, joint_rotation

Y = np.array([0.0, 1.0, 0.0])
MAX_BEND = np.radians(89.0)


def random_rotations(n, seed, max_bend=MAX_BEND):
    """Rotations with bends uniform in [0, max_bend] in every direction and any twist."""
    rng = np.random.default_rng(seed)
    tp, td = rng.uniform(-np.pi, np.pi, (2, n))
    phi = rng.uniform(-np.pi, np.pi, n)
    bend = rng.uniform(0, max_bend, n)
    axis = np.stack([np.cos(phi), np.zeros(n), np.sin(phi)], axis=1)
    swing = rot.from_axis_angle(axis, bend)
    return rot.multiply(rot.multiply(rot.from_axis_angle(Y, tp), swing), rot.from_axis_angle(Y, td)), tp


def test_single_angles_are_the_documented_axes():
    a = 0.7
    np.testing.assert_allclose(joint_rotation([a, 0, 0, 0]), rot.from_axis_angle([1, 0, 0], a), atol=1e-15)
    np.testing.assert_allclose(joint_rotation([0, a, 0, 0]), rot.from_axis_angle([0, 0, 1], a), atol=1e-15)
    np.testing.assert_allclose(joint_rotation([0, 0, a, 0]), rot.from_axis_angle([0, 1, 0], a), atol=1e-15)
    np.testing.assert_allclose(joint_rotation([0, 0, 0, a]), rot.from_axis_angle([0, 1, 0], a), atol=1e-15)
    # Shaft direction formula of the module docstring.
    al, be, tp = 0.3, -0.5, 1.1
    d = rot.rotate(joint_rotation([al, be, tp, 2.0]), Y)
    expect = rot.rotate(
        rot.from_axis_angle(Y, tp), [-np.sin(be), np.cos(al) * np.cos(be), np.sin(al) * np.cos(be)]
    )
    np.testing.assert_allclose(d, expect, atol=1e-15)


def test_rotation_to_angles_and_back_is_exact_for_bends_up_to_89_degrees():
    q, tp = random_rotations(20000, seed=1)
    a = joint_angles(q, tp)
    assert np.all(bend_angle(a) <= MAX_BEND + 1e-12)
    assert np.all(np.abs(a[:, :2]) < np.pi / 2)
    assert rot.angle(joint_rotation(a), q).max() < 1e-12
    np.testing.assert_allclose(a[:, 2], tp)


@given(
    st.floats(-1.2, 1.2),
    st.floats(-1.2, 1.2),
    st.floats(-np.pi + 1e-9, np.pi),
    st.floats(-np.pi + 1e-9, np.pi),
)
@settings(max_examples=500, deadline=None)
def test_angles_to_rotation_and_back(alpha, beta, tp, td):
    a = np.array([alpha, beta, tp, td])
    back = joint_angles(joint_rotation(a), tp)
    d = np.angle(np.exp(1j * (back - a)))
    assert np.abs(d).max() < 1e-9


def test_the_bend_does_not_depend_on_the_twists():
    rng = np.random.default_rng(2)
    a = rng.uniform(-1.2, 1.2, (1000, 4))
    a[:, 2:] = rng.uniform(-np.pi, np.pi, (1000, 2))
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
    assert np.abs(np.diff(a[:, :2], axis=0)).max() < 0.05
