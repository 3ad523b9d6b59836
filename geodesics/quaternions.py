"""Unit quaternions ``(w, x, y, z)`` (Blender's order, scalar first) to rotation matrices and back.

The one conversion both :mod:`solver.rotations` and :mod:`tangible.rotations` build on. Batched over
leading axes; matrices act on column vectors (``R @ v``). Arrays may be float64 or complex128 (complex-step
differentiation): every choice between formulas is made on real parts, and norms are ``sqrt(Σ q²)``, so
the conversions stay analytic — which scipy's ``Rotation`` is not (it takes float64 only).
"""

from __future__ import annotations

import numpy as np

__all__ = ["from_matrix", "to_matrix"]


def to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of unit quaternions.

    Parameters
    ----------
    q : (..., 4) ndarray
        Unit quaternions ``(w, x, y, z)``, float64 or complex128 (not normalized here).

    Returns
    -------
    (..., 3, 3) ndarray
        Of ``q``'s dtype.
    """
    w, x, y, z = np.moveaxis(q, -1, 0)
    R = np.empty((*w.shape, 3, 3), dtype=q.dtype)
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - w * z)
    R[..., 0, 2] = 2 * (x * z + w * y)
    R[..., 1, 0] = 2 * (x * y + w * z)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - w * x)
    R[..., 2, 0] = 2 * (x * z - w * y)
    R[..., 2, 1] = 2 * (y * z + w * x)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def from_matrix(R: np.ndarray) -> np.ndarray:
    """Unit quaternions with ``w >= 0`` of rotation matrices (Shepperd's method: the largest pivot).

    Parameters
    ----------
    R : (..., 3, 3) ndarray
        Rotation matrices, float64 or complex128.

    Returns
    -------
    (..., 4) ndarray
        ``(w, x, y, z)`` of ``R``'s dtype; of the pair ±q the one with ``w >= 0``.
    """
    M = R
    t = np.stack(
        [
            1 + M[..., 0, 0] + M[..., 1, 1] + M[..., 2, 2],
            1 + M[..., 0, 0] - M[..., 1, 1] - M[..., 2, 2],
            1 - M[..., 0, 0] + M[..., 1, 1] - M[..., 2, 2],
            1 - M[..., 0, 0] - M[..., 1, 1] + M[..., 2, 2],
        ],
        -1,
    )
    pick = np.argmax(t.real, axis=-1)
    d21, d02, d10 = M[..., 2, 1] - M[..., 1, 2], M[..., 0, 2] - M[..., 2, 0], M[..., 1, 0] - M[..., 0, 1]
    s21, s02, s10 = M[..., 2, 1] + M[..., 1, 2], M[..., 0, 2] + M[..., 2, 0], M[..., 1, 0] + M[..., 0, 1]
    candidates = np.stack(
        [
            np.stack([t[..., 0], d21, d02, d10], -1),
            np.stack([d21, t[..., 1], s10, s02], -1),
            np.stack([d02, s10, t[..., 2], s21], -1),
            np.stack([d10, s02, s21, t[..., 3]], -1),
        ],
        -2,
    )
    q = np.take_along_axis(candidates, pick[..., None, None], axis=-2)[..., 0, :]
    q = q / np.sqrt(np.sum(q * q, axis=-1, keepdims=True))
    return np.where(q[..., :1].real < 0, -q, q)
