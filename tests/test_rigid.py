"""The shared Kabsch fit (geodesics.rigid): closed-form recoveries, weights, batching, reflections."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from geodesics.rigid import kabsch, rigid_fit


def _rigid(rng, n=None) -> np.ndarray:
    """Seeded random rigid transforms (4, 4), or (n, 4, 4)."""
    k = 1 if n is None else n
    G = np.zeros((k, 4, 4))
    G[:, :3, :3] = Rotation.random(k, random_state=rng.integers(2**31)).as_matrix()
    G[:, :3, 3] = rng.normal(size=(k, 3))
    G[:, 3, 3] = 1.0
    return G[0] if n is None else G


def test_rigid_fit_recovers_a_known_rotation_and_translation():
    rng = np.random.default_rng(0)
    for _ in range(20):
        G = _rigid(rng)
        P = rng.normal(size=(15, 3))
        Q = P @ G[:3, :3].T + G[:3, 3]
        np.testing.assert_allclose(rigid_fit(P, Q), G, rtol=0, atol=1e-12)


def test_kabsch_recovers_a_known_rotation_of_vectors():
    rng = np.random.default_rng(1)
    R = Rotation.random(random_state=3).as_matrix()
    a = rng.normal(size=(9, 3))
    np.testing.assert_allclose(kabsch(a, a @ R.T), R, rtol=0, atol=1e-12)


def test_weights_are_least_squares_weights():
    rng = np.random.default_rng(2)
    G = _rigid(rng)
    P = rng.normal(size=(12, 3))
    Q = P @ G[:3, :3].T + G[:3, 3]
    Q[8:] += rng.normal(scale=0.5, size=(4, 3))  # outliers, weighted out exactly
    w = np.r_[rng.uniform(0.5, 2.0, 8), np.zeros(4)]
    np.testing.assert_allclose(rigid_fit(P, Q, w), G, rtol=0, atol=1e-12)
    # With noise everywhere, a weight is a sqrt-weight on both vector sets, and the fit is a minimum.
    a, b = rng.normal(size=(2, 12, 3))
    R = kabsch(a, b, w + 0.1)
    s = np.sqrt(w + 0.1)[:, None]
    np.testing.assert_allclose(R, kabsch(a * s, b * s), rtol=0, atol=1e-12)

    def cost(M):
        return np.einsum("k,ki->", w + 0.1, (a @ M.T - b) ** 2)

    for turn in Rotation.from_rotvec(rng.normal(scale=1e-3, size=(20, 3))).as_matrix():
        assert cost(R) <= cost(turn @ R)


def test_batches_fit_each_set_on_its_own():
    rng = np.random.default_rng(3)
    G = _rigid(rng, 6)
    P = rng.normal(size=(6, 10, 3))
    Q = np.einsum("nij,nkj->nki", G[:, :3, :3], P) + G[:, None, :3, 3] + rng.normal(scale=0.01, size=P.shape)
    w = rng.uniform(0.1, 1.0, (6, 10))
    fits = rigid_fit(P, Q, w)
    assert fits.shape == (6, 4, 4)
    for i in range(6):
        np.testing.assert_allclose(fits[i], rigid_fit(P[i], Q[i], w[i]), rtol=0, atol=1e-12)
    assert kabsch(P, Q).shape == (6, 3, 3)


def test_a_mirror_image_gets_the_best_rotation_not_a_reflection():
    rng = np.random.default_rng(4)
    a = rng.normal(size=(30, 3))
    mirrored = a * [1.0, 1.0, -1.0]
    R = kabsch(a, mirrored)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    # The best proper fit of a z-mirror of points thinnest along z leaves them as they are.
    flat = np.concatenate([np.diag([3.0, 2.0, 0.1]), -np.diag([3.0, 2.0, 0.1])])
    np.testing.assert_allclose(kabsch(flat, flat * [1.0, 1.0, -1.0]), np.eye(3), atol=1e-12)
    G = rigid_fit(a, mirrored + np.array([1.0, 2.0, 3.0]))
    assert np.linalg.det(G[:3, :3]) == pytest.approx(1.0)
    np.testing.assert_array_equal(G[3], [0.0, 0.0, 0.0, 1.0])
