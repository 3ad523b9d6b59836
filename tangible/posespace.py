"""Pose-space interpolation for the bones the device does not drive (§3.2, after Buck et al. 2000).

A :class:`PoseSpace` is built once from sample poses: the *keys* are the driven bones' rotations, the
*values* the other bones' rotations. Each query then

1. aligns the key quaternions with the samples' hemisphere (q and −q are one rotation) and stacks them;
2. projects them onto the samples' first two principal components (PCA, 2-D as in the paper);
3. finds the Delaunay triangle (scipy) containing the projection and its barycentric weights — outside
   the samples' convex hull, the nearest point of the hull's boundary is used, which keeps the result
   continuous;
4. blends the triangle's sample values with **barycentric slerp**:
   ``q = slerp(slerp(q₀, q₁, w₁/(w₀+w₁)), q₂, w₂)``.

Why this blend: on every edge of the triangulation (one weight zero) it is exactly the slerp of that
edge's two samples, whichever way round the triangle lists them, so the interpolant is continuous across
neighbouring triangles and equals every sample at its vertex; it stays inside the spherical triangle
spanned by the three rotations (a convex blend) and costs two slerps per bone, no iteration (unlike a
weighted Karcher mean, which agrees with it to second order in the triangle's size). A normalized
weighted quaternion sum would be as cheap but does not reduce to slerp on the edges.

Degenerate sample sets are handled: one distinct sample gives a constant, samples whose projections are
collinear give a 1-D piecewise-linear interpolation along the line, and samples that project to the same
point are merged into their equal-weight blend.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import Delaunay

from . import rotations as rot
from .errors import RigError

__all__ = ["PoseSpace", "blend"]


def blend(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Barycentric slerp of up to three rotation sets.

    Parameters
    ----------
    values : (k, u, 4)
        k = 1, 2 or 3 sets of u quaternions.
    weights : (k,)
        Non-negative, summing to 1.

    Returns
    -------
    (u, 4)
    """
    k = len(weights)
    q = values[0]
    if k >= 2:
        s = weights[0] + weights[1]
        q = rot.slerp(q, values[1], weights[1] / s if s > 0 else 0.0)
    if k == 3:
        q = rot.slerp(q, values[2], weights[2])
    return q


def _merge(values: np.ndarray) -> np.ndarray:
    """Equal-weight blend of n rotation sets (n, u, 4), by a running slerp mean."""
    q = values[0]
    for i in range(1, len(values)):
        q = rot.slerp(q, values[i], 1.0 / (i + 1))
    return q


class PoseSpace:
    """Interpolate value rotations from key rotations over a set of sample poses.

    Parameters
    ----------
    keys : (s, l, 4) array_like
        Each sample's driven-bone rotations (quaternions ``(w, x, y, z)``).
    values : (s, u, 4) array_like
        Each sample's rotations of the bones to synthesize.
    """

    def __init__(self, keys, values):
        K = np.asarray(keys, dtype=np.float64)
        V = np.asarray(values, dtype=np.float64)
        if (
            K.ndim != 3
            or K.shape[-1] != 4
            or V.ndim != 3
            or V.shape[-1] != 4
            or len(K) != len(V)
            or not len(K)
        ):
            raise RigError(
                f"keys (s, l, 4) and values (s, u, 4) need the same s ≥ 1, got {K.shape}, {V.shape}"
            )
        if not (np.all(np.isfinite(K)) and np.all(np.isfinite(V))):
            raise RigError("sample rotations must be finite")
        K = K / np.linalg.norm(K, axis=-1, keepdims=True)
        V = V / np.linalg.norm(V, axis=-1, keepdims=True)
        # Hemisphere of each driven bone: align to sample 0, then to the normalized mean of the aligned set.
        ref = np.where(np.sum(K * K[:1], axis=-1, keepdims=True) < 0, -K, K).sum(axis=0)
        self._ref = ref / np.maximum(np.linalg.norm(ref, axis=-1, keepdims=True), 1e-300)
        flat = self._align(K).reshape(len(K), -1)
        self._mean = flat.mean(axis=0)
        _, sigma, Vt = np.linalg.svd(flat - self._mean, full_matrices=False)
        tol = 1e-9 * max(float(sigma[0]) if sigma.size else 0.0, 1.0)
        rank = int(np.sum(sigma > tol))
        self._axes = Vt[: min(rank, 2)]
        y = (flat - self._mean) @ self._axes.T
        # Merge samples that project to the same point.
        spread = float(np.ptp(y, axis=0).max()) if y.size else 0.0
        key = np.round(y / max(spread, 1e-300) * 1e9) if spread > 0 else np.zeros_like(y)
        _, first, group = np.unique(key, axis=0, return_index=True, return_inverse=True)
        group = group.reshape(-1)
        order = np.argsort(first)
        relabel = np.empty_like(order)
        relabel[order] = np.arange(order.size)
        group = relabel[group]
        self.points = y[np.sort(first)]  # (n, d) projected distinct samples
        self.values = np.array([_merge(V[group == g]) for g in range(order.size)])  # (n, u, 4)
        self.sample_group = group
        n, d = self.points.shape[0], self._axes.shape[0]
        if n >= 3 and d == 2:
            self._tri = Delaunay(self.points)
            self._edges = self._tri.convex_hull
            self._T = self._tri.transform[:, :2]
            self._origin = self._tri.transform[:, 2]
        else:
            self._tri = None
            if d >= 1 and n >= 2:
                t = self.points[:, 0]
                self._line = np.argsort(t)
                self._t = t[self._line]

    def _align(self, K: np.ndarray) -> np.ndarray:
        return np.where(np.sum(K * self._ref, axis=-1, keepdims=True) < 0, -K, K)

    def project(self, key) -> np.ndarray:
        """(d,) coordinates of a key pose (l, 4) in the 2-D (or lower) pose space."""
        k = np.asarray(key, dtype=np.float64)
        if k.shape != self._ref.shape:
            raise RigError(f"a key pose has shape {self._ref.shape}, got {k.shape}")
        k = k / np.linalg.norm(k, axis=-1, keepdims=True)
        return (self._align(k).reshape(-1) - self._mean) @ self._axes.T

    def weights(self, key) -> tuple[np.ndarray, np.ndarray]:
        """Distinct-sample indices (k,) and convex weights (k,), k ≤ 3, for a key pose (l, 4)."""
        y = self.project(key)
        if self._tri is not None:
            # Barycentric coordinates in every triangle at once (a few dozen): cheaper than a walk.
            b = np.einsum("tij,tj->ti", self._T, y - self._origin)
            w = np.column_stack([b, 1.0 - b.sum(axis=1)])
            inside = np.flatnonzero(w.min(axis=1) >= -1e-12)
            if inside.size:
                s = int(inside[0])
                w = np.clip(w[s], 0.0, None)
                return self._tri.simplices[s], w / w.sum()
            a, c = self.points[self._edges[:, 0]], self.points[self._edges[:, 1]]
            ac = c - a
            t = np.clip(np.sum((y - a) * ac, axis=1) / np.maximum(np.sum(ac * ac, axis=1), 1e-300), 0.0, 1.0)
            dist = np.sum((a + t[:, None] * ac - y) ** 2, axis=1)
            e = int(np.argmin(dist))
            return self._edges[e], np.array([1.0 - t[e], t[e]])
        if len(self.points) == 1 or self._axes.shape[0] == 0:
            return np.array([0]), np.array([1.0])
        t = float(y[0])
        i = int(np.clip(np.searchsorted(self._t, t) - 1, 0, len(self._t) - 2))
        u = float(np.clip((t - self._t[i]) / (self._t[i + 1] - self._t[i]), 0.0, 1.0))
        return self._line[[i, i + 1]], np.array([1.0 - u, u])

    def __call__(self, key) -> np.ndarray:
        """(u, 4) synthesized value rotations for a key pose (l, 4)."""
        idx, w = self.weights(key)
        return blend(self.values[idx], w)
