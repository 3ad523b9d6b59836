"""Bones as Blender poses them: their rest data, their channels, and the discrete settings that let many be
placed at once (``armature.cc``).

A bone's *rest* matrix is Blender's ``arm_mat`` (``Bone.matrix_local``); its *pose* matrix is
``pose_mat`` (``PoseBone.matrix``); its *local* (channel) matrix is ``chan_mat`` (``PoseBone.matrix_basis``
once location, rotation and scale are composed). How a bone's parent places it is :mod:`.parenting`; the
spaces constraints work in, :mod:`.spaces`. Matrix conventions are those of :mod:`.math_matrix`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SolverError
from ..rotations import EULER_ORDERS, euler_to_matrix
from . import analytic
from .math_matrix import affine, normalize_v3
from .math_rotation import axis_angle_normalized_to_mat3, quat_to_mat3
from .stack import constant

#: Blender's ``Bone.inherit_scale`` modes.
INHERIT_SCALE_MODES = ("FULL", "FIX_SHEAR", "ALIGNED", "AVERAGE", "NONE", "NONE_LEGACY")
#: Pose-bone rotation modes (``PoseBone.rotation_mode``), in Blender's order.
ROTATION_MODES = ("QUATERNION", "XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX", "AXIS_ANGLE")


def _frozen(value, shape) -> np.ndarray:
    array = np.array(value, dtype=np.float64).reshape(shape)
    array.setflags(write=False)
    return array


@dataclass(frozen=True, eq=False)
class Bone:
    """The rest data of one bone that posing needs (Blender's ``Bone`` plus its pose bone's rotation mode).

    Attributes
    ----------
    name : str
        The bone's name.
    matrix_local : (4, 4) ndarray
        Rest matrix in armature space (Blender's ``arm_mat``, ``Bone.matrix_local``).
    length : float
        Rest length (``Bone.length``).
    parent : str or None
        The parent bone's name.
    matrix : (3, 3) ndarray
        Rest orientation relative to the parent (Blender's ``bone_mat``, ``Bone.matrix``).
    head : (3,) ndarray
        Head relative to the parent's tail, in the parent's rest frame (Blender's ``Bone.head``).
    use_connect, use_inherit_rotation, use_local_location : bool
        Blender's flags of the same names.
    inherit_scale : str
        One of :data:`INHERIT_SCALE_MODES`.
    rotation_mode : str
        The pose bone's rotation mode (one of :data:`ROTATION_MODES`); constraints decompose Euler
        angles in it (``XYZ`` for quaternion and axis-angle bones).
    bbone_segments : int
        B-Bone segments (1: a plain bone).
    head_radius, tail_radius, envelope_distance : float
        Envelope of the bone (``Bone.head_radius`` ...), used by Armature constraints with envelopes.
    use_envelope_multiply : bool
        ``Bone.use_envelope_multiply``.
    """

    name: str
    matrix_local: np.ndarray
    length: float
    parent: str | None = None
    matrix: np.ndarray | None = None
    head: np.ndarray | None = None
    use_connect: bool = False
    use_inherit_rotation: bool = True
    inherit_scale: str = "FULL"
    use_local_location: bool = True
    rotation_mode: str = "QUATERNION"
    bbone_segments: int = 1
    head_radius: float = 0.1
    tail_radius: float = 0.1
    envelope_distance: float = 0.25
    use_envelope_multiply: bool = False

    def __post_init__(self):
        arm = _frozen(self.matrix_local, (4, 4))
        object.__setattr__(self, "matrix_local", arm)
        object.__setattr__(self, "length", float(self.length))
        if self.inherit_scale not in INHERIT_SCALE_MODES:
            raise SolverError(f"bone {self.name!r}: unknown inherit_scale {self.inherit_scale!r}")
        if self.rotation_mode not in ROTATION_MODES:
            raise SolverError(f"bone {self.name!r}: unknown rotation mode {self.rotation_mode!r}")
        if self.matrix is not None:
            object.__setattr__(self, "matrix", _frozen(self.matrix, (3, 3)))
        if self.head is not None:
            object.__setattr__(self, "head", _frozen(self.head, (3,)))

    @property
    def head_local(self) -> np.ndarray:
        """(3,) rest head in armature space (Blender's ``arm_head``)."""
        return self.matrix_local[:3, 3]

    @property
    def tail_local(self) -> np.ndarray:
        """(3,) rest tail in armature space (Blender's ``arm_tail``)."""
        return self.matrix_local[:3, 3] + self.length * self.matrix_local[:3, 1]

    @property
    def euler_order(self) -> str:
        """The Euler order constraints use for this bone (Blender's ``cob->rotOrder``)."""
        return self.rotation_mode if self.rotation_mode in EULER_ORDERS else "XYZ"

    def offset(self, parent: Bone) -> np.ndarray:
        """(4, 4) the bone's rest frame in its parent's (``BKE_bone_offset_matrix_get``): ``bone_mat``, at
        ``head`` plus the parent's length along Y (from the rest matrices when ``matrix``/``head`` are
        unset)."""
        if self.matrix is None or self.head is None:
            return np.linalg.inv(parent.matrix_local) @ self.matrix_local
        offs = np.eye(4)
        offs[:3, :3] = self.matrix
        offs[:3, 3] = self.head
        offs[1, 3] += parent.length
        return offs


def channel_matrix(location, rotation, scale):
    """(..., 4, 4) a pose bone's local matrix (``BKE_pchan_to_mat4``): ``T(location) R diag(scale)``.

    Parameters
    ----------
    location : (..., 3) array_like
    rotation : (..., 3, 3) array_like
        From :func:`rotation_matrix`.
    scale : (..., 3) array_like

    Blender drops the location of connected bones; :func:`solver.rig.constraints.pose_bone` does that.
    """
    rotation, scale = np.asarray(rotation), np.asarray(scale)
    return affine(rotation * scale[..., None, :], location)


def rotation_matrix(mode: str, rotation) -> np.ndarray:
    """(..., 3, 3) the rotation of a pose bone's stored rotation in its mode (``BKE_pchan_rot_to_mat3``).

    Parameters
    ----------
    mode : str
        An Euler order (``rotation`` is ``rotation_euler`` (..., 3)), ``QUATERNION`` (``(w, x, y, z)``
        (..., 4), normalized first; a zero quaternion is Blender's ``(0, 1, 0, 0)``) or ``AXIS_ANGLE``
        (``(angle, x, y, z)`` (..., 4); a zero axis is no rotation).
    """
    r = np.asarray(rotation)
    if mode in EULER_ORDERS:
        return euler_to_matrix(r, mode)
    if mode == "QUATERNION":
        n = analytic.norm(r)
        zero = n.real == 0
        q = np.where(zero[..., None], np.array([0.0, 1.0, 0.0, 0.0]), r / np.where(zero, 1.0, n)[..., None])
        return quat_to_mat3(q)
    if mode == "AXIS_ANGLE":
        axis, length = normalize_v3(r[..., 1:])
        R = axis_angle_normalized_to_mat3(axis, np.sin(r[..., 0]), np.cos(r[..., 0]))
        return np.where((length.real == 0)[..., None, None], np.eye(3), R)
    raise SolverError(f"unknown rotation mode {mode!r}; use one of {', '.join(ROTATION_MODES)}")


def bone_key(bone: Bone, parent: Bone | None) -> tuple:
    """The discrete settings of a bone's placement: bones (and their parents) with equal keys can be
    posed in one :class:`BoneStack`.

    A root bone: ``("root", use_local_location)``; a child: ``("child", use_connect, use_inherit_rotation,
    inherit_scale, use_local_location)``. Rest matrices, lengths and offsets are continuous (arrays of
    the stack).
    """
    if parent is None:
        return ("root", bool(bone.use_local_location))
    return (
        "child",
        bool(bone.use_connect),
        bool(bone.use_inherit_rotation),
        bone.inherit_scale,
        bool(bone.use_local_location),
    )


class BoneStack:
    """The rest data of ``g`` bones with one :func:`bone_key`, as arrays over the stack axis.

    Build it with :meth:`of`. Arrays are in the stack layout: per-bone constants ``(g, 1, ...)``.

    Attributes
    ----------
    names : tuple of str
    key : tuple
        The common :func:`bone_key`.
    bones : tuple of Bone
    size : int
        ``g``.
    root, connect, inherit_rotation, local_location : bool
    inherit_scale : str
    full : bool
        Plain parenting: the parent's pose times the offset (inherited rotation, ``FULL`` scale).
    offset : (g, 1, 4, 4)
        ``BKE_bone_offset_matrix_get`` of each bone in its parent (a root bone's rest matrix).
    head_column : (g, 1, 4, 1)
        The offsets' translations as homogeneous columns (where connected heads go).
    rest, rest_inverse : (g, 1, 4, 4)
        The bones' rest matrices (``arm_mat``) and their inverses.
    parent_rest : (g, 1, 4, 4) or None
        The parents' rest matrices.
    length : (g, 1)
        Rest lengths.
    """

    def __init__(self, names, key, bones, offset, rest, parent_rest, length):
        self.names, self.key, self.bones = names, key, bones
        self.size = len(names)
        self.root = key[0] == "root"
        self.connect = not self.root and key[1]
        self.inherit_rotation = self.root or key[2]
        self.inherit_scale = "FULL" if self.root else key[3]
        self.local_location = key[-1]
        self.full = not self.root and self.inherit_rotation and self.inherit_scale == "FULL"
        self.offset = offset
        self.offset_translation = offset[..., :3, 3]
        self.head_column = constant(offset[:, 0, :, 3:])
        self.rest = rest
        self.rest_inverse = constant(np.linalg.inv(rest[:, 0]))
        self.parent_rest = parent_rest
        self.length = length

    @classmethod
    def of(cls, bones, parents) -> BoneStack:
        """The stack of ``bones`` (sequence of :class:`Bone`) under ``parents`` (their parents' Bones, or
        None for roots), which must all have one :func:`bone_key`."""
        bones, parents = tuple(bones), tuple(parents)
        if not bones or len(bones) != len(parents):
            raise SolverError("a bone stack needs one parent (or None) per bone, and at least one bone")
        keys = {bone_key(b, p) for b, p in zip(bones, parents, strict=True)}
        if len(keys) != 1:
            raise SolverError(
                f"bones {', '.join(b.name for b in bones[:4])} differ in their parenting settings "
                f"({len(keys)} kinds); stack them by bone_key"
            )
        key = keys.pop()
        root = key[0] == "root"
        offsets = [b.matrix_local if root else b.offset(p) for b, p in zip(bones, parents, strict=True)]
        return cls(
            names=tuple(b.name for b in bones),
            key=key,
            bones=bones,
            offset=constant(offsets),
            rest=constant([b.matrix_local for b in bones]),
            parent_rest=None if root else constant([p.matrix_local for p in parents]),
            length=constant([b.length for b in bones]),
        )
