"""Batched unit quaternions, scalar first ``(w, x, y, z)`` as Blender's ``rotation_quaternion``.

Every function broadcasts over leading axes. Rotations act on column vectors (``R @ v``); the product
``multiply(a, b)`` is the rotation "first b, then a", like ``A @ B`` for matrices.
"""

from __future__ import annotations

import numpy as np

from geodesics import quaternions

#: The identity rotation.
IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


def normalize(q) -> np.ndarray:
    """(..., 4) unit quaternions with ``w >= 0`` (the canonical one of the pair ±q) of quaternions ``q``
    (..., 4)."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0.0, -q, q)


def multiply(a, b) -> np.ndarray:
    """(..., 4) Hamilton product ``a b`` of quaternions (..., 4): the rotation b followed by a."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def conjugate(q) -> np.ndarray:
    """(..., 4) the inverse rotation of unit quaternions ``q`` (..., 4)."""
    q = np.asarray(q, dtype=np.float64)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def from_rotvec(v) -> np.ndarray:
    """(..., 4) quaternions of rotation vectors ``v`` (..., 3): axis times angle in radians."""
    v = np.asarray(v, dtype=np.float64)
    angle = np.linalg.norm(v, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(h)/angle = 0.5 sinc(h/π); np.sinc is exact at 0.
    scale = 0.5 * np.sinc(half / np.pi)
    return np.concatenate([np.cos(half), scale * v], axis=-1)


def from_axis_angle(axis, angle) -> np.ndarray:
    """(..., 4) rotations by ``angle`` (...,) radians about unit ``axis`` (..., 3) or a fixed axis (3,)."""
    angle = np.asarray(angle, dtype=np.float64)[..., None]
    axis = np.asarray(axis, dtype=np.float64)
    return np.concatenate([np.cos(0.5 * angle), np.sin(0.5 * angle) * axis * np.ones_like(angle)], axis=-1)


def to_matrix(q) -> np.ndarray:
    """(..., 3, 3) rotation matrices of quaternions (..., 4) (normalized first)."""
    q = np.asarray(q, dtype=np.float64)
    return quaternions.to_matrix(q / np.linalg.norm(q, axis=-1, keepdims=True))


def from_matrix(R) -> np.ndarray:
    """(..., 4) canonical quaternions (``w >= 0``) of rotation matrices (..., 3, 3).

    Uses the largest of the four candidate pivots, so it is accurate for every rotation.
    """
    return quaternions.from_matrix(np.asarray(R, dtype=np.float64))


def rotate(q, v) -> np.ndarray:
    """(..., 3) vectors ``v`` (..., 3) rotated by unit quaternions ``q`` (..., 4)."""
    q = np.asarray(q, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    u = q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + q[..., :1] * t + np.cross(u, t)


def angle(a, b) -> np.ndarray:
    """(...,) the angle in radians of the rotation taking ``b`` to ``a`` (unit, (..., 4)), 0 to π, accurate
    near 0."""
    r = multiply(conjugate(b), a)
    return 2.0 * np.arctan2(np.linalg.norm(r[..., 1:], axis=-1), np.abs(r[..., 0]))


def slerp(a, b, t) -> np.ndarray:
    """(..., 4) spherical linear interpolation from ``a`` (t = 0) to ``b`` (t = 1), unit (..., 4), along the
    shorter arc.

    ``t`` broadcasts as (...,). Exact at both ends; falls back to normalized linear interpolation when the
    two quaternions are within 1e-6 rad of each other on the unit sphere (rotations within about 2e-6 rad).
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)[..., None]
    d = np.sum(a * b, axis=-1, keepdims=True)
    b = np.where(d < 0.0, -b, b)
    d = np.abs(d)
    theta = np.arccos(np.clip(d, -1.0, 1.0))
    sin = np.sin(theta)
    small = sin < 1e-6
    safe = np.where(small, 1.0, sin)
    wa = np.where(small, 1.0 - t, np.sin((1.0 - t) * theta) / safe)
    wb = np.where(small, t, np.sin(t * theta) / safe)
    q = wa * a + wb * b
    return q / np.linalg.norm(q, axis=-1, keepdims=True)
