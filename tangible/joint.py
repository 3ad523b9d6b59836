"""The joint of §3.1: a universal (Cardan) joint with a twisting ring at either end.

Frames. A joint's **inlet frame** is fixed to the piece it is plugged into, with ``y`` along the incoming
shaft (as a Blender bone's y axis runs from head to tail) and ``x`` the axis of the first hinge. Its
**outlet frame** is fixed to the outgoing shaft. The four sensed angles (radians, as in a data message)
are, from the inlet outwards:

``twist_proximal`` τp
    the proximal ring, turning the whole joint about the inlet ``y`` axis;
``bend_a`` α
    the first hinge, about ``x``;
``bend_b`` β
    the second hinge, about the cross-shaft's other axis (``z`` once the first hinge has turned);
``twist_distal`` τd
    the distal ring, about the outgoing shaft.

so that the outlet frame is ``R = Ry(τp) · Rx(α) · Rz(β) · Ry(τd)`` in the inlet frame, and the shaft
points along ``R ŷ = Ry(τp) (−sin β, cos α cos β, sin α cos β)``. All angles zero is the straight joint
(identity).

Why this has no gimbal lock: the bend (the angle between the shaft and ``ŷ``) is ``arccos(cos α cos β)``
whatever the twists, and for every bend below 90° the hinge angles follow smoothly from the shaft
direction — ``β = atan2(−d_x, √(d_y² + d_z²))``, ``α = atan2(d_z, d_y)`` with ``√(d_y² + d_z²) ≥ cos(bend)
> 0`` — so moving the shaft along any great circle within the bend cone moves both hinges smoothly (no
Euler-angle zig-zag, Fig. 4). The only singular shaft directions are ``±x̂`` (a 90° bend about the second
hinge), at the edge of the mechanical range.

The two twists add up to one rotational degree of freedom, so a rotation does not tell how the twist is
shared between the rings: :func:`joint_angles` takes the proximal twist as given (0 by default) and
returns the unique remaining angles.
"""

from __future__ import annotations

import numpy as np

from . import rotations as rot

__all__ = ["BEND_LIMIT", "bend_angle", "joint_angles", "joint_rotation"]

#: Bends (shaft to straight) below this are inside the joint's range, where the conversions are smooth.
BEND_LIMIT = 0.5 * np.pi


def _about(axis: int, angle: np.ndarray) -> np.ndarray:
    q = np.zeros((*angle.shape, 4))
    q[..., 0] = np.cos(0.5 * angle)
    q[..., 1 + axis] = np.sin(0.5 * angle)
    return q


def joint_rotation(angles) -> np.ndarray:
    """Outlet frame in the inlet frame, from sensed angles.

    Parameters
    ----------
    angles : (..., 4) array_like
        ``(bend_a, bend_b, twist_proximal, twist_distal)`` in radians.

    Returns
    -------
    (..., 4)
        Unit quaternions ``(w, x, y, z)``, canonical (``w >= 0``).
    """
    a = np.asarray(angles, dtype=np.float64)
    if a.shape[-1:] != (4,):
        raise ValueError(f"joint angles must have shape (..., 4), got {a.shape}")
    q = rot.multiply(
        rot.multiply(_about(1, a[..., 2]), _about(0, a[..., 0])),
        rot.multiply(_about(2, a[..., 1]), _about(1, a[..., 3])),
    )
    return rot.normalize(q)


def joint_angles(rotation, twist_proximal=0.0) -> np.ndarray:
    """Sensed angles that produce ``rotation`` with the given proximal twist.

    Parameters
    ----------
    rotation : (..., 4) array_like
        Unit quaternions of the outlet frame in the inlet frame, with a bend below 90°.
    twist_proximal : (...,) array_like
        The proximal ring's angle to assume (radians).

    Returns
    -------
    (..., 4)
        ``(bend_a, bend_b, twist_proximal, twist_distal)``; for bends below 90° both hinge angles lie in
        (−π/2, π/2);
        ``twist_distal`` in (−π, π].
    """
    q = rot.normalize(rotation)
    tp = np.broadcast_to(np.asarray(twist_proximal, dtype=np.float64), q.shape[:-1])
    m = rot.multiply(_about(1, -tp), q)
    d = rot.rotate(m, np.array([0.0, 1.0, 0.0]))
    beta = np.arctan2(-d[..., 0], np.hypot(d[..., 1], d[..., 2]))
    alpha = np.arctan2(d[..., 2], d[..., 1])
    rest = rot.multiply(rot.conjugate(rot.multiply(_about(0, alpha), _about(2, beta))), m)
    twist = 2.0 * np.arctan2(rest[..., 2], rest[..., 0])
    twist = np.mod(twist + np.pi, 2.0 * np.pi) - np.pi
    return np.stack([alpha, beta, tp, np.where(twist == -np.pi, np.pi, twist)], axis=-1)


def bend_angle(angles) -> np.ndarray:
    """(...,) the bend (angle between the shaft and straight, radians) of sensed angles (..., 4)."""
    a = np.asarray(angles, dtype=np.float64)
    return np.arccos(np.clip(np.cos(a[..., 0]) * np.cos(a[..., 1]), -1.0, 1.0))
