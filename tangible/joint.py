"""The twist-universal-twist joint of the published device (§3.1; firmware and host code of
``oliglauser/atamid``): sensed angles ↔ rotation, by the firmware's conventions, with no gimbal lock.

**Angles.** A data record carries four 14-bit angles (LSB = 360/16384°) in this order, which is also the
order of every ``(..., 4)`` array here (:data:`ANGLES`):

``twist_proximal`` τp
    the ring at the joint's base, turning the whole joint about the incoming shaft;
``bend_a`` α, ``bend_b`` β
    the two hinges of the universal joint (cross-shaft), from the base outwards;
``twist_distal`` τd
    the ring at the joint's end, about the outgoing shaft.

The firmware (``Hardware/Firmware/utility.c``, ``update_sensor_messages``) subtracts the zero offsets
stored by the ``'z'`` command and adds ``0x0FFF`` (≈ 90°) to both bends, so that a bend is never near the
14-bit wrap; with polarity 1 (``'x'`` command) it first mirrors both bend readings (``0x3FFF − a``),
which flips the signs of α and β (equivalently: ``R → Ry(π) R Ry(π)⁻¹``, the joint seen turned half way
round its shaft). The protocol decoder hands this module radians in record order, the bends' ``0x0FFF``
removed, every angle wrapped to (−π, π]; all zero is the pose the joint was zeroed in, straight, the
identity. (The firmware wraps with ``% 0x3FFF`` rather than ``% 0x4000``, so a negative twist reads one
LSB further from zero than it is: 0.022°, left to the decoder.)

**Which controller measures what.** One joint is two microcontrollers sharing one id. The ``0x74`` half
(``NODE_JOINT_TUT_TU``, at the base) reads τp from a 1-D MLX90363 and α, β from the 2-D MLX90363 of the
cross-shaft; the ``0x84`` half (``NODE_JOINT_TUT_T``, at the end, the ``0x74`` half's child on the bus)
reads τd from its own 1-D MLX90363 and sends it, raw and not zeroed, in bytes 15–16 of a ``'D'`` record
under the shared id. The ``0x74`` half polls it like any child; its relay loop (``Src/main.c``, the
``RECEIVING`` state) swallows records carrying its own id instead of relaying them, keeping the distal
reading (``angles[3]``), and ``update_sensor_messages`` then subtracts the zero offsets it stores for all
four (``'z'`` command) and sends them as one record — only when all four readings are non-zero (a fresh
distal reading each time: ``angles[3]`` is cleared after use) unless a data mode is set (``'d'`` command;
in data mode 2 the ``0x74`` half relays its brother's records instead of absorbing them). Commands sent
by id (``'C'``) to the joint reach both halves (``main.c`` forwards them), and ``'i'``, ``'t'`` and
``'h'`` sent directly to the ``0x74`` half are passed on to its brother (``utility.c``,
``process_uart_command``).

**Their frame and ours.** The authors' host code composes (``Software/RigReducer/puppet_things.h``, line
95, ``update_geometry``; degrees, their ``angle1..4`` the record's raw values converted to degrees, the
bends still carrying their offset)::

    ROT4 = Rx(a1) · Rz(90° − a2) · Ry(a3 − 90°) · Rx(a4)

with the bone along their ``x`` (line 125: ``r = Lengths(b,0) * UnitX``) and ``ROT4`` the outgoing link in
the incoming one (line 104: ``dRR = dR[i] * ROT4``, line 140: ``vQ[b] = vQ[p] * dRR[b]``). Our frames
are Blender's, the bone along ``y``; the two are related by the cyclic relabelling

    our ``x`` = their ``z``,  our ``y`` = their ``x``,  our ``z`` = their ``y``

(a proper rotation, 120° about (1, 1, 1), no sign changes): ``v_ours = P v_theirs`` with
``P =`` :data:`THEIR_AXES` ``= [[0,0,1],[1,0,0],[0,1,0]]`` and a rotation ``R_ours = P R_theirs Pᵀ``
(:func:`from_theirs`, :func:`to_theirs`), which turns their ``Rx, Ry, Rz`` into our ``Ry, Rz, Rx``.
With ``a2 = 90° + α`` and ``a3 = 90° + β``:

    R = Ry(τp) · Rx(−α) · Rz(β) · Ry(τd)

The joint's **inlet frame** is fixed to the piece it is plugged into, ``y`` along the incoming shaft; the
**outlet frame** (``R`` in the inlet frame) is fixed to the outgoing shaft, which points along
``R ŷ = Ry(τp) (−sin β, cos α cos β, −sin α cos β)``.

One LSB apart: the firmware's bend offset ``0x0FFF`` is one LSB short of the host's 90°. The host's
``MessageParser`` that converts records to degrees is not published; if it converts ``raw · 360/16384``
as the firmware's comments do, the host's hinges read one LSB (0.022°) off ours — its straight joint is
``Rz(0.022°) Ry(−0.022°)`` in its axes, 0.031° from the identity — and ours, exact for the firmware's
zero, is theirs with ``90°`` replaced by ``0x0FFF`` LSB (``tests/test_tangible_joint.py`` checks both).
The host also drops a reading with any raw angle exactly 0 (identity instead).

**No gimbal lock in the range.** Each hinge turns less than 90° either way, so ``cos β > 0``: the
shaft, turned back by the proximal ring, ``d = Ry(−τp) R ŷ``, gives both hinges smoothly,
``β = atan2(−d_x, √(d_y² + d_z²))`` and ``α = atan2(−d_z, d_y)`` with ``√(d_y² + d_z²) = cos β > 0``, and
the distal ring is what is left. Moving the shaft along any great circle within the cone of bends below
90° moves both hinges smoothly (no Euler-angle zig-zag, Fig. 4): the hinges' speed is at most
``1/cos β``. The only singular shaft directions are ``±x̂`` (β = ∓90°: the second hinge folded flat),
past the mechanical range. At and beyond that edge :func:`joint_angles` still returns finite angles that
reproduce the rotation (α = 0 on the singular line, where α and τd turn about the same axis), with an
error growing like ``ε / cos β`` as the edge is approached.

The two rings add up to one degree of freedom, so a rotation does not tell how the twist is shared
between them: :func:`joint_angles` takes the proximal twist as given (0 by default) and returns the
unique remaining angles.
"""

from __future__ import annotations

import numpy as np

from . import rotations as rot

__all__ = [
    "ANGLES",
    "BEND_LIMIT",
    "THEIR_AXES",
    "bend_angle",
    "from_theirs",
    "joint_angles",
    "joint_rotation",
    "to_theirs",
]

#: The four sensed angles, in record order (the last axis of every angle array).
ANGLES = ("twist_proximal", "bend_a", "bend_b", "twist_distal")
#: Bends (shaft to straight) below this are inside the joint's range, where the conversions are smooth.
BEND_LIMIT = 0.5 * np.pi

#: Their axes in ours: column i is their axis i expressed in our frame (``v_ours = P v_theirs``).
THEIR_AXES = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
THEIR_AXES.setflags(write=False)
# The same as a quaternion: 120° about (1, 1, 1).
_P = rot.from_matrix(THEIR_AXES)


def _about(axis: int, angle: np.ndarray) -> np.ndarray:
    q = np.zeros((*np.shape(angle), 4))
    q[..., 0] = np.cos(0.5 * angle)
    q[..., 1 + axis] = np.sin(0.5 * angle)
    return q


def from_theirs(rotation) -> np.ndarray:
    """(..., 4) rotations ``rotation`` (..., 4) (quaternions, in the authors' bone-along-x frame) in our
    bone-along-y frame: ``P R Pᵀ``."""
    return rot.multiply(rot.multiply(_P, rotation), rot.conjugate(_P))


def to_theirs(rotation) -> np.ndarray:
    """(..., 4) the inverse of :func:`from_theirs`: ``Pᵀ R P`` of rotations ``rotation`` (..., 4) in our
    frame."""
    return rot.multiply(rot.multiply(rot.conjugate(_P), rotation), _P)


def joint_rotation(angles) -> np.ndarray:
    """Outlet frame in the inlet frame, from sensed angles: ``Ry(τp) · Rx(−α) · Rz(β) · Ry(τd)``.

    Parameters
    ----------
    angles : (..., 4) array_like
        ``(twist_proximal, bend_a, bend_b, twist_distal)`` in radians, record order, bend offsets removed.

    Returns
    -------
    (..., 4)
        Unit quaternions ``(w, x, y, z)``.
    """
    a = np.asarray(angles, dtype=np.float64)
    if a.shape[-1:] != (4,):
        raise ValueError(f"joint angles must have shape (..., 4), got {a.shape}")
    q = rot.multiply(
        rot.multiply(_about(1, a[..., 0]), _about(0, -a[..., 1])),
        rot.multiply(_about(2, a[..., 2]), _about(1, a[..., 3])),
    )
    return rot.normalize(q)


def joint_angles(rotation, twist_proximal=0.0) -> np.ndarray:
    """Sensed angles that produce ``rotation`` with the given proximal twist.

    Parameters
    ----------
    rotation : (..., 4) array_like
        Unit quaternions of the outlet frame in the inlet frame.
    twist_proximal : (...,) array_like
        The proximal ring's angle to assume (radians).

    Returns
    -------
    (..., 4)
        ``(twist_proximal, bend_a, bend_b, twist_distal)``. ``bend_b`` lies in [−π/2, π/2], ``bend_a`` and
        ``twist_distal`` in (−π, π]; for bends below 90° both hinges lie in (−π/2, π/2).
    """
    q = rot.normalize(rotation)
    tp = np.broadcast_to(np.asarray(twist_proximal, dtype=np.float64), q.shape[:-1])
    m = rot.multiply(_about(1, -tp), q)
    d = rot.rotate(m, np.array([0.0, 1.0, 0.0]))
    across = np.hypot(d[..., 1], d[..., 2])
    beta = np.arctan2(-d[..., 0], across)
    # On the singular line (the second hinge folded flat) α and τd turn about the same axis: put it all
    # on τd.
    alpha = np.where(across > 1e-14, np.arctan2(-d[..., 2], d[..., 1]), 0.0)
    rest = rot.multiply(rot.conjugate(rot.multiply(_about(0, -alpha), _about(2, beta))), m)
    twist = 2.0 * np.arctan2(rest[..., 2], rest[..., 0])
    twist = np.mod(twist + np.pi, 2.0 * np.pi) - np.pi
    alpha = np.where(alpha == -np.pi, np.pi, alpha)
    return np.stack([tp, alpha, beta, np.where(twist == -np.pi, np.pi, twist)], axis=-1)


def bend_angle(angles) -> np.ndarray:
    """(...,) the bend (angle between the shaft and straight, radians) of sensed angles (..., 4)."""
    a = np.asarray(angles, dtype=np.float64)
    return np.arccos(np.clip(np.cos(a[..., 1]) * np.cos(a[..., 2]), -1.0, 1.0))
