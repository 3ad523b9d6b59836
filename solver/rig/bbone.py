"""Blender's B-Bones (Bendy Bones) as the Armature modifier deforms with them, exactly, in numpy.

A B-Bone is a deform bone with ``bbone_segments > 1``: Blender bends it along a cubic Bézier curve
whose handles come from neighbouring bones, and a vertex weighted to it follows two adjacent
*segment joints* of the curve instead of the bone's plain matrix. This module is a port of Blender's
``source/blender/blenkernel/intern/armature.cc`` as of a recent main (the curved mapping exists since
4.0), verified against bpy 5.0.1's Armature modifier and ``PoseBone.bbone_segment_matrix`` /
``bbone_segment_index``:

* ``BKE_pchan_bbone_handles_get``, ``BKE_pchan_bbone_spline_params_get``,
  ``BKE_pchan_bbone_handles_compute``, ``BKE_pchan_bbone_spline_compute`` (with
  ``equalize_cubic_bezier``, ``evaluate_cubic_bezier``, ``ease_handle_axis``,
  ``make_bbone_spline_matrix``) -> :func:`spline_matrices`;
* ``BKE_pchan_bbone_segments_cache_compute`` -> :func:`deform_matrices` (the ``bbone_deform_mats``),
  and :func:`stack_deform_matrices` for many bones at once (see "Stacks" below);
* ``BKE_pchan_bbone_deform_segment_index`` (``find_bbone_segment_index_straight`` / ``_curved``,
  ``compute_bbone_segment_boundaries``, ``BKE_pchan_bbone_deform_clamp_segment_index``) ->
  :func:`vertex_segments`;

and of ``armature_deform.cc`` (``b_bone_deform``, ``pchan_bone_deform``) for how they combine, plus the
math helpers they call (``vec_roll_to_mat3_normalized``, ``mat3_vec_to_roll``, ``mat3_to_quat``,
``quat_split_swing_and_twist``, ``cubic_tangent_factor_circle_v3``, ``mat4_to_size``,
``BKE_armature_mat_pose_to_bone``).

Conventions
-----------
* Everything is in the armature object's space. Matrices act on column vectors (``p' = M @ p``),
  ``matrix_local`` is Blender's ``Bone.matrix_local`` (rest), ``pose`` is ``PoseBone.matrix`` (posed).
* A bone's shape depends on its own posed matrix and on the posed matrices of its two *handle* bones
  (:attr:`BBone.start`, :attr:`BBone.end`; see :class:`BBone` for how Blender picks them), plus, when a
  ``bbone_handle_use_scale_*`` / ``bbone_handle_use_ease_*`` flag reads a handle's own scale, the posed
  matrix of that handle's parent bone. Everything else is a constant held by :class:`BBone`.

How a vertex is posed (Blender's Armature modifier, Preserve Volume off)
-------------------------------------------------------------------------
For a vertex with rest position ``co`` (armature space) and vertex-group weights ``w_b`` on deform bones
``b``, Blender forms

    ``posed = co + Σ_b w_b (A_b co - co) / Σ_b w_b``   when ``Σ_b w_b > 0.0001``, else ``co``,

(which is ``Σ_b w_b A_b co / Σ_b w_b``), where for each bone

    ``A_b = (1 - blend) M[index] + blend M[index + 1]``,

``M = deform_matrices(bbone_b, pose_b, ...)`` (``(..., segments + 1, 4, 4)``) and
``(index, blend) = vertex_segments(bbone_b, co)`` (constants of the rest pose, see
:func:`blend_segments`). For a bone with ``segments == 1`` Blender uses the plain
``pose @ inv(matrix_local)`` (its ``chan_mat``); :func:`deform_matrices` then returns that matrix twice
and :func:`vertex_segments` returns ``index 0, blend 0``, so the same formula holds for every bone.

Complex-step differentiation
----------------------------
:func:`deform_matrices`, :func:`stack_deform_matrices` and :func:`spline_matrices` accept float64 or
complex128 matrices with any leading batch dimensions and are analytic in them (see
:mod:`solver.rig.analytic`): branches are taken on real parts only. The stacked code applies the functions
numpy evaluates slowly on complex numbers (square roots, sines, logarithms, arc tangents) to the real
part and carries the derivative in the imaginary part, as :func:`solver.rig.analytic.atan2` does: exact for
complex-step arrays, whose imaginary parts are infinitesimal. One deliberate choice: Blender treats a
bone whose pose scale is non-uniform by more than 1e-6 in a separate "scaled" branch
(``param->do_scale``); both branches give the same value when the scale is uniform, and complex inputs
always take the scaled branch, whose derivative is the one Blender's function has under any
perturbation (the unscaled branch's derivative is wrong for perturbations that make the scale
non-uniform).

Stacks
------
The solver evaluates every B-Bone of a hand hundreds of times per solve, with derivatives. A
:class:`BBoneStack` (:func:`stacks` groups a rig's bones into few) holds bones whose discrete settings
agree (segments, handle types and kinds, use of the handles' scales; a bone missing a handle is masked),
with every constant of the rest pose precomputed; :func:`stack_deform_matrices` evaluates them all with
the branches taken once per stack. It gives what :func:`deform_matrices` gives bone by bone (which now
calls it with one bone; the first, bone-by-bone port stays as the reference of the tests), to 1e-13.

Complex-step arrays with many directions of one pose (real parts equal along the leading axes, as
:func:`solver.rig.analytic.directions` makes them) take a faster road: the per-bone state the curve is built
from (handles, length, rolls, scales: 12 numbers) is differentiated with respect to the pose entries it
reads, the curve is evaluated once with one complex-step direction per state variable, and the chain
rule is applied to the directions' imaginary parts in one matrix product per bone. The derivatives are
the complex-step ones, exact to rounding.

Limits
------
Blender computes in float32; this module computes in float64, so results agree to float32 rounding
(about 1e-6 relative). The one place where Blender's rounding is larger is the handle length of a
nearly straight curve: ``cubic_tangent_factor_circle_v3`` takes ``1 - cos(a)`` of a small float32 angle,
which is noisy to ~1e-4 relative there (not reproducible, and harmless: the curve is then almost
straight; it shows as ~1e-5 differences in segment rotations when the curve in/out offsets are set). A
handle scale read through a handle bone whose parent passes on its scale with
an Inherit Scale other than ``"FULL"``, or without Inherit Rotation, is not modelled: such a B-Bone's
:meth:`BBone.unsupported` says so, and the caller should refuse the rig rather than approximate it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..errors import SolverError
from . import analytic
from .math_rotation import axis_angle_normalized_to_mat3

__all__ = [
    "HANDLE_TYPES",
    "MAPPING_MODES",
    "MAX_SEGMENTS",
    "BBone",
    "BBoneHandle",
    "BBoneStack",
    "blend_segments",
    "deform_matrices",
    "spline_matrices",
    "stack_deform_matrices",
    "stacks",
    "vertex_segments",
]

#: Blender's ``Bone.bbone_handle_type_start`` / ``_end`` values.
HANDLE_TYPES = ("AUTO", "ABSOLUTE", "RELATIVE", "TANGENT")
#: Blender's ``Bone.bbone_mapping_mode`` values.
MAPPING_MODES = ("STRAIGHT", "CURVED")
#: Blender's ``Bone.inherit_scale`` values.
INHERIT_SCALE_MODES = ("FULL", "FIX_SHEAR", "ALIGNED", "AVERAGE", "NONE", "NONE_LEGACY")
#: Blender's ``MAX_BBONE_SUBDIV``: the most segments a B-Bone has, and the number of steps of the
#: polyline that measures the curve's length.
MAX_SEGMENTS = 32
#: Blender's threshold (``BKE_pchan_bbone_spline_params_get``) above which a pose scale is non-uniform.
UNIFORM_SCALE_EPSILON = 1e-6


# --------------------------------------------------------------------------------------------------
# The constants of a B-Bone


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
        """Names of the start and end handle bones whose posed matrices :func:`deform_matrices` takes
        (``None`` where there is no handle, and both ``None`` for a plain bone, ``segments == 1``)."""
        if self.segments == 1:
            return None, None
        return tuple(None if h is None else h.name for h in (self.start, self.end))  # type: ignore[return-value]

    @property
    def handle_parent_names(self) -> tuple[str | None, str | None]:
        """Names of the parents of the start and end handles whose posed matrices
        :func:`deform_matrices` takes because a handle's own scale is read (``None`` where not)."""
        return tuple(
            h.parent if self._reads_handle_scale(side) else None  # type: ignore[return-value]
            for side, h in (("start", self.start), ("end", self.end))
        )

    def _start_joins(self) -> bool:
        """Blender's ``prev_bbone``: an absolute start handle that is itself a B-Bone."""
        return (
            self.start is not None
            and self.handle_type_start in ("AUTO", "ABSOLUTE")
            and self.start.segments > 1
        )

    def _end_joins(self) -> bool:
        """Blender's ``next_bbone``."""
        return self.end is not None and self.handle_type_end in ("AUTO", "ABSOLUTE") and self.end.segments > 1

    def _reads_handle_scale(self, side: str) -> bool:
        """Whether the pose-time scale of a handle bone matters (``BBONE_HANDLE_SCALE_ANY``)."""
        handle = getattr(self, side)
        if self.segments == 1 or handle is None:
            return False
        if side == "start" and self._start_joins():  # Blender skips prev_mat and prev_scale then
            return False
        return any(getattr(self, f"handle_use_scale_{side}")) or getattr(self, f"handle_use_ease_{side}")

    def unsupported(self) -> str | None:
        """A sentence naming the option of this B-Bone that this module cannot reproduce exactly, or
        ``None`` when it can (then :func:`deform_matrices` is exact)."""
        for side in ("start", "end"):
            if not self._reads_handle_scale(side):
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
    def _rest(self) -> np.ndarray:
        """(segments + 1, 4, 4) Blender's ``bbone_rest_mats``."""
        return _spline(self, rest=True)

    @cached_property
    def _stack(self) -> BBoneStack:
        """The one-bone :class:`BBoneStack` :func:`deform_matrices` evaluates."""
        return BBoneStack.of([self])

    @cached_property
    def _unbend(self) -> np.ndarray:
        """(segments + 1, 4, 4) ``inv(rest[a]) @ inv(matrix_local)``: armature space to segment space."""
        return np.linalg.inv(self._rest) @ np.linalg.inv(self.matrix_local)

    @cached_property
    def _boundaries(self):
        """The curved mapping's BSP planes (``compute_bbone_segment_boundaries``)."""
        arm, segs = self.matrix_local, self.segments
        points = self._rest[:, :3, 3] @ arm[:3, :3].T + arm[:3, 3]
        normals = self._rest[:, :3, 1] @ arm[:3, :3].T
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


# --------------------------------------------------------------------------------------------------
# Math helpers (Blender's BLI), analytic in complex-step inputs


def _normalize(v, eps: float = 1e-35):
    """Blender's ``normalize_v3``: (unit vector, length); a vector with ``|v|² <= 1e-35`` becomes zero."""
    d2 = np.sum(v * v, axis=-1)
    ok = d2.real > eps
    d = np.sqrt(np.where(ok, d2, 1.0))
    unit = np.where(ok[..., None], v / d[..., None], 0.0)
    return unit, np.where(ok, d, 0.0)


def _vec_roll_to_mat3(vec, roll):
    """(..., 3, 3) ``vec_roll_to_mat3``: the rotation taking +y to ``vec``'s direction, then rolled."""
    nor, _ = _normalize(vec)
    x, y, z = nor[..., 0], nor[..., 1], nor[..., 2]
    safe, critical = 6.1e-3, 2.5e-4
    theta = 1 + y
    theta_alt = x * x + z * z
    regular = (theta.real > safe) | (theta_alt.real > critical * critical)
    theta = np.where(theta.real <= safe, theta_alt * 0.5 + theta_alt * theta_alt * 0.125, theta)
    theta = np.where(regular, theta, 1.0)
    B = np.zeros((*nor.shape[:-1], 3, 3), dtype=nor.dtype)
    B[..., 1, 0], B[..., 0, 1] = -x, x
    B[..., 1, 1], B[..., 2, 1], B[..., 1, 2] = y, z, -z
    B[..., 0, 0] = 1 - x * x / theta
    B[..., 2, 2] = 1 - z * z / theta
    B[..., 0, 2] = B[..., 2, 0] = -x * z / theta
    B = np.where(regular[..., None, None], B, np.diag([-1.0, -1.0, 1.0]))
    return axis_angle_normalized_to_mat3(nor, np.sin(roll), np.cos(roll)) @ B


def _twist_y(M):
    """``quat_split_swing_and_twist(mat3_to_quat(M), 1)``: the twist angle of M about its y axis."""
    cols = analytic.norm(M, axis=-2)
    M = np.where((cols.real > 0)[..., None, :], M / np.where(cols.real > 0, cols, 1.0)[..., None, :], M)
    det = np.linalg.det(M)
    M = np.where(~np.isfinite(det.real)[..., None, None], np.eye(3), M)
    M = np.where((det.real < 0)[..., None, None], -M, M)
    m = {(r, c): M[..., r, c] for r in range(3) for c in range(3)}

    def branch(trace, flip):
        trace = np.where(trace.real > 0, trace, 1.0)
        s = 2 * np.sqrt(trace)
        return np.where(flip, -s, s)

    # mat3_normalized_to_quat_fast, keeping (w, y) up to one positive factor.
    sx = branch(1 + m[0, 0] - m[1, 1] - m[2, 2], m[2, 1].real < m[1, 2].real)
    sy = branch(1 - m[0, 0] + m[1, 1] - m[2, 2], m[0, 2].real < m[2, 0].real)
    sz = branch(1 - m[0, 0] - m[1, 1] + m[2, 2], m[1, 0].real < m[0, 1].real)
    sw = branch(1 + m[0, 0] + m[1, 1] + m[2, 2], np.zeros(sx.shape, bool))
    candidates = [
        ((m[2, 1] - m[1, 2]) / sx, (m[1, 0] + m[0, 1]) / sx),
        ((m[0, 2] - m[2, 0]) / sy, sy / 4),
        ((m[1, 0] - m[0, 1]) / sz, (m[2, 1] + m[1, 2]) / sz),
        (sw / 4, (m[0, 2] - m[2, 0]) / sw),
    ]
    negative_z = m[2, 2].real < 0
    pick = np.where(
        negative_z, np.where(m[0, 0].real > m[1, 1].real, 0, 1), np.where(m[0, 0].real < -m[1, 1].real, 2, 3)
    )
    w = np.choose(pick, [c[0] for c in candidates])
    y = np.choose(pick, [c[1] for c in candidates])
    flip = w.real < 0
    return 2 * analytic.atan2(np.where(flip, -y, y), np.where(flip, -w, w))


def _mat3_vec_to_roll(mat, vec):
    """``mat3_vec_to_roll``: the roll that, with ``vec``, gives the orientation closest to ``mat``."""
    vecmat = _vec_roll_to_mat3(vec, np.zeros(vec.shape[:-1]))
    return _twist_y(np.linalg.inv(vecmat) @ mat)


def _circle_factor(t1, t2):
    """``cubic_tangent_factor_circle_v3`` for unit tangents, in the closed form
    ``1 / (2 (1 + cos(acos(t1·t2) / 2)))`` of Blender's ``(1 - cos a) / (2 sin² a)``."""
    d = np.sum(t1 * t2, axis=-1)
    eps = 1e-5
    inside = (d.real <= 1 - eps) & (d.real >= -1 + eps)
    c = np.sqrt((1 + np.where(inside, d, 0.0)) / 2)
    value = 1 / (2 * (1 + c))
    return np.where(inside, value, np.where(d.real > 1 - eps, 0.25, 0.5))


def _apply(M, p):
    """Affine matrices (..., 4, 4) applied to points (..., 3)."""
    return np.einsum("...ij,...j->...i", M[..., :3, :3], p) + M[..., :3, 3]


def _handle_scale(handle: BBoneHandle, pose, parent_pose):
    """(..., 3) ``mat4_to_size(BKE_armature_mat_pose_to_bone(handle, handle.pose_mat))`` for a handle
    whose parent (if any) it inherits fully: the column lengths of ``inv(rotscale) @ pose``."""
    rotscale = (
        handle.matrix_local[:3, :3]
        if handle.parent is None
        else (parent_pose[..., :3, :3] @ handle.parent_offset[:3, :3])
    )
    return analytic.norm(np.linalg.inv(rotscale) @ pose[..., :3, :3], axis=-2)


# --------------------------------------------------------------------------------------------------
# The curve


def _check_pose(what: str, bb: BBone, value):
    if value is None:
        raise SolverError(f"B-Bone {bb.name!r} needs the posed matrix of {what}")
    M = np.asarray(value)
    if M.shape[-2:] != (4, 4):
        raise SolverError(
            f"B-Bone {bb.name!r}: the posed matrix of {what} must have shape (..., 4, 4), got {M.shape}"
        )
    if not np.issubdtype(M.dtype, np.number) or not np.all(np.isfinite(M)):
        raise SolverError(f"B-Bone {bb.name!r}: the posed matrix of {what} must be finite")
    return M if np.iscomplexobj(M) else M.astype(np.float64)


def _inputs(bb: BBone, pose, prev_pose, next_pose, prev_parent_pose, next_parent_pose):
    """The matrices the curve needs, checked and broadcast to one batch shape (None where not needed)."""
    need = {"pose": pose}
    names = {"pose": f"the bone {bb.name!r}"}
    if bb.start is not None:
        need["prev"], names["prev"] = prev_pose, f"its start handle {bb.start.name!r}"
    if bb.end is not None:
        need["next"], names["next"] = next_pose, f"its end handle {bb.end.name!r}"
    for side, key, value in (
        ("start", "prev_parent", prev_parent_pose),
        ("end", "next_parent", next_parent_pose),
    ):
        handle = getattr(bb, side)
        if bb._reads_handle_scale(side) and handle.parent is not None:
            need[key] = value
            names[key] = f"{handle.parent!r}, the parent of its {side} handle {handle.name!r}"
    mats = {k: _check_pose(names[k], bb, v) for k, v in need.items()}
    batch = np.broadcast_shapes(*(m.shape[:-2] for m in mats.values()))
    return {k: np.broadcast_to(m, (*batch, 4, 4)) for k, m in mats.items()}, batch


def _spline(bb: BBone, rest: bool, mats=None, batch=()):
    """(..., segments + 1, 4, 4) the segment joint matrices in bone space (``BKE_pchan_bbone_spline_setup``
    with ``for_deform``): Blender's ``bbone_rest_mats`` (``rest``) or ``bbone_pose_mats``."""
    segs, L = bb.segments, bb.length
    start, end = bb.start, bb.end
    dtype = np.result_type(*(mats.values() if mats else ()), np.float64)
    one = np.ones(batch)

    # BKE_pchan_bbone_spline_params_get
    if rest:
        sc = np.ones((*batch, 3))
        imat = np.linalg.inv(bb.matrix_local)
        head, tail = bb.head_local, bb.tail_local
    else:
        P = mats["pose"]
        scale = analytic.norm(P[..., :3, :3], axis=-2)
        if np.iscomplexobj(P):
            do_scale = np.ones(batch, bool)
        else:
            do_scale = (np.abs(scale[..., 0] - scale[..., 1]) > UNIFORM_SCALE_EPSILON) | (
                np.abs(scale[..., 1] - scale[..., 2]) > UNIFORM_SCALE_EPSILON
            )
        sc = np.where(do_scale[..., None], scale, 1.0)
        unscaled = P.astype(dtype, copy=True)
        unscaled[..., :3, :3] = P[..., :3, :3] / sc[..., None, :]
        imat = np.linalg.inv(unscaled)
        head = P[..., :3, 3]
        tail = head + P[..., :3, 1] * L

    def posed(key, handle):
        M = mats[key]
        h = M[..., :3, 3]
        return M, h, h + M[..., :3, 1] * handle.length

    prev_joins, next_joins = bb._start_joins(), bb._end_joins()
    prev_scale = np.ones((*batch, 3))
    next_scale = np.ones((*batch, 3))
    prev_h = prev_mat = next_h = next_mat = None
    if start is not None:
        kind = bb.handle_type_start
        if not rest:
            Pp, pp_head, pp_tail = posed("prev", start)
        if kind == "RELATIVE":
            prev_h = np.zeros((*batch, 3)) if rest else _apply(imat, head - (pp_head - start.head_local))
        elif kind == "TANGENT":
            h1 = bb.head_local - (start.tail_local - start.head_local) if rest else head - (pp_tail - pp_head)
            prev_h = _apply(imat, h1)
        else:
            prev_h = _apply(imat, start.head_local if rest else pp_head)
        if not prev_joins:
            prev_mat = imat[..., :3, :3] @ (start.matrix_local if rest else Pp)[..., :3, :3]
            if not rest and bb._reads_handle_scale("start"):
                prev_scale = _handle_scale(start, Pp, mats.get("prev_parent"))
    if end is not None:
        kind = bb.handle_type_end
        if not rest:
            Pn, pn_head, pn_tail = posed("next", end)
        if kind == "RELATIVE":
            next_h = (
                np.broadcast_to(np.array([0.0, L, 0.0]), (*batch, 3))
                if rest
                else _apply(imat, tail + (pn_head - end.head_local))
            )
        elif kind == "TANGENT":
            h2 = bb.tail_local + (end.tail_local - end.head_local) if rest else tail + (pn_tail - pn_head)
            next_h = _apply(imat, h2)
        else:
            next_h = _apply(imat, end.tail_local if rest else pn_tail)
        next_mat = imat[..., :3, :3] @ (end.matrix_local if rest else Pn)[..., :3, :3]
        if not rest and bb._reads_handle_scale("end"):
            next_scale = _handle_scale(end, Pn, mats.get("next_parent"))

    pose_level = 0.0 if rest else 1.0
    ease1 = (bb.bone_ease_in + pose_level * bb.pose_ease_in) * one
    ease2 = (bb.bone_ease_out + pose_level * bb.pose_ease_out) * one
    roll1 = bb.bone_roll_in + pose_level * bb.pose_roll_in
    roll2 = bb.bone_roll_out + pose_level * bb.pose_roll_out
    if bb.use_endroll_as_inroll and start is not None:
        roll1 += start.bone_roll_out + pose_level * start.pose_roll_out
    scale_in = bb.bone_scale_in * (1.0 if rest else bb.pose_scale_in) * one[..., None]
    scale_out = bb.bone_scale_out * (1.0 if rest else bb.pose_scale_out) * one[..., None]
    curve_in = (
        np.array([bb.bone_curve_in_x, bb.bone_curve_in_z])
        + pose_level * np.array([bb.pose_curve_in_x, bb.pose_curve_in_z]) * one[..., None]
    )
    curve_out = (
        np.array([bb.bone_curve_out_x, bb.bone_curve_out_z])
        + pose_level * np.array([bb.pose_curve_out_x, bb.pose_curve_out_z]) * one[..., None]
    )
    if bb.use_scale_easing:
        ease1 = ease1 * scale_in[..., 1]
        curve_in = curve_in * scale_in[..., 1:2]
        ease2 = ease2 * scale_out[..., 1]
        curve_out = curve_out * scale_out[..., 1:2]
    use = np.array(bb.handle_use_scale_start, float)
    scale_in = scale_in * (use * prev_scale + (1 - use))
    if bb.handle_use_ease_start:
        ease1 = ease1 * prev_scale[..., 1]
        curve_in = curve_in * prev_scale[..., 1:2]
    use = np.array(bb.handle_use_scale_end, float)
    scale_out = scale_out * (use * next_scale + (1 - use))
    if bb.handle_use_ease_end:
        ease2 = ease2 * next_scale[..., 1]
        curve_out = curve_out * next_scale[..., 1:2]

    # BKE_pchan_bbone_handles_compute (ease and offsets)
    length = L * sc[..., 1]
    epsilon = 1e-5 * L
    r1 = r2 = 0.0
    y_axis = np.broadcast_to(np.array([0.0, 1.0, 0.0]), (*batch, 3))
    if start is not None:
        h1 = prev_h.astype(dtype, copy=True)
        if prev_joins:
            h1[..., 1] -= length
        h1, n = _normalize(h1)
        h1 = -np.where((n.real < epsilon)[..., None], -y_axis, h1)
        if not prev_joins:
            r1 = _mat3_vec_to_roll(prev_mat, h1)
    else:
        h1 = y_axis
    if end is not None:
        h2 = next_h.astype(dtype, copy=True)
        if not next_joins:
            h2[..., 1] -= length
        h2, n = _normalize(h2)
        h2 = np.where((n.real < epsilon)[..., None], y_axis, h2)
        r2 = _mat3_vec_to_roll(next_mat, h2)
    else:
        h2 = y_axis
    circle = length * _circle_factor(h1, h2) / 0.75
    h1 = h1 * (ease1 * circle)[..., None]
    h2 = h2 * (-ease2 * circle)[..., None]
    roll1 = r1 + roll1 * one
    roll2 = r2 + roll2 * one
    h1 = h1 + np.stack([curve_in[..., 0] * sc[..., 0], 0 * one, curve_in[..., 1] * sc[..., 2]], axis=-1)
    h2 = h2 + np.stack([curve_out[..., 0] * sc[..., 0], 0 * one, curve_out[..., 1] * sc[..., 2]], axis=-1)

    # BKE_pchan_bbone_spline_compute (for_deform)
    c3 = np.stack([0 * length, length, 0 * length], axis=-1)
    controls = np.stack([np.zeros_like(c3), h1 * one[..., None], c3 + h2, c3], axis=-2)  # (..., 4, 3)
    log_in = np.log(np.where(scale_in[..., 1].real < 1e-4, 1e-4, scale_in[..., 1]))
    log_out = np.log(np.where(scale_out[..., 1].real < 1e-4, 1e-4, scale_out[..., 1]))
    fac = np.arange(segs) / (segs - 1)
    segment_scales = np.exp(fac * log_out[..., None] + (1 - fac) * log_in[..., None])
    t = _equalize(controls, segment_scales)

    deriv1 = np.diff(controls, axis=-2)
    deriv2 = np.diff(deriv1, axis=-2)
    first = _ease_axis(deriv1[..., 0, :], deriv2[..., 0, :])
    last = _ease_axis(deriv1[..., 2, :], -deriv2[..., 1, :])
    pos, tangent = _bezier(controls, t[..., 1:segs])
    pos = np.concatenate([controls[..., :1, :], pos, controls[..., 3:, :]], axis=-2)
    axis = np.concatenate([first[..., None, :], tangent, last[..., None, :]], axis=-2)
    f = np.arange(segs + 1) / segs
    roll = f * roll2[..., None] + (1 - f) * roll1[..., None]
    scale_x = f * scale_out[..., 0:1] + (1 - f) * scale_in[..., 0:1]
    scale_z = f * scale_out[..., 2:3] + (1 - f) * scale_in[..., 2:3]

    # make_bbone_spline_matrix
    R = _vec_roll_to_mat3(axis, roll)
    out = np.zeros((*R.shape[:-2], 4, 4), dtype=np.result_type(R, pos))
    out[..., :3, :3] = R / sc[..., None, :, None] * sc[..., None, None, :]  # S^-1 R S
    out[..., :3, 3] = pos / sc[..., None, :]
    out[..., 3, 3] = 1.0
    out[..., :, 0] *= scale_x[..., None]
    out[..., :, 2] *= scale_z[..., None]
    return out


def _bezier(controls, t):
    """``evaluate_cubic_bezier`` at parameters t (..., k): positions and (unnormalized) tangents."""
    t = t[..., None]
    c = [controls[..., None, i, :] for i in range(4)]
    a = [c[i] + t * (c[i + 1] - c[i]) for i in range(3)]
    b = [a[i] + t * (a[i + 1] - a[i]) for i in range(2)]
    tangent = b[1] - b[0]
    return b[0] + tangent * t, tangent


def _ease_axis(d1, d2):
    """``ease_handle_axis``: fade from the first to the second derivative when the handle is short."""
    gap = 0.1
    len2 = np.sum(d2 * d2, axis=-1)
    len1 = np.sum(d1 * d1, axis=-1)
    nonzero = len2.real != 0
    ratio = len1 / np.where(nonzero, len2, 1.0)
    use = nonzero & (ratio.real < gap * gap)
    root = np.sqrt(np.where(use & (ratio.real > 0), ratio, 1.0))
    root = np.where(use & (ratio.real > 0), root, 0.0)
    return d1 + np.where(use[..., None], d2 * (gap - root)[..., None], 0.0)


def _equalize(controls, segment_scales):
    """(..., segments + 1) ``equalize_cubic_bezier``: Bézier parameters of points spaced along the
    curve's length (measured on a 32-step polyline) in proportion to the segment scales."""
    temp = MAX_SEGMENTS
    segs = segment_scales.shape[-1]
    coords, _ = _bezier(controls, np.arange(temp + 1) / temp)
    pdist = np.concatenate(
        [
            np.zeros((*coords.shape[:-2], 1)),
            np.cumsum(analytic.norm(np.diff(coords, axis=-2), axis=-1), axis=-1),
        ],
        axis=-1,
    )
    step = pdist[..., -1] / np.sum(segment_scales, axis=-1)
    dist = np.cumsum(segment_scales * step[..., None], axis=-1)  # (..., segs): dist at points 1..segs
    nr = 1 + np.sum(pdist[..., None, 1:temp].real <= dist[..., :, None].real, axis=-1)
    upper = np.take_along_axis(pdist, nr, axis=-1)
    lower = np.take_along_axis(pdist, nr - 1, axis=-1)
    fac = (upper - dist) / (upper - lower)
    t = (nr - fac) / temp
    zeros = np.zeros((*t.shape[:-1], 1), dtype=t.dtype)
    return np.concatenate([zeros, t[..., : segs - 1], zeros + 1.0], axis=-1)


# --------------------------------------------------------------------------------------------------
# Stacks: many B-Bones at once
#
# The same math as ``_spline`` for a stack of g bones whose discrete settings agree: every branch on a
# setting is taken once per stack, every constant of the rest pose is computed once, and the arrays are
# laid out component first, bone last -- vectors (3, L, g), matrices (3, 3, L, g), per joint (3, a, L,
# g) with a = segments + 1 and L the flattened leading dimensions -- so that numpy works on long
# contiguous runs (it is slow on short trailing axes). Functions that numpy evaluates slowly on complex
# numbers (sqrt, sin, cos, exp, log) are applied to the real part with the derivative carried in the
# imaginary part, as analytic.atan2 does: exact for complex-step arrays.

_Y_AXIS = np.array([0.0, 1.0, 0.0])
# Bézier weights of (h1, h2, c3) in the curve's point (columns 0-2) and tangent (3-5) at parameter t,
# as polynomials in (1, t, t², t³); the curve's controls are 0, h1, c3 + h2, c3 = (0, length, 0).
_BEZIER = np.array(
    [
        [0.0, 0.0, 0.0, 1.0, 0.0, 0.0],
        [3.0, 0.0, 0.0, -4.0, 2.0, 2.0],
        [-6.0, 3.0, 3.0, 3.0, -3.0, -2.0],
        [3.0, -3.0, -2.0, 0.0, 0.0, 0.0],
    ]
)
# The steps of the 32-step polyline that measures the curve's length, as weights of (h1, h2, c3).
_STEPS = np.arange(MAX_SEGMENTS + 1) / MAX_SEGMENTS
_POLYLINE = np.diff(np.stack([_STEPS**0, _STEPS, _STEPS**2, _STEPS**3], -1) @ _BEZIER[:, :3], axis=0)
# ease_handle_axis at the ends: the first derivative at the start and end, then the second ones, as
# weights of (h1, h2, c3); and what a unit of easing adds to the tangent weights there.
_END_DERIVATIVES = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [-2.0, 1.0, 1.0], [-1.0, 2.0, 1.0]])
_EASE_TANGENT = np.array([[-2.0, 1.0, 1.0], [-1.0, 2.0, 1.0]])
_STEPS_AND_ENDS = np.concatenate([_POLYLINE, _END_DERIVATIVES])
# mat3_normalized_to_quat_fast's four branches (x, y, z, w), each giving the quaternion's (w, y) up to
# a common factor as an affine function of the matrix entries m[3 r + c]: rows w of the four branches,
# then y of the same.
_TWIST = np.zeros((8, 9))
for _row, _terms in enumerate(
    [
        {7: 1, 5: -1},
        {2: 1, 6: -1},
        {3: 1, 1: -1},
        {0: 1, 4: 1, 8: 1},
        {3: 1, 1: 1},
        {0: -1, 4: 1, 8: -1},
        {7: 1, 5: 1},
        {2: 1, 6: -1},
    ]
):
    for _entry, _sign in _terms.items():
        _TWIST[_row, _entry] = _sign
del _row, _terms, _entry, _sign
_TWIST_CONSTANT = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0])[:, None]
# Cofactors of a 3x3 block of a flattened 4x4 matrix: C[i, j] = A[i+1, j+1] A[i+2, j+2] - A[i+1, j+2]
# A[i+2, j+1] (indices mod 3), as four gathers of the 16 entries.
_COFACTOR = np.array(
    [
        [4 * ((i + a) % 3) + (j + b) % 3 for i in range(3) for j in range(3)]
        for a, b in ((1, 1), (2, 2), (1, 2), (2, 1))
    ]
)
# The same for the first row of a flattened 3x3 (entries 3 r + c): its determinant is
# Σ_j A[0, j] (F[0] F[1] - F[2] F[3])[j].
_DET3 = np.array([[3 * a + (j + b) % 3 for j in range(3)] for a, b in ((1, 1), (2, 2), (1, 2), (2, 1))])
_FRAME = np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 1.0]])[:, :, None, None, None]
_SIGNS = np.array([-1.0, 1.0])[:, None, None, None]


def _complex(real, imag):
    """real + i imag (numpy's complex multiplication of a real array by 1j is slow)."""
    out = np.empty(np.broadcast_shapes(real.shape, imag.shape), np.complex128)
    out.real = real
    out.imag = imag
    return out


def _real(x, shared: bool):
    """The real part of x, or when ``shared`` of its first entry along axis -2, the direction axis of
    a complex-step array whose entries there all have the same real part."""
    return x.real[..., :1, :] if shared else x.real


def _sqrt(x, shared: bool = False):
    if not np.iscomplexobj(x):
        return np.sqrt(x)
    root = np.sqrt(_real(x, shared))
    return _complex(root, x.imag * (0.5 / root))


def _rsqrt(x, shared: bool = False):
    """1 / sqrt(x)."""
    if not np.iscomplexobj(x):
        return 1.0 / np.sqrt(x)
    inv = 1.0 / np.sqrt(_real(x, shared))
    return _complex(inv, x.imag * (-0.5 * inv * inv * inv))


def _exp(x):
    if not np.iscomplexobj(x):
        return np.exp(x)
    e = np.exp(x.real)
    return _complex(e, e * x.imag)


def _log(x):
    if not np.iscomplexobj(x):
        return np.log(x)
    return _complex(np.log(x.real), x.imag / x.real)


def _cos_sin(x, shared: bool = False):
    """(2, ...) cos x and sin x."""
    r = _real(x, shared)
    cs = np.stack([np.cos(r), np.sin(r)])
    if not np.iscomplexobj(x):
        return cs
    return _complex(cs, cs[::-1] * x.imag * _SIGNS.reshape(2, *(1,) * x.ndim))


def _mm(A, B):
    """Component-first matrix products: (n, k, ...) @ (k, m, ...) -> (n, m, ...)."""
    if A.size * B.shape[1] <= 4096:
        return (A[:, :, None] * B[None]).sum(1)
    out = A[:, 0, None] * B[0]
    for j in range(1, A.shape[1]):
        out += A[:, j, None] * B[j]
    return out


def _inv3(P):
    """(3, 3, ...) the inverse of the 3x3 blocks of component-first 4x4 matrices (4, 4, ...)."""
    F = P.reshape(16, *P.shape[2:])[_COFACTOR]
    C = (F[0] * F[1] - F[2] * F[3]).reshape(3, 3, *P.shape[2:])
    det = (P[0, :3] * C[0]).sum(0)
    return C.swapaxes(0, 1) / det


def _frame_columns(n):
    """The x and z columns (3, 2, ...) of ``vec_roll_to_mat3(n, 0)`` for unit vectors n (3, ...) (its y
    column is n), or None when some n takes Blender's branches for n near -y: the caller then falls back
    on ``_vec_roll_to_mat3``."""
    theta = 1.0 + n[1]
    if theta.real.min() <= 6.1e-3:
        return None
    ratio = n[::2] / theta  # (x, z) / theta
    stretched = n + _Y_AXIS.reshape(3, *(1,) * (n.ndim - 1))  # (x, theta, z)
    frame = _FRAME.reshape(3, 2, *(1,) * (n.ndim - 1))
    return frame - stretched[:, None] * ratio[None]


def _twist(M, shared: bool = False):
    """(...) ``_twist_y`` of component-first (3, 3, ...): the twist about y of ``mat3_to_quat(M)``. Each
    branch of ``mat3_normalized_to_quat_fast`` gives the quaternion's (w, y) up to a common factor, and
    the twist ``2 atan2(y, w)`` with w made positive is ``2 atan(y / w)``. ``shared`` as for
    :func:`_real`."""
    shape = M.shape[2:]
    cn2 = (M * M).sum(0)
    if _real(cn2, shared).min() > 0:
        M = M * _rsqrt(cn2, shared)
    else:
        ok = cn2.real > 0
        M = M * np.where(ok, _rsqrt(np.where(ok, cn2, 1.0)), 1.0)
    m = _real(M, shared)
    F = m.reshape(9, *m.shape[2:])[_DET3]
    det = (m[0] * (F[0] * F[1] - F[2] * F[3])).sum(0)
    if det.min() < 0:
        M = np.where(det < 0, -M, M)
        m = _real(M, shared)
    pick = np.where(m[2, 2] < 0, np.where(m[0, 0] > m[1, 1], 0, 1), np.where(m[0, 0] < -m[1, 1], 2, 3))
    pick = np.broadcast_to(pick, shape).reshape(-1)
    wy = _TWIST @ M.reshape(9, -1) + _TWIST_CONSTANT  # (8, n)
    column = np.arange(pick.size)
    ratio = (wy[pick + 4, column] / wy[pick, column]).reshape(shape)
    if not np.iscomplexobj(ratio):
        return 2.0 * np.arctan(ratio)
    r = _real(ratio, shared)
    return _complex(2.0 * np.arctan(r), ratio.imag * (2.0 / (1.0 + r * r)))


class _Side:
    """The handles at one end (start or end) of the bones of a stack; arrays over the stack axis."""

    def __init__(self, side: str, bbones, key):
        self.side = side
        self.kind, self.joins, self.reads_scale, self.has_parent = key
        handles = [getattr(bb, side) if _side_key(bb, side) is not None else None for bb in bbones]
        self.present = np.array([h is not None for h in handles])
        self.absent = np.flatnonzero(~self.present)
        self.partial = not self.present.all()
        self.names = tuple(None if h is None else h.name for h in handles)
        self.parent_names = tuple(h.parent if h is not None and self.has_parent else None for h in handles)
        some = next(h for h in handles if h is not None)
        handles = [some if h is None else h for h in handles]  # stand-ins, masked out
        self.head_local = np.array([h.head_local for h in handles]).T[:, None]  # (3, 1, g)
        self.length = np.array([h.length for h in handles])
        if self.reads_scale:
            self.use_scale = (
                np.array([getattr(bb, f"handle_use_scale_{side}") for bb in bbones], float).T * self.present
            )[:, None]  # (3, 1, g)
            self.use_ease = np.array([getattr(bb, f"handle_use_ease_{side}") for bb in bbones], float)
            self.use_ease = self.use_ease * self.present
            # inv(rotscale) = inv(parent_offset) inv(parent_pose), or inv(matrix_local)
            self.rest_inverse = np.moveaxis(
                np.array(
                    [
                        np.linalg.inv((h.parent_offset if self.has_parent else h.matrix_local)[:3, :3])
                        for h in handles
                    ]
                ),
                0,
                -1,
            )[:, :, None]  # (3, 3, 1, g)


def _side_key(bb: BBone, side: str):
    """The discrete settings of one end of a B-Bone that the curve's math branches on (None: no handle):
    (handle type, the handle is a B-Bone the curve joins, its scale is read, its parent is needed)."""
    handle = getattr(bb, side)
    if bb.segments == 1 or handle is None:
        return None
    joins = bb._start_joins() if side == "start" else bb._end_joins()
    reads = bb._reads_handle_scale(side)
    return (getattr(bb, f"handle_type_{side}"), joins, reads, reads and handle.parent is not None)


def _stack_keys(bbones) -> tuple[int, object, object] | None:
    """The common (segments, start key, end key) of B-Bones that can share a stack, or None. A bone
    without a handle at one end fits a stack whose other bones have one there (it is masked out)."""
    segments = {bb.segments for bb in bbones}
    if len(segments) != 1:
        return None
    keys = []
    for side in ("start", "end"):
        found = {_side_key(bb, side) for bb in bbones} - {None}
        if len(found) > 1:
            return None
        keys.append(found.pop() if found else None)
    return segments.pop(), keys[0], keys[1]


class BBoneStack:
    """B-Bones that :func:`stack_deform_matrices` evaluates together.

    They have the same ``segments`` and, at each end, the same handle type, the same kind of handle (a
    B-Bone the curve joins, or not) and the same use of the handle's scale (``bbone_handle_use_scale_*``
    / ``bbone_handle_use_ease_*`` on or off, the handle having a parent or not), among the bones that
    have a handle there; a bone without a handle at an end is masked out of that end's math. Every other
    setting (rest matrices, lengths, ease, roll, curve, scale, the handles' rest data, ``mapping_mode``)
    may differ from bone to bone. Build with :meth:`of` or :func:`stacks`.

    Attributes
    ----------
    bbones : tuple of BBone
        The bones, in the order of the stack axis ``g`` of :func:`stack_deform_matrices`.
    segments : int
        Their ``bbone_segments``.
    """

    def __init__(self, bbones, keys):
        self.bbones = tuple(bbones)
        self.segments, start_key, end_key = keys
        self._templates: dict = {}
        s = self.segments
        if s == 1:
            self._inverse_rest = np.array([np.linalg.inv(bb.matrix_local) for bb in self.bbones])
            self._start = self._end = None
            return
        self._start = None if start_key is None else _Side("start", self.bbones, start_key)
        self._end = None if end_key is None else _Side("end", self.bbones, end_key)
        self._sides = sides = [x for x in (self._start, self._end) if x is not None]
        self._length = np.array([bb.length for bb in self.bbones])
        self._eps2 = (1e-5 * self._length) ** 2
        self._partial = any(x.partial for x in sides)
        if sides:
            self._present = np.stack([x.present for x in sides])[:, None]  # (sides, 1, g)
            # Blender shortens a handle by the bone's length unless it is a joined start or a joined end
            self._offset = np.array([float(x.joins if x.side == "start" else not x.joins) for x in sides])
            self._offset = self._offset[:, None, None]
            self._sign = np.array([-1.0 if x.side == "start" else 1.0 for x in sides])[:, None, None]
        self._rolled = [x for x in sides if not (x.side == "start" and x.joins)]
        # the entries (4 r + c, top three rows) of each posed matrix the curve depends on
        every, rotation, head = np.arange(12), np.array([0, 1, 2, 4, 5, 6, 8, 9, 10]), np.array([3, 7, 11])
        self._entries = [every]
        for x in (self._start, self._end):
            if x is None:
                self._entries.append(None)
            elif x.side == "start" and x.joins:
                self._entries.append(head)
            else:
                self._entries.append(rotation if x.kind == "TANGENT" else every)
        self._entries += [rotation, rotation]
        # BKE_pchan_bbone_spline_params_get's constants, bone and pose levels combined
        ease, roll, curve, scale_in, scale_out = [], [], [], [], []
        for bb in self.bbones:
            e = [bb.bone_ease_in + bb.pose_ease_in, bb.bone_ease_out + bb.pose_ease_out]
            r = [bb.bone_roll_in + bb.pose_roll_in, bb.bone_roll_out + bb.pose_roll_out]
            if bb.use_endroll_as_inroll and bb.start is not None:
                r[0] += bb.start.bone_roll_out + bb.start.pose_roll_out
            c = np.array(
                [
                    [bb.bone_curve_in_x + bb.pose_curve_in_x, 0.0, bb.bone_curve_in_z + bb.pose_curve_in_z],
                    [
                        bb.bone_curve_out_x + bb.pose_curve_out_x,
                        0.0,
                        bb.bone_curve_out_z + bb.pose_curve_out_z,
                    ],
                ]
            )
            si, so = bb.bone_scale_in * bb.pose_scale_in, bb.bone_scale_out * bb.pose_scale_out
            if bb.use_scale_easing:
                e = [e[0] * si[1], e[1] * so[1]]
                c = c * np.array([[si[1]], [so[1]]])
            ease.append([e[0], -e[1]])
            roll.append(r)
            curve.append(c)
            scale_in.append(si)
            scale_out.append(so)
        self._ease = np.array(ease).T[:, None]  # (2, 1, g): ease in, minus ease out
        self._roll = np.array(roll).T[:, None]  # (2, 1, g)
        self._curve = np.moveaxis(np.array(curve), 0, -1)[:, :, None]  # (2, 3, 1, g) -> per side, xyz
        self._curve = self._curve.swapaxes(0, 1)  # (3, 2, 1, g)
        self._scale_in = np.array(scale_in).T[:, None]  # (3, 1, g)
        self._scale_out = np.array(scale_out).T[:, None]
        f = np.arange(s + 1) / s
        self._blend = np.stack([1 - f, f], -1)  # (a, 2): joint a takes (1 - f) of the in, f of the out
        self._reads_scale = any(x.reads_scale for x in sides)
        if not self._reads_scale:
            self._fractions = _segment_fractions(self._scale_in[1], self._scale_out[1], s)  # (s - 1, 1, g)
            self._scale_xz = _interpolate(self._blend, self._scale_in[::2], self._scale_out[::2])
        unbend = np.array([bb._unbend for bb in self.bbones])  # (g, a, 4, 4)
        self._unbend = np.moveaxis(unbend, (2, 3, 1, 0), (0, 1, 2, 3))[:, :, :, None]  # (4, 4, a, 1, g)
        self._unbend_t = unbend.swapaxes(-1, -2).copy()  # (g, a, 4, 4), transposed
        self._unbend_rows = unbend  # (g, a, 4, 4)

    def _steps(self, complex_: tuple[bool, ...], g: int) -> list:
        """Per posed-matrix argument, the imaginary parts (4, 4, m, g) giving one complex-step direction to
        each entry the curve reads of the complex arguments (``complex_``), m of them in all."""
        key = ("steps", complex_)
        steps = self._templates.get(key)
        if steps is None:
            entries = [e if c else [] for e, c in zip(self._entries, complex_, strict=True)]
            m, q, steps = sum(len(e) for e in entries), 0, []
            for e in entries:
                step = np.zeros((4, 4, m, g))
                step[np.asarray(e, int) // 4, np.asarray(e, int) % 4, q + np.arange(len(e))] = analytic.STEP
                steps.append(step)
                q += len(e)
            self._templates[key] = steps
        return steps

    def _powers(self, batch, dtype) -> np.ndarray:
        """(4, a, *batch) a fresh array of 1, t, t², t³ for the joints' curve parameters t, filled at the
        ends (t = 0 and 1); the inner joints are left to fill."""
        key = (batch, dtype)
        template = self._templates.get(key)
        if template is None:
            if len(self._templates) > 16:
                self._templates.clear()
            template = np.zeros((4, self.segments + 1, *batch), dtype)
            template[0] = 1.0
            template[1:, self.segments] = 1.0
            self._templates[key] = template
        return template.copy()

    @classmethod
    def of(cls, bbones) -> BBoneStack:
        """The stack of these B-Bones, in this order.

        Raises
        ------
        SolverError
            When the list is empty, holds something else than BBone, or holds bones that cannot share
            a stack (see :class:`BBoneStack`; the message names two of them).
        """
        bbones = tuple(bbones)
        if not bbones or not all(isinstance(bb, BBone) for bb in bbones):
            raise SolverError(f"a B-Bone stack needs one or more BBone, got {bbones!r:.200}")
        keys = _stack_keys(bbones)
        if keys is None:
            first = bbones[0]
            other = next((bb for bb in bbones[1:] if _stack_keys((first, bb)) is None), bbones[-1])
            raise SolverError(
                f"B-Bones {first.name!r} and {other.name!r} cannot share a stack: their segments, handle "
                f"types, kinds of handle (a B-Bone or not) or uses of a handle's scale differ"
            )
        return cls(bbones, keys)

    @property
    def names(self) -> tuple[str, ...]:
        """The bones' names, along the stack axis."""
        return tuple(bb.name for bb in self.bbones)

    @property
    def handle_names(self) -> tuple[tuple[str | None, ...] | None, tuple[str | None, ...] | None]:
        """(start, end): per bone, the handle bone whose posed matrix goes in ``starts`` / ``ends`` of
        :func:`stack_deform_matrices` (``None`` for a bone without one), or ``None`` for a side where no
        bone of the stack has a handle (then pass ``None``)."""
        return tuple(None if x is None else x.names for x in (self._start, self._end))  # type: ignore[return-value]

    @property
    def handle_parent_names(self) -> tuple[tuple[str | None, ...] | None, tuple[str | None, ...] | None]:
        """(start, end): per bone, the parent of the handle whose posed matrix goes in
        ``start_parents`` / ``end_parents`` (its scale is read), or ``None`` for a side that needs
        none."""
        return tuple(
            None if x is None or not x.has_parent else x.parent_names for x in (self._start, self._end)
        )  # type: ignore[return-value]

    def gather(self, pose) -> tuple:
        """``(poses, starts, ends, start_parents, end_parents)`` for :func:`stack_deform_matrices`, each
        (..., g, 4, 4) (the bones' batch shapes broadcast) or None where the stack needs none, from
        ``pose``, a mapping or a callable giving a bone's posed matrix (..., 4, 4) by name; a bone
        without a handle gets its own pose in the handle's place."""
        get = pose if callable(pose) else pose.__getitem__

        def stacked(names):
            if names is None:
                return None
            mats = [
                np.asarray(get(own if n is None else n)) for n, own in zip(names, self.names, strict=True)
            ]
            shape = np.broadcast_shapes(*(m.shape for m in mats))
            return np.stack([np.broadcast_to(m, shape) for m in mats], axis=-3)

        return (
            stacked(self.names),
            *map(stacked, self.handle_names),
            *map(stacked, self.handle_parent_names),
        )

    def __len__(self) -> int:
        return len(self.bbones)

    def __repr__(self) -> str:
        return f"BBoneStack({', '.join(self.names)}; segments={self.segments})"


def _interpolate(blend, start, end):
    """(a, ...) per joint ``(1 - f) start + f end`` from (n, ...) per bone values: (n, a, ...)."""
    return start[:, None] * blend[:, 0, None, None] + end[:, None] * blend[:, 1, None, None]


def _segment_fractions(scale_in_y, scale_out_y, segs: int):
    """(segs - 1, ...) where ``equalize_cubic_bezier`` puts the inner joints, as fractions of the curve's
    length, from the y scales in and out (``BKE_pchan_bbone_spline_compute``)."""
    log_in = _log(np.where(scale_in_y.real < 1e-4, 1e-4, scale_in_y))
    log_out = _log(np.where(scale_out_y.real < 1e-4, 1e-4, scale_out_y))
    fac = (np.arange(segs) / (segs - 1)).reshape(segs, *(1,) * log_in.ndim)
    cumulative = np.cumsum(_exp(fac * log_out + (1 - fac) * log_in), axis=0)
    return cumulative[: segs - 1] / cumulative[-1]


def stacks(bbones) -> list[BBoneStack]:
    """Group B-Bones into few :class:`BBoneStack`: each bone joins the first stack it fits, in order.
    Plain bones (``segments == 1``) are grouped too."""
    groups: list[list[BBone]] = []
    for bb in bbones:
        if not isinstance(bb, BBone):
            raise SolverError(f"stacks takes BBone, got {type(bb).__name__}")
        for group in groups:
            if _stack_keys((*group, bb)) is not None:
                group.append(bb)
                break
        else:
            groups.append([bb])
    return [BBoneStack.of(group) for group in groups]


def _stack_state(st: BBoneStack, P, prev, nxt, prev_parent, next_parent, shared: bool = False):
    """The per-bone quantities the curve is built from (``BKE_pchan_bbone_spline_params_get`` and
    ``BKE_pchan_bbone_handles_compute``), from component-first posed matrices (4, 4, L, g): the handles
    ``H`` (3, 2, L, g) (the curve's controls are 0, H[:, 0], c3 + H[:, 1], c3 = (0, length, 0)),
    ``length`` (L, g), ``roll`` (2, ., g) in and out, the pose scale ``sc`` (3, L, g), and the scales in
    and out (3, ., g). ``shared`` as for :func:`_real`."""
    complex_ = any(np.iscomplexobj(m) for m in (P, prev, nxt, prev_parent, next_parent) if m is not None)
    P3 = P[:3, :3]
    scale = _sqrt((P3 * P3).sum(0), shared)  # column lengths
    if complex_:
        sc = scale
    else:
        uniform = (np.abs(scale[0] - scale[1]) <= UNIFORM_SCALE_EPSILON) & (
            np.abs(scale[1] - scale[2]) <= UNIFORM_SCALE_EPSILON
        )
        sc = np.where(uniform, 1.0, scale)
    # imat = inv(P3 / sc) = diag(sc) adj(P3) / det(P3)
    F = P.reshape(16, *P.shape[2:])[_COFACTOR]
    C = (F[0] * F[1] - F[2] * F[3]).reshape(3, 3, *P.shape[2:])
    imat = C.swapaxes(0, 1) * (sc / (P3[0] * C[0]).sum(0))[:, None]
    head = P[:3, 3]
    length = st._length * sc[1]

    def own(side, M):
        if not side.partial:
            return M
        M = M.copy()
        M[..., side.absent] = (P if np.iscomplexobj(M) else P.real)[..., side.absent]
        return M

    columns, mats = [], {}
    if (x := st._start) is not None:
        Pp = mats["start"] = own(x, prev)
        if x.kind == "RELATIVE":
            v = x.head_local - Pp[:3, 3]
        elif x.kind == "TANGENT":
            v = Pp[:3, 1] * -x.length
        else:
            v = Pp[:3, 3] - head
        columns.append(v[:, None])
    if (x := st._end) is not None:
        Pn = mats["end"] = own(x, nxt)
        if x.kind == "RELATIVE":
            v = P[:3, 1] * st._length + Pn[:3, 3] - x.head_local
        elif x.kind == "TANGENT":
            v = P[:3, 1] * st._length + Pn[:3, 1] * x.length
        else:
            v = Pn[:3, 3] + Pn[:3, 1] * x.length - head
        columns.append(v[:, None])
    columns += [mats[x.side][:3, :3] for x in st._rolled]
    nv = len(st._sides)
    roll = st._roll
    scale_in, scale_out = st._scale_in, st._scale_out
    if not nv:
        H = np.broadcast_to(_Y_AXIS[:, None, None, None], (3, 2, *P.shape[2:]))
        ease, curve = st._ease, st._curve
    else:
        Y = _mm(imat, np.concatenate(columns, axis=1))  # (3, nv + 3 rolled, L, g)
        V = Y[:, :nv]
        V[1] -= length * st._offset
        d2 = (V * V).sum(0)
        use = _real(d2, shared) >= st._eps2
        if st._partial:
            use = use & st._present
        if use.all():
            unit = V * (_rsqrt(d2, shared) * st._sign)
        else:
            unit = V * (_rsqrt(np.where(use, d2, 1.0)) * st._sign)
            unit = np.where(use, unit, _Y_AXIS[:, None, None, None])
        if nv == 2:
            H = unit
        else:
            row = np.broadcast_to(_Y_AXIS[:, None, None, None], unit.shape)
            H = np.concatenate([unit, row] if st._sides[0].side == "start" else [row, unit], axis=1)
        if st._rolled:
            index = [st._sides.index(x) for x in st._rolled]
            N = Y[:, nv:].reshape(3, len(index), 3, *Y.shape[2:]).swapaxes(1, 2)  # (3, 3, r, L, g)
            r = _roll_of(N, unit[:, index], shared)
            if st._partial:
                r = r * st._present[index]
            if len(index) == 1:
                pad = np.zeros_like(r)
                r = np.concatenate([r, pad] if st._rolled[0].side == "start" else [pad, r])
            roll = roll + r
        factors = [1.0, 1.0]  # ease and curve factors of the handles' own scales
        for x in st._sides:
            if not x.reads_scale:
                continue
            rest_inverse = x.rest_inverse
            if x.has_parent:
                rest_inverse = _mm(
                    rest_inverse, _inv3(own(x, prev_parent if x.side == "start" else next_parent))
                )
            handle_scale = _sqrt((lambda A: (A * A).sum(0))(_mm(rest_inverse, mats[x.side][:3, :3])))
            scaled = x.use_scale * handle_scale + (1 - x.use_scale)
            if x.side == "start":
                scale_in = scale_in * scaled
            else:
                scale_out = scale_out * scaled
            factors[x.side == "end"] = x.use_ease * handle_scale[1] + (1 - x.use_ease)
        if st._reads_scale:
            E = np.stack(np.broadcast_arrays(*factors, length)[:2])
            ease, curve = st._ease * E, st._curve * E
        else:
            ease, curve = st._ease, st._curve
    # cubic_tangent_factor_circle_v3, then the handles' lengths, ease and curve offsets
    d = (H[:, 0] * H[:, 1]).sum(0)
    if d.real.max() <= 1 - 1e-5 and d.real.min() >= -1 + 1e-5:
        factor = 0.5 / (1 + _sqrt((1 + d) * 0.5, shared))
    else:
        inside = (d.real <= 1 - 1e-5) & (d.real >= -1 + 1e-5)
        factor = 0.5 / (1 + _sqrt(np.where(inside, 1 + d, 1.0) * 0.5))
        factor = np.where(inside, factor, np.where(d.real > 1 - 1e-5, 0.25, 0.5))
    H = H * (ease * (factor * length * (1 / 0.75))) + curve * sc[:, None]
    return H, length, roll, sc, scale_in, scale_out


def _roll_of(N, h, shared: bool = False):
    """(...) ``mat3_vec_to_roll(N, h)`` for component-first N (3, 3, ...) and unit h (3, ...)."""
    columns = _frame_columns(h)
    if columns is None:
        B = _vec_roll_to_mat3(np.moveaxis(h, 0, -1), np.zeros(h.shape[1:]))
        return _twist(_mm(np.moveaxis(np.linalg.inv(B), (-2, -1), (0, 1)), N))
    return _twist(_mm(np.stack([columns[:, 0], h, columns[:, 1]]), N), shared)


def _stack_joints(st: BBoneStack, H, length, roll, sc, scale_in, scale_out, shared: bool = False):
    """(3, 4, a, L, g) per joint ``[R diag(sc σ) | p]``: the joint's rotation R with its x / z scale σ
    and the pose scale, and its position p, in bone space times sc (Blender's ``bbone_pose_mats`` are
    ``diag(1 / sc)`` of this). ``shared``: axis L is a complex-step direction axis along which the real
    parts agree, so branches and real functions are taken on its first entry."""
    s, a = st.segments, st.segments + 1
    batch = length.shape
    n = length.size
    dtype = H.dtype
    h1, h2 = H[:, 0], H[:, 1]
    controls = np.concatenate([H.swapaxes(0, 1), (length * _Y_AXIS[:, None, None])[None]])  # h1, h2, c3
    # equalize_cubic_bezier (the polyline's steps) and ease_handle_axis (the derivatives at the ends)
    both = (_STEPS_AND_ENDS @ controls.reshape(3, -1)).reshape(MAX_SEGMENTS + 4, 3, *batch)
    sq = (both * both).sum(1)
    padded = np.empty((MAX_SEGMENTS + 1, *batch), dtype)
    padded[0] = 0.0
    np.cumsum(_sqrt(sq[:MAX_SEGMENTS], shared), axis=0, out=padded[1:])  # the polyline's length so far
    fractions = _segment_fractions(scale_in[1], scale_out[1], s) if st._reads_scale else st._fractions
    dist = padded[-1] * fractions  # (s - 1, L, g)
    count = (_real(padded, shared)[1:MAX_SEGMENTS, None] <= _real(dist, shared)[None]).sum(0)
    index = (np.broadcast_to(count, dist.shape) * n + np.arange(n).reshape(batch)).reshape(-1)
    lower = padded.reshape(-1)[index].reshape(dist.shape)
    upper = padded.reshape(-1)[index + n].reshape(dist.shape)
    powers = st._powers(batch, dtype)  # (4, a, L, g): 1, t, t², t³ with t = 0 and 1 at the ends
    t = powers[1, 1:s]
    np.multiply(count + (dist - lower) / (upper - lower), 1.0 / MAX_SEGMENTS, out=t)
    np.multiply(t, t, out=powers[2, 1:s])
    np.multiply(powers[2, 1:s], t, out=powers[3, 1:s])
    weights = (_BEZIER.T @ powers.reshape(4, -1)).reshape(2, 3, a, *batch)  # point, tangent; h1, h2, c3
    first, second = _real(sq[MAX_SEGMENTS : MAX_SEGMENTS + 2], shared), _real(sq[MAX_SEGMENTS + 2 :], shared)
    short = first < 0.01 * second
    if short.any():
        ratio = sq[MAX_SEGMENTS : MAX_SEGMENTS + 2] / np.where(short, sq[MAX_SEGMENTS + 2 :], 1.0)
        positive = short & (ratio.real > 0)
        k = np.where(short, 0.1 - np.where(positive, _sqrt(np.where(positive, ratio, 1.0)), 0.0), 0.0)
        weights[1][:, [0, s]] += _EASE_TANGENT.T[:, :, None, None] * k
    vectors = weights[:, 0, None] * h1[:, None] + weights[:, 1, None] * h2[:, None]  # (2, 3, a, L, g)
    vectors[:, 1] += weights[:, 2] * length
    point, tangent = vectors[0], vectors[1]
    # make_bbone_spline_matrix: vec_roll_to_mat3 of the tangent and the interpolated roll, the scales
    roll = (st._blend @ roll.reshape(2, -1)).reshape(a, *roll.shape[1:])  # (a, ., g)
    scale_xz = _interpolate(st._blend, scale_in[::2], scale_out[::2]) if st._reads_scale else st._scale_xz
    scale_xz = scale_xz * sc[::2, None]  # (2, a, L, g)
    out = np.empty((3, 4, a, *batch), np.result_type(tangent, roll, scale_xz))
    t2 = (tangent * tangent).sum(0)
    normal = tangent * _rsqrt(t2, shared)
    theta = 1.0 + normal[1]
    if _real(t2, shared).min() <= 1e-35 or _real(theta, shared).min() <= 6.1e-3:
        columns = None  # vec_roll_to_mat3's branches for a tangent near -y
    elif normal.size > 3000:
        # With B = vec_roll_to_mat3(n, 0), whose x and z columns are e_x - x/θ (x, θ, z) and e_z - z/θ
        # (x, θ, z) (θ = 1 + y), the x and z columns of B Ry(roll) are (c, 0, -s) - α (x, θ, z) and
        # (s, 0, c) - β (x, θ, z), with (α, β) the (x/θ, z/θ) rotated by the roll.
        cs = _cos_sin(roll, shared)  # (2, a, ., g): cos, sin
        turned = cs[::-1] * _SIGNS  # -sin, cos
        ratio = normal[::2] / theta
        ab = (cs * ratio[0] + turned * ratio[1]) * -scale_xz
        np.multiply((normal + _Y_AXIS[:, None, None, None])[:, None], ab, out=out[:, 0:3:2])
        out[0, 0:3:2] += cs * scale_xz
        out[2, 0:3:2] += turned * scale_xz
        np.multiply(normal, sc[1], out=out[:, 1])
        out[:, 3] = point
        return out
    else:
        columns = _frame_columns(normal)
    if columns is None:
        R = _vec_roll_to_mat3(np.moveaxis(tangent, 0, -1), np.broadcast_to(roll, tangent.shape[1:]))
        R = np.moveaxis(R, (-2, -1), (0, 1))
        out[:, 0:3:2] = R[:, 0:3:2] * scale_xz
        out[:, 1] = R[:, 1] * sc[1]
    else:
        cs = _cos_sin(roll, shared)  # (2, a, ., g): cos, sin
        # the x and z columns of B Ry(roll): (c B0 - s B2, s B0 + c B2), each times its scale
        rotated = columns[:, :1] * cs + columns[:, 1:] * (cs[::-1] * _SIGNS)
        np.multiply(rotated, scale_xz, out=out[:, 0:3:2])
        np.multiply(normal, sc[1], out=out[:, 1])
    out[:, 3] = point
    return out


def _check_stack_pose(st: BBoneStack, what: str, value):
    if value is None:
        raise SolverError(f"B-Bone stack {st!r} needs the posed matrices of {what}")
    M = np.asarray(value)
    if M.ndim < 3 or M.shape[-3:] != (len(st), 4, 4):
        raise SolverError(
            f"B-Bone stack {st!r}: the posed matrices of {what} must have shape (..., {len(st)}, 4, 4), "
            f"got {M.shape}"
        )
    if not (np.issubdtype(M.dtype, np.floating) or np.issubdtype(M.dtype, np.complexfloating)):
        M = M.astype(np.float64)
    return M


def _assemble(P, sc, joints, unbend):
    """(3, 4, a, L, g) ``diag(1 / sc) joints unbend`` in the pose: ``P diag(1/sc) joints unbend``."""
    G = (joints[:, :3, None] * unbend[None, :3]).sum(1)  # (3, 4, a, L, g)
    G[:, 3] += joints[:, 3]
    U = P[:3, :3] / sc
    M = (U[:, :, None, None] * G[None]).sum(1)
    M[:, 3] += P[:3, 3, None]
    return M


# --------------------------------------------------------------------------------------------------
# Public API


def spline_matrices(
    bbone: BBone,
    pose=None,
    prev_pose=None,
    next_pose=None,
    prev_parent_pose=None,
    next_parent_pose=None,
    *,
    rest: bool = False,
) -> np.ndarray:
    """The B-Bone's segment joint matrices in bone space, as ``PoseBone.bbone_segment_matrix(i, rest)``.

    Parameters
    ----------
    bbone : BBone
        A bone with ``segments > 1``.
    pose : (..., 4, 4) float or complex
        The bone's posed matrix (``PoseBone.matrix``), armature space; ignored with ``rest``.
    prev_pose, next_pose : (..., 4, 4) float or complex
        The posed matrices of the start / end handle bones (:attr:`BBone.handle_names`); required when
        the handle exists.
    prev_parent_pose, next_parent_pose : (..., 4, 4) float or complex
        The posed matrices of the handles' parents (:attr:`BBone.handle_parent_names`); required when
        named there.
    rest : bool
        The rest shape (Blender's ``bbone_rest_mats``) instead of the posed one (``bbone_pose_mats``).

    Returns
    -------
    (..., segments + 1, 4, 4)
        Joint ``i`` of the curve, from head (0) to tail (``segments``), in the bone's (posed or rest)
        space; ``(segments + 1, 4, 4)`` with ``rest``.
    """
    if bbone.segments == 1:
        raise SolverError(f"bone {bbone.name!r} is not a B-Bone (bbone_segments is 1)")
    if rest:
        return bbone._rest.copy()
    mats, batch = _inputs(bbone, pose, prev_pose, next_pose, prev_parent_pose, next_parent_pose)
    return _spline(bbone, False, mats, batch)


def deform_matrices(
    bbone: BBone, pose, prev_pose=None, next_pose=None, prev_parent_pose=None, next_parent_pose=None
) -> np.ndarray:
    """The matrices the Armature modifier blends for a vertex weighted to this bone (``bbone_deform_mats``).

    Parameters
    ----------
    bbone : BBone
    pose : (..., 4, 4) float or complex
        The bone's posed matrix (``PoseBone.matrix``), armature space.
    prev_pose, next_pose, prev_parent_pose, next_parent_pose : (..., 4, 4), optional
        As for :func:`spline_matrices` (unused when ``segments == 1``).

    Returns
    -------
    (..., segments + 1, 4, 4)
        ``M[a] = pose @ spline[a] @ inv(rest_spline[a]) @ inv(matrix_local)`` (``BKE_pchan_bbone_segments_
        cache_compute``; Blender's array has an extra leading ``inv(matrix_local)``, left out here):
        each takes a rest-pose point in armature space to its posed position as joint ``a`` moves it.
        With ``segments == 1``, two copies of ``pose @ inv(matrix_local)`` (``(..., 2, 4, 4)``).
    """
    if bbone.segments == 1:
        P = _check_pose(f"the bone {bbone.name!r}", bbone, pose)
        M = P @ np.linalg.inv(bbone.matrix_local)
        return np.stack([M, M], axis=-3)
    mats, _ = _inputs(bbone, pose, prev_pose, next_pose, prev_parent_pose, next_parent_pose)
    keys = ("pose", "prev", "next", "prev_parent", "next_parent")
    args = [None if mats.get(k) is None else mats[k][..., None, :, :] for k in keys]
    return stack_deform_matrices(bbone._stack, *args)[..., 0, :, :, :]


def _deform_reference(
    bbone: BBone, pose, prev_pose=None, next_pose=None, prev_parent_pose=None, next_parent_pose=None
) -> np.ndarray:
    """:func:`deform_matrices` computed bone by bone as the first port did (``_spline``), kept as the
    reference the stacked evaluation is tested against."""
    mats, batch = _inputs(bbone, pose, prev_pose, next_pose, prev_parent_pose, next_parent_pose)
    spline = _spline(bbone, False, mats, batch)
    return mats["pose"][..., None, :, :] @ spline @ bbone._unbend


def vertex_segments(bbone: BBone, rest_points) -> tuple[np.ndarray, np.ndarray]:
    """Which two segment joints a rest-pose point follows, and how (``BKE_pchan_bbone_deform_segment_index``).

    Parameters
    ----------
    bbone : BBone
    rest_points : (n, 3) float
        Rest positions in armature space (the Armature modifier's ``co`` after its ``premat``).

    Returns
    -------
    index : (n,) int
        The first joint, in ``[0, segments - 1]`` (``0`` for a plain bone).
    blend : (n,) float
        The weight of joint ``index + 1`` in ``[0, 1]`` (``0`` for a plain bone); joint ``index`` gets
        ``1 - blend``. ``"STRAIGHT"`` mapping projects the point on the bone's rest axis; ``"CURVED"``
        locates it between the planes normal to the rest curve at the joints, smoothed as Blender does.
    """
    co = np.asarray(rest_points, dtype=np.float64)
    if co.ndim != 2 or co.shape[1] != 3 or not np.all(np.isfinite(co)):
        raise SolverError(
            f"B-Bone {bbone.name!r}: rest points must be a finite (n, 3) array, got shape {co.shape}"
        )
    n, segs = len(co), bbone.segments
    if segs == 1 or n == 0:
        return np.zeros(n, np.int64), np.zeros(n)
    if bbone.mapping_mode == "STRAIGHT":
        inv = np.linalg.inv(bbone.matrix_local)
        y = co @ inv[1, :3] + inv[1, 3]
        return _clamp_segment(y / bbone.length, segs)
    normals, offsets, segment_scale, depth_scale = bbone._boundaries
    rows = np.arange(n)
    start = np.full(n, -1)
    end = np.full(n, segs + 1)
    bias = np.zeros(n, np.int64)
    dist = np.full((n, segs + 1), np.nan)
    stack = np.zeros((n, segs + 1), np.int64)
    top = np.full(n, -1)
    while True:
        active = end - start > 1
        if not active.any():
            break
        r = rows[active]
        mid = (start[r] + end[r] + bias[r]) // 2
        d = np.einsum("ij,ij->i", co[r], normals[mid]) - offsets[mid]
        top[r] += 1
        stack[r, top[r]] = mid
        dist[r, mid] = d
        below = d < 0
        end[r] = np.where(below, mid, end[r])
        start[r] = np.where(below, start[r], mid)
        bias[r] = below.astype(np.int64)
    size = 1.0 / segs
    inner = (end > 0) & (start < segs)
    d1 = np.abs(dist[rows, np.clip(start, 0, segs)])
    d2 = np.abs(dist[rows, np.clip(end, 0, segs)])
    with np.errstate(invalid="ignore", divide="ignore"):
        head_tail = np.where(inner, size * (start + d1 / (d1 + d2)), np.where(end <= 0, 0.0, 1.0))
    for level in range(top.max(), -1, -1):
        r = rows[top >= level]
        idx = stack[r, level]
        boundary_pos = idx * size
        point_dist = dist[r, idx] * segment_scale
        point_abs = np.abs(point_dist)
        gap = np.abs(head_tail[r] - boundary_pos) - point_abs
        dist_coeff = 1.0 - point_abs * depth_scale[level]
        smooth = (gap > 0) & (dist_coeff > 0)
        scaled_gap = gap * 3.0
        with np.errstate(invalid="ignore", divide="ignore"):
            slope_coeff = scaled_gap / (scaled_gap + point_abs)
        dist_smooth = dist_coeff * dist_coeff * 8.0 / (7.0 * dist_coeff + 1.0)
        w = slope_coeff * dist_smooth
        target = boundary_pos + point_dist
        head_tail[r] = np.where(smooth, w * target + (1 - w) * head_tail[r], head_tail[r])
    return _clamp_segment(head_tail, segs)


def _clamp_segment(head_tail, segs: int):
    """``BKE_pchan_bbone_deform_clamp_segment_index``."""
    pre_blend = np.clip(head_tail, 0.0, 1.0) * segs
    index = np.clip(np.floor(pre_blend).astype(np.int64), 0, segs - 1)
    return index, np.clip(pre_blend - index, 0.0, 1.0)


def blend_segments(matrices, index, blend) -> np.ndarray:
    """(..., n, 4, 4) each point's blended matrix ``(1 - blend) M[index] + blend M[index + 1]``.

    Parameters
    ----------
    matrices : (..., segments + 1, 4, 4)
        From :func:`deform_matrices`.
    index, blend : (n,)
        From :func:`vertex_segments`.

    A vertex fully weighted to the bone lands at ``(blend_segments(...) @ [co, 1])[:3]``; with several
    bones, Blender sums ``w_b (A_b co - co)`` and divides by ``Σ w_b`` (see the module docstring).
    """
    M = np.asarray(matrices)
    index = np.asarray(index)
    blend = np.asarray(blend)[:, None, None]
    return (1 - blend) * M[..., index, :, :] + blend * M[..., index + 1, :, :]


#: The fewest complex-step directions for which :func:`stack_deform_matrices` differentiates through the
#: per-bone state (below, it evaluates the curve on every direction).
_JACOBIAN_MIN = 10


def _stack_jacobian(st: BBoneStack, Pt) -> np.ndarray:
    """(L, g, a, 4, 4) :func:`stack_deform_matrices` of complex-step inputs (4, 4, L, g) whose real parts
    agree along L (the L directions of one pose).

    Rather than evaluating the curve on every direction, this evaluates it at the shared value with one
    complex-step direction per variable it depends on, then applies the chain rule with the inputs'
    imaginary parts: the per-bone state s (handles, length, rolls, pose scale, ...) as a function of the
    inputs' top three rows (J1), the joints ``G = diag(1/sc) joints unbend`` as a function of s, and
    ``M = P G``, so that ``dM = dP G + P (dG/ds) J1 dIn``, one matrix product per bone at the end."""
    L, g = Pt[0].shape[2:]
    a = st.segments + 1
    complex_ = [M is not None and np.iscomplexobj(M) for M in Pt]
    entries = [e for e, c in zip(st._entries, complex_, strict=True) if c]
    m_in = sum(len(e) for e in entries)
    steps = st._steps(tuple(complex_), g)  # the inputs' imaginary parts: one direction per entry read
    X, dIn = [], []
    for M, c, e, step in zip(Pt, complex_, st._entries, steps, strict=True):
        if M is None:
            X.append(None)
        elif not c:
            X.append(np.broadcast_to(M.real[:, :, :1], (4, 4, m_in, g)))
        else:
            X.append(_complex(M.real[:, :, :1], step))
            dIn.append(M.imag.reshape(16, L, g)[e])
    # the state and its derivatives: on the L directions, or with respect to the inputs' entries
    direct = m_in >= L
    n = L if direct else m_in
    H, length, roll, sc, scale_in, scale_out = _stack_state(st, *(Pt if direct else X), shared=True)
    fields = [H.reshape(6, n, g), length[None], roll]
    if st._reads_scale:
        fields += [scale_in, scale_out]
    fields.append(sc)
    state = np.concatenate([np.broadcast_to(f, (f.shape[0], n, g)) for f in fields])  # (m, n, g)
    m = state.shape[0]
    dIn = np.ascontiguousarray(np.concatenate(dIn).transpose(2, 1, 0))  # (g, L, m_in)
    if direct:
        ds = np.ascontiguousarray(state.imag.transpose(2, 1, 0))  # (g, L, m)
    else:
        ds = dIn @ np.ascontiguousarray(state.imag.transpose(2, 1, 0) * (1.0 / analytic.STEP))
    # the joints and their derivatives with respect to the state: a complex-step direction for each
    # variable but the pose scale sc, which only scales the joints' columns (its derivative is the column
    # over sc)
    k = m - 3
    X = _complex(state.real[:k, :1], analytic.STEP * np.eye(k)[:, :, None])  # (k, k, g)
    sc0 = state.real[k:, 0]  # (3, g)
    sin, sout = (X[9:12], X[12:15]) if st._reads_scale else (scale_in, scale_out)
    joints = _stack_joints(st, X[:6].reshape(3, 2, k, g), X[6], X[7:9], sc0[:, None], sin, sout, shared=True)
    # Z: diag(1 / sc) joints, then its derivatives, per bone and joint (g, a, 3, 4, 1 + m)
    J0 = joints.real[:, :, :, 0].transpose(3, 2, 0, 1)  # (g, a, 3, 4)
    inverse = 1.0 / sc0.T  # (g, 3)
    Z = np.empty((g, a, 3, 4, m + 1))
    np.multiply(J0, inverse[:, None, :, None], out=Z[..., 0])
    np.multiply(
        joints.imag.transpose(4, 2, 0, 1, 3),
        (inverse / analytic.STEP)[:, None, :, None, None],
        out=Z[..., 1 : k + 1],
    )
    Z[..., k + 1 :] = 0.0
    # d/dsc_r: column r of the joints over sc_r, then the derivative of the rows' 1 / sc
    r, rk = np.arange(3), k + 1 + np.arange(3)
    Z[:, :, :, r, rk] = J0[..., :3] * inverse[:, None, :, None] * inverse[:, None, None, :]
    Z[:, :, r, :, rk] -= (J0[:, :, :3] * (inverse * inverse)[:, None, :, None]).transpose(2, 0, 1, 3)
    # P diag(1/sc) joints unbend, per bone and joint as (P ⊗ unbendᵀ) vec(joints)
    P0 = Pt[0].real[:, :, 0].transpose(2, 0, 1)  # (g, 4, 4)
    T = P0[:, None, :3, None, :3, None] * st._unbend_t[:, :, None, :, None, :]  # (g, a, i, k, r, c)
    MK = T.reshape(g, a, 12, 12) @ Z.reshape(g, a, 12, m + 1)  # (g, a, (i, k), value + m)
    MK[:, :, 3::4, 0] += P0[:, None, :3, 3]
    # dM = ds (dM/ds) + dP G, one product (L, m + 12) @ (m + 12, a 12) per bone
    W = np.zeros((g, m + 12, a, 3, 4))
    W[:, :m] = MK[..., 1:].transpose(0, 3, 1, 2).reshape(g, m, a, 3, 4)
    G0 = np.zeros((g, a, 4, 4))
    np.matmul(Z[..., 0], st._unbend_rows, out=G0[:, :, :3])
    G0[:, :, 3, 3] = 1.0
    G0 = G0.transpose(0, 2, 1, 3)  # (g, r, a, k)
    for i in range(3):
        W[:, m + 4 * i : m + 4 * i + 4, :, i, :] = G0
    A = np.zeros((g, L, m + 12))
    A[:, :, :m] = ds
    if complex_[0]:
        A[:, :, m:] = dIn[:, :, :12]
    out = np.empty((L, g, a, 4, 4), np.complex128)
    value = np.empty((g, a, 4, 4))
    value[:, :, :3] = MK[..., 0].reshape(g, a, 3, 4)
    value[:, :, 3] = (0.0, 0.0, 0.0, 1.0)
    out.real[...] = value
    out.imag[..., 3, :] = 0.0
    W = W.reshape(g, m + 12, a * 12)
    for i in range(g):  # bone by bone, to keep the temporary small
        out.imag[:, i, :, :3, :] = (A[i] @ W[i]).reshape(L, a, 3, 4)
    return out


def stack_deform_matrices(
    stack: BBoneStack, poses, starts=None, ends=None, start_parents=None, end_parents=None
) -> np.ndarray:
    """:func:`deform_matrices` of every bone of a stack at once.

    Parameters
    ----------
    stack : BBoneStack
    poses : (..., g, 4, 4) float or complex
        The bones' posed matrices (``PoseBone.matrix``) along the stack axis (:attr:`BBoneStack.names`).
    starts, ends : (..., g, 4, 4) or None
        The posed matrices of the start / end handle bones (:attr:`BBoneStack.handle_names`); ``None``
        when no bone of the stack has a handle there. The entries of bones without a handle are not
        used (:meth:`BBoneStack.gather` puts the bone's own pose there).
    start_parents, end_parents : (..., g, 4, 4) or None
        The posed matrices of the handles' parents (:attr:`BBoneStack.handle_parent_names`).

    Returns
    -------
    (..., g, segments + 1, 4, 4)
        :func:`deform_matrices` of each bone; the leading dimensions are those of the arguments,
        broadcast. A stack of plain bones (``segments == 1``) gives two copies, (..., g, 2, 4, 4).

    Notes
    -----
    Posed matrices are affine: their last rows are not read. Complex arguments whose real parts agree
    along the leading dimensions (the complex-step directions of one pose), at least ``_JACOBIAN_MIN``
    of them, are differentiated through the per-bone state (see the module's "Stacks"); others are
    evaluated direction by direction. Both give the complex-step derivatives to rounding.
    """
    if not isinstance(stack, BBoneStack):
        raise SolverError(f"stack_deform_matrices needs a BBoneStack, got {type(stack).__name__}")
    st, g = stack, len(stack)
    mats = [_check_stack_pose(st, "the bones", poses)]
    if st.segments == 1:
        M = mats[0] @ st._inverse_rest
        return np.stack([M, M], axis=-3)
    for what, value, needed in (
        ("the start handles", starts, st._start),
        ("the end handles", ends, st._end),
        ("the start handles' parents", start_parents, st._start is not None and st._start.has_parent),
        ("the end handles' parents", end_parents, st._end is not None and st._end.has_parent),
    ):
        mats.append(_check_stack_pose(st, what, value) if needed else None)
    shapes = {m.shape[:-3] for m in mats if m is not None}
    batch = shapes.pop() if len(shapes) == 1 else np.broadcast_shapes(*shapes)
    size = math.prod(batch)

    def component_first(M):
        if M is None:
            return None
        if M.shape[:-3] != batch:
            M = np.broadcast_to(M, (*batch, g, 4, 4))
        return np.ascontiguousarray(M.reshape(size, g, 4, 4).transpose(2, 3, 0, 1))

    Pt = [component_first(M) for M in mats]
    complex_ = [M is not None and np.iscomplexobj(M) for M in Pt]
    if (
        size >= _JACOBIAN_MIN
        and any(complex_)
        and all((M.real[:3] == M.real[:3, :, :1]).all() for M, c in zip(Pt, complex_, strict=True) if c)
    ):
        return _stack_jacobian(st, Pt).reshape(*batch, g, st.segments + 1, 4, 4)
    H, length, roll, sc, scale_in, scale_out = _stack_state(st, *Pt)
    joints = _stack_joints(st, H, length, roll, sc, scale_in, scale_out)
    M = _assemble(Pt[0], sc, joints, st._unbend)
    a = st.segments + 1
    out = np.empty((size, g, a, 4, 4), M.dtype)
    out[..., :3, :] = M.transpose(3, 4, 2, 0, 1)
    out[..., 3, :] = (0.0, 0.0, 0.0, 1.0)
    return out.reshape(*batch, g, a, 4, 4)
