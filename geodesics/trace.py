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
from .tangent import arrival_to_basis, corner_halfedges, face_to_vertex, to_face_frame, vertex_to_face

#: A ray passing within this barycentric distance of a vertex goes through the vertex.
VERTEX_SNAP = 1e-11


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


@per_mesh
def _halfedges(mesh: TriMesh) -> tuple[np.ndarray, ...]:
    """(3m,) each, per halfedge h (from corner h % 3 of face h // 3 to the next corner): its tail and its
    vector in the face's frame (complex), the next and previous halfedges, the twin, and the rotation
    into the twin's frame (1 on the boundary, where no ray crosses)."""
    tail = mesh.face_points.ravel()
    vector = tail[mesh.halfedge_next] - tail
    rotation = np.where(mesh.twin >= 0, mesh.halfedge_rotation, 1.0)
    return tail, vector, np.asarray(mesh.halfedge_next), np.asarray(mesh.halfedge_prev), mesh.twin, rotation


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
        local = corner_halfedges(mesh, faces[at_vertex], v0[at_vertex]) % 3
        bary[np.flatnonzero(at_vertex), local] = 1

    walk = _Walk(mesh, faces, bary, d, length)
    limit = 4 * mesh.n_faces + 100
    with np.errstate(divide="ignore", invalid="ignore"):  # rays along an edge: inf and NaN, never chosen
        for _ in range(limit):
            if not walk.live:
                break
            walk.step()
        else:
            raise GeodesicError(
                f"geodesic tracing did not finish within {limit} steps (the mesh may be corrupt)"
            )
    return _finish(mesh, *walk.ends(), unit, length, walk.stopped, walk.travelled)


class _Walk:
    """Rays walking across faces, one face per :meth:`step`, and where each ray ended.

    Live rays are of two kinds. *Entered* rays came into their face across one of its edges: one entry
    per ray, ``ray`` (n,) its index among the k rays, ``h`` (n,) the face's halfedge it crossed, ``u`` (n,)
    where on it (0 at its tail, 1 at its head: the same number the ray had leaving the previous face, so
    positions carry over exactly), direction ``dirn`` (n,) in the face's frame and length left
    ``remaining`` (n,). Which of the two other edges such a ray leaves by is the side of the ray the
    opposite corner lies on; where on that edge, and how far away, two cross products say.
    *Anchored* rays start inside a face, on an edge or at a vertex: each ray's origin, and rays leaving a
    vertex straight on. ``anchored`` lists batches of (ray, face, B (3, c), dirn, remaining), B their
    barycentric coordinates; their first exit comes from the barycentric coordinates' rates of change
    (:meth:`_leave`), which also tell a ray running along an edge from one leaving the face.
    The ends, per ray (k,): ``end_face``, ``end_bary`` (k, 3), ``end_dir`` (in the end face's frame),
    ``stopped`` (the boundary stopped it short) and ``travelled``. Entered rays that end inside a face
    are collected in ``inside`` as (ray, h, u, dirn, length) and placed all at once by :meth:`ends`.
    """

    def __init__(self, mesh: TriMesh, faces, bary, d, length):
        self.mesh = mesh
        self.GX, self.GY, self.TOL = _face_gradients(mesh)
        self.tail, self.vector, self.next, self.prev, self.twin, self.rotation = _halfedges(mesh)
        self.end_face, self.end_bary, self.end_dir = faces.copy(), bary.copy(), d.copy()
        self.stopped = np.zeros(len(faces), bool)
        self.travelled = length.copy()
        self.ray, self.h = np.empty(0, np.int64), np.empty(0, np.int64)
        self.u, self.dirn, self.remaining = np.empty(0), np.empty(0, complex), np.empty(0)
        live = np.flatnonzero(length > 0)
        self.anchored = [(live, faces[live], np.ascontiguousarray(bary[live].T), d[live], length[live])]
        self.inside: list[tuple[np.ndarray, ...]] = []

    @property
    def live(self) -> bool:
        return self.ray.size > 0 or len(self.anchored) > 0

    def step(self) -> None:
        """Move every live ray to where it leaves its face. A ray whose length ends inside the face ends
        there; one that reaches the boundary stops on it; one that reaches a vertex goes straight on
        through it (:func:`_through_vertex`) and is anchored there; the others cross the edge into the
        next face."""
        anchored, self.anchored = self.anchored, []
        if self.ray.size:
            self._walk_entered()
        for batch in anchored:
            self._leave(*batch)

    def _walk_entered(self) -> None:
        h, u, d, length = self.h, self.u, self.dirn, self.remaining
        tail, vector = self.tail, self.vector
        p = tail.take(h) + u * vector.take(h)
        ahead, behind = self.next.take(h), self.prev.take(h)
        back = np.conj(d)
        # The corner opposite the entry edge on the ray's left: the ray leaves by the edge after it.
        out = np.where((back * (tail.take(behind) - p)).imag > 0, ahead, behind)
        w = np.conj(tail.take(out) - p)
        edge = vector.take(out)
        across = (back * edge).imag
        t = np.maximum((w * edge).imag / across, 0.0)
        s = np.clip((w * d).imag / across, 0.0, 1.0)  # where on the exit edge, 0 at its tail
        twin = self.twin.take(out)
        done = length <= t
        stop = done | (np.abs(s - 0.5) > 0.5 - VERTEX_SNAP) | (twin < 0)
        if stop.any():
            self._stop_entered(stop, done, out, s, length - t)
            go = ~stop
            self.ray, length, out, twin, s, d, t = (
                self.ray[go],
                length[go],
                out[go],
                twin[go],
                s[go],
                d[go],
                t[go],
            )
        self.h, self.u, self.dirn, self.remaining = twin, 1.0 - s, d * self.rotation.take(out), length - t

    def _stop_entered(self, stop, done, out, s, left) -> None:
        """Entered rays that do not cross an edge this step (``stop``): the ``done`` ones end inside
        their face, the others meet their exit edge ``out`` at ``s`` with ``left`` to go."""
        if done.any():
            self.inside.append(
                (self.ray[done], self.h[done], self.u[done], self.dirn[done], self.remaining[done])
            )
        at_edge = stop & ~done
        if at_edge.any():
            self._meet_edge(self.ray[at_edge], out[at_edge], s[at_edge], self.dirn[at_edge], left[at_edge])

    def _meet_edge(self, ray, out, s, d, left) -> None:
        """Rays ``ray`` met their face's halfedge ``out`` at ``s`` along it, moving along ``d`` with
        ``left`` to go, and do not cross it: at one of its ends they pass through that vertex, elsewhere
        it is a boundary edge and they stop on it."""
        corner = np.minimum(s, 1.0 - s) < VERTEX_SNAP
        if np.any(~corner):
            self._stop_on_edge(ray[~corner], out[~corner], s[~corner], d[~corner], left[~corner])
        if np.any(corner):
            out, s = out[corner], s[corner]
            local = np.where(s < 0.5, out, self.next[out]) % 3
            self._through_vertices(ray[corner], out // 3, local, d[corner], left[corner])

    def ends(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """End faces (k,), barycentric coordinates (k, 3) and directions (k,) in the end faces' frames,
        with the rays that ended inside a face after entering it placed there: their coordinates at the
        entry edge plus ``length`` times their rates of change along the ray."""
        if self.inside:
            ray, h, u, d, length = (np.concatenate(parts) for parts in zip(*self.inside, strict=True))
            face, lanes = h // 3, np.arange(ray.size)
            B = length * (np.take(self.GX, face, axis=1) * d.real + np.take(self.GY, face, axis=1) * d.imag)
            B[h % 3, lanes] += 1.0 - u
            B[self.next[h] % 3, lanes] += u
            self._end(ray, face, B.T, d)
            self.inside = []
        return self.end_face, self.end_bary, self.end_dir

    def _leave(self, ray, face, B, dirn, remaining) -> None:
        """Move anchored rays to where they leave their face, found from the rates of change ``db``
        (3, n) of their barycentric coordinates: the first to reach 0 marks the exit edge (opposite
        its corner). A ray running along an edge from a vertex or an edge point does not leave by it."""
        dx, dy = dirn.real.copy(), dirn.imag.copy()
        db = np.take(self.GX, face, axis=1) * dx + np.take(self.GY, face, axis=1) * dy
        leaving = db < -np.take(self.TOL, face, axis=1)
        t = np.where(leaving, -B / db, np.inf)
        np.maximum(t, 0.0, out=t)
        t01 = np.minimum(t[0], t[1])
        t_exit = np.minimum(t01, t[2])
        j = np.where(t[2] < t01, 2, np.where(t[1] < t[0], 1, 0))
        done = remaining <= t_exit
        if np.any(done):
            ends = (B[:, done] + remaining[done] * db[:, done]).T
            self._end(ray[done], face[done], ends, dirn[done])
        out = 3 * face + (j + 1) % 3  # the exit edge: from corner j + 1 to corner j + 2
        lanes, head = np.arange(ray.size), (j + 2) % 3
        s = np.clip(B[head, lanes] + t_exit * db[head, lanes], 0.0, 1.0)
        remaining = remaining - t_exit
        twin = self.twin.take(out)
        stop = done | (np.abs(s - 0.5) > 0.5 - VERTEX_SNAP) | (twin < 0)
        at_edge = stop & ~done
        if np.any(at_edge):
            self._meet_edge(ray[at_edge], out[at_edge], s[at_edge], dirn[at_edge], remaining[at_edge])
        go = ~stop
        self.ray = np.concatenate([self.ray, ray[go]])
        self.h = np.concatenate([self.h, twin[go]])
        self.u = np.concatenate([self.u, 1.0 - s[go]])
        self.dirn = np.concatenate([self.dirn, dirn[go] * self.rotation.take(out[go])])
        self.remaining = np.concatenate([self.remaining, remaining[go]])

    def _end(self, ray, faces, bary, d) -> None:
        """Record where rays ``ray`` end: faces, coordinates (len(ray), 3), directions."""
        self.end_face[ray], self.end_bary[ray], self.end_dir[ray] = faces, bary, d

    def _stop_on_edge(self, ray, h, s, d, remaining) -> None:
        """Stop rays ``ray`` where they reach the boundary halfedges ``h``, at ``s`` along them (0 at the
        tail), ``remaining`` short of their length."""
        at = np.zeros((ray.size, 3))
        lanes = np.arange(ray.size)
        at[lanes, h % 3] = 1.0 - s
        at[lanes, self.next[h] % 3] = s
        self._end(ray, h // 3, at, d)
        self.stopped[ray] = True
        self.travelled[ray] -= remaining

    def _through_vertices(self, ray, face, corner, d, remaining) -> None:
        """Rays ``ray`` reached corner ``corner`` of ``face`` moving along ``d``: those at a boundary
        vertex stop there; the others leave the vertex straight on, anchored there."""
        faces, directions, bary, stop = _through_vertex(self.mesh, face, corner, d)
        if np.any(stop):
            self._end(ray[stop], faces[stop], bary[stop], directions[stop])
            self.stopped[ray[stop]] = True
            self.travelled[ray[stop]] -= remaining[stop]
        go = ~stop
        B = np.ascontiguousarray(bary[go].T)
        self.anchored.append((ray[go], faces[go], B, directions[go], remaining[go]))


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
    bary /= (bary[:, 0] + bary[:, 1] + bary[:, 2])[:, None]
    kept = (bary >= VERTEX_SNAP).view(np.uint8)
    at_vertex = np.flatnonzero(kept[:, 0] + kept[:, 1] + kept[:, 2] == 1)
    bary[bary < VERTEX_SNAP] = 0.0
    bary[at_vertex] = kept[at_vertex]
    points = SurfacePoints(faces, bary)
    directions = arrival_to_basis(mesh, points, faces, d)
    zero = length == 0
    directions[zero] = unit[zero]
    return Trace(points, directions, stopped, travelled)
