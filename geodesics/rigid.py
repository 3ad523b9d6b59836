"""Least-squares rigid alignment (Kabsch 1976), batched over leading axes and optionally weighted.

Both functions return proper rotations (determinant +1): where the best orthogonal fit is a reflection
(a mirror image), the best rotation is returned instead.
"""

from __future__ import annotations

import numpy as np

__all__ = ["kabsch", "rigid_fit"]


def kabsch(a, b, weights=None) -> np.ndarray:
    """Rotations minimizing ``Σ_i w_i |R a_i − b_i|²`` for vector sets ``a``, ``b`` (not centred).

    Parameters
    ----------
    a, b : (..., k, 3) array_like
        Paired vectors; leading axes are a batch.
    weights : (..., k) array_like, optional
        Non-negative weight of each pair (default 1).

    Returns
    -------
    (..., 3, 3) ndarray
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if weights is not None:
        b = b * np.asarray(weights, dtype=np.float64)[..., None]
    U, _, Vt = np.linalg.svd(np.swapaxes(a, -1, -2) @ b)
    V, Ut = np.swapaxes(Vt, -1, -2), np.swapaxes(U, -1, -2)
    d = np.sign(np.linalg.det(V @ Ut))
    V[..., :, 2] *= (d + (d == 0))[..., None]  # flip the last axis of a reflection (a zero det stays)
    return V @ Ut


def rigid_fit(source, target, weights=None) -> np.ndarray:
    """Rigid transforms ``G = [[R, t], [0, 1]]`` minimizing ``Σ_i w_i |R p_i + t − q_i|²``.

    Parameters
    ----------
    source, target : (..., k, 3) array_like
        Paired points ``p_i`` and ``q_i``.
    weights : (..., k) array_like, optional
        Non-negative weight of each pair (default 1), not all zero.

    Returns
    -------
    (..., 4, 4) ndarray
    """
    P = np.asarray(source, dtype=np.float64)
    Q = np.asarray(target, dtype=np.float64)
    w = np.ones(P.shape[:-1]) if weights is None else np.asarray(weights, dtype=np.float64)
    w = w / w.sum(axis=-1, keepdims=True)
    cp = w[..., None, :] @ P  # (..., 1, 3) centroids
    cq = w[..., None, :] @ Q
    R = kabsch(P - cp, Q - cq, w)
    G = np.zeros((*R.shape[:-2], 4, 4))
    G[..., :3, :3] = R
    G[..., :3, 3] = cq[..., 0, :] - (cp @ np.swapaxes(R, -1, -2))[..., 0, :]
    G[..., 3, 3] = 1.0
    return G
