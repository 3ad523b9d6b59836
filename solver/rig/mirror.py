"""Mirroring poses from one side of a rig to the other, exactly as Blender's Pose › Paste Pose Flipped.

* :func:`flip_name` — Blender's side-name flip (``"hand.L"`` ↔ ``"hand.R"``), re-exported from
  :mod:`geodesics.mirror`.
* :func:`flip_channels` — the flip of one rotation mode's channels (vectorized: many bones or frames).
* :class:`PoseChannel`, :func:`paste_channel`, :func:`mirror_pose` — a pose bone's transform channels and
  the whole paste, including the conversion between rotation modes when the two sides differ.

Conventions (those of Blender's pose bones; the field names are ``bpy.types.PoseBone``'s):

* ``location`` (3,), ``scale`` (3,); ``rotation_mode`` one of ``"QUATERNION"``, the six Euler orders
  ``"XYZ"`` … ``"ZYX"``, ``"AXIS_ANGLE"``; ``rotation_quaternion`` (w, x, y, z), ``rotation_euler``
  (x, y, z), ``rotation_axis_angle`` (angle, x, y, z). A pose bone keeps all three rotation fields; only
  its mode's one is used, and pasting writes only the receiving bone's mode's field.
* B-Bone channels: ``bbone_curveinx``, ``bbone_curveinz``, ``bbone_curveoutx``, ``bbone_curveoutz``,
  ``bbone_rollin``, ``bbone_rollout``, ``bbone_easein``, ``bbone_easeout`` (scalars) and
  ``bbone_scalein``, ``bbone_scaleout`` (3,).
* The flip mirrors through the armature's local x = 0 plane (its YZ plane), as Blender does: it is a
  mirror only for bones whose rest frames are themselves mirror images (a symmetric rig).

Blender computes in float32; these functions compute the same formulas in float64, so they agree with
Blender to float32 rounding, except within that rounding of the branch points of the Euler conversions
(gimbal lock, ties between the two Euler solutions).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, fields, replace

import numpy as np
from numpy.typing import ArrayLike

from geodesics.mirror import flip_name

from ..errors import SolverError
from .bones import quaternion_to_matrix
from .constraints import normalized_matrix_to_euler

__all__ = [
    "BBONE_FLIPPED",
    "BBONE_SCALARS",
    "BBONE_VECTORS",
    "MAXBONENAME",
    "ROTATION_MODES",
    "PoseChannel",
    "axis_angle_to_quat",
    "euler_to_quat",
    "flip_channels",
    "flip_name",
    "mirror_pose",
    "paste_channel",
    "quat_to_axis_angle",
    "quat_to_euler",
]

#: Blender's rotation modes (``PoseBone.rotation_mode``).
ROTATION_MODES = ("QUATERNION", "XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX", "AXIS_ANGLE")
#: Size of Blender's bone-name buffer, terminating NUL included (flipped names are cut to 63 bytes).
MAXBONENAME = 64
#: Scalar B-Bone channels, and those of them that a flip negates.
BBONE_SCALARS = (
    "bbone_curveinx",
    "bbone_curveinz",
    "bbone_curveoutx",
    "bbone_curveoutz",
    "bbone_rollin",
    "bbone_rollout",
    "bbone_easein",
    "bbone_easeout",
)
BBONE_FLIPPED = ("bbone_curveinx", "bbone_curveoutx", "bbone_rollin", "bbone_rollout")
#: Vector (3,) B-Bone channels (copied unchanged by a flip).
BBONE_VECTORS = ("bbone_scalein", "bbone_scaleout")

#: Blender's ``rotOrders``: the axes (i, j, k) and the parity of each Euler order.
_ORDERS = {
    "XYZ": ((0, 1, 2), 0),
    "XZY": ((0, 2, 1), 1),
    "YXZ": ((1, 0, 2), 1),
    "YZX": ((1, 2, 0), 0),
    "ZXY": ((2, 0, 1), 0),
    "ZYX": ((2, 1, 0), 1),
}


# ---------------------------------------------------------------------- Blender's rotation conversions
# Ports of math_rotation_c.cc, vectorized over leading dimensions; the matrix ones are solver.rig.bones' and
# solver.rig.constraints'.


def quat_to_euler(q, order: str = "XYZ") -> np.ndarray:
    """(..., 3) Blender's ``quat_to_eulO``: Euler angles of quaternions (..., 4) (not normalized first)."""
    return normalized_matrix_to_euler(quaternion_to_matrix(np.asarray(q, dtype=np.float64)), order)


def euler_to_quat(e, order: str = "XYZ") -> np.ndarray:
    """(..., 4) Blender's ``eulO_to_quat`` (and ``eul_to_quat`` for XYZ) of Euler angles (..., 3)."""
    e = np.asarray(e, dtype=np.float64)
    (i, j, k), parity = _ORDERS[order]
    ti = e[..., i] * 0.5
    tj = e[..., j] * (-0.5 if parity else 0.5)
    th = e[..., k] * 0.5
    ci, cj, ch = np.cos(ti), np.cos(tj), np.cos(th)
    si, sj, sh = np.sin(ti), np.sin(tj), np.sin(th)
    cc, cs, sc, ss = ci * ch, ci * sh, si * ch, si * sh
    a = np.empty((*e.shape[:-1], 3))
    a[..., i] = cj * sc - sj * cs
    a[..., j] = cj * ss + sj * cc
    a[..., k] = cj * cs - sj * sc
    q = np.concatenate([(cj * cc + sj * ss)[..., None], a], -1)
    if parity:
        q[..., j + 1] = -q[..., j + 1]
    return q


def axis_angle_to_quat(axis, angle) -> np.ndarray:
    """(..., 4) Blender's ``axis_angle_to_quat`` of ``axis`` (..., 3) and ``angle`` (...): a zero axis gives
    the identity."""
    axis = np.asarray(axis, dtype=np.float64)
    angle = np.asarray(angle, dtype=np.float64)
    length_sq = (axis * axis).sum(-1)
    ok = length_sq > 1.0e-35  # normalize_v3_v3's threshold
    unit = axis / np.sqrt(np.where(ok, length_sq, 1.0))[..., None]
    half = 0.5 * angle
    q = np.concatenate([np.cos(half)[..., None], unit * np.sin(half)[..., None]], -1)
    return np.where(ok[..., None], q, np.array([1.0, 0.0, 0.0, 0.0]))


def quat_to_axis_angle(q) -> tuple[np.ndarray, np.ndarray]:
    """Blender's ``quat_to_axis_angle`` of ``q`` (..., 4): ``(axis (..., 3), angle (...))``, angle in [0, 2π].

    Below a half-angle sine of 0.0005 the axis is not divided (so it is not unit length); a zero axis
    becomes +y.
    """
    q = np.asarray(q, dtype=np.float64)
    # Clipped: float32 rounds |w| <= 1 + ulp to 1 (Blender gives NaN for a stored |w| > 1, this does not).
    half = np.arccos(np.clip(q[..., 0], -1.0, 1.0))
    si = np.sin(half)
    si = np.where(np.abs(si) < 0.0005, 1.0, si)
    axis = q[..., 1:] / si[..., None]
    zero = np.all(axis == 0, axis=-1)
    axis = np.where(zero[..., None], np.array([0.0, 1.0, 0.0]), axis)
    return axis, 2.0 * half


def _normalize_qt(q: np.ndarray) -> np.ndarray:
    """``normalize_qt``: a zero quaternion becomes (0, 1, 0, 0)."""
    length = np.sqrt((q * q).sum(-1))
    ok = length != 0
    return np.where(ok[..., None], q / np.where(ok, length, 1.0)[..., None], np.array([0.0, 1.0, 0.0, 0.0]))


# ---------------------------------------------------------------------- flipping channels


def flip_channels(location, rotation, mode: str, *, bbone: Mapping[str, np.ndarray] | None = None):
    """Flip transform channels to the other side, as Paste Pose Flipped does to a pasted bone.

    A port of the ``flip`` block of ``pose_bone_do_paste`` (``editors/armature/pose_transform.cc``):

    * location: x negated;
    * Euler (any order): the y and z angles negated;
    * quaternion: normalized, converted to XYZ Euler angles, y and z negated, converted back;
    * axis-angle: converted to XYZ Euler angles through a quaternion, y and z negated, converted back
      (``quat_to_axis_angle``: angle in [0, 2π]);
    * B-Bones: ``bbone_curveinx``, ``bbone_curveoutx``, ``bbone_rollin``, ``bbone_rollout`` negated, the
      others unchanged; scale unchanged.

    Parameters
    ----------
    location : (..., 3) array_like
    rotation : (..., 3) or (..., 4) array_like
        Euler angles, a quaternion (w, x, y, z) or an axis-angle (angle, x, y, z), as ``mode`` says.
    mode : str
        One of :data:`ROTATION_MODES`.
    bbone : mapping of str to array_like, optional
        Any of the B-Bone channels by their ``PoseBone`` names, each (...) or (..., 3).

    Returns
    -------
    location : (..., 3) ndarray
    rotation : (..., 3) or (..., 4) ndarray
    bbone : dict
        The flipped B-Bone channels (empty if none were given).
    """
    location = np.array(location, dtype=np.float64)
    rotation = np.array(rotation, dtype=np.float64)
    _check_mode(mode)
    width = 3 if mode in _ORDERS else 4
    if location.shape[-1:] != (3,) or rotation.shape[-1:] != (width,):
        raise SolverError(
            f"flip_channels needs location (..., 3) and a {mode} rotation (..., {width}); got "
            f"{location.shape} and {rotation.shape}"
        )
    location[..., 0] *= -1
    if mode in _ORDERS:
        rotation[..., 1:] *= -1
    elif mode == "AXIS_ANGLE":
        e = quat_to_euler(axis_angle_to_quat(rotation[..., 1:], rotation[..., 0]), "XYZ")
        e[..., 1:] *= -1
        axis, angle = quat_to_axis_angle(euler_to_quat(e, "XYZ"))
        rotation = np.concatenate([angle[..., None], axis], -1)
    else:
        e = quat_to_euler(_normalize_qt(rotation), "XYZ")
        e[..., 1:] *= -1
        rotation = euler_to_quat(e, "XYZ")
    flipped = {}
    for name, value in (bbone or {}).items():
        if name not in BBONE_SCALARS and name not in BBONE_VECTORS:
            raise SolverError(
                f"unknown B-Bone channel {name!r}; use {', '.join(BBONE_SCALARS + BBONE_VECTORS)}"
            )
        value = np.array(value, dtype=np.float64)
        flipped[name] = -value if name in BBONE_FLIPPED else value
    return location, rotation, flipped


def _check_mode(mode: str) -> None:
    if mode not in ROTATION_MODES:
        raise SolverError(f"unknown rotation mode {mode!r}; use one of {', '.join(ROTATION_MODES)}")


# ---------------------------------------------------------------------- pose channels and the paste


#: The vector channels of a PoseChannel and their sizes.
_VECTOR_SIZES = {
    "location": 3,
    "rotation_quaternion": 4,
    "rotation_euler": 3,
    "rotation_axis_angle": 4,
    "scale": 3,
    "bbone_scalein": 3,
    "bbone_scaleout": 3,
}


@dataclass(frozen=True, eq=False)
class PoseChannel:
    """A pose bone's transform channels, named as ``bpy.types.PoseBone``'s properties.

    Vector channels are stored as read-only float64 arrays (``location`` (3,), ``rotation_quaternion``
    (4,), ``rotation_euler`` (3,), ``rotation_axis_angle`` (4,), ``scale`` (3,), ``bbone_scalein`` and
    ``bbone_scaleout`` (3,)); defaults are Blender's rest values.

    Build one from a pose bone with ``PoseChannel.from_object(pose_bone)`` (any object with those
    attributes) and write one back with ``channel.apply_to(pose_bone)``.
    """

    location: ArrayLike = (0.0, 0.0, 0.0)
    rotation_mode: str = "QUATERNION"
    rotation_quaternion: ArrayLike = (1.0, 0.0, 0.0, 0.0)
    rotation_euler: ArrayLike = (0.0, 0.0, 0.0)
    rotation_axis_angle: ArrayLike = (0.0, 0.0, 1.0, 0.0)
    scale: ArrayLike = (1.0, 1.0, 1.0)
    bbone_curveinx: float = 0.0
    bbone_curveinz: float = 0.0
    bbone_curveoutx: float = 0.0
    bbone_curveoutz: float = 0.0
    bbone_rollin: float = 0.0
    bbone_rollout: float = 0.0
    bbone_easein: float = 0.0
    bbone_easeout: float = 0.0
    bbone_scalein: ArrayLike = (1.0, 1.0, 1.0)
    bbone_scaleout: ArrayLike = (1.0, 1.0, 1.0)

    def __post_init__(self):
        _check_mode(self.rotation_mode)
        for name, size in _VECTOR_SIZES.items():
            value = np.array(getattr(self, name), dtype=np.float64).reshape(-1)
            if value.shape != (size,) or not np.all(np.isfinite(value)):
                raise SolverError(
                    f"PoseChannel.{name} must be {size} finite numbers, got {getattr(self, name)!r}"
                )
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        for name in BBONE_SCALARS:
            value = float(getattr(self, name))
            if not np.isfinite(value):
                raise SolverError(f"PoseChannel.{name} must be finite, got {value}")
            object.__setattr__(self, name, value)

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """The channel names (``PoseBone`` property names)."""
        return tuple(f.name for f in fields(cls))

    @classmethod
    def from_object(cls, pose_bone) -> PoseChannel:
        """Read the channels from anything with ``PoseBone``'s attributes (e.g. a bpy pose bone)."""
        return cls(**{name: _plain(getattr(pose_bone, name)) for name in cls.names()})

    def apply_to(self, pose_bone) -> None:
        """Set the channels on anything with ``PoseBone``'s attributes (e.g. a bpy pose bone)."""
        for name in self.names():
            value = getattr(self, name)
            setattr(pose_bone, name, value.tolist() if isinstance(value, np.ndarray) else value)

    def as_dict(self) -> dict:
        """The channels by name: vector channels as their (3,) or (4,) arrays, the rest as floats and str."""
        return {name: getattr(self, name) for name in self.names()}

    def rotation(self) -> np.ndarray:
        """The active rotation field (the one ``rotation_mode`` uses): ``rotation_euler`` (3,), or
        ``rotation_quaternion`` or ``rotation_axis_angle`` (4,), read-only."""
        return self._field_of(self.rotation_mode)

    def _field_of(self, mode: str) -> np.ndarray:
        if mode == "QUATERNION":
            return self.rotation_quaternion
        if mode == "AXIS_ANGLE":
            return self.rotation_axis_angle
        return self.rotation_euler


def _plain(value):
    if isinstance(value, str):
        return value
    if hasattr(value, "__len__"):  # bpy's vectors, quaternions and arrays
        return np.array(list(value), dtype=np.float64)
    return float(value)


def _rotation_field(mode: str) -> str:
    return {"QUATERNION": "rotation_quaternion", "AXIS_ANGLE": "rotation_axis_angle"}.get(
        mode, "rotation_euler"
    )


def paste_channel(source: PoseChannel, target: PoseChannel, flip: bool = True) -> PoseChannel:
    """``target`` after Blender pastes ``source``'s channels onto it (``pose_bone_do_paste``).

    Location, scale and the B-Bone channels are copied; the rotation is converted into ``target``'s
    rotation mode when the modes differ, exactly as Blender does it, including two quirks of its code: an
    Euler source pasted onto an Euler bone of another order is converted from the source's *quaternion*
    field, and an axis-angle source pasted onto a quaternion bone uses the *target's* axis-angle angle.
    Only the target mode's rotation field changes. With ``flip``, the result is flipped
    (:func:`flip_channels`). Custom properties (which Blender also copies) are not modelled.
    """
    mode, src_mode = target.rotation_mode, source.rotation_mode
    if mode == src_mode:
        rotation = source._field_of(mode)
    elif mode in _ORDERS:
        if src_mode == "AXIS_ANGLE":
            aa = source.rotation_axis_angle
            rotation = quat_to_euler(axis_angle_to_quat(aa[1:], aa[0]), mode)
        else:
            rotation = quat_to_euler(source.rotation_quaternion, mode)
    elif mode == "AXIS_ANGLE":
        if src_mode in _ORDERS:
            axis, angle = quat_to_axis_angle(euler_to_quat(source.rotation_euler, src_mode))
        else:
            axis, angle = quat_to_axis_angle(source.rotation_quaternion)
        rotation = np.concatenate([[angle], axis])
    elif src_mode in _ORDERS:
        rotation = euler_to_quat(source.rotation_euler, src_mode)
    else:  # axis-angle onto quaternion: Blender passes the target's own angle (pchan->rotAngle)
        rotation = axis_angle_to_quat(source.rotation_axis_angle[1:], target.rotation_axis_angle[0])
    bbone = {name: getattr(source, name) for name in BBONE_SCALARS + BBONE_VECTORS}
    location = source.location
    if flip:
        location, rotation, bbone = flip_channels(location, rotation, mode, bbone=bbone)
    return replace(
        target,
        location=location,
        scale=source.scale,
        **{_rotation_field(mode): rotation},
        **{name: (float(v) if np.ndim(v) == 0 else v) for name, v in bbone.items()},
    )


def mirror_pose(
    channels: Mapping[str, PoseChannel],
    *,
    selected: Iterable[str] | None = None,
    selected_mask: Iterable[str] | None = None,
) -> dict[str, PoseChannel]:
    """The pose after Copy Pose then Paste Pose Flipped (``pose.copy``, ``pose.paste(flipped=True)``).

    Each copied bone's channels go, flipped, onto the bone named :func:`flip_name` of it (a bone without
    a side, such as ``"spine"``, onto itself; a bone whose flipped name does not exist is skipped).
    Values are taken from the pose as it was before the paste, so the two sides swap.

    Parameters
    ----------
    channels : mapping of bone name -> PoseChannel
        Every bone of the armature, as it is.
    selected : iterable of str, optional
        The bones selected when the pose was copied (only those are pasted); default all.
    selected_mask : iterable of str, optional
        Paste's "On Selected Only": the bones selected when pasting (only those receive values). None
        (default) or empty: every bone may receive, as Blender falls back to when nothing is selected.

    Returns
    -------
    dict of bone name -> PoseChannel
        Every bone's channels after the paste (unchanged for bones that received nothing).
    """
    sources = list(channels) if selected is None else [name for name in channels if name in set(selected)]
    receivers = None if selected_mask is None else set(selected_mask)
    if receivers is not None and not receivers:
        receivers = None
    out = dict(channels)
    for name in sources:
        other = flip_name(name, max_bytes=MAXBONENAME)
        if other not in channels or (receivers is not None and other not in receivers):
            continue
        out[other] = paste_channel(channels[name], channels[other], flip=True)
    return out
