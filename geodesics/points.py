"""Batched surface points: a face index and barycentric coordinates per point.

A point whose barycentric coordinates have exactly one nonzero entry lies on a vertex and uses that
vertex's tangent basis; every other point uses its face's basis (see :mod:`geodesics.tangent`).
Coordinates within ``SNAP`` of zero are snapped to zero on construction, so points meant to be on an
edge or a vertex are exactly there.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .closest import ClosestPoints
from .errors import MeshError, describe_ids
from .mesh import TriMesh

#: Barycentric coordinates smaller than this are snapped to exactly zero.
SNAP = 1e-12
#: Barycentric coordinates may undershoot zero (or their sum miss one) by this much before it is an error.
TOLERANCE = 1e-9


@dataclass(frozen=True, eq=False)
class SurfacePoints:
    """k points on a triangle mesh, each a face index and barycentric coordinates.

    Parameters
    ----------
    faces : (k,) array_like of int
    bary : (k, 3) array_like of float
        Barycentric coordinates with respect to ``mesh.faces[faces]``; non-negative, summing to one.
    """

    faces: np.ndarray
    bary: np.ndarray

    def __post_init__(self):
        faces = np.array(self.faces, dtype=np.int64, copy=True).reshape(-1)
        bary = np.array(self.bary, dtype=np.float64, copy=True)
        if bary.ndim == 1 and bary.size == 3:
            bary = bary[None, :]
        if bary.ndim != 2 or bary.shape[1] != 3 or len(bary) != len(faces):
            raise MeshError(
                f"surface points need faces (k,) and bary (k, 3); got {faces.shape} and {bary.shape}"
            )
        b0, b1, b2 = bary.T  # row reductions over three columns are much faster done by hand
        total = b0 + b1 + b2
        valid = (np.minimum(np.minimum(b0, b1), b2) >= -TOLERANCE) & (np.abs(total - 1) <= TOLERANCE)
        if not valid.all():
            _raise_invalid(bary, np.flatnonzero(~valid))
        tiny = bary < SNAP
        if tiny.any():
            bary[tiny] = 0.0
        # Renormalize only rows that need it, so constructing from valid coordinates changes no bits.
        off = np.flatnonzero(tiny[:, 0] | tiny[:, 1] | tiny[:, 2] | (np.abs(total - 1) > 1e-14))
        if off.size:
            rows = bary[off]
            bary[off] = rows / (rows[:, 0] + rows[:, 1] + rows[:, 2])[:, None]
        faces.setflags(write=False)
        bary.setflags(write=False)
        object.__setattr__(self, "faces", faces)
        object.__setattr__(self, "bary", bary)

    # ------------------------------------------------------------------ construction

    @classmethod
    def from_vertices(cls, mesh: TriMesh, vertex_ids) -> SurfacePoints:
        """Points exactly on the given vertices (each expressed in one of its faces)."""
        v = np.asarray(vertex_ids, dtype=np.int64).reshape(-1)
        bad = np.flatnonzero((v < 0) | (v >= mesh.n_vertices))
        if bad.size:
            raise MeshError(
                f"vertex indices {describe_ids(v[bad])} are out of range 0..{mesh.n_vertices - 1}"
            )
        h = mesh.vertex_halfedge[v]
        bad = np.flatnonzero(h < 0)
        if bad.size:
            raise MeshError(f"vertices {describe_ids(v[bad])} belong to no face", vertices=v[bad])
        bary = np.zeros((v.size, 3))
        bary[np.arange(v.size), h % 3] = 1.0
        return cls(h // 3, bary)

    @classmethod
    def from_positions(cls, mesh: TriMesh, faces, positions) -> SurfacePoints:
        """Points at 3D positions known to lie on (or just off) the given faces, e.g. ray hits.

        Positions are projected onto their face's plane and clamped into the triangle.
        """
        f = np.asarray(faces, dtype=np.int64).reshape(-1)
        X = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        if len(X) != len(f):
            raise MeshError(f"got {len(f)} faces but {len(X)} positions")
        _check_faces(mesh, f)
        axes = mesh.face_axes(f)
        d = X - mesh.vertices[mesh.faces[f, 0]]
        z = np.einsum("kj,kj->k", d, axes[:, 0]) + 1j * np.einsum("kj,kj->k", d, axes[:, 1])
        return cls(f, _clamped_bary(mesh.face_points[f], z))

    @classmethod
    def nearest(cls, mesh: TriMesh, positions) -> SurfacePoints:
        """The closest surface point to each 3D position (k, 3), exactly (see
        :class:`geodesics.ClosestPoints`, whose solver for ``mesh`` is built once and reused)."""
        X = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        if not np.all(np.isfinite(X)):
            raise MeshError("positions contain NaN or infinite values")
        found = ClosestPoints.of(mesh).query(X)
        return cls(found.faces, found.bary)

    @staticmethod
    def concatenate(parts) -> SurfacePoints:
        parts = list(parts)
        return SurfacePoints(
            np.concatenate([p.faces for p in parts]) if parts else np.empty(0, np.int64),
            np.concatenate([p.bary for p in parts]) if parts else np.empty((0, 3)),
        )

    # ------------------------------------------------------------------ access

    def __len__(self) -> int:
        return len(self.faces)

    def __getitem__(self, index) -> SurfacePoints:
        if np.isscalar(index):
            index = [index]
        return SurfacePoints(self.faces[index], self.bary[index])

    def __repr__(self) -> str:
        return f"SurfacePoints({len(self)} points)"

    def validate(self, mesh: TriMesh) -> SurfacePoints:
        """Raise MeshError unless every face index exists in ``mesh``; returns self."""
        _check_faces(mesh, self.faces)
        return self

    def positions(self, mesh: TriMesh) -> np.ndarray:
        """(k, 3) positions in space."""
        self.validate(mesh)
        return np.einsum("kj,kjd->kd", self.bary, mesh.vertices[mesh.faces[self.faces]])

    def in_face_frame(self, mesh: TriMesh) -> np.ndarray:
        """(k,) complex positions in each point's face frame."""
        b, P = self.bary, mesh.face_points[self.faces]
        return b[:, 0] * P[:, 0] + b[:, 1] * P[:, 1] + b[:, 2] * P[:, 2]

    def vertex_ids(self, mesh: TriMesh) -> np.ndarray:
        """(k,) the vertex each point lies on, or -1 when it is not on a vertex."""
        count, corners = self._nonzero
        on = np.flatnonzero(count == 1)
        v = np.full(len(self), -1, np.int64)
        v[on] = mesh.faces[self.faces[on], corners[on]]
        return v

    def edge_halfedges(self, mesh: TriMesh) -> np.ndarray:
        """(k,) the halfedge (of the point's face) a point lies on strictly inside of, or -1."""
        count, corners = self._nonzero
        on = np.flatnonzero(count == 2)
        h = np.full(len(self), -1, np.int64)
        h[on] = 3 * self.faces[on] + (4 - corners[on]) % 3  # the edge after the corner whose coordinate is 0
        return h

    @cached_property
    def _nonzero(self) -> tuple[np.ndarray, np.ndarray]:
        """(k,) each: how many of a point's coordinates are nonzero, and the sum of their corners' numbers
        (0, 1, 2): the corner of a point on a vertex, 3 minus the zero corner of a point on an edge."""
        nonzero = (self.bary != 0).view(np.uint8)
        return nonzero[:, 0] + nonzero[:, 1] + nonzero[:, 2], nonzero[:, 1] + 2 * nonzero[:, 2]


def _raise_invalid(bary: np.ndarray, bad: np.ndarray) -> None:
    """Raise MeshError naming the rows ``bad`` of ``bary`` (k, 3), which are not barycentric coordinates:
    those with NaN or infinite entries first."""
    infinite = np.flatnonzero(~np.all(np.isfinite(bary), axis=1))
    if infinite.size:
        raise MeshError(
            f"surface points {describe_ids(infinite)} have NaN or infinite barycentric coordinates"
        )
    raise MeshError(
        f"surface points {describe_ids(bad)} have barycentric coordinates that are negative or do not "
        f"sum to one (e.g. {bary[bad[0]].tolist()})"
    )


def _check_faces(mesh: TriMesh, faces: np.ndarray) -> None:
    bad = np.flatnonzero((faces < 0) | (faces >= mesh.n_faces))
    if bad.size:
        raise MeshError(
            f"surface points {describe_ids(bad)} refer to faces outside 0..{mesh.n_faces - 1} "
            f"(e.g. face {int(faces[bad[0]])})"
        )


def barycentric(P: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Barycentric coordinates of complex points z in triangles with complex corners P (k, 3)."""

    def cross(a, b):
        return (np.conj(a) * b).imag

    area = cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    b0 = cross(P[:, 2] - P[:, 1], z - P[:, 1]) / area
    b1 = cross(P[:, 0] - P[:, 2], z - P[:, 2]) / area
    return np.stack([b0, b1, 1 - b0 - b1], 1)


def _clamped_bary(P: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Barycentric coordinates of the closest point of each triangle to z."""
    b = barycentric(P, z)
    inside = np.all(b >= 0, axis=1)
    if np.all(inside):
        return b
    out = np.flatnonzero(~inside)
    best = np.zeros((out.size, 3))
    best_d = np.full(out.size, np.inf)
    for k in range(3):
        a, c = P[out, k], P[out, (k + 1) % 3]
        t = np.clip(((np.conj(c - a) * (z[out] - a)).real) / np.abs(c - a) ** 2, 0, 1)
        d = np.abs(a + t * (c - a) - z[out])
        closer = d < best_d
        cand = np.zeros((out.size, 3))
        cand[:, k] = 1 - t
        cand[:, (k + 1) % 3] = t
        best[closer], best_d[closer] = cand[closer], d[closer]
    b[out] = best
    return b


def distances_to_faces(mesh: TriMesh, point: np.ndarray, face: np.ndarray, X: np.ndarray) -> np.ndarray:
    """(k,) the distance from position ``X[point[i]]`` to triangle ``face[i]`` (its closest point)."""
    closest = SurfacePoints.from_positions(mesh, face, X[point]).positions(mesh)
    return np.linalg.norm(closest - X[point], axis=1)
