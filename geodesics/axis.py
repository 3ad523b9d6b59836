"""Axes: the piecewise-geodesic curves that carry contact patches (Contact Edit §4.1, Algorithms 1 and 3).

An axis is points a_1 … a_m joined by shortest geodesics. Intrinsically it is its segment lengths and its
turning angles; given a start point and an initial direction, those determine the axis on any surface,
which is how patches are moved, bent and transferred.

Conventions (complex unit tangent vectors, each in its point's basis):

* ``tangents[i]`` is the direction in which the axis leaves a_i; at the last point, the direction in
  which the last segment arrives, turned by ``turning[-1]`` (1 unless the axis was bent there).
* ``turning[i]`` = tangents[i] / (direction in which segment i-1 arrives at a_i), for i ≥ 1;
  ``turning[0]`` is 1. A straight continuation has turning 1 (arrival directions at vertices are their
  straight-on continuations, see :func:`geodesics.tangent.arrival_to_basis`).
"""

from __future__ import annotations

import numpy as np

from .errors import ContactError, describe_ids
from .exact import GeodesicField, Path
from .maps import geodesic_path, transport
from .mesh import TriMesh
from .points import SurfacePoints
from .tangent import arrival_to_basis, corner_halfedges, from_face_frame
from .trace import exp_map

#: Turning angles this close to 1 are straight: such runs of segments are traced as one geodesic.
STRAIGHT = 1e-12


class Axis:
    """A piecewise-geodesic curve through surface points (Algorithm 1).

    Parameters
    ----------
    mesh : TriMesh
    points : SurfacePoints
        The axis points a_1 … a_m (m ≥ 2), consecutive ones distinct; each pair is joined by the exact
        shortest geodesic.

    Attributes
    ----------
    points : SurfacePoints (m)
    lengths : (m-1,) float
        Geodesic length of each segment.
    turning : (m,) complex
        Unit turning angle at each point (see the module conventions).
    tangents : (m,) complex
        Unit tangent direction at each point, in that point's basis.
    """

    def __init__(self, mesh: TriMesh, points: SurfacePoints):
        points.validate(mesh)
        m = len(points)
        if m < 2:
            raise ContactError(f"an axis needs at least two points, got {m}")
        components = mesh.face_components[points.faces]
        apart = np.flatnonzero(components != components[0])
        if apart.size:
            raise ContactError(
                f"axis points {describe_ids(apart)} lie on another connected component than the first point"
            )
        lengths, leave, arrive = _segments(mesh, points[np.arange(m - 1)], points[np.arange(1, m)])
        scale = mesh.mean_edge_length
        same = np.flatnonzero(lengths <= 1e-12 * scale)
        if same.size:
            raise ContactError(
                f"axis points {int(same[0])} and {int(same[0]) + 1} coincide "
                f"({same.size} repeated point{'s' if same.size > 1 else ''} in all): remove duplicates"
            )
        turning = np.ones(m, np.complex128)
        turning[1:-1] = leave[1:] / arrive[:-1]
        self._set(mesh, points, lengths, turning, np.concatenate([leave, arrive[-1:]]))

    def _set(self, mesh, points, lengths, turning, tangents) -> None:
        self.mesh = mesh
        self.points = points
        for name, value in (("lengths", lengths), ("turning", turning), ("tangents", tangents)):
            value = np.array(value)
            value.setflags(write=False)
            setattr(self, name, value)

    @classmethod
    def embedded(cls, mesh: TriMesh, points: SurfacePoints, lengths, turning, tangents) -> Axis:
        """An axis from its embedding as stored (a contact file, a mirror image, a bend): its ``m``
        points on ``mesh``, ``(m-1,)`` segment lengths, ``(m,)`` unit turning angles and ``(m,)`` unit
        tangents. Nothing is traced; the shapes, lengths and unit lengths are checked."""
        m = len(points)
        lengths = np.asarray(lengths, np.float64)
        turning, tangents = np.asarray(turning, np.complex128), np.asarray(tangents, np.complex128)
        if m < 2 or lengths.shape != (m - 1,) or turning.shape != (m,) or tangents.shape != (m,):
            raise ContactError(
                f"the axis has {m} points but {lengths.size} lengths, {turning.size} turning angles "
                f"and {tangents.size} tangents (expected m-1, m, m with m >= 2)"
            )
        if not np.all(np.isfinite(lengths) & (lengths > 0)):
            raise ContactError("axis lengths must be positive and finite")
        if np.any(np.abs(np.abs(turning) - 1) > 1e-9) or np.any(np.abs(np.abs(tangents) - 1) > 1e-9):
            raise ContactError("axis turning angles and tangents must be unit complex numbers")
        axis = cls.__new__(cls)
        axis._set(mesh, points, lengths, turning, tangents)
        return axis

    @classmethod
    def between(cls, mesh: TriMesh, a: SurfacePoints, b: SurfacePoints) -> Axis:
        """The shortest geodesic from a to b, with every edge crossing (and every vertex it bends around)
        as an axis point, as the paper's axis tool does."""
        return cls.along(mesh, geodesic_path(mesh, a, b))

    @classmethod
    def along(cls, mesh: TriMesh, path: Path) -> Axis:
        """The axis along a geodesic ``path`` (from :func:`geodesic_path` or :meth:`GeodesicField.path`),
        with every edge crossing and every vertex it bends around as an axis point."""
        tol = 1e-12 * mesh.mean_edge_length
        keep = [0]  # drop crossings that coincide (a path through a vertex crosses it twice)
        for i in range(1, len(path.points)):
            if np.linalg.norm(path.polyline[i] - path.polyline[keep[-1]]) > tol:
                keep.append(i)
        keep[-1] = len(path.points) - 1  # b itself, even where a crossing coincides with it
        if len(keep) < 2:
            raise ContactError("the two axis end points coincide")
        return cls(mesh, path.points[np.array(keep)])

    # ------------------------------------------------------------------ properties

    def __len__(self) -> int:
        return len(self.points)

    def __repr__(self) -> str:
        return f"Axis({len(self)} points, length {self.length:.4g})"

    @property
    def start(self) -> SurfacePoints:
        """The first axis point (one surface point)."""
        return self.points[[0]]

    @property
    def direction(self) -> complex:
        """The initial direction, in the first point's basis."""
        return complex(self.tangents[0])

    @property
    def length(self) -> float:
        return float(self.lengths.sum())

    # ------------------------------------------------------------------ reconstruction and edits

    def trace(
        self,
        mesh: TriMesh,
        start: SurfacePoints,
        direction: complex,
        *,
        mirror: bool = False,
        scale: float = 1.0,
    ) -> Axis:
        """This axis's shape laid out on ``mesh`` from ``start`` along ``direction`` (Algorithm 3).

        Parameters
        ----------
        mirror : bool
            Negate the turning angles, for the mirror image (transfer onto a surface that faces this one).
        scale : float
            Multiply every segment length (the retargeting paper's λ_A).

        Raises
        ------
        ContactError
            If the axis runs off the surface's boundary; says where.
        """
        turning = np.conj(self.turning) if mirror else self.turning
        return _lay_out(mesh, start, direction, self.lengths * scale, turning)

    def rotate(self, angle: float) -> Axis:
        """Rotate the whole axis about its first point by ``angle`` radians (counter-clockwise)."""
        return _lay_out(
            self.mesh, self.start, self.direction * np.exp(1j * angle), self.lengths, self.turning
        )

    def translate(self, to: SurfacePoints) -> Axis:
        """Move the axis so it starts at ``to``: its initial direction is parallel-transported along the
        shortest geodesic from the current start to ``to``, then the axis is traced anew (§4.3.1)."""
        path = geodesic_path(self.mesh, self.start, to)
        direction = transport(self.mesh, path, np.array([self.direction]))[0]
        return _lay_out(self.mesh, to, direction, self.lengths, self.turning)

    def bend(self, index: int, angle: float) -> Axis:
        """Rotate the part of the axis from point ``index`` on about that point by ``angle`` radians,
        leaving the part before it in place (§4.3.3)."""
        if not 1 <= index < len(self):
            raise ContactError(f"can only bend at axis points 1 to {len(self) - 1}, not at {index}")
        turning = self.turning.copy()
        turning[index] *= np.exp(1j * angle)
        tangent = self.tangents[index] * np.exp(1j * angle)
        tangents = np.concatenate([self.tangents[:index], [tangent]])
        points = self.points[np.arange(index + 1)]
        if index < len(self) - 1:  # lay out the part beyond the bend; the part before stays as it is
            rest = _lay_out(self.mesh, self.points[[index]], tangent, self.lengths[index:], turning[index:])
            tangents = np.concatenate([tangents, rest.tangents[1:]])
            points = SurfacePoints.concatenate([points, rest.points[np.arange(1, len(rest))]])
        return Axis.embedded(self.mesh, points, self.lengths, turning, tangents)


def _lay_out(mesh, start, direction, lengths, turning) -> Axis:
    """Trace segment lengths and turning angles from ``start`` along ``direction``.

    Runs of segments joined with turning 1 form one straightest geodesic, so each run is one batched
    exp_map call (rays of the run's cumulative lengths from its first point).
    """
    start.validate(mesh)
    m = len(lengths) + 1
    direction = complex(direction) / abs(direction)
    points = [start]
    tangents = np.empty(m, np.complex128)
    tangents[0] = direction
    bends = [i for i in range(1, m - 1) if abs(turning[i] - 1) > STRAIGHT] + [m - 1]
    first, here = 0, start
    for last in bends:
        ray_lengths = np.cumsum(lengths[first:last])
        trace = exp_map(mesh, here, ray_lengths * tangents[first])
        if trace.hit_boundary.any():
            stop = int(np.argmax(trace.hit_boundary))
            done = lengths[:first].sum() + trace.lengths[stop]
            raise ContactError(
                f"the axis runs off the surface's boundary in segment {first + stop + 1} of {m - 1}, "
                f"after {done:.4g} of its {lengths.sum():.4g} length"
            )
        points.append(trace.points)
        tangents[first + 1 : last + 1] = trace.directions * turning[first + 1 : last + 1]
        first, here = last, trace.points[[len(trace.points) - 1]]
    return Axis.embedded(mesh, SurfacePoints.concatenate(points), lengths, turning, tangents)


def _segments(mesh: TriMesh, p: SurfacePoints, q: SurfacePoints):
    """Exact shortest geodesics from each p to each q: lengths, leaving directions (p's bases) and
    arriving directions (q's bases). Pairs that share a face are joined inside it, others by the exact
    solver."""
    k = len(p)
    lengths = np.empty(k)
    leave = np.empty(k, np.complex128)
    arrive = np.empty(k, np.complex128)
    face = _shared_faces(mesh, p, q)
    near = np.flatnonzero(face >= 0)
    if near.size:
        f = face[near]
        d = _position_in(mesh, q[near], f) - _position_in(mesh, p[near], f)
        lengths[near] = np.abs(d)
        unit = np.where(lengths[near] > 0, d / np.where(lengths[near] > 0, lengths[near], 1), 0)
        leave[near] = from_face_frame(mesh, p[near], f, unit)
        arrive[near] = arrival_to_basis(mesh, q[near], f, unit)
    for i in np.flatnonzero(face < 0):
        query = GeodesicField(mesh, p[[i]], q[[i]]).query(q[[i]])
        lengths[i] = query.distances[0]
        leave[i] = query.initial_directions[0]
        arrive[i] = query.final_directions[0]
    return lengths, leave, arrive


def _holders(mesh: TriMesh, x: SurfacePoints) -> list[np.ndarray]:
    """Candidate faces holding each point: its own face and, on an edge, the face across it."""
    e = x.edge_halfedges(mesh)
    across = np.where(e >= 0, mesh.twin[np.maximum(e, 0)], -1)
    return [x.faces, np.where(across >= 0, across // 3, -1)]


def _holds(mesh: TriMesh, faces: np.ndarray, x: SurfacePoints) -> np.ndarray:
    """Whether each face holds its point: the point's face, the face across its edge, a face of its vertex."""
    v = x.vertex_ids(mesh)
    e = x.edge_halfedges(mesh)
    across = np.where(e >= 0, mesh.twin[np.maximum(e, 0)], -1)
    ok = faces >= 0
    safe = np.maximum(faces, 0)
    held = (safe == x.faces) | ((across >= 0) & (across // 3 == safe))
    held |= (v >= 0) & np.any(mesh.faces[safe] == v[:, None], axis=1)
    return ok & held


def _shared_faces(mesh: TriMesh, p: SurfacePoints, q: SurfacePoints) -> np.ndarray:
    """(k,) a face holding both p[i] and q[i], or -1 when none of the obvious candidates does."""
    out = np.full(len(p), -1, np.int64)
    for cand in _holders(mesh, p) + _holders(mesh, q):
        hit = (out < 0) & _holds(mesh, cand, p) & _holds(mesh, cand, q)
        out[hit] = cand[hit]
    return out


def _position_in(mesh: TriMesh, x: SurfacePoints, faces: np.ndarray) -> np.ndarray:
    """(k,) complex positions of points in the frames of faces holding them."""
    z = x.in_face_frame(mesh)
    v = x.vertex_ids(mesh)
    out = z.copy()
    moved = (faces != x.faces) & (v < 0)
    if np.any(moved):  # across an edge: map the point itself, not just directions
        e = x.edge_halfedges(mesh)[moved]
        out[moved] = mesh.halfedge_offset[e] + mesh.halfedge_rotation[e] * z[moved]
    at = v >= 0
    if np.any(at):
        out[at] = mesh.face_points.ravel()[corner_halfedges(mesh, faces[at], v[at])]
    return out
