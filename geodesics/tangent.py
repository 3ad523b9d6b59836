"""Tangent bases and tangent vectors as complex numbers.

* A point inside a face or on an edge uses its face's frame (see :mod:`geodesics.mesh`): ``x + iy``.
* A point on a vertex uses the vertex basis of geometry-central: the angle of a direction is its angle on
  the surface from the vertex's reference halfedge, counter-clockwise, times ``vertex_angle_scale``
  (2π / angle sum inside, π / angle sum on the boundary). Rotating by π in this basis is "straight on"
  (Polthier and Schmies' straightest continuation, which splits the angle sum in half).

All functions are vectorized over k directions.
"""

from __future__ import annotations

import numpy as np

from .errors import MeshError, describe_ids
from .mesh import TriMesh
from .points import SurfacePoints


def corner_halfedges(mesh: TriMesh, faces: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """(k,) halfedge of ``faces[i]`` that starts at ``vertices[i]`` (the face's corner at that vertex), for
    ``faces`` and ``vertices`` (k,)."""
    faces, vertices = np.asarray(faces), np.asarray(vertices)
    corners = mesh.faces[faces]
    first, second = corners[:, 1] == vertices, corners[:, 2] == vertices
    bad = np.flatnonzero(~(first | second | (corners[:, 0] == vertices)))
    if bad.size:
        raise MeshError(
            f"vertices {describe_ids(vertices[bad])} are not corners of faces {describe_ids(faces[bad])}"
        )
    return 3 * faces + first + 2 * second


def _edge_direction(mesh: TriMesh, halfedges: np.ndarray) -> np.ndarray:
    """Unit direction of each halfedge in its face's frame."""
    P = mesh.face_points
    f, k = halfedges // 3, halfedges % 3
    e = P[f, (k + 1) % 3] - P[f, k]
    return e / np.abs(e)


def face_to_vertex(mesh: TriMesh, halfedges: np.ndarray, z: np.ndarray) -> np.ndarray:
    """(k,) complex: directions ``z`` (k,) complex given in face(h)'s frame, at the tail vertex of each
    halfedge h of ``halfedges`` (k,), expressed in that vertex's basis.

    The direction is measured on the surface from the corner's first edge, so a direction pointing out
    of face(h) is carried around the vertex as far as its angle says.
    """
    h = np.asarray(halfedges, dtype=np.int64)
    z = np.asarray(z, dtype=np.complex128)
    v = mesh.halfedge_tail[h]
    a = mesh.halfedge_angle[h] + np.angle(z / _edge_direction(mesh, h))
    theta = mesh.angle_sums[v]
    a = np.where(mesh.is_boundary_vertex[v], a, np.mod(a, theta))
    return np.abs(z) * np.exp(1j * a * mesh.vertex_angle_scale[v])


def vertex_to_face(mesh: TriMesh, vertices: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Directions ``z`` (k,) complex in the bases of ``vertices`` (k,), as ``(h, z_face)``: the (k,) corner
    halfedge h at the vertex whose face contains the direction, and the (k,) complex direction in face(h)'s
    frame."""
    v = np.asarray(vertices, dtype=np.int64)
    z = np.asarray(z, dtype=np.complex128)
    theta = mesh.angle_sums[v]
    scaled = np.mod(np.angle(z), 2 * np.pi)
    # On the boundary the basis spans [0, π]; a direction pointing off the surface goes to the nearer edge.
    outside = mesh.is_boundary_vertex[v] & (scaled > np.pi)
    scaled = np.where(outside, np.where(scaled > 1.5 * np.pi, 0.0, np.pi), scaled)
    a = np.minimum(scaled / mesh.vertex_angle_scale[v], theta)
    a = np.where(mesh.is_boundary_vertex[v], a, np.mod(a, theta))
    lo, hi = mesh.ring_start[v], mesh.ring_start[v + 1] - 1
    pos = np.clip(np.searchsorted(mesh.ring_key, v * mesh.ring_key_stride + a, side="right") - 1, lo, hi)
    angle = mesh.halfedge_angle
    for _ in range(2):  # the composite search key loses a few ulps; settle on exact comparisons
        pos = np.where((pos > lo) & (a < angle[mesh.ring[pos]]), pos - 1, pos)
        nxt = np.minimum(pos + 1, hi)
        pos = np.where((pos < hi) & (a >= angle[mesh.ring[nxt]]), nxt, pos)
    h = mesh.ring[pos]
    local = np.clip(a - angle[h], 0.0, mesh.corner_angles.ravel()[h])
    return h, np.abs(z) * _edge_direction(mesh, h) * np.exp(1j * local)


def face_rotation(mesh: TriMesh, source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(k,) unit complex r with ``z_target = r * z_source`` for faces ``source`` and ``target`` (k,) that are
    equal or share an edge."""
    source = np.asarray(source, dtype=np.int64)
    target = np.asarray(target, dtype=np.int64)
    h = 3 * source[:, None] + np.arange(3)
    t = mesh.twin[h]
    across = (t >= 0) & (t // 3 == target[:, None])
    same = source == target
    bad = np.flatnonzero(~same & ~across.any(1))
    if bad.size:
        raise MeshError(f"faces {describe_ids(source[bad])} and {describe_ids(target[bad])} share no edge")
    rot = mesh.halfedge_rotation[h[np.arange(source.size), np.argmax(across, axis=1)]]
    return np.where(same, 1.0 + 0j, rot)


def to_face_frame(mesh: TriMesh, points: SurfacePoints, z) -> tuple[np.ndarray, np.ndarray]:
    """Directions ``z`` (k,) complex (or one for all) given in each point's basis, as ``(faces, z_face)``,
    both (k,), in the frame of a face holding the point (for a vertex point: the face the direction points
    into)."""
    z = np.broadcast_to(np.asarray(z, dtype=np.complex128), (len(points),)).copy()
    faces = points.faces.copy()
    v = points.vertex_ids(mesh)
    at = v >= 0
    if np.any(at):
        h, z[at] = vertex_to_face(mesh, v[at], z[at])
        faces[at] = h // 3
    return faces, z


def from_face_frame(mesh: TriMesh, points: SurfacePoints, faces, z_face) -> np.ndarray:
    """(k,) complex: directions ``z_face`` (k,) complex given in the frames of ``faces`` (k,) (each holding
    its point), in each point's basis.

    For a point on an edge, ``faces`` may be either face of that edge.
    """
    faces = np.asarray(faces, dtype=np.int64)
    z = np.asarray(z_face, dtype=np.complex128).copy()
    v = points.vertex_ids(mesh)
    at = v >= 0
    if np.any(at):
        z[at] = face_to_vertex(mesh, corner_halfedges(mesh, faces[at], v[at]), z[at])
    moved = np.flatnonzero(~at & (faces != points.faces))  # in another face than the point's own
    if moved.size:
        z[moved] *= face_rotation(mesh, faces[moved], points.faces[moved])
    return z


def arrival_to_basis(mesh: TriMesh, points: SurfacePoints, faces, z_face) -> np.ndarray:
    """(k,) complex: directions of travel ``z_face`` (k,) complex *arriving* at points, given in the frames
    of ``faces`` (k,) (each holding its point), in the points' bases.

    At a vertex, the direction of arrival is its straight-on continuation: the way back rotated by π in
    the vertex basis (Polthier and Schmies' straightest rule), so an arrival followed by an unchanged
    departure passes straight through.
    """
    faces = np.asarray(faces, dtype=np.int64)
    z = np.asarray(z_face, dtype=np.complex128)
    out = from_face_frame(mesh, points, faces, z)
    v = points.vertex_ids(mesh)
    at = v >= 0
    if np.any(at):
        out[at] = -face_to_vertex(mesh, corner_halfedges(mesh, faces[at], v[at]), -z[at])
    return out


def change_basis(mesh: TriMesh, z, source: SurfacePoints, target: SurfacePoints) -> np.ndarray:
    """(k,) complex: directions ``z`` (k,) complex (or one for all) re-expressed from the bases of
    ``source`` points (k) in the bases of ``target`` points (k).

    Each source/target pair must share a face (or, for edge points, an edge): a face basis and the
    basis of one of its vertices, two vertices of one face, two faces of one edge.
    """
    if len(source) != len(target):
        raise MeshError(f"got {len(source)} source points but {len(target)} target points")
    faces, zf = to_face_frame(mesh, source, z)
    common = _common_faces(mesh, source, target, faces)
    moved = np.flatnonzero(common != faces)
    if moved.size:
        # A direction at a vertex points into some face of the vertex; the common face may be any other face
        # of it, not necessarily one across an edge, so carry the direction around the vertex instead (also
        # across an edge: a rigid rotation would be read back by face_to_vertex the other way around the
        # vertex when the direction is more than π from the corner, off by the angle defect).
        vs = source.vertex_ids(mesh)
        around = moved[vs[moved] >= 0]
        across = moved[vs[moved] < 0]
        zf[across] *= face_rotation(mesh, faces[across], common[across])
        zf[around] = _around_vertex(mesh, vs[around], faces[around], zf[around], common[around])
    return from_face_frame(mesh, target, common, zf)


def _around_vertex(
    mesh: TriMesh, v: np.ndarray, source: np.ndarray, z: np.ndarray, target: np.ndarray
) -> np.ndarray:
    """Directions at vertices ``v`` given in the frames of faces ``source``, in the frames of faces ``target``
    (both around ``v``): the same surface angle at ``v``, measured from the target corner's first edge.

    Around an interior vertex that angle is defined modulo the angle sum θ; the representative nearest the
    middle of the target corner that lies in (-π, π] is used (one exists when θ <= 2π), so ``face_to_vertex``
    at the target corner gives back the same vertex direction.
    """
    hs = corner_halfedges(mesh, source, v)
    ht = corner_halfedges(mesh, target, v)
    delta = mesh.halfedge_angle[hs] + np.angle(z / _edge_direction(mesh, hs)) - mesh.halfedge_angle[ht]
    theta = mesh.angle_sums[v]
    middle = 0.5 * mesh.corner_angles.ravel()[ht]
    wrapped = middle + np.mod(delta - middle + 0.5 * theta, theta) - 0.5 * theta
    wrapped = np.where(wrapped > np.pi, wrapped - theta, wrapped)
    wrapped = np.where(wrapped <= -np.pi, wrapped + theta, wrapped)
    delta = np.where(mesh.is_boundary_vertex[v], delta, wrapped)
    return np.abs(z) * _edge_direction(mesh, ht) * np.exp(1j * delta)


def _common_faces(mesh: TriMesh, source: SurfacePoints, target: SurfacePoints, preferred) -> np.ndarray:
    """A face holding both points of each pair, preferring ``preferred`` (a face holding the source)."""
    k = len(source)
    candidates = np.stack([preferred, target.faces, source.faces], 1)
    vt, vs = target.vertex_ids(mesh), source.vertex_ids(mesh)
    ok = np.zeros((k, 3), bool)
    for j in range(3):
        F = mesh.faces[candidates[:, j]]
        holds_t = np.where(vt >= 0, (vt[:, None] == F).any(1), candidates[:, j] == target.faces)
        holds_s = np.where(vs >= 0, (vs[:, None] == F).any(1), candidates[:, j] == source.faces)
        adjacent_t = (vt < 0) & _adjacent_on_edge(mesh, candidates[:, j], target)
        adjacent_s = (vs < 0) & _adjacent_on_edge(mesh, candidates[:, j], source)
        ok[:, j] = (holds_t | adjacent_t) & (holds_s | adjacent_s)
    common = candidates[np.arange(k), np.argmax(ok, axis=1)]
    # The candidates miss shared faces that hold neither point's own face nor the preferred one (e.g. two
    # vertices of a face, each expressed in another of its faces): search those pairs' faces explicitly.
    bad = []
    for i in np.flatnonzero(~ok.any(1)):
        shared = _holding(mesh, source, i) & _holding(mesh, target, i)
        if shared:
            common[i] = min(shared)
        else:
            bad.append(i)
    if bad:
        raise MeshError(
            f"point pairs {describe_ids(bad)} share no face, so their bases cannot be compared directly"
        )
    return common


def _holding(mesh: TriMesh, points: SurfacePoints, i: int) -> set[int]:
    """The faces that hold point i: its face, both faces of its edge, or all faces around its vertex."""
    v = points.vertex_ids(mesh)[i]
    if v >= 0:
        return set((mesh.ring[mesh.ring_start[v] : mesh.ring_start[v + 1]] // 3).tolist())
    h = points.edge_halfedges(mesh)[i]
    return {int(points.faces[i])} | ({int(mesh.twin[h] // 3)} if h >= 0 and mesh.twin[h] >= 0 else set())


def _adjacent_on_edge(mesh: TriMesh, faces: np.ndarray, points: SurfacePoints) -> np.ndarray:
    """Whether each point lies on an edge that ``faces[i]`` shares."""
    h = points.edge_halfedges(mesh)
    t = np.where(h >= 0, mesh.twin[np.maximum(h, 0)], -1)
    return (h >= 0) & (t >= 0) & (t // 3 == faces)


def tangent_axes(mesh: TriMesh, points: SurfacePoints) -> np.ndarray:
    """(k, 2, 3) the x and y axes of each point's tangent basis in space.

    Face points: their face's frame. Vertex points: the reference halfedge projected onto the plane of
    the angle-weighted vertex normal, and the normal crossed with it. ``tangent_to_3d`` and
    ``tangent_from_3d`` use these axes.
    """
    points.validate(mesh)
    axes = mesh.face_axes(points.faces).copy()
    v = points.vertex_ids(mesh)
    at = np.flatnonzero(v >= 0)
    if at.size:
        vv = v[at]
        n = mesh.vertex_normals[vv]
        h = mesh.vertex_halfedge[vv]
        x = mesh.vertices[mesh.halfedge_head[h]] - mesh.vertices[vv]
        x -= n * np.einsum("kd,kd->k", x, n)[:, None]
        x /= np.linalg.norm(x, axis=1, keepdims=True)
        axes[at, 0] = x
        axes[at, 1] = np.cross(n, x)
    return axes


def tangent_to_3d(mesh: TriMesh, points: SurfacePoints, z) -> np.ndarray:
    """(k, 3) tangent vectors ``z`` (k,) complex (or one for all) in each point's basis, as vectors in
    space."""
    axes = tangent_axes(mesh, points)
    z = np.broadcast_to(np.asarray(z, dtype=np.complex128), (len(points),))
    return z.real[:, None] * axes[:, 0] + z.imag[:, None] * axes[:, 1]


def tangent_from_3d(mesh: TriMesh, points: SurfacePoints, vectors) -> np.ndarray:
    """(k,) complex: ``vectors`` (k, 3) in space projected onto each point's tangent basis."""
    axes = tangent_axes(mesh, points)
    X = np.asarray(vectors, dtype=np.float64).reshape(-1, 3)
    return np.einsum("kd,kd->k", X, axes[:, 0]) + 1j * np.einsum("kd,kd->k", X, axes[:, 1])
