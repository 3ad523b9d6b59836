"""The exponential map: straightest geodesics (Polthier and Schmies 2006), many rays at once.

A ray is a face, barycentric coordinates and a direction in the face's frame. Inside a face it is a
straight line; crossing an edge, its coordinates are carried over exactly (the same two numbers on the
shared edge) and its direction is rotated by the edge's unfolding. A ray that meets a vertex leaves it
"straight on": with equal surface angle (half the angle sum) on either side, which is a rotation by π
in the vertex's tangent basis. A ray that meets the boundary stops there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import GeodesicError, MeshError
from .mesh import TriMesh, per_mesh
from .points import SurfacePoints
from .tangent import arrival_to_basis, face_to_vertex, to_face_frame, vertex_to_face

#: A ray passing within this barycentric distance of a vertex goes through the vertex.
VERTEX_SNAP = 1e-11
_CORNERS = np.arange(3)[:, None]


@dataclass(frozen=True, eq=False)
class Trace:
    """End of a batch of traced geodesics.

    Attributes
    ----------
    points : SurfacePoints
        (k) end points.
    directions : (k,) complex
        Unit direction of travel at the end, in the end point's tangent basis.
    hit_boundary : (k,) bool
        True where the ray reached the boundary and stopped there, short of its length.
    lengths : (k,) float
        Distance travelled: the requested length, or less where the boundary stopped the ray.
    """

    points: SurfacePoints
    directions: np.ndarray
    hit_boundary: np.ndarray
    lengths: np.ndarray


@per_mesh
def _face_gradients(mesh: TriMesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(3, m) each: x and y components of the barycentric gradients in the face frames, and the slope
    below which a ray counts as parallel to an edge (rounding noise, not an exit). Rows are corners."""
    P = mesh.face_points
    twice_area = (np.conj(P[:, 1] - P[:, 0]) * (P[:, 2] - P[:, 0])).imag
    G = (1j * (np.roll(P, -2, axis=1) - np.roll(P, -1, axis=1)) / twice_area[:, None]).T
    return np.ascontiguousarray(G.real), np.ascontiguousarray(G.imag), np.ascontiguousarray(1e-12 * np.abs(G))


def exp_map(mesh: TriMesh, origins: SurfacePoints, z) -> Trace:
    """Trace straightest geodesics from ``origins`` along tangent vectors ``z``.

    Parameters
    ----------
    mesh : TriMesh
    origins : SurfacePoints
        k origins, or a single origin shared by all rays.
    z : (k,) array_like of complex
        Direction and length of each ray, in its origin's tangent basis.

    Returns
    -------
    Trace
        End points, ending directions in the end points' bases, boundary flags, distances travelled.
    """
    z = np.atleast_1d(np.asarray(z, dtype=np.complex128))
    if len(origins) == 1 and z.size != 1:
        origins = origins[np.zeros(z.size, np.int64)]
    if z.ndim != 1 or z.size != len(origins):
        raise MeshError(f"got {len(origins)} origins but {z.size} tangent vectors")
    if not np.all(np.isfinite(z)):
        raise MeshError("tangent vectors contain NaN or infinite values")
    origins.validate(mesh)
    length = np.abs(z)
    unit = np.where(length > 0, z / np.where(length > 0, length, 1), 0)

    faces, d = to_face_frame(mesh, origins, np.where(length > 0, unit, 1.0))
    bary = origins.bary.copy()
    v0 = origins.vertex_ids(mesh)
    at_vertex = v0 >= 0
    if np.any(at_vertex):  # the start face was chosen by direction: put the vertex's coordinate there
        bary[at_vertex] = 0
        local = np.argmax(mesh.faces[faces[at_vertex]] == v0[at_vertex, None], axis=1)
        bary[np.flatnonzero(at_vertex), local] = 1

    walk = _Walk(mesh, faces, bary, d, length)
    limit = 4 * mesh.n_faces + 100
    for _ in range(limit):
        if walk.ray.size == 0:
            break
        walk.step()
    else:
        raise GeodesicError(f"geodesic tracing did not finish within {limit} steps (the mesh may be corrupt)")
    return _finish(
        mesh, walk.end_face, walk.end_bary, walk.end_dir, unit, length, walk.stopped, walk.travelled
    )


class _Walk:
    """Rays walking across faces, one face per :meth:`step`, and where each ray ended.

    The live rays' state, one entry (column of ``B``) per ray still walking: ``ray`` (n,) its index
    among the k rays, ``face`` (n,), barycentric coordinates ``B`` (3, n), direction ``dirn`` (n,) in
    the face frame, length left ``remaining`` (n,) and ``entry`` (n,), the corner opposite the edge it
    came in through (-1: none, it starts inside the face, on an edge or at a vertex).
    The ends, per ray (k,): ``end_face``, ``end_bary`` (k, 3), ``end_dir`` (in the end face's frame),
    ``stopped`` (the boundary stopped it short) and ``travelled``.
    """

    def __init__(self, mesh: TriMesh, faces, bary, d, length):
        self.mesh = mesh
        self.GX, self.GY, self.TOL = _face_gradients(mesh)
        self.end_face, self.end_bary, self.end_dir = faces.copy(), bary.copy(), d.copy()
        self.stopped = np.zeros(len(faces), bool)
        self.travelled = length.copy()
        self.ray = np.flatnonzero(length > 0)
        self.face, self.B, self.dirn = faces[self.ray], np.ascontiguousarray(bary[self.ray].T), d[self.ray]
        self.remaining = length[self.ray]
        self.entry = np.full(self.ray.size, -1)
        self.lanes = np.arange(self.ray.size)  # 0 … n-1, sliced to the live count

    def step(self) -> None:
        """Move every live ray to where it leaves its face. A ray whose length ends inside the face ends
        there; one that reaches the boundary stops on it; one that reaches a vertex goes straight on
        through it (:func:`_through_vertex`); the others cross the edge into the next face."""
        db, t_exit, j = self._exits()
        done = self.remaining <= t_exit
        if np.any(done):
            lanes = np.flatnonzero(done)
            ends = (self.B[:, lanes] + self.remaining[lanes] * db[:, lanes]).T
            self._end(lanes, self.face[lanes], ends, self.dirn[lanes])
        # The exit edge runs from corner j1 to corner j2.
        lanes = self.lanes[: self.ray.size]
        j1, j2 = (j + 1) % 3, (j + 2) % 3
        with np.errstate(invalid="ignore"):
            exit_b = self.B + t_exit * db
        b1 = np.maximum(exit_b[j1, lanes], 0.0)
        b2 = np.maximum(exit_b[j2, lanes], 0.0)
        self.remaining = self.remaining - t_exit
        h = 3 * self.face + j1
        twin = self.mesh.twin[h]
        near_vertex = (np.minimum(b1, b2) < VERTEX_SNAP) & ~done
        boundary = (twin < 0) & ~near_vertex & ~done
        if np.any(boundary):
            self._stop_on_edge(np.flatnonzero(boundary), j1, j2, b1, b2)
        through = self._through_vertices(np.flatnonzero(near_vertex), np.where(b1 >= b2, j1, j2))
        if np.any(done | near_vertex | boundary):
            go = np.flatnonzero(~(done | near_vertex | boundary))
            h, twin, b1, b2 = h[go], twin[go], b1[go], b2[go]
            self.ray, self.dirn, self.remaining = self.ray[go], self.dirn[go], self.remaining[go]
        self._cross(h, twin, b1, b2)
        if through is not None:
            self._join(*through)

    def _exits(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For each live ray, the rates of change of its coordinates along its direction ``db`` (3, n),
        the distance to where it leaves its face ``t_exit`` (n,), and the corner ``j`` (n,) whose
        coordinate reaches 0 there (the exit edge is opposite it)."""
        face, dirn, entry = self.face, self.dirn, self.entry
        dx, dy = dirn.real.copy(), dirn.imag.copy()
        db = np.take(self.GX, face, axis=1) * dx + np.take(self.GY, face, axis=1) * dy
        leaving = (db < 0) & (entry != _CORNERS)
        anchored = np.flatnonzero(entry < 0)
        if anchored.size:  # a ray leaving a vertex or edge may run along an edge: not an exit
            leaving[:, anchored] &= db[:, anchored] < -np.take(self.TOL, face[anchored], axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(leaving, -self.B / db, np.inf)
        np.maximum(t, 0.0, out=t)
        t01 = np.minimum(t[0], t[1])
        t_exit = np.minimum(t01, t[2])
        j = np.where(t[2] < t01, 2, np.where(t[1] < t[0], 1, 0))
        return db, t_exit, j

    def _end(self, lanes, faces, bary, d) -> None:
        """Record where the live rays ``lanes`` end: faces, coordinates (len(lanes), 3), directions."""
        idx = self.ray[lanes]
        self.end_face[idx], self.end_bary[idx], self.end_dir[idx] = faces, bary, d

    def _stop_on_edge(self, lanes, j1, j2, b1, b2) -> None:
        """Stop the live rays ``lanes`` where they reach the boundary edge from corner j1 to j2 (at
        coordinates b1, b2), short of their length."""
        at = np.zeros((lanes.size, 3))
        at[np.arange(lanes.size), j1[lanes]] = b1[lanes]
        at[np.arange(lanes.size), j2[lanes]] = b2[lanes]
        self._end(lanes, self.face[lanes], at, self.dirn[lanes])
        idx = self.ray[lanes]
        self.stopped[idx] = True
        self.travelled[idx] -= self.remaining[lanes]

    def _through_vertices(self, lanes, corner):
        """Rays ``lanes`` reached their face's ``corner[lanes]``: those at a boundary vertex stop there;
        the state (ray, face, B (3, c), dirn, remaining) of the others, leaving the vertex straight on,
        or None when no ray reached a vertex."""
        if lanes.size == 0:
            return None
        faces, directions, bary, stop = _through_vertex(
            self.mesh, self.face[lanes], corner[lanes], self.dirn[lanes]
        )
        idx, remaining = self.ray[lanes], self.remaining[lanes]
        if np.any(stop):
            self._end(lanes[stop], faces[stop], bary[stop], directions[stop])
            self.stopped[idx[stop]] = True
            self.travelled[idx[stop]] -= remaining[stop]
        go = ~stop
        return idx[go], faces[go], bary[go].T, directions[go], remaining[go]

    def _cross(self, h, twin, b1, b2) -> None:
        """Carry the live rays across their exit halfedges ``h`` into the ``twin`` faces: the same two
        coordinates (the twin runs the other way), the direction rotated by the edge's unfolding."""
        jj = twin % 3
        lanes = self.lanes[: self.ray.size]
        self.B = np.zeros((3, self.ray.size))
        self.B[jj, lanes] = b2
        self.B[(jj + 1) % 3, lanes] = b1
        self.face, self.dirn, self.entry = twin // 3, self.dirn * self.mesh.halfedge_rotation[h], (jj + 2) % 3

    def _join(self, ray, face, B, dirn, remaining) -> None:
        """Add rays that left a vertex to the live ones (no entry edge)."""
        self.ray = np.concatenate([self.ray, ray])
        self.face = np.concatenate([self.face, face])
        self.B = np.concatenate([self.B, B], axis=1)
        self.dirn = np.concatenate([self.dirn, dirn])
        self.remaining = np.concatenate([self.remaining, remaining])
        self.entry = np.concatenate([self.entry, np.full(ray.size, -1)])


def _through_vertex(mesh: TriMesh, faces, local, d):
    """Continue rays that reached corner ``local`` of ``faces`` moving along ``d``: straight on, i.e. a
    rotation by π in the vertex basis.

    Returns the new faces, directions (face frames) and one-hot coordinates, and a flag for rays stopped
    because the vertex is on the boundary (those keep their arrival face and direction).
    """
    corner = 3 * faces + local
    v = mesh.faces[faces, local]
    stop = mesh.is_boundary_vertex[v]
    out_face, out_dir, local = faces.copy(), d.copy(), local.copy()
    go = ~stop
    if np.any(go):
        back = face_to_vertex(mesh, corner[go], -d[go])
        h, out_dir[go] = vertex_to_face(mesh, v[go], -back)
        out_face[go] = h // 3
        local[go] = h % 3
    bary = np.zeros((faces.size, 3))
    bary[np.arange(faces.size), local] = 1.0
    return out_face, out_dir, bary, stop


def _finish(mesh, faces, bary, d, unit, length, stopped, travelled) -> Trace:
    """Snap end points onto vertices they (numerically) sit on and express directions in their bases."""
    np.maximum(bary, 0.0, out=bary)
    bary /= bary.sum(1, keepdims=True)
    at_vertex = np.count_nonzero(bary >= VERTEX_SNAP, axis=1) == 1
    local = np.argmax(bary, axis=1)
    bary[at_vertex] = 0.0
    bary[np.flatnonzero(at_vertex), local[at_vertex]] = 1.0
    bary[~at_vertex[:, None] & (bary < VERTEX_SNAP)] = 0.0
    points = SurfacePoints(faces, bary)
    directions = arrival_to_basis(mesh, points, faces, d)
    zero = length == 0
    directions[zero] = unit[zero]
    return Trace(points, directions, stopped, travelled)
