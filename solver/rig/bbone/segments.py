"""Which two segment joints of a B-Bone a rest-pose point follows, and how
(``BKE_pchan_bbone_deform_segment_index``), and the blend of their matrices."""

from __future__ import annotations

import numpy as np

from ...errors import SolverError
from .model import BBone


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
    normals, offsets, segment_scale, depth_scale = bbone.segment_boundaries
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
        From :func:`~solver.rig.bbone.deform_matrices`.
    index, blend : (n,)
        From :func:`vertex_segments`.

    A vertex fully weighted to the bone lands at ``(blend_segments(...) @ [co, 1])[:3]``; with several
    bones, Blender sums ``w_b (A_b co - co)`` and divides by ``Σ w_b`` (see the module docstring).
    """
    M = np.asarray(matrices)
    index = np.asarray(index)
    blend = np.asarray(blend)[:, None, None]
    return (1 - blend) * M[..., index, :, :] + blend * M[..., index + 1, :, :]
