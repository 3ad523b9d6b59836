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
from ..rotations import EULER_ORDERS
from .bones import ROTATION_MODES
from .math_rotation import axis_angle_to_quat, eulO_to_quat, normalize_qt, quat_to_axis_angle, quat_to_eulO

__all__ = [
    "BBONE_FLIPPED",
    "BBONE_SCALARS",
    "BBONE_VECTORS",
    "MAXBONENAME",
    "ROTATION_MODES",
    "PoseChannel",
    "flip_channels",
    "flip_name",
    "mirror_pose",
    "paste_channel",
]

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
    width = 3 if mode in EULER_ORDERS else 4
    if location.shape[-1:] != (3,) or rotation.shape[-1:] != (width,):
        raise SolverError(
            f"flip_channels needs location (..., 3) and a {mode} rotation (..., {width}); got "
            f"{location.shape} and {rotation.shape}"
        )
    location[..., 0] *= -1
    if mode in EULER_ORDERS:
        rotation[..., 1:] *= -1
    elif mode == "AXIS_ANGLE":
        e = quat_to_eulO(axis_angle_to_quat(rotation[..., 1:], rotation[..., 0]), "XYZ")
        e[..., 1:] *= -1
        axis, angle = quat_to_axis_angle(eulO_to_quat(e, "XYZ"))
        rotation = np.concatenate([angle[..., None], axis], -1)
    else:
        e = quat_to_eulO(normalize_qt(rotation), "XYZ")
        e[..., 1:] *= -1
        rotation = eulO_to_quat(e, "XYZ")
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
    elif mode in EULER_ORDERS:
        if src_mode == "AXIS_ANGLE":
            aa = source.rotation_axis_angle
            rotation = quat_to_eulO(axis_angle_to_quat(aa[1:], aa[0]), mode)
        else:
            rotation = quat_to_eulO(source.rotation_quaternion, mode)
    elif mode == "AXIS_ANGLE":
        if src_mode in EULER_ORDERS:
            axis, angle = quat_to_axis_angle(eulO_to_quat(source.rotation_euler, src_mode))
        else:
            axis, angle = quat_to_axis_angle(source.rotation_quaternion)
        rotation = np.concatenate([[angle], axis])
    elif src_mode in EULER_ORDERS:
        rotation = eulO_to_quat(source.rotation_euler, src_mode)
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
