"""The shared quaternion conversions (geodesics.quaternions): round trips, sign, complex steps."""

import numpy as np
from scipy.spatial.transform import Rotation

from geodesics.quaternions import from_matrix, to_matrix


def test_round_trip_and_canonical_sign_against_scipy():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(6, 5, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    R = to_matrix(q)
    np.testing.assert_allclose(
        R.reshape(-1, 3, 3), Rotation.from_quat(q.reshape(-1, 4)[:, [1, 2, 3, 0]]).as_matrix(), atol=1e-14
    )
    back = from_matrix(R)
    assert back.shape == q.shape and np.all(back[..., 0] >= 0)
    np.testing.assert_allclose(back, np.where(q[..., :1] < 0, -q, q), atol=1e-14)
    # Every pivot: half turns about each axis.
    for axis in np.eye(3):
        np.testing.assert_allclose(from_matrix(to_matrix(np.r_[0.0, axis])), np.r_[0.0, axis], atol=1e-15)


def test_complex_steps_carry_exact_derivatives():
    rng = np.random.default_rng(1)
    q, dq = rng.normal(size=(2, 4))
    q /= np.linalg.norm(q)
    dq -= (dq @ q) * q  # stay on the unit sphere to first order
    h = 1e-30
    step = to_matrix(q + 1j * h * dq)
    fd = (to_matrix(q + 1e-7 * dq) - to_matrix(q - 1e-7 * dq)) / 2e-7
    np.testing.assert_allclose(step.imag / h, fd, atol=1e-8)
    R = to_matrix(q)
    dR = step.imag / h
    derivative = from_matrix(R + 1j * h * dR).imag / h
    sign = 1.0 if q[0] >= 0 else -1.0
    np.testing.assert_allclose(derivative, sign * dq, atol=1e-9)
