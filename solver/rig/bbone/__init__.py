"""Blender's B-Bones (Bendy Bones) as the Armature modifier deforms with them, exactly, in numpy.

A B-Bone is a deform bone with ``bbone_segments > 1``: Blender bends it along a cubic Bézier curve
whose handles come from neighbouring bones, and a vertex weighted to it follows two adjacent
*segment joints* of the curve instead of the bone's plain matrix. This package is a port of Blender's
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
:mod:`solver.rig.analytic`): branches are taken on real parts only. One deliberate choice: Blender treats a
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
the branches taken once per stack (:mod:`.stacked`). It gives what the bone-by-bone port
(:mod:`.reference`, which the tests hold it to) gives, to 1e-13; :func:`deform_matrices` is a stack of
one bone.

Complex-step arrays with many directions of one pose (real parts equal along the leading axes, as
:func:`solver.rig.analytic.directions` makes them) take a faster road (:mod:`.jacobian`): the per-bone
state the curve is built from (handles, length, rolls, scales: 12 numbers) is differentiated with
respect to the pose entries it reads, the curve is evaluated once with one complex-step direction per
state variable, and the chain rule is applied to the directions' imaginary parts in one matrix product
per bone. The derivatives are the complex-step ones, exact to rounding.

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

from .bbone_stack import BBoneStack, stacks
from .deform import deform_matrices, stack_deform_matrices
from .model import HANDLE_TYPES, MAPPING_MODES, BBone, BBoneHandle
from .reference import MAX_SEGMENTS, spline_matrices
from .segments import blend_segments, vertex_segments

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
