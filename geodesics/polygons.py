"""Triangulation of polygon meshes, keeping each triangle's polygon and corners.

Quads are split as Blender splits them (along corners 0-2 unless that folds the quad, then 1-3), so a
triangulated Blender mesh and ours agree on quads; larger polygons are ear-clipped in their best-fit
plane.
"""

from __future__ import annotations

import numpy as np

from .errors import MeshError, describe_ids


def _newell_normal(P: np.ndarray) -> np.ndarray:
    """(..., s, 3) polygon corners -> (..., 3) Newell normal (not normalized)."""
    Q = np.roll(P, -1, axis=-2)
    return np.stack(
        [
            ((P[..., 1] - Q[..., 1]) * (P[..., 2] + Q[..., 2])).sum(-1),
            ((P[..., 2] - Q[..., 2]) * (P[..., 0] + Q[..., 0])).sum(-1),
            ((P[..., 0] - Q[..., 0]) * (P[..., 1] + Q[..., 1])).sum(-1),
        ],
        axis=-1,
    )


def _split_quads(V: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """(q, 4) quads -> (q, 2, 3) corner indices (0..3) of the two triangles of each quad."""
    P = V[quads]
    normal = _newell_normal(P)
    a = np.einsum("ij,ij->i", np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), normal)
    b = np.einsum("ij,ij->i", np.cross(P[:, 2] - P[:, 0], P[:, 3] - P[:, 0]), normal)
    along_02 = (a > 0) & (b > 0)
    tris = np.where(
        along_02[:, None, None],
        np.array([[0, 1, 2], [0, 2, 3]]),
        np.array([[0, 1, 3], [1, 2, 3]]),
    )
    return tris


def _ear_clip(P: np.ndarray) -> list[tuple[int, int, int]]:
    """Ear-clip one simple polygon given as (s, 3) corners; returns corner-index triangles."""
    normal = _newell_normal(P)
    length = np.linalg.norm(normal)
    if length == 0:
        return [(0, i, i + 1) for i in range(1, len(P) - 1)]
    normal /= length
    x = P[1] - P[0] if np.linalg.norm(P[1] - P[0]) > 0 else np.cross(normal, [1.0, 0, 0])
    x = x - normal * (x @ normal)
    x /= np.linalg.norm(x)
    y = np.cross(normal, x)
    q = np.stack([P @ x, P @ y], 1)
    # Projected corners carry rounding errors: cross products this small count as zero (collinear), so that
    # collinear corners are not clipped as (degenerate) ears and corners on a candidate's edge block it.
    tol = 1e-12 * float(np.max(np.ptp(q, axis=0))) ** 2
    remaining = list(range(len(P)))
    triangles = []

    def cross(o, a, b):
        return (q[a, 0] - q[o, 0]) * (q[b, 1] - q[o, 1]) - (q[a, 1] - q[o, 1]) * (q[b, 0] - q[o, 0])

    while len(remaining) > 3:
        best, best_area = None, -np.inf
        count = len(remaining)
        for idx in range(count):
            a, b, c = remaining[idx - 1], remaining[idx], remaining[(idx + 1) % count]
            area = cross(a, b, c)
            if area <= tol:
                continue
            inside = any(
                cross(a, b, p) >= -tol and cross(b, c, p) >= -tol and cross(c, a, p) >= -tol
                for p in remaining
                if p not in (a, b, c)
            )
            if not inside:
                best = idx
                break
            if area > best_area:
                best, best_area = idx, area
        if best is None:  # no convex corner at all: the polygon is degenerate; fall back to a fan
            best = 0
        a, b, c = remaining[best - 1], remaining[best], remaining[(best + 1) % len(remaining)]
        triangles.append((a, b, c))
        remaining.pop(best)
    triangles.append(tuple(remaining))
    return triangles


def triangulate_polygons(vertices: np.ndarray, polygons) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangulate polygons.

    Parameters
    ----------
    vertices : (n, 3) float array
    polygons : sequence of int sequences, (p, s) int array, or ``(corner_vertices, sizes)``
        The last form is Blender's flat layout: every polygon's vertex indices one after another (L,)
        and each polygon's corner count (p,).

    Returns
    -------
    faces : (m, 3) int64
    polygon : (m,) int64, the polygon each triangle comes from
    corners : (m, 3) int64, each triangle corner's index within its polygon
    """
    flat, sizes = _flat_polygons(polygons)
    if sizes.size == 0:
        raise MeshError("the mesh has no faces")
    small = np.flatnonzero(sizes < 3)
    if small.size:
        raise MeshError(f"polygons {describe_ids(small)} have fewer than three corners", faces=small)
    n = len(vertices)
    bad = (flat < 0) | (flat >= n)
    if np.any(bad):
        owner = np.repeat(np.arange(sizes.size), sizes)
        bad_polygons = np.unique(owner[bad])
        raise MeshError(
            f"polygons {describe_ids(bad_polygons)} use vertex indices outside 0..{n - 1}", faces=bad_polygons
        )
    start = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    faces, polygon, corners = [], [], []
    tri = np.flatnonzero(sizes == 3)
    if tri.size:
        local = np.tile([0, 1, 2], (tri.size, 1))
        faces.append(flat[start[tri, None] + local])
        polygon.append(tri)
        corners.append(local)
    quad = np.flatnonzero(sizes == 4)
    if quad.size:
        Q = flat[start[quad, None] + np.arange(4)]
        local = _split_quads(vertices, Q)  # (q, 2, 3)
        faces.append(np.take_along_axis(Q[:, None, :], local, axis=2).reshape(-1, 3))
        polygon.append(np.repeat(quad, 2))
        corners.append(local.reshape(-1, 3))
    for i in np.flatnonzero(sizes > 4):
        ring = flat[start[i] : start[i] + sizes[i]]
        local = np.array(_ear_clip(vertices[ring]), dtype=np.int64)
        faces.append(ring[local])
        polygon.append(np.full(len(local), i))
        corners.append(local)
    polygon = np.concatenate(polygon)
    order = np.argsort(polygon, kind="stable")
    return (
        np.concatenate(faces)[order].astype(np.int64),
        polygon[order].astype(np.int64),
        np.concatenate(corners)[order].astype(np.int64),
    )


def _flat_polygons(polygons) -> tuple[np.ndarray, np.ndarray]:
    """Any accepted polygon layout as (corner vertex indices, corner counts)."""
    if isinstance(polygons, tuple) and len(polygons) == 2 and not np.isscalar(polygons[1]):
        flat, sizes = (np.asarray(a) for a in polygons)
        if flat.ndim == 1 and sizes.ndim == 1:
            if not (np.issubdtype(flat.dtype, np.integer) and np.issubdtype(sizes.dtype, np.integer)):
                raise MeshError("corner vertices and polygon sizes must be integers")
            if sizes.sum() != flat.size:
                raise MeshError(f"polygon sizes add up to {sizes.sum()} corners, but {flat.size} are given")
            return flat.astype(np.int64), sizes.astype(np.int64)
    if isinstance(polygons, np.ndarray) and polygons.ndim == 2:
        return polygons.astype(np.int64).ravel(), np.full(len(polygons), polygons.shape[1], np.int64)
    try:
        polys = [np.asarray(p, dtype=np.int64).ravel() for p in polygons]
    except (TypeError, ValueError) as err:
        raise MeshError(f"polygons must be sequences of vertex indices: {err}") from None
    if not polys:
        return np.empty(0, np.int64), np.empty(0, np.int64)
    return np.concatenate(polys), np.array([p.size for p in polys], np.int64)
