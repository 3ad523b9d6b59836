"""A B-Bone's settings as one validated value: :class:`BBone` (Blender's ``Bone`` and ``PoseBone``) and its
handle bones, :class:`BBoneHandle`, with the rest shape derived from them."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ...errors import SolverError
from ..bones import INHERIT_SCALE_MODES
from .reference import MAX_SEGMENTS, curve_joints

#: Blender's ``Bone.bbone_handle_type_start`` / ``_end`` values.
HANDLE_TYPES = ("AUTO", "ABSOLUTE", "RELATIVE", "TANGENT")
#: Blender's ``Bone.bbone_mapping_mode`` values.
MAPPING_MODES = ("STRAIGHT", "CURVED")


def _vector(value, what: str, where: str, size: int = 3) -> np.ndarray:
    a = np.array(value, dtype=np.float64)
    if a.shape != (size,) or not np.all(np.isfinite(a)):
        raise SolverError(f"{where}: {what} must be {size} finite numbers, got {value!r}")
    a.setflags(write=False)
    return a


def _matrix(value, what: str, where: str) -> np.ndarray:
    a = np.array(value, dtype=np.float64)
    if a.shape != (4, 4) or not np.all(np.isfinite(a)):
        raise SolverError(f"{where}: {what} must be a finite 4x4 matrix, got shape {a.shape}")
    if np.abs(a[3] - (0, 0, 0, 1)).max() > 1e-9:
        raise SolverError(f"{where}: {what} must be affine (last row 0, 0, 0, 1), got {a[3].tolist()}")
    if abs(np.linalg.det(a[:3, :3])) < 1e-30:
        raise SolverError(f"{where}: {what} is singular")
    a.setflags(write=False)
    return a


def _number(value, what: str, where: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise SolverError(f"{where}: {what} must be a number, got {value!r}") from None
    if not np.isfinite(x):
        raise SolverError(f"{where}: {what} must be finite, got {value!r}")
    return x


def _length(value, what: str, where: str) -> float:
    x = _number(value, what, where)
    if x <= 0:
        raise SolverError(f"{where}: {what} must be positive (a zero-length bone), got {x!r}")
    return x


def _segments(value, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or not 1 <= value <= MAX_SEGMENTS:
        raise SolverError(
            f"{where}: bbone_segments must be an integer from 1 to {MAX_SEGMENTS}, got {value!r}"
        )
    return int(value)


def _choice(value, options, what: str, where: str) -> str:
    if value not in options:
        raise SolverError(f"{where}: {what} must be one of {', '.join(options)}, got {value!r}")
    return value


def _flags(value, what: str, where: str, size: int) -> tuple[bool, ...]:
    try:
        flags = tuple(value) if size > 1 else (value,)
    except TypeError:
        flags = ()
    if len(flags) != size or not all(isinstance(f, bool | np.bool_) for f in flags):
        raise SolverError(f"{where}: {what} must be {size} booleans, got {value!r}")
    return tuple(bool(f) for f in flags)


@dataclass(frozen=True, eq=False)
class BBoneHandle:
    """The rest data of a handle bone of a B-Bone (the bone before or after it on the curve).

    Attributes
    ----------
    name : str
        The handle bone's name (``Bone.name``); its posed matrix is what the caller passes.
    matrix_local : (4, 4) float
        ``Bone.matrix_local``: its rest matrix in armature space (Blender's ``arm_mat``).
    length : float
        ``Bone.length``.
    head_local, tail_local : (3,) float
        ``Bone.head_local`` / ``Bone.tail_local`` (Blender's ``arm_head`` / ``arm_tail``).
    segments : int
        ``Bone.bbone_segments`` of the handle: an ``AUTO``/``ABSOLUTE`` handle that is itself a B-Bone
        joins the curves smoothly (Blender's ``prev_bbone`` / ``next_bbone``).
    bone_roll_out, pose_roll_out : float
        ``Bone.bbone_rollout`` and ``PoseBone.bbone_rollout`` of the handle, added to the B-Bone's roll
        in when it has ``use_endroll_as_inroll``.
    parent : str or None
        ``Bone.parent.name`` of the handle; its posed matrix is needed only to read the handle's own
        scale (``bbone_handle_use_scale_*`` / ``bbone_handle_use_ease_*``).
    parent_offset : (4, 4) float or None
        The handle's rest matrix relative to its parent's (Blender's ``offs_bone``: ``Bone.matrix`` with
        translation ``Bone.head + (0, parent.length, 0)``); required when ``parent`` is set.
    inherit_scale : str
        ``Bone.inherit_scale`` of the handle.
    use_inherit_rotation : bool
        ``Bone.use_inherit_rotation`` of the handle.
    """

    name: str
    matrix_local: np.ndarray
    length: float
    head_local: np.ndarray
    tail_local: np.ndarray
    segments: int = 1
    bone_roll_out: float = 0.0
    pose_roll_out: float = 0.0
    parent: str | None = None
    parent_offset: np.ndarray | None = None
    inherit_scale: str = "FULL"
    use_inherit_rotation: bool = True

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise SolverError(f"a B-Bone handle needs a bone name, got {self.name!r}")
        where = f"B-Bone handle {self.name!r}"
        put = object.__setattr__
        put(self, "matrix_local", _matrix(self.matrix_local, "matrix_local", where))
        put(self, "length", _length(self.length, "length", where))
        put(self, "head_local", _vector(self.head_local, "head_local", where))
        put(self, "tail_local", _vector(self.tail_local, "tail_local", where))
        put(self, "segments", _segments(self.segments, where))
        put(self, "bone_roll_out", _number(self.bone_roll_out, "bbone_rollout (bone)", where))
        put(self, "pose_roll_out", _number(self.pose_roll_out, "bbone_rollout (pose bone)", where))
        if self.parent is not None and (not isinstance(self.parent, str) or not self.parent):
            raise SolverError(f"{where}: parent must be a bone name or None, got {self.parent!r}")
        if self.parent is None:
            put(self, "parent_offset", None)
        else:
            if self.parent_offset is None:
                raise SolverError(f"{where}: parent_offset is required with parent {self.parent!r}")
            put(self, "parent_offset", _matrix(self.parent_offset, "parent_offset", where))
        put(self, "inherit_scale", _choice(self.inherit_scale, INHERIT_SCALE_MODES, "inherit_scale", where))
        put(
            self,
            "use_inherit_rotation",
            _flags(self.use_inherit_rotation, "use_inherit_rotation", where, 1)[0],
        )


@dataclass(frozen=True, eq=False)
class BBone:
    """Every constant the B-Bone shape of one bone depends on (Blender's ``Bone`` and ``PoseBone``).

    Blender sums the bone-level and pose-level ease, roll and curve values and multiplies the scales
    (``BKE_pchan_bbone_spline_params_get``); the rest shape (which deformation cancels out) uses the
    bone-level values alone. The pose-level values are taken as constants: a rig that animates or
    drives them must be read again.

    Handles (``BKE_pchan_bbone_handles_get``): with ``bbone_handle_type_start == "AUTO"`` the start
    handle is the bone's parent if the bone is connected (``use_connect``), else none; with
    ``"AUTO"`` at the end it is the bone's last connected child, if any. Any other type uses the custom
    handle bone (``bbone_custom_handle_start`` / ``_end``), none if unset. :attr:`start` and :attr:`end`
    hold the handle bones so resolved (``None`` for none), with the handle type saying how each is used.

    Attributes
    ----------
    name : str
        ``Bone.name``.
    matrix_local : (4, 4) float
        ``Bone.matrix_local`` (Blender's ``arm_mat``).
    length : float
        ``Bone.length``.
    head_local, tail_local : (3,) float
        ``Bone.head_local`` / ``Bone.tail_local``.
    segments : int
        ``Bone.bbone_segments`` (1 to 32; 1 is a plain bone).
    mapping_mode : str
        ``Bone.bbone_mapping_mode``: ``"STRAIGHT"`` or ``"CURVED"`` (how a vertex picks its segments).
    handle_type_start, handle_type_end : str
        ``Bone.bbone_handle_type_start`` / ``_end``: ``"AUTO"``, ``"ABSOLUTE"``, ``"RELATIVE"`` or
        ``"TANGENT"``.
    start, end : BBoneHandle or None
        The resolved start and end handle bones.
    bone_ease_in, bone_ease_out : float
        ``Bone.bbone_easein`` / ``Bone.bbone_easeout``.
    pose_ease_in, pose_ease_out : float
        ``PoseBone.bbone_easein`` / ``PoseBone.bbone_easeout`` (added).
    bone_roll_in, bone_roll_out, pose_roll_in, pose_roll_out : float
        ``Bone.bbone_rollin`` / ``bbone_rollout`` and the ``PoseBone`` ones (added), radians.
    bone_curve_in_x, bone_curve_in_z, bone_curve_out_x, bone_curve_out_z : float
        ``Bone.bbone_curveinx`` / ``bbone_curveinz`` / ``bbone_curveoutx`` / ``bbone_curveoutz``.
    pose_curve_in_x, pose_curve_in_z, pose_curve_out_x, pose_curve_out_z : float
        The ``PoseBone`` ones (added).
    bone_scale_in, bone_scale_out, pose_scale_in, pose_scale_out : (3,) float
        ``Bone.bbone_scalein`` / ``bbone_scaleout`` and the ``PoseBone`` ones (multiplied).
    use_endroll_as_inroll : bool
        ``Bone.use_endroll_as_inroll``: add the start handle's roll out to the roll in.
    use_scale_easing : bool
        ``Bone.use_scale_easing``: multiply ease and curve in/out by the y scale in/out.
    handle_use_scale_start, handle_use_scale_end : (bool, bool, bool)
        ``Bone.bbone_handle_use_scale_start`` / ``_end``: multiply scale in/out x, y, z by the handle
        bone's local scale.
    handle_use_ease_start, handle_use_ease_end : bool
        ``Bone.bbone_handle_use_ease_start`` / ``_end``: multiply ease and curve in/out by the handle
        bone's local y scale.
    """

    name: str
    matrix_local: np.ndarray
    length: float
    head_local: np.ndarray
    tail_local: np.ndarray
    segments: int = 1
    mapping_mode: str = "STRAIGHT"
    handle_type_start: str = "AUTO"
    handle_type_end: str = "AUTO"
    start: BBoneHandle | None = None
    end: BBoneHandle | None = None
    bone_ease_in: float = 1.0
    bone_ease_out: float = 1.0
    pose_ease_in: float = 0.0
    pose_ease_out: float = 0.0
    bone_roll_in: float = 0.0
    bone_roll_out: float = 0.0
    pose_roll_in: float = 0.0
    pose_roll_out: float = 0.0
    bone_curve_in_x: float = 0.0
    bone_curve_in_z: float = 0.0
    bone_curve_out_x: float = 0.0
    bone_curve_out_z: float = 0.0
    pose_curve_in_x: float = 0.0
    pose_curve_in_z: float = 0.0
    pose_curve_out_x: float = 0.0
    pose_curve_out_z: float = 0.0
    bone_scale_in: np.ndarray = (1.0, 1.0, 1.0)
    bone_scale_out: np.ndarray = (1.0, 1.0, 1.0)
    pose_scale_in: np.ndarray = (1.0, 1.0, 1.0)
    pose_scale_out: np.ndarray = (1.0, 1.0, 1.0)
    use_endroll_as_inroll: bool = False
    use_scale_easing: bool = False
    handle_use_scale_start: tuple[bool, bool, bool] = (False, False, False)
    handle_use_scale_end: tuple[bool, bool, bool] = (False, False, False)
    handle_use_ease_start: bool = False
    handle_use_ease_end: bool = False

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise SolverError(f"a B-Bone needs a bone name, got {self.name!r}")
        where = f"B-Bone {self.name!r}"
        put = object.__setattr__
        put(self, "matrix_local", _matrix(self.matrix_local, "matrix_local", where))
        put(self, "length", _length(self.length, "length", where))
        put(self, "head_local", _vector(self.head_local, "head_local", where))
        put(self, "tail_local", _vector(self.tail_local, "tail_local", where))
        put(self, "segments", _segments(self.segments, where))
        put(self, "mapping_mode", _choice(self.mapping_mode, MAPPING_MODES, "bbone_mapping_mode", where))
        for side in ("start", "end"):
            put(
                self,
                f"handle_type_{side}",
                _choice(
                    getattr(self, f"handle_type_{side}"), HANDLE_TYPES, f"bbone_handle_type_{side}", where
                ),
            )
            handle = getattr(self, side)
            if handle is not None and not isinstance(handle, BBoneHandle):
                raise SolverError(
                    f"{where}: {side} must be a BBoneHandle or None, got {type(handle).__name__}"
                )
            if handle is not None and handle.name == self.name:
                raise SolverError(f"{where}: the bone cannot be its own {side} handle")
            put(
                self,
                f"handle_use_scale_{side}",
                _flags(getattr(self, f"handle_use_scale_{side}"), f"bbone_handle_use_scale_{side}", where, 3),
            )
            put(
                self,
                f"handle_use_ease_{side}",
                _flags(getattr(self, f"handle_use_ease_{side}"), f"bbone_handle_use_ease_{side}", where, 1)[
                    0
                ],
            )
        for level in ("bone", "pose"):
            for what in ("ease", "roll"):
                for end in ("in", "out"):
                    key = f"{level}_{what}_{end}"
                    put(self, key, _number(getattr(self, key), f"bbone_{what}{end} ({level})", where))
            for end in ("in", "out"):
                for axis in ("x", "z"):
                    key = f"{level}_curve_{end}_{axis}"
                    put(self, key, _number(getattr(self, key), f"bbone_curve{end}{axis} ({level})", where))
                key = f"{level}_scale_{end}"
                put(self, key, _vector(getattr(self, key), f"bbone_scale{end} ({level})", where))
        for key in ("use_endroll_as_inroll", "use_scale_easing"):
            put(self, key, _flags(getattr(self, key), key, where, 1)[0])

    # -- derived -----------------------------------------------------------------------------------

    @property
    def handle_names(self) -> tuple[str | None, str | None]:
        """Names of the start and end handle bones whose posed matrices
        :func:`~solver.rig.bbone.deform_matrices` takes (``None`` where there is no handle, and both ``None``
        for a plain bone, ``segments == 1``)."""
        if self.segments == 1:
            return None, None
        return tuple(None if h is None else h.name for h in (self.start, self.end))  # type: ignore[return-value]

    @property
    def handle_parent_names(self) -> tuple[str | None, str | None]:
        """Names of the parents of the start and end handles whose posed matrices
        :func:`~solver.rig.bbone.deform_matrices` takes because a handle's own scale is read (``None`` where
        not)."""
        return tuple(
            h.parent if self.reads_handle_scale(side) else None  # type: ignore[return-value]
            for side, h in (("start", self.start), ("end", self.end))
        )

    def start_joins(self) -> bool:
        """Blender's ``prev_bbone``: an absolute start handle that is itself a B-Bone."""
        return (
            self.start is not None
            and self.handle_type_start in ("AUTO", "ABSOLUTE")
            and self.start.segments > 1
        )

    def end_joins(self) -> bool:
        """Blender's ``next_bbone``."""
        return self.end is not None and self.handle_type_end in ("AUTO", "ABSOLUTE") and self.end.segments > 1

    def reads_handle_scale(self, side: str) -> bool:
        """Whether the pose-time scale of a handle bone matters (``BBONE_HANDLE_SCALE_ANY``)."""
        handle = getattr(self, side)
        if self.segments == 1 or handle is None:
            return False
        if side == "start" and self.start_joins():  # Blender skips prev_mat and prev_scale then
            return False
        return any(getattr(self, f"handle_use_scale_{side}")) or getattr(self, f"handle_use_ease_{side}")

    def unsupported(self) -> str | None:
        """A sentence naming the option of this B-Bone that this module cannot reproduce exactly, or
        ``None`` when it can (then :func:`~solver.rig.bbone.deform_matrices` is exact)."""
        for side in ("start", "end"):
            if not self.reads_handle_scale(side):
                continue
            handle = getattr(self, side)
            if handle.parent is not None and (
                handle.inherit_scale != "FULL" or not handle.use_inherit_rotation
            ):
                how = (
                    "without Inherit Rotation"
                    if not handle.use_inherit_rotation
                    else f"with Inherit Scale {handle.inherit_scale!r}"
                )
                return (
                    f"B-Bone {self.name!r} reads the scale of its {side} handle {handle.name!r} "
                    f"(bbone_handle_use_scale_{side} / bbone_handle_use_ease_{side}), which inherits "
                    f"from its parent {handle.parent!r} {how}; only handles that inherit fully "
                    f"(Inherit Scale 'FULL' with Inherit Rotation) are modelled"
                )
        return None

    @cached_property
    def rest_joints(self) -> np.ndarray:
        """(segments + 1, 4, 4) Blender's ``bbone_rest_mats``."""
        return curve_joints(self, rest=True)

    @cached_property
    def unbend(self) -> np.ndarray:
        """(segments + 1, 4, 4) ``inv(rest[a]) @ inv(matrix_local)``: armature space to segment space."""
        return np.linalg.inv(self.rest_joints) @ np.linalg.inv(self.matrix_local)

    @cached_property
    def segment_boundaries(self):
        """The curved mapping's BSP planes (``compute_bbone_segment_boundaries``)."""
        arm, segs = self.matrix_local, self.segments
        points = self.rest_joints[:, :3, 3] @ arm[:3, :3].T + arm[:3, 3]
        normals = self.rest_joints[:, :3, 1] @ arm[:3, :3].T
        normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
        offsets = np.sum(points * normals, axis=1)
        arc_length = np.linalg.norm(np.diff(points, axis=0), axis=1).sum()
        bsp_depth = int(np.ceil(np.log2(segs + 2)))
        straight = np.linalg.norm(points[segs] - points[0])
        max_depth_scale = segs * (straight / arc_length) * 0.222
        scale_factor = max(max_depth_scale, 1.0) ** (1.0 / (bsp_depth - 1))
        depth_scale = np.full(segs + 2, np.nan)
        depth_scale[:bsp_depth] = segs / max_depth_scale * scale_factor ** np.arange(bsp_depth)
        return normals, offsets, 1.0 / arc_length, depth_scale
