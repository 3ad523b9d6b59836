"""The exponential map: straightest geodesics (Polthier and Schmies 2006), many rays at once.

A ray is a face, barycentric coordinates and a direction in the face's frame. Inside a face it is a
straight line; crossing an edge, its coordinates are carried over exactly (the same two numbers on the
shared edge) and its direction is rotated by the edge's unfolding. A ray that meets a vertex leaves it
"straight on": with equal surface angle (half the angle sum) on either side, which is a rotation by π
in the vertex's tangent basis. A ray that meets the boundary stops there.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from .errors import GeodesicError, MeshError
from .mesh import TriMesh
from .points import SurfacePoints
from .tangent import arrival_to_basis, face_to_vertex, to_face_frame, vertex_to_face

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


@cache
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
    k = z.size
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

    end_face, end_bary, end_dir = faces.copy(), bary.copy(), d.copy()
    stopped = np.zeros(k, bool)
    travelled = length.copy()

    # Ray state, one column per live ray: face, barycentric coordinates (3, n), direction in the face
    # frame, length left, and the corner opposite the edge it came in through (-1: none).
    ray = np.flatnonzero(length > 0)
    face, B, dirn = faces[ray], np.ascontiguousarray(bary[ray].T), d[ray]
    remaining = length[ray]
    entry = np.full(ray.size, -1)
    GX, GY, TOL = _face_gradients(mesh)
    twin, rot = mesh.twin, mesh.halfedge_rotation
    corners = np.arange(3)[:, None]
    all_lanes = np.arange(ray.size)
    limit = 4 * mesh.n_faces + 100
    for _ in range(limit):
        if ray.size == 0:
            break
        dx, dy = dirn.real.copy(), dirn.imag.copy()
        db = np.take(GX, face, axis=1) * dx + np.take(GY, face, axis=1) * dy
        leaving = (db < 0) & (corners != entry)
        anchored = np.flatnonzero(entry < 0)
        if anchored.size:  # a ray leaving a vertex or edge may run along an edge: not an exit
            leaving[:, anchored] &= db[:, anchored] < -np.take(TOL, face[anchored], axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(leaving, -B / db, np.inf)
        np.maximum(t, 0.0, out=t)
        t01 = np.minimum(t[0], t[1])
        t_exit = np.minimum(t01, t[2])
        j = np.where(t[2] < t01, 2, np.where(t[1] < t[0], 1, 0))  # the corner whose coordinate hits 0

        done = remaining <= t_exit
        if np.any(done):
            d_lanes = np.flatnonzero(done)
            idx = ray[d_lanes]
            end_face[idx] = face[d_lanes]
            end_bary[idx] = (B[:, d_lanes] + remaining[d_lanes] * db[:, d_lanes]).T
            end_dir[idx] = dirn[d_lanes]
        # Move to the exit edge, which runs from corner j1 to corner j2.
        lanes = all_lanes[: ray.size]
        j1, j2 = (j + 1) % 3, (j + 2) % 3
        with np.errstate(invalid="ignore"):
            exit_b = B + t_exit * db
        b1 = np.maximum(exit_b[j1, lanes], 0.0)
        b2 = np.maximum(exit_b[j2, lanes], 0.0)
        remaining = remaining - t_exit
        h = 3 * face + j1
        tw = twin[h]
        near_vertex = (np.minimum(b1, b2) < VERTEX_SNAP) & ~done
        boundary = (tw < 0) & ~near_vertex & ~done
        special = near_vertex | boundary
        any_special = np.any(special)
        if any_special:
            if np.any(boundary):
                bl = np.flatnonzero(boundary)
                idx = ray[bl]
                eb = np.zeros((idx.size, 3))
                eb[np.arange(idx.size), j1[bl]] = b1[bl]
                eb[np.arange(idx.size), j2[bl]] = b2[bl]
                end_face[idx], end_bary[idx], end_dir[idx] = face[bl], eb, dirn[bl]
                stopped[idx] = True
                travelled[idx] -= remaining[bl]
            corner_rays = np.flatnonzero(near_vertex)
            vv = np.where(b1 >= b2, j1, j2)[corner_rays]
            vf, vd, vb, vstop = _through_vertex(mesh, face[corner_rays], vv, dirn[corner_rays])
            idx = ray[corner_rays]
            if np.any(vstop):
                s = idx[vstop]
                end_face[s], end_bary[s], end_dir[s] = vf[vstop], vb[vstop], vd[vstop]
                stopped[s] = True
                travelled[s] -= remaining[corner_rays][vstop]
            keep = ~vstop
            corner_remaining = remaining[corner_rays][keep]
        if any_special or np.any(done):
            go = np.flatnonzero(~(done | special))
            ray, tw, h, b1, b2 = ray[go], tw[go], h[go], b1[go], b2[go]
            dirn, remaining = dirn[go], remaining[go]
        # Across the edge: the same two coordinates (the twin runs the other way), the direction rotated.
        jj = tw % 3
        lanes = all_lanes[: ray.size]
        B = np.zeros((3, ray.size))
        B[jj, lanes] = b2
        B[(jj + 1) % 3, lanes] = b1
        face, dirn, entry = tw // 3, dirn * rot[h], (jj + 2) % 3
        if any_special:
            ray = np.concatenate([ray, idx[keep]])
            face = np.concatenate([face, vf[keep]])
            B = np.concatenate([B, vb[keep].T], axis=1)
            dirn = np.concatenate([dirn, vd[keep]])
            remaining = np.concatenate([remaining, corner_remaining])
            entry = np.concatenate([entry, np.full(corner_remaining.size, -1)])
    else:
        raise GeodesicError(f"geodesic tracing did not finish within {limit} steps (the mesh may be corrupt)")

    return _finish(mesh, end_face, end_bary, end_dir, unit, length, stopped, travelled)


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
