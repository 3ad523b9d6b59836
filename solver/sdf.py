"""Signed distances: to a closed triangle mesh (exact), to a half-space and to a box (analytic).

Sign convention: negative inside, positive outside, zero on the surface.

:class:`MeshSDF` finds each query's exact closest point on the mesh (candidate faces from a k-d tree of
face centroids, then the exact point-triangle distance) and takes the sign from the angle-weighted
pseudonormal of the closest feature (face, edge or vertex): Bærentzen and Aanæs, *Signed distance
computation using the angle weighted pseudonormal*, IEEE TVCG 11(3), 2005, which is exact for closed,
manifold, consistently oriented meshes (what :class:`~geodesics.TriMesh` validates, plus no boundary).
Candidate faces come from a k-d tree of face centroids (several per unusually large face), so a face
whose nearest representative is farther than the best distance found plus the largest face radius is
never tested.

Ours rather than ``trimesh.proximity.signed_distance``, which is the independent oracle of the tests
(``tests/test_trimesh_oracle.py``): trimesh decides a point's region of a triangle and settles between
competing faces with absolute tolerances (1e-13 on dot products, 1e-8 on squared distances), so on a mug
in metres, a tenth of a millimetre from its surface, it can return a neighbouring face's point several
percent farther (the tests compare it on meshes scaled up until its tolerances vanish, and check that
ours are scale-invariant); it signs points whose closest point is on an edge or a vertex by ray-cast
containment and leaves points within 1e-8 of the surface unsigned, where the pseudonormal is exact; and
it is an order of magnitude slower on the solver's meshes.

:class:`HalfSpace` and :class:`Box` are the table or ground of the retargeting paper's Eq. 6, with
gradients for the solver (Inigo Quilez's box distance).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from geodesics import TriMesh

from .errors import SolverError, describe_ids

#: Faces with the representatives nearest a query are tested first; most queries need no others.
NEAREST_CANDIDATES = 16
#: Faces larger than this quantile of the faces' circumradii are represented by several points.
LARGE_FACE_QUANTILE = 0.9


def _points(x) -> np.ndarray:
    X = np.asarray(x, dtype=np.float64)
    if X.ndim == 1:
        X = X[None]
    if X.ndim != 2 or X.shape[1] != 3:
        raise SolverError(f"query points must have shape (k, 3), got {X.shape}")
    return X


def face_samples(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Points that stand for the faces of a mesh in a nearest-neighbour search.

    Every face (corners (m, 3, 3)) is represented by the centroids of its L x L sub-triangles (L = 1 for
    all but unusually large faces, beyond the :data:`LARGE_FACE_QUANTILE` of circumradii): each point of
    a face is within ``spacing`` of one of them, so a face is at least (distance to its nearest
    representative) - spacing away from any query. Returns the samples (s, 3), the face each stands
    for (s,) and ``spacing``.
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
    return np.concatenate(samples), np.concatenate(owners), float((radius / levels).max())


class MeshSDF:
    """Exact signed distance to a closed triangle mesh.

    Parameters
    ----------
    mesh : TriMesh
        Closed (no boundary edges), outward oriented.

    Raises
    ------
    SolverError
        If the mesh has boundary edges (inside and outside are then undefined).
    """

    def __init__(self, mesh: TriMesh):
        open_edges = np.flatnonzero(mesh.twin < 0)
        if open_edges.size:
            faces = describe_ids(open_edges // 3)
            raise SolverError(f"signed distance needs a closed mesh; faces {faces} have boundary edges")
        self.mesh = mesh
        T = mesh.vertices[mesh.faces]
        self._corners = T
        samples, self._owner, self._spacing = face_samples(T)
        self._tree = cKDTree(samples)
        self._box = (mesh.vertices.min(0), mesh.vertices.max(0))
        n = mesh.face_normals
        self._edge_normals = (n[np.arange(3 * mesh.n_faces) // 3] + n[mesh.twin // 3]).reshape(-1, 3, 3)

    def __call__(self, points, max_distance: float = np.inf) -> np.ndarray:
        """(k,) signed distances of points (k, 3); see :meth:`query` for ``max_distance``."""
        return self.query(points, max_distance)[0]

    def evaluate(self, points, band: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """Signed distances (k,) and their gradients (k, 3) at points (k, 3), as :class:`HalfSpace` and
        :class:`Box` give them, so that a closed mesh can be what a hand keeps out of.

        The gradient is the unit vector from the closest point to the query (outwards inside as well
        as outside); on the surface, the closest face's normal. Points provably farther than ``band``
        from the surface get a positive lower bound on their distance and a zero gradient *whether
        they are inside or outside*: a penalty on penetration then acts within ``band`` of the surface
        only, which is what keeps it cheap (a hand mostly away from the object costs one nearest-
        neighbour query per vertex). The default band is infinite: exact signs everywhere (and
        :meth:`query`'s bound, with ``max_distance = 0``, outside the bounding box).
        """
        X = _points(points)
        signed = np.empty(len(X))
        gradient = np.zeros_like(X)
        near = np.arange(len(X))
        if np.isfinite(band):
            gap = np.linalg.norm(np.maximum(self._box[0] - X, 0) + np.maximum(X - self._box[1], 0), axis=1)
            near = np.flatnonzero(gap <= band)
            signed[gap > band] = gap[gap > band]
            first, _ = self._tree.query(X[near], distance_upper_bound=band + self._spacing)
            # No point of the surface is closer than this (with no sample in reach: than the band).
            lower = np.where(np.isinf(first), band, first - self._spacing)
            far = np.isinf(first) | (lower > band)
            signed[near[far]] = lower[far]
            near = near[~far]
        signed[near], closest, face = self.query(X[near], max_distance=0.0)
        exact = face >= 0
        off = exact & (signed[near] != 0)
        rows = near[off]
        gradient[rows] = (X[rows] - closest[off]) / signed[rows, None]
        on = exact & (signed[near] == 0)
        gradient[near[on]] = self.mesh.face_normals[face[on]]
        return signed, gradient

    def query(self, points, max_distance: float = np.inf) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Signed distances (k,), closest points (k, 3) and their faces (k,) for points (k, 3).

        Parameters
        ----------
        points : (k, 3) array_like
        max_distance : float
            Points outside the mesh's bounding box and provably farther than this from the surface get
            a positive lower bound on their distance instead of the exact value (their closest point is
            then NaN and their face -1). The default computes every distance exactly.
        """
        X = _points(points)
        if not np.all(np.isfinite(X)):
            raise SolverError("query points must be finite")
        n = len(X)
        signed = np.empty(n)
        out_closest = np.full((n, 3), np.nan)
        out_face = np.full(n, -1, np.int64)
        box_gap = np.linalg.norm(np.maximum(self._box[0] - X, 0) + np.maximum(X - self._box[1], 0), axis=1)
        far = box_gap > max_distance  # outside the box, hence outside the mesh
        signed[far] = box_gap[far]
        near = np.flatnonzero(~far)
        if near.size == 0:
            return signed, out_closest, out_face
        Y = X[near]
        m = len(Y)
        k = min(NEAREST_CANDIDATES, len(self._owner))
        sample_dist, nearest = self._tree.query(Y, k=k)
        sample_dist = sample_dist.reshape(m, k)
        nearest = self._owner[nearest.reshape(m, k)]
        dist, closest, feature = _closest_on_triangles(
            np.repeat(Y, k, axis=0), self._corners[nearest.ravel()]
        )
        pick = np.argmin(dist.reshape(m, k), axis=1)
        flat = np.arange(m) * k + pick
        best, best_closest, best_feature = dist[flat], closest[flat], feature[flat]
        best_face = nearest[np.arange(m), pick]
        # Exact unless an unseen face could be closer: the k-th sample is within reach.
        unsure = (k < len(self._owner)) & (sample_dist[:, -1] <= best + self._spacing)
        lower = np.maximum(box_gap[near], sample_dist[:, 0] - self._spacing)
        bound = unsure & (box_gap[near] > 0) & (lower > max_distance)
        redo = np.flatnonzero(unsure & ~bound)
        if redo.size:
            lists = self._tree.query_ball_point(Y[redo], best[redo] + self._spacing * (1 + 1e-9))
            # Each (query, face) pair once: a face can have several samples in a query's ball.
            found = np.fromiter((len(c) for c in lists), np.int64, len(lists))
            pairs = np.unique(
                np.repeat(np.arange(redo.size), found) * len(self._corners)
                + self._owner[np.concatenate(lists).astype(np.int64)]
            )
            owner, faces = redo[pairs // len(self._corners)], pairs % len(self._corners)
            counts = np.bincount(pairs // len(self._corners), minlength=redo.size)
            d, c, f = _closest_on_triangles(Y[owner], self._corners[faces])
            order = np.lexsort((d, owner))
            first = order[np.concatenate([[0], np.cumsum(counts)[:-1]])]
            best[redo], best_closest[redo] = d[first], c[first]
            best_feature[redo], best_face[redo] = f[first], faces[first]
        normal = self.mesh.face_normals[best_face].copy()
        on_vertex = best_feature < 3
        normal[on_vertex] = self.mesh.vertex_normals[
            self.mesh.faces[best_face[on_vertex], best_feature[on_vertex]]
        ]
        on_edge = (best_feature >= 3) & (best_feature < 6)
        normal[on_edge] = self._edge_normals[best_face[on_edge], best_feature[on_edge] - 3]
        side = np.einsum("kj,kj->k", Y - best_closest, normal)
        exact = ~bound
        signed[near] = np.where(bound, lower, np.where(side < 0, -best, best))
        out_closest[near[exact]] = best_closest[exact]
        out_face[near[exact]] = best_face[exact]
        return signed, out_closest, out_face


def _closest_on_triangles(P: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distances (k,), closest points (k, 3) and features (k,) of points P (k, 3) on triangles (k, 3, 3).

    Features: 0, 1, 2 = corner; 3, 4, 5 = edge (0-1), (1-2), (2-0); 6 = face interior (Ericson's
    region tests, *Real-Time Collision Detection*, 5.1.5).
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
    feature = np.select(conditions, [0, 1, 2, 3, 4, 5], 6)
    # Barycentric weights of b and c in each region (a's is 1 - v - w).
    zero = np.zeros_like(d1)
    v = np.select(conditions, [zero, zero + 1, zero, t_ab, 1 - t_bc, zero], vb * denom)
    w = np.select(conditions, [zero, zero, zero + 1, zero, t_bc, t_ca], vc * denom)
    closest = a + v[:, None] * ab + w[:, None] * ac
    return np.linalg.norm(P - closest, axis=1), closest, feature


@dataclass(frozen=True)
class HalfSpace:
    """The solid ``(x - point) . normal <= 0`` (a table top or the ground, its free side along normal)."""

    point: np.ndarray = field(default_factory=lambda: np.zeros(3))
    normal: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))

    def __post_init__(self):
        p = np.asarray(self.point, dtype=np.float64).reshape(-1)
        n = np.asarray(self.normal, dtype=np.float64).reshape(-1)
        if p.size != 3 or n.size != 3 or not (np.all(np.isfinite(p)) and np.all(np.isfinite(n))):
            raise SolverError("a half-space needs a finite point (3,) and normal (3,)")
        length = np.linalg.norm(n)
        if length == 0:
            raise SolverError("a half-space needs a nonzero normal")
        object.__setattr__(self, "point", p)
        object.__setattr__(self, "normal", n / length)

    def evaluate(self, x) -> tuple[np.ndarray, np.ndarray]:
        """Signed distances (k,) and their gradients (k, 3) at points (k, 3)."""
        X = _points(x)
        return (X - self.point) @ self.normal, np.broadcast_to(self.normal, X.shape)


@dataclass(frozen=True)
class Box:
    """A solid box (a table): centre (3,), half extents (3,), rotation (3, 3) from box to world axes."""

    center: np.ndarray
    half_extents: np.ndarray
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self):
        c = np.asarray(self.center, dtype=np.float64).reshape(-1)
        h = np.asarray(self.half_extents, dtype=np.float64).reshape(-1)
        R = np.asarray(self.rotation, dtype=np.float64)
        if c.size != 3 or h.size != 3 or R.shape != (3, 3):
            raise SolverError("a box needs a centre (3,), half extents (3,) and a rotation (3, 3)")
        if not (
            np.all(np.isfinite(c)) and np.all(np.isfinite(R)) and np.all(h > 0) and np.all(np.isfinite(h))
        ):
            raise SolverError("a box needs a finite centre and rotation and positive finite half extents")
        if np.abs(R.T @ R - np.eye(3)).max() > 1e-9 or np.linalg.det(R) <= 0:
            raise SolverError("a box's rotation must be a rotation matrix")
        object.__setattr__(self, "center", c)
        object.__setattr__(self, "half_extents", h)
        object.__setattr__(self, "rotation", R)

    def evaluate(self, x) -> tuple[np.ndarray, np.ndarray]:
        """Signed distances (k,) and their gradients (k, 3) at points (k, 3)."""
        local = (_points(x) - self.center) @ self.rotation
        sign = np.where(local < 0, -1.0, 1.0)
        q = np.abs(local) - self.half_extents
        outside = np.maximum(q, 0.0)
        out_len = np.linalg.norm(outside, axis=1)
        inside = np.minimum(q.max(1), 0.0)
        grad_local = np.divide(outside, out_len[:, None], out=np.zeros_like(q), where=out_len[:, None] > 0)
        deepest = np.argmax(q, axis=1)
        interior = out_len == 0
        grad_local[interior] = 0.0
        grad_local[interior, deepest[interior]] = 1.0
        return out_len + inside, (grad_local * sign) @ self.rotation.T
