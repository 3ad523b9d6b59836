"""Closest points on a triangle mesh: for points in space, the nearest point of the surface, exactly.

This is the Euclidean query (straight lines through space); :func:`geodesics.closest_points` is the
geodesic one (the nearest of several surface points, measured on the surface).

:class:`ClosestPoints` precomputes once per mesh and answers batches of queries, in the style of
potpourri3d's solver objects; ``ClosestPoints.of(mesh)`` is the one of a mesh, built on first use and
kept while the mesh lives (a :class:`~geodesics.TriMesh` is immutable).

How a query is answered:

* Every face is represented in a k-d tree by the centroids of its L x L sub-triangles
  (:func:`face_samples`; L = 1 but for unusually large faces), each within its ``reach`` (the
  sub-triangles' circumradius, at most ``spacing``) of every point it stands for: a face is at least
  (distance to one of its representatives) - reach from any query.
* The :data:`NEAREST_CANDIDATES` representatives nearest a query are looked up; the face of the
  nearest is at most its distance d0 away, so only faces with a representative within its reach of d0
  are tested exactly (:func:`closest_on_triangles`). When a representative beyond those could still
  stand for a closer face (the last one is within the best distance found plus ``spacing``), every face
  with a representative within reach of the best distance is tested instead. The answer is therefore
  exact, whatever the mesh; where faces tie, the first found wins.
* With ``max_distance``, a query that is provably farther from the surface than that (by its distance
  to the mesh's bounding box, or by its nearest representative) gets a lower bound greater than
  ``max_distance`` instead, and no closest point: far queries cost a box test or one bounded
  nearest-neighbour search.

Conventions. ``faces[i]`` indexes ``mesh.faces``; ``bary[i]`` are the barycentric coordinates of the
closest point with respect to that face's corners (non-negative, summing to one: exactly zero on the
coordinates of the corners a closest point on an edge or a corner does not involve). ``features[i]``
names the part of the face the closest point lies on: 0, 1, 2 = corner k; 3, 4, 5 = edge (0-1), (1-2),
(2-0); 6 = the interior (Ericson's regions, *Real-Time Collision Detection*, 5.1.5). Queries that got a
bound have NaN points and barycentric coordinates and face and feature -1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .errors import MeshError
from .mesh import TriMesh, per_mesh

#: Faces with the representatives nearest a query are tested first; most queries need no others.
NEAREST_CANDIDATES = 32
#: Faces larger than this quantile of the faces' circumradii are represented by several points.
LARGE_FACE_QUANTILE = 0.9


@dataclass(frozen=True, eq=False)
class Closest:
    """The closest points of a batch of k queries (see the module docstring for the conventions).

    Attributes
    ----------
    distances : (k,) float
        Distance from each query to the surface; for a query beyond ``max_distance``, a lower bound
        greater than it.
    points : (k, 3) float
        The closest points (NaN where bounded).
    faces : (k,) int
        The face each closest point lies in (-1 where bounded).
    bary : (k, 3) float
        Its barycentric coordinates in that face (NaN where bounded).
    features : (k,) int
        The corner (0-2), edge (3-5) or interior (6) of the face it lies on (-1 where bounded).
    """

    distances: np.ndarray
    points: np.ndarray
    faces: np.ndarray
    bary: np.ndarray
    features: np.ndarray


def face_samples(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points that stand for the faces of a mesh in a nearest-neighbour search.

    Every face (corners (m, 3, 3)) is represented by the centroids of its L x L sub-triangles (L = 1 for
    all but unusually large faces, beyond the :data:`LARGE_FACE_QUANTILE` of circumradii): each point of
    a face is within its sub-triangles' circumradius (the face's over L, the sample's ``reach``) of one
    of them, so a face is at least (distance to one of its representatives) - reach away from any query.
    Returns the samples (s, 3), the face each stands for (s,) and their reach (s,).
    """
    T = np.asarray(corners, dtype=np.float64)
    centroids = T.mean(1)
    radius = np.linalg.norm(T - centroids[:, None], axis=2).max(1)
    levels = np.maximum(1, np.ceil(radius / np.quantile(radius, LARGE_FACE_QUANTILE))).astype(np.int64)
    samples, owners = [], []
    for level in np.unique(levels):
        faces = np.flatnonzero(levels == level)
        i, j = np.meshgrid(np.arange(level), np.arange(level), indexing="ij")
        up, down = i + j <= level - 1, i + j <= level - 2
        uv = (
            np.concatenate(
                [
                    np.stack([i[up] + 1 / 3, j[up] + 1 / 3], 1),
                    np.stack([i[down] + 2 / 3, j[down] + 2 / 3], 1),
                ]
            )
            / level
        )
        bary = np.stack([1 - uv.sum(1), uv[:, 0], uv[:, 1]], 1)
        samples.append(np.einsum("sc,fcd->fsd", bary, T[faces]).reshape(-1, 3))
        owners.append(np.repeat(faces, len(bary)))
    owner = np.concatenate(owners)
    return np.concatenate(samples), owner, (radius / levels)[owner]


def closest_on_triangles(P: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, ...]:
    """The closest point of each triangle to each point, pairwise.

    Parameters
    ----------
    P : (k, 3) float
        Points.
    T : (k, 3, 3) float
        Triangles: ``T[i, c]`` is corner c of the triangle of ``P[i]``.

    Returns
    -------
    distances : (k,) float
    points : (k, 3) float
        ``a + v (b - a) + w (c - a)``.
    bary : (k, 3) float
        ``(1 - v - w, v, w)``, with exact zeros off the closest feature.
    features : (k,) int
        0, 1, 2 = corner; 3, 4, 5 = edge (0-1), (1-2), (2-0); 6 = interior (Ericson's region tests).
    """
    a, b, c = T[:, 0], T[:, 1], T[:, 2]
    ab, ac = b - a, c - a

    def dot(u, v):
        return np.einsum("kj,kj->k", u, v)

    ap, bp, cp = P - a, P - b, P - c
    d1, d2 = dot(ab, ap), dot(ac, ap)
    d3, d4 = dot(ab, bp), dot(ac, bp)
    d5, d6 = dot(ab, cp), dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ab = d1 / (d1 - d3)
        t_ca = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        denom = 1.0 / (va + vb + vc)
    conditions = [
        (d1 <= 0) & (d2 <= 0),
        (d3 >= 0) & (d4 <= d3),
        (d6 >= 0) & (d5 <= d6),
        (vc <= 0) & (d1 >= 0) & (d3 <= 0),
        (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0),
        (vb <= 0) & (d2 >= 0) & (d6 <= 0),
    ]
    features = np.select(conditions, [0, 1, 2, 3, 4, 5], 6)
    # Barycentric weights of b and c in each region (a's is 1 - v - w).
    v = np.choose(features, [0.0, 1.0, 0.0, t_ab, 1 - t_bc, 0.0, vb * denom])
    w = np.choose(features, [0.0, 0.0, 1.0, 0.0, t_bc, t_ca, vc * denom])
    points = a + v[:, None] * ab + w[:, None] * ac
    bary = np.stack([np.where(features == 4, 0.0, 1 - v - w), v, w], 1)
    return _lengths(P - points), points, bary, features


def _lengths(V: np.ndarray) -> np.ndarray:
    """(k,) Euclidean lengths of the rows of V (k, 3): the bits of ``np.linalg.norm(V, axis=1)`` without
    its general reduction over rows of three."""
    sq = V * V
    return np.sqrt(sq[:, 0] + sq[:, 1] + sq[:, 2])


class ClosestPoints:
    """Exact closest points on a triangle mesh, for batches of query points.

    Parameters
    ----------
    mesh : TriMesh
        Any valid mesh (open or closed, one component or several). The solver keeps its own copy of
        what it needs and no reference to the mesh.
    """

    def __init__(self, mesh: TriMesh):
        self._corners = mesh.vertices[mesh.faces]
        samples, self._owner, self._reach = face_samples(self._corners)
        self._spacing = float(self._reach.max())
        self._tree = cKDTree(samples)
        used = self._corners.reshape(-1, 3)
        self._lo, self._hi = used.min(0), used.max(0)

    @classmethod
    def of(cls, mesh: TriMesh) -> ClosestPoints:
        """The solver of ``mesh``: built on first use, shared by every later call while the mesh lives."""
        return _solver_of(mesh)

    def box_gap(self, points) -> np.ndarray:
        """(k,) distance of points (k, 3) to the bounding box of the mesh's faces (0 inside it): a lower
        bound on their distance to the surface."""
        X = np.asarray(points, dtype=np.float64)
        return _lengths(np.maximum(self._lo - X, 0) + np.maximum(X - self._hi, 0))

    def query(self, points, max_distance=np.inf, *, box_gap=None) -> Closest:
        """The closest surface points of points (k, 3).

        Parameters
        ----------
        points : (k, 3) array_like
            Finite query points; a single point (3,) is a batch of one.
        max_distance : float or (k,) array_like
            Queries provably farther than this from the surface get a lower bound greater than it
            instead of their distance, and no closest point (see :class:`Closest`). The default
            answers every query exactly.
        box_gap : (k,) array_like, optional
            The points' :meth:`box_gap`, when the caller has computed it already.

        Returns
        -------
        Closest

        Raises
        ------
        MeshError
            For points of another shape, NaN or infinite points, a NaN ``max_distance``, or a
            ``box_gap`` of another shape.
        """
        X = np.asarray(points, dtype=np.float64)
        if X.ndim == 1:
            X = X[None]
        if X.ndim != 2 or X.shape[1] != 3:
            raise MeshError(f"query points must have shape (k, 3), got {X.shape}")
        if not np.all(np.isfinite(X)):
            raise MeshError("query points contain NaN or infinite values")
        k = len(X)
        try:
            limit = np.broadcast_to(np.asarray(max_distance, dtype=np.float64), (k,))
        except ValueError:
            raise MeshError(
                f"max_distance must be a number or one per query point ({k}), got shape "
                f"{np.shape(max_distance)}"
            ) from None
        if np.any(np.isnan(limit)):
            raise MeshError("max_distance must not be NaN")
        result = Closest(
            np.empty(k), np.full((k, 3), np.nan), np.full(k, -1), np.full((k, 3), np.nan), np.full(k, -1)
        )
        gap = self.box_gap(X) if box_gap is None else np.asarray(box_gap, dtype=np.float64)
        if gap.shape != (k,):
            raise MeshError(f"box_gap must have shape ({k},), got {gap.shape}")
        far = gap > limit
        result.distances[far] = gap[far]
        rows = np.flatnonzero(~far)
        if rows.size == 0:
            return result
        finite = np.isfinite(limit[rows])
        # A query within max_distance + spacing of its nearest representative finds every representative
        # it needs within max_distance + 2 spacing; one with none there is farther than max_distance.
        for group in (rows[finite], rows[~finite]):
            if group.size:
                reach = limit[group].max() + 2 * self._spacing
                (
                    result.distances[group],
                    result.points[group],
                    result.bary[group],
                    result.features[group],
                    result.faces[group],
                ) = self._search(X[group], limit[group], gap[group], reach)
        return result

    def _search(
        self, Y: np.ndarray, limit: np.ndarray, gap: np.ndarray, reach: float
    ) -> tuple[np.ndarray, ...]:
        """Distances (m,), closest points (m, 3), barycentric coordinates (m, 3), features (m,) and faces
        (m,) of points Y (m, 3) whose representatives within ``reach`` are all they need, bounded where
        provably farther than ``limit`` (m,); ``gap`` (m,) is their distance to the bounding box."""
        m, n = len(Y), len(self._owner)
        k = min(NEAREST_CANDIDATES, n)
        spacing = self._spacing
        slack = 1e-9 * spacing  # rounding in the bounds, where a face is kept rather than left out
        sample_dist, nearest = self._tree.query(Y, k=k, distance_upper_bound=reach)
        sample_dist, nearest = sample_dist.reshape(m, k), nearest.reshape(m, k)
        lower = np.maximum(gap, np.minimum(sample_dist[:, 0], reach) - spacing)
        exact = np.flatnonzero(lower <= limit)
        best = np.where(lower <= limit, np.nan, lower)
        best_closest, best_bary = np.full((m, 3), np.nan), np.full((m, 3), np.nan)
        best_feature, best_face = np.full(m, -1), np.full(m, -1)
        if exact.size == 0:
            return best, best_closest, best_bary, best_feature, best_face
        # The face of the nearest representative is at most sample_dist[:, 0] away: a face can only be
        # closer if one of its representatives is within its reach of that (absent ones are inf, their
        # index n clipped).
        sample_dist, nearest = sample_dist[exact], nearest[exact]
        reach_of = np.take(self._reach, nearest, mode="clip")
        row, slot = np.nonzero(sample_dist - reach_of <= sample_dist[:, :1] + slack)
        face = self._owner[nearest[row, slot]]
        dist, closest, bary, feature = closest_on_triangles(Y[exact[row]], self._corners[face])
        table = np.full(sample_dist.shape, np.inf)
        table[row, slot] = dist
        pair = np.zeros(sample_dist.shape, np.int64)
        pair[row, slot] = np.arange(row.size)
        pick = pair[np.arange(exact.size), np.argmin(table, axis=1)]
        best[exact], best_closest[exact], best_bary[exact] = dist[pick], closest[pick], bary[pick]
        best_feature[exact], best_face[exact] = feature[pick], face[pick]
        # Exact unless an unseen face could be closer: the k-th representative is within reach.
        redo = exact[(k < n) & (sample_dist[:, -1] <= best[exact] + spacing)]
        if redo.size:
            faces, d, c, b, f = self._ball_search(Y[redo], best[redo], slack)
            best[redo], best_closest[redo], best_bary[redo] = d, c, b
            best_feature[redo], best_face[redo] = f, faces
        return best, best_closest, best_bary, best_feature, best_face

    def _ball_search(self, Y: np.ndarray, best: np.ndarray, slack: float) -> tuple[np.ndarray, ...]:
        """Faces (r,), distances (r,), closest points (r, 3), barycentric coordinates (r, 3) and features
        (r,) of points Y (r, 3) whose closest face is within ``best`` (r,): every face with a
        representative within its reach of that is tested (ties go to the lowest face index)."""
        lists = self._tree.query_ball_point(Y, best + self._spacing + slack)
        found = np.fromiter((len(c) for c in lists), np.int64, len(lists))
        point = np.repeat(np.arange(len(Y)), found)
        sample = np.concatenate(lists).astype(np.int64)
        near = _lengths(Y[point] - self._tree.data[sample]) - self._reach[sample] <= best[point] + slack
        # Each (query, face) pair once: a face can have several representatives in a query's ball.
        faces_total = len(self._corners)
        pairs = np.unique(point[near] * faces_total + self._owner[sample[near]])
        point, faces = pairs // faces_total, pairs % faces_total
        d, c, b, f = closest_on_triangles(Y[point], self._corners[faces])
        start = np.flatnonzero(np.r_[True, point[1:] != point[:-1]])
        lowest = np.minimum.reduceat(d, start)
        first = np.flatnonzero(d == np.repeat(lowest, np.diff(np.r_[start, d.size])))
        first = first[np.r_[True, point[first][1:] != point[first][:-1]]]
        return faces[first], d[first], c[first], b[first], f[first]


_solver_of = per_mesh(ClosestPoints)
