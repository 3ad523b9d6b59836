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
    polygons : sequence of int sequences, or (p, s) int array

    Returns
    -------
    faces : (m, 3) int64
    polygon : (m,) int64, the polygon each triangle comes from
    corners : (m, 3) int64, each triangle corner's index within its polygon
    """
    if isinstance(polygons, np.ndarray) and polygons.ndim == 2:
        polys = [np.asarray(p, dtype=np.int64) for p in polygons]
    else:
        try:
            polys = [np.asarray(p, dtype=np.int64).ravel() for p in polygons]
        except (TypeError, ValueError) as err:
            raise MeshError(f"polygons must be sequences of vertex indices: {err}") from None
    if not polys:
        raise MeshError("the mesh has no faces")
    sizes = np.array([p.size for p in polys])
    small = np.flatnonzero(sizes < 3)
    if small.size:
        raise MeshError(f"polygons {describe_ids(small)} have fewer than three corners", faces=small)
    n = len(vertices)
    flat = np.concatenate(polys)
    if flat.size and (flat.min() < 0 or flat.max() >= n):
        offsets = np.repeat(np.arange(len(polys)), sizes)
        bad = np.unique(offsets[(flat < 0) | (flat >= n)])
        raise MeshError(f"polygons {describe_ids(bad)} use vertex indices outside 0..{n - 1}", faces=bad)

    faces, polygon, corners = [], [], []
    tri = np.flatnonzero(sizes == 3)
    if tri.size:
        faces.append(np.stack([polys[i] for i in tri]))
        polygon.append(tri)
        corners.append(np.tile([0, 1, 2], (tri.size, 1)))
    quad = np.flatnonzero(sizes == 4)
    if quad.size:
        Q = np.stack([polys[i] for i in quad])
        local = _split_quads(vertices, Q)  # (q, 2, 3)
        faces.append(np.take_along_axis(Q[:, None, :], local, axis=2).reshape(-1, 3))
        polygon.append(np.repeat(quad, 2))
        corners.append(local.reshape(-1, 3))
    for i in np.flatnonzero(sizes > 4):
        local = np.array(_ear_clip(vertices[polys[i]]), dtype=np.int64)
        faces.append(polys[i][local])
        polygon.append(np.full(len(local), i))
        corners.append(local)
    polygon = np.concatenate(polygon)
    order = np.argsort(polygon, kind="stable")
    return (
        np.concatenate(faces)[order].astype(np.int64),
        polygon[order].astype(np.int64),
        np.concatenate(corners)[order].astype(np.int64),
    )
