"""Box modelling for procedural assets: a closed polygon cage, extrusions, Catmull-Clark subdivision.

A :class:`Cage` is a closed, consistently oriented polygon mesh (faces counter-clockwise seen from
outside) whose vertices carry attributes, e.g. skin weights. :meth:`Cage.extrude` grows a region of
faces into a new ring of vertices, the way an artist extrudes fingers out of a palm block.
:func:`catmull_clark` subdivides the cage; it is linear in the cage's vertices, so applying the same
stencils to one-hot bone weights gives smooth, non-negative skin weights that still sum to one.
:func:`quads_to_triangles` splits each quad along its shorter diagonal.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse


class Cage:
    """A closed polygon mesh under construction.

    Parameters
    ----------
    n_attributes : int
        Number of per-vertex attribute channels (e.g. bones for skin weights).
    """

    def __init__(self, n_attributes: int):
        self._points: list[np.ndarray] = []
        self._attributes: list[np.ndarray] = []
        self.n_attributes = n_attributes
        self.faces: list[tuple[int, ...]] = []

    @property
    def n_vertices(self) -> int:
        return len(self._points)

    @property
    def points(self) -> np.ndarray:
        """(n, 3) vertex positions."""
        return np.array(self._points, dtype=np.float64).reshape(-1, 3)

    @property
    def attributes(self) -> np.ndarray:
        """(n, a) per-vertex attributes."""
        return np.array(self._attributes, dtype=np.float64).reshape(-1, self.n_attributes)

    def add_vertices(self, points, attributes) -> np.ndarray:
        """Append vertices (k, 3) with attributes (k, a) (or one row for all); returns their (k,) indices."""
        P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        A = np.broadcast_to(np.asarray(attributes, dtype=np.float64), (len(P), self.n_attributes))
        start = self.n_vertices
        self._points.extend(P)
        self._attributes.extend(A)
        return np.arange(start, start + len(P))

    def set_attributes(self, vertices, attributes) -> None:
        """Overwrite the attributes (a,) or (k, a) of the given vertices."""
        A = np.broadcast_to(np.asarray(attributes, dtype=np.float64), (len(vertices), self.n_attributes))
        for v, a in zip(vertices, A, strict=True):
            self._attributes[v] = a

    def add_face(self, vertices, outward=None) -> int:
        """Append a polygon; with ``outward`` (3,), reverse it if needed so its normal points that way."""
        face = tuple(int(v) for v in vertices)
        if outward is not None and np.dot(self.face_normal(face), outward) < 0:
            face = face[::-1]
        self.faces.append(face)
        return len(self.faces) - 1

    def face_normal(self, face) -> np.ndarray:
        """(3,) Newell normal (unnormalized, area-weighted) of a polygon (its vertex indices)."""
        P = np.array([self._points[v] for v in face])
        return 0.5 * np.cross(P, np.roll(P, -1, axis=0)).sum(0)

    def extrude(self, faces, ring, attributes) -> list[int]:
        """Extrude a region of faces into a new ring of vertices; return the region's new face indices.

        Parameters
        ----------
        faces : sequence of int
            A disk of faces. Their vertices are copied, the copies replace them in these faces, and each
            boundary edge of the region gets a quad joining the old vertices to the copies.
        ring : (k, 3) array_like or callable
            Positions of the copies: a callable maps the region's vertex positions (k, 3) (in
            ascending vertex order) to new ones; an array gives the new boundary loop in any cyclic
            order and direction, matched to the old loop by angle around both loops' centres (only for
            regions without interior vertices).
        attributes : (a,) or (k, a) array_like
            Attributes of the copies.
        """
        faces = list(faces)
        region = sorted({v for f in faces for v in self.faces[f]})
        old = np.array([self._points[v] for v in region])
        if callable(ring):
            new_positions = np.asarray(ring(old), dtype=np.float64)
        else:
            new_positions = self._match_loop(faces, region, np.asarray(ring, dtype=np.float64))
        A = np.broadcast_to(np.asarray(attributes, dtype=np.float64), (len(region), self.n_attributes))
        copies = dict(zip(region, self.add_vertices(new_positions, A).tolist(), strict=True))
        inside = {(f[k], f[(k + 1) % len(f)]) for i in faces for f in [self.faces[i]] for k in range(len(f))}
        for u, v in sorted(inside):
            if (v, u) not in inside:
                self.faces.append((u, v, copies[v], copies[u]))
        for i in faces:
            self.faces[i] = tuple(copies[v] for v in self.faces[i])
        return faces

    def bridge(self, face_a: int, face_b: int) -> None:
        """Remove two faces that face each other and join their loops with quads (adds a handle)."""
        A, B = self.faces[face_a], self.faces[face_b]
        if len(A) != len(B):
            raise ValueError("bridged faces need the same number of vertices")
        n = len(A)
        PA = np.array([self._points[v] for v in A])
        PB = np.array([self._points[v] for v in B])
        # Facing loops run in opposite directions: A[k] pairs with B[(shift - k) % n].
        costs = [np.linalg.norm(PA - PB[(s - np.arange(n)) % n], axis=1).sum() for s in range(n)]
        shift = int(np.argmin(costs))
        match = [B[(shift - k) % n] for k in range(n)]
        for k in range(n):
            self.faces.append((A[k], A[(k + 1) % n], match[(k + 1) % n], match[k]))
        for f in sorted((face_a, face_b), reverse=True):
            del self.faces[f]

    def _match_loop(self, faces, region, ring: np.ndarray) -> np.ndarray:
        loop = self._boundary_loop(faces)
        if len(loop) != len(region) or len(ring) != len(loop):
            raise ValueError("an explicit ring needs a region without interior vertices and one point each")
        old = np.array([self._points[v] for v in loop])
        normal = sum(self.face_normal(self.faces[f]) for f in faces)
        normal = normal / np.linalg.norm(normal)
        x = old[0] - old.mean(0)
        x -= normal * np.dot(x, normal)
        x /= np.linalg.norm(x)
        y = np.cross(normal, x)

        def angles(P):
            d = P - P.mean(0)
            return np.arctan2(d @ y, d @ x)

        a_old, a_new = angles(old), angles(ring)
        best, best_cost = None, np.inf
        n = len(loop)
        for direction in (1, -1):
            for shift in range(n):
                order = (shift + direction * np.arange(n)) % n
                diff = np.angle(np.exp(1j * (a_new[order] - a_old)))
                cost = np.sum(diff**2)
                if cost < best_cost:
                    best, best_cost = order, cost
        positions = np.empty((len(region), 3))
        index = {v: i for i, v in enumerate(region)}
        for k, v in enumerate(loop):
            positions[index[v]] = ring[best[k]]
        return positions

    def _boundary_loop(self, faces) -> list[int]:
        edges = {(f[k], f[(k + 1) % len(f)]) for i in faces for f in [self.faces[i]] for k in range(len(f))}
        nxt = {u: v for u, v in edges if (v, u) not in edges}
        start = next(iter(sorted(nxt)))
        loop = [start]
        while nxt[loop[-1]] != start:
            loop.append(nxt[loop[-1]])
        return loop


def catmull_clark(points, faces, attributes, levels: int = 1):
    """Catmull-Clark subdivision of a closed polygon mesh, applied alike to positions and attributes.

    Parameters
    ----------
    points : (n, 3) array_like
    faces : sequence of sequences of int
        Closed, manifold, consistently oriented polygons.
    attributes : (n, a) array_like
        Per-vertex attributes, subdivided with the same (affine, non-negative) stencils.
    levels : int

    Returns
    -------
    points : (n', 3) ndarray
    quads : (m', 4) ndarray of int
        Counter-clockwise like the input.
    attributes : (n', a) ndarray
    """
    P = np.asarray(points, dtype=np.float64)
    A = np.asarray(attributes, dtype=np.float64)
    polys = [np.asarray(f, dtype=np.int64) for f in faces]
    for _ in range(levels):
        S, quads = _subdivision_step(len(P), polys)
        P, A = S @ P, S @ A
        polys = list(quads)
    return P, np.asarray(polys, dtype=np.int64).reshape(-1, 4), A


def _subdivision_step(n: int, polys: list[np.ndarray]) -> tuple[sparse.csr_matrix, np.ndarray]:
    sizes = np.array([len(f) for f in polys])
    nf = len(polys)
    corner_v = np.concatenate(polys)
    corner_f = np.repeat(np.arange(nf), sizes)
    start = np.repeat(np.cumsum(sizes) - sizes, sizes)
    local = np.arange(corner_v.size) - start
    corner_next = corner_v[start + (local + 1) % sizes[corner_f]]
    lo, hi = np.minimum(corner_v, corner_next), np.maximum(corner_v, corner_next)
    keys, edge_of = np.unique(lo * n + hi, return_inverse=True)
    ne = keys.size
    if np.any(np.bincount(edge_of, minlength=ne) != 2):
        raise ValueError("Catmull-Clark needs a closed manifold cage (every edge in two faces)")
    eu, ev = keys // n, keys % n
    # Face points: (nf, n).
    Fm = sparse.csr_matrix((1.0 / sizes[corner_f], (corner_f, corner_v)), shape=(nf, n))
    # Edge points: (ne, n) = (u + v + face point + face point) / 4.
    edge_faces = sparse.csr_matrix((np.full(corner_f.size, 0.25), (edge_of, corner_f)), shape=(ne, nf))
    ends = sparse.csr_matrix(
        (np.full(2 * ne, 0.25), (np.tile(np.arange(ne), 2), np.concatenate([eu, ev]))), shape=(ne, n)
    )
    Em = ends + edge_faces @ Fm
    # Vertex points: (Q + 2R + (k - 3) P) / k with Q the mean face point, R the mean edge midpoint.
    valence = np.bincount(corner_v, minlength=n).astype(np.float64)
    vertex_faces = sparse.csr_matrix((1.0 / valence[corner_v], (corner_v, corner_f)), shape=(n, nf))
    mid_rows = np.concatenate([eu, ev, eu, ev])
    mid_cols = np.concatenate([eu, ev, ev, eu])
    mids = sparse.csr_matrix(
        (0.5 / valence[mid_rows], (mid_rows, mid_cols)), shape=(n, n)
    )  # mean of the midpoints of the edges at each vertex
    Vm = sparse.diags(1.0 / valence) @ (vertex_faces @ Fm + 2 * mids) + sparse.diags((valence - 3) / valence)
    S = sparse.vstack([Vm, Em, Fm]).tocsr()
    corner_prev = start + (local - 1) % sizes[corner_f]
    quads = np.stack([corner_v, n + edge_of, n + ne + corner_f, n + edge_of[corner_prev]], 1)
    return S, quads


def quads_to_triangles(points, quads) -> np.ndarray:
    """(2m, 3) triangles of quads (m, 4) of ``points`` (n, 3), each split along its shorter diagonal."""
    P = np.asarray(points, dtype=np.float64)
    Q = np.asarray(quads, dtype=np.int64)
    d02 = np.linalg.norm(P[Q[:, 0]] - P[Q[:, 2]], axis=1)
    d13 = np.linalg.norm(P[Q[:, 1]] - P[Q[:, 3]], axis=1)
    along02 = d02 <= d13
    first = np.where(along02[:, None], Q[:, [0, 1, 2]], Q[:, [0, 1, 3]])
    second = np.where(along02[:, None], Q[:, [0, 2, 3]], Q[:, [1, 2, 3]])
    return np.stack([first, second], 1).reshape(-1, 3)
