"""Validated manifold triangle meshes with halfedge connectivity and intrinsic face frames.

Conventions (written here because every other module relies on them):

* Halfedge ``h = 3*f + k`` runs from ``faces[f, k]`` to ``faces[f, (k+1) % 3]``; it belongs to face ``f``,
  whose interior lies on its left. ``twin[h]`` is the opposite halfedge, or -1 on the boundary.
* Each face has a 2D **face frame**: its first vertex at the origin, its first edge along +x, the face in
  the upper half plane. Points and directions in a face frame are complex numbers ``x + iy``.
  ``face_points[f]`` holds the three corners in that frame. The face's tangent basis is this frame.
* Around a vertex, outgoing halfedges are ordered counter-clockwise (``twin[prev[h]]`` is the next one),
  starting from the vertex's reference halfedge (for a boundary vertex: the one whose twin is -1).
  ``halfedge_angle[h]`` is the angle, measured on the surface, from the reference halfedge to ``h``.
  A vertex's tangent basis rescales these angles by ``vertex_angle_scale`` (2π / angle sum inside,
  π / angle sum on the boundary), exactly as geometry-central does.
"""

from __future__ import annotations

import functools
import hashlib
import warnings
import weakref
from collections.abc import Callable
from functools import cached_property
from typing import TypeVar

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from .arrays import readonly
from .errors import MeshError, MeshWarning, describe_ids

_T = TypeVar("_T")

#: A face whose height is below this fraction of its longest edge is degenerate.
DEGENERATE_HEIGHT = 1e-12


class TriMesh:
    """An immutable, validated, manifold (possibly bounded, possibly multi-component) triangle mesh.

    Parameters
    ----------
    vertices : (n, 3) array_like of float
        Vertex positions.
    faces : (m, 3) array_like of int
        Vertex indices of each triangle, counter-clockwise seen from outside.

    Raises
    ------
    MeshError
        For NaN/inf coordinates, out-of-range or repeated indices, degenerate (zero-area) faces,
        non-manifold edges or vertices, or inconsistently oriented neighbours. The error names the
        offending elements and keeps them in its ``vertices``/``faces``/``edges`` attributes.

    Vertices that no face uses are kept (so indices stay those of the caller) and reported with a
    :class:`MeshWarning`; they are listed in ``isolated_vertices``.
    """

    def __init__(self, vertices, faces):
        V = np.array(vertices, dtype=np.float64, copy=True)
        if V.ndim != 2 or V.shape[1] != 3:
            raise MeshError(f"vertices must have shape (n, 3), got {V.shape}")
        F = np.array(faces, copy=True)
        if F.size == 0:
            raise MeshError("the mesh has no faces")
        if F.ndim != 2 or F.shape[1] != 3:
            raise MeshError(
                f"faces must have shape (m, 3), got {F.shape}; use TriMesh.from_polygons for polygons"
            )
        if not np.issubdtype(F.dtype, np.integer) and (
            not np.all(np.isfinite(F)) or np.any(np.round(F) != F)
        ):
            raise MeshError("face indices must be integers")
        F = F.astype(np.int64)
        self._vertices = readonly(V)
        self._faces = readonly(F)
        self._validate_indices()
        self._validate_coordinates()
        self._build_twins()
        self._validate_geometry()
        self._build_vertex_fans()
        used = np.zeros(len(V), bool)
        used[F.ravel()] = True
        self.isolated_vertices = readonly(np.flatnonzero(~used))
        if self.isolated_vertices.size:
            warnings.warn(
                f"{self.isolated_vertices.size} vertices are used by no face and are ignored: "
                f"{describe_ids(self.isolated_vertices)}",
                MeshWarning,
                stacklevel=2,
            )
        # Set by from_polygons: which polygon, and which of its corners, each triangle came from.
        self.triangle_polygon: np.ndarray | None = None
        self.triangle_corners: np.ndarray | None = None

    # ------------------------------------------------------------------ construction helpers

    @classmethod
    def from_polygons(cls, vertices, polygons) -> TriMesh:
        """Triangulate polygons (e.g. a Blender mesh) and remember where each triangle came from.

        Parameters
        ----------
        vertices : (n, 3) array_like of float
        polygons : sequence of sequences of int, or (p, s) array_like of int
            Vertex indices of each polygon, counter-clockwise seen from outside.

        Returns
        -------
        TriMesh
            With ``triangle_polygon`` (m,) giving each triangle's polygon and ``triangle_corners``
            (m, 3) giving, for each triangle corner, its corner index within that polygon.

        Raises
        ------
        MeshError
            As :class:`TriMesh` does, with ``faces`` holding the offending *polygons*.
        """
        from .polygons import triangulate_polygons

        vertices = np.asarray(vertices, dtype=np.float64)
        faces, polygon, corners = triangulate_polygons(vertices, polygons)
        try:
            mesh = cls(vertices, faces)
        except MeshError as err:
            polygons_at_fault = np.unique(polygon[err.faces]) if err.faces.size else err.faces
            where = f" (polygons {describe_ids(polygons_at_fault)})" if polygons_at_fault.size else ""
            raise MeshError(
                f"{err}{where}", vertices=err.vertices, faces=polygons_at_fault, edges=err.edges
            ) from None
        mesh.triangle_polygon = readonly(polygon)
        mesh.triangle_corners = readonly(corners)
        return mesh

    def _validate_indices(self) -> None:
        F, n = self._faces, len(self._vertices)
        bad = np.flatnonzero(np.any((F < 0) | (n <= F), axis=1))
        if bad.size:
            raise MeshError(f"faces {describe_ids(bad)} use vertex indices outside 0..{n - 1}", faces=bad)
        repeated = np.flatnonzero((F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0]))
        if repeated.size:
            raise MeshError(
                f"faces {describe_ids(repeated)} are degenerate: they repeat a vertex", faces=repeated
            )

    def _validate_coordinates(self) -> None:
        bad = np.flatnonzero(~np.all(np.isfinite(self._vertices), axis=1))
        if bad.size:
            raise MeshError(f"vertices {describe_ids(bad)} have NaN or infinite coordinates", vertices=bad)

    def _build_twins(self) -> None:
        F, n = self._faces, len(self._vertices)
        tail = F.ravel()
        head = F[:, [1, 2, 0]].ravel()
        lo, hi = np.minimum(tail, head), np.maximum(tail, head)
        _, edge_of, edge_count = np.unique(lo * n + hi, return_inverse=True, return_counts=True)
        crowded = edge_count[edge_of] > 2
        if np.any(crowded):
            pairs = np.unique(np.stack([lo[crowded], hi[crowded]], 1), axis=0)
            raise MeshError(
                f"{len(pairs)} edges are non-manifold (shared by more than two faces), e.g. edge "
                f"{tuple(int(x) for x in pairs[0])}, used by faces "
                f"{describe_ids(np.flatnonzero(crowded) // 3)}",
                edges=pairs,
                faces=np.flatnonzero(crowded) // 3,
            )
        key = tail * n + head
        order = np.argsort(key, kind="stable")
        sorted_key = key[order]
        same = np.flatnonzero(sorted_key[1:] == sorted_key[:-1])
        if same.size:
            h = np.concatenate([order[same], order[same + 1]])
            pairs = np.unique(np.stack([lo[h], hi[h]], 1), axis=0)
            raise MeshError(
                f"faces {describe_ids(h // 3)} are oriented inconsistently with their neighbours "
                f"(edge {tuple(int(x) for x in pairs[0])} runs the same way in both of its faces)",
                faces=h // 3,
                edges=pairs,
            )
        reverse = head * n + tail
        pos = np.minimum(np.searchsorted(sorted_key, reverse), len(key) - 1)
        found = sorted_key[pos] == reverse
        self.twin = readonly(np.where(found, order[pos], -1))
        self.halfedge_tail = readonly(tail)
        self.halfedge_head = readonly(head)
        self.halfedge_edge = readonly(edge_of)
        self.n_edges = int(edge_count.size)

    def _validate_geometry(self) -> None:
        V, F = self._vertices, self._faces
        e1 = V[F[:, 1]] - V[F[:, 0]]
        e2 = V[F[:, 2]] - V[F[:, 0]]
        normal = np.cross(e1, e2)
        twice_area = np.linalg.norm(normal, axis=1)
        longest = np.sqrt(
            np.max(np.stack([(e1**2).sum(1), (e2**2).sum(1), ((e2 - e1) ** 2).sum(1)], 1), axis=1)
        )
        bad = np.flatnonzero(twice_area <= DEGENERATE_HEIGHT * longest**2)
        if bad.size:
            raise MeshError(
                f"faces {describe_ids(bad)} are degenerate (zero area: collinear or coincident vertices)",
                faces=bad,
            )
        len1 = np.linalg.norm(e1, axis=1)
        x = e1 / len1[:, None]
        nrm = normal / twice_area[:, None]
        y = np.cross(nrm, x)
        self.face_normals = readonly(nrm)
        self.face_areas = readonly(0.5 * twice_area)
        self._face_axes = np.stack([x, y], axis=1)  # (m, 2, 3): the face frame's x and y axes in 3D
        P = np.zeros((len(F), 3), np.complex128)
        P[:, 1] = len1
        P[:, 2] = (e2 * x).sum(1) + 1j * (e2 * y).sum(1)
        self.face_points = readonly(P)

    def _build_vertex_fans(self) -> None:
        """Order each vertex's outgoing halfedges counter-clockwise; reject non-manifold vertices."""
        n, twin, tail = len(self._vertices), self.twin, self.halfedge_tail
        nh = twin.size
        halfedges = np.arange(nh)
        prev = halfedges - halfedges % 3 + (halfedges + 2) % 3
        corners_at = np.bincount(tail, minlength=n)
        open_out = np.flatnonzero(twin < 0)
        boundary_out = np.bincount(tail[open_out], minlength=n)
        pinched = np.flatnonzero(boundary_out > 1)
        if pinched.size:
            raise MeshError(
                f"vertices {describe_ids(pinched)} are non-manifold (several boundary fans meet there)",
                vertices=pinched,
            )
        # Corner angle at the tail of each halfedge.
        P = self.face_points
        k = halfedges % 3
        f = halfedges // 3
        corner = np.angle((P[f, (k + 2) % 3] - P[f, k]) / (P[f, (k + 1) % 3] - P[f, k]))
        start = np.full(n, -1, np.int64)
        start[tail] = halfedges
        start[tail[open_out]] = open_out
        ring_pos = np.full(nh, -1, np.int64)
        # Cumulative angles around each vertex, summed per vertex while walking its fan (a global cumsum
        # minus per-vertex offsets would lose precision on large meshes).
        angle = np.zeros(nh)
        verts = np.flatnonzero(start >= 0)
        cur = start[verts]
        acc = corner[cur]
        ring_pos[cur] = 0
        fan_size = np.zeros(n, np.int64)
        fan_size[verts] = 1
        step = 0
        while verts.size:
            step += 1
            nxt = twin[prev[cur]]
            go = (nxt >= 0) & (nxt != start[verts])
            verts, cur, acc = verts[go], nxt[go], acc[go]
            ring_pos[cur] = step
            angle[cur] = acc
            acc = acc + corner[cur]
            fan_size[verts] += 1
        pinched = np.flatnonzero(fan_size != corners_at)
        if pinched.size:
            raise MeshError(
                f"vertices {describe_ids(pinched)} are non-manifold (their faces form more than one fan)",
                vertices=pinched,
            )
        order = np.lexsort((ring_pos, tail))
        ring_start = np.zeros(n + 1, np.int64)
        ring_start[1:] = np.cumsum(corners_at)
        angle_sum = np.bincount(tail, weights=corner, minlength=n)
        is_boundary = boundary_out > 0
        with np.errstate(divide="ignore"):
            scale = np.where(is_boundary, np.pi, 2 * np.pi) / angle_sum
        scale[corners_at == 0] = 0.0
        self.corner_angles = readonly(corner.reshape(-1, 3))
        self.angle_sums = readonly(angle_sum)
        self.is_boundary_vertex = readonly(is_boundary)
        self.halfedge_angle = readonly(angle)
        self.vertex_angle_scale = readonly(scale)
        self.vertex_halfedge = readonly(start)
        #: Outgoing halfedges of vertex v in counter-clockwise order: ring[ring_start[v]:ring_start[v+1]].
        self.ring = readonly(order)
        self.ring_start = readonly(ring_start)
        # Sorted search key (vertex, angle) for finding the corner that holds a direction.
        self.ring_key_stride = float(angle_sum.max()) + 1.0
        self.ring_key = readonly(tail[order] * self.ring_key_stride + angle[order])

    # ------------------------------------------------------------------ basic data

    @property
    def vertices(self) -> np.ndarray:
        """(n, 3) float64 vertex positions (read-only)."""
        return self._vertices

    @property
    def faces(self) -> np.ndarray:
        """(m, 3) int64 vertex indices of each triangle (read-only)."""
        return self._faces

    @property
    def n_vertices(self) -> int:
        return len(self._vertices)

    @property
    def n_faces(self) -> int:
        return len(self._faces)

    def __repr__(self) -> str:
        return (
            f"TriMesh({self.n_vertices} vertices, {self.n_faces} faces, "
            f"{self.n_components} component{'s' if self.n_components != 1 else ''}, "
            f"{int(np.count_nonzero(self.twin < 0))} boundary edges)"
        )

    # ------------------------------------------------------------------ derived quantities

    @cached_property
    def topology_hash(self) -> str:
        """SHA-256 of the vertex count and the faces: equal for every pose or shape of one topology, so
        intrinsic data (surface points, contact files) made on one is valid on the others."""
        digest = hashlib.sha256(np.int64(self.n_vertices).tobytes())
        digest.update(np.ascontiguousarray(self._faces, dtype="<i8").tobytes())
        return digest.hexdigest()

    @cached_property
    def halfedge_next(self) -> np.ndarray:
        """(3m,) the next halfedge around the same face."""
        h = np.arange(3 * self.n_faces)
        return readonly(h - h % 3 + (h + 1) % 3)

    @cached_property
    def halfedge_prev(self) -> np.ndarray:
        """(3m,) the previous halfedge around the same face."""
        h = np.arange(3 * self.n_faces)
        return readonly(h - h % 3 + (h + 2) % 3)

    @cached_property
    def halfedge_lengths(self) -> np.ndarray:
        """(3m,) length of each halfedge."""
        P = self.face_points
        return readonly(np.abs(P[:, [1, 2, 0]] - P).ravel())

    @cached_property
    def face_centroids(self) -> np.ndarray:
        """(m, 3) the centroid of each face."""
        return readonly(self._vertices[self._faces].mean(axis=1))

    @cached_property
    def face_radii(self) -> np.ndarray:
        """(m,) how far each face reaches from its centroid (no point of the face is farther)."""
        corners = self._vertices[self._faces]
        return readonly(np.linalg.norm(corners - self.face_centroids[:, None], axis=2).max(axis=1))

    @cached_property
    def mean_edge_length(self) -> float:
        return float(self.halfedge_lengths.mean())

    @cached_property
    def signed_volume(self) -> float:
        """The volume the faces enclose, ``Σ det(a, b, c) / 6`` (divergence theorem): positive for a closed
        mesh whose faces point out, negative for one turned inside out; for an open mesh, that of the
        cone from the origin."""
        return float(np.linalg.det(self._vertices[self._faces]).sum() / 6.0)

    @cached_property
    def bounding_diagonal(self) -> float:
        """Length of the bounding-box diagonal of the used vertices: the scale for tolerances."""
        used = self._vertices[np.unique(self._faces)]
        return float(np.linalg.norm(used.max(0) - used.min(0)))

    @cached_property
    def face_components(self) -> np.ndarray:
        """(m,) connected-component label of each face (components share edges)."""
        h = np.flatnonzero(self.twin >= 0)
        m = self.n_faces
        graph = coo_matrix((np.ones(h.size), (h // 3, self.twin[h] // 3)), shape=(m, m))
        _, labels = connected_components(graph, directed=False)
        return readonly(labels.astype(np.int64))

    @cached_property
    def vertex_components(self) -> np.ndarray:
        """(n,) component label of each vertex; -1 for isolated vertices."""
        labels = np.full(self.n_vertices, -1, np.int64)
        labels[self._faces.ravel()] = np.repeat(self.face_components, 3)
        return readonly(labels)

    @cached_property
    def n_components(self) -> int:
        return int(self.face_components.max()) + 1

    @cached_property
    def halfedge_rotation(self) -> np.ndarray:
        """(3m,) unit complex: a direction in face(h)'s frame times this is that direction in face(twin h)'s
        frame (the Levi-Civita transport across the edge). NaN on boundary halfedges."""
        rot, _ = self._unfolding
        return rot

    @cached_property
    def halfedge_offset(self) -> np.ndarray:
        """(3m,) complex: point z of face(h)'s frame is ``offset[h] + rotation[h] * z`` in face(twin h)'s."""
        _, offset = self._unfolding
        return offset

    @cached_property
    def _unfolding(self) -> tuple[np.ndarray, np.ndarray]:
        P = self.face_points.ravel()
        nh = P.size
        h = np.arange(nh)
        nxt = h - h % 3 + (h + 1) % 3
        t = self.twin
        inner = t >= 0
        rot = np.full(nh, np.nan + 0j)
        off = np.full(nh, np.nan + 0j)
        hi, ti = h[inner], t[inner]
        e_here = P[nxt[hi]] - P[hi]
        e_there = P[ti] - P[nxt[ti]]
        r = (e_there / np.abs(e_there)) / (e_here / np.abs(e_here))
        rot[hi] = r
        off[hi] = P[nxt[ti]] - r * P[hi]
        return readonly(rot), readonly(off)

    @cached_property
    def vertex_normals(self) -> np.ndarray:
        """(n, 3) angle-weighted unit vertex normals (zero for isolated vertices)."""
        N = np.zeros((self.n_vertices, 3))
        w = self.corner_angles
        for k in range(3):
            np.add.at(N, self._faces[:, k], self.face_normals * w[:, k, None])
        norm = np.linalg.norm(N, axis=1, keepdims=True)
        return readonly(np.divide(N, norm, out=np.zeros_like(N), where=norm > 0))

    def face_axes(self, faces) -> np.ndarray:
        """(k, 2, 3) 3D x and y axes of the frames of the given ``faces`` (k,)."""
        return self._face_axes[np.asarray(faces, dtype=np.int64)]


def per_mesh(build: Callable[[TriMesh], _T]) -> Callable[[TriMesh], _T]:
    """``build(mesh)`` computed on first use and kept while the mesh lives (a :class:`TriMesh` is
    immutable). Unlike ``functools.cache`` it keeps no mesh alive: in a Blender session, where every
    operator call makes new meshes, a plain cache would hold them all. What ``build`` returns must not
    refer to the mesh, or the mesh would never be freed."""
    results: weakref.WeakKeyDictionary[TriMesh, _T] = weakref.WeakKeyDictionary()

    @functools.wraps(build)
    def cached(mesh: TriMesh) -> _T:
        try:
            return results[mesh]
        except KeyError:
            value = results[mesh] = build(mesh)
            return value

    return cached
