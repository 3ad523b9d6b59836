"""Surface points as the retargeting paper's authors write them: ``v``/``e``/``f`` strings.

The Kinematic Motion Retargeting tools (repository ``lakshmipathyarjun6/kinematic-motion-retargeting``)
store every surface point (contacts, virtual markers, axis points) as a string of geometry-central's
``SurfacePoint`` (``serializeSurfacePoint`` / ``deserializeSurfacePoint`` in
``src/contactTransferEditContext/geometryProcessingContext.cpp``):

* ``"v <vertex>"`` — on a vertex;
* ``"e <edge> <t>"`` — on an edge, at ``(1 - t)·first + t·second`` of its first and second vertices;
* ``"f <face> <b1> <b2> <b3>"`` — inside a face, barycentric coordinates in the face's vertex order.

The indices are **geometry-central's**, of the mesh their plugin builds from the polygon list with
``loadMeshFromExplicitGeometry`` (their fork's ``src/surface/meshio.cpp``): vertices no face uses are
stripped first (``SimplePolygonMesh::stripUnusedVertices``, so later vertices move down), faces keep
their order, and the ``ManifoldSurfaceMesh`` constructor (``src/surface/manifold_surface_mesh.cpp``)
numbers edges in the order it first meets them, walking face by face and each face's halfedges in
order; an edge's first vertex is the tail of the halfedge that created it. :class:`GeometryCentralIndex`
reproduces that numbering from our :class:`~geodesics.TriMesh` (whose faces are the file's, in order).

Their writer prints numbers with ``std::to_string`` (six decimals); :func:`format_points` writes the
shortest decimal that reads back to the same float64 (their reader parses either with ``>>``), and
:func:`parse_points` accepts coordinates that sum to one only to the printed precision
(:data:`PRINTED_TOLERANCE`), renormalizing them.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .errors import MeshError
from .mesh import TriMesh
from .points import SurfacePoints

#: Barycentric coordinates read from a string may miss a sum of one, or undershoot zero, by this much
#: (the authors' six printed decimals leave up to 1.5e-6 over three coordinates).
PRINTED_TOLERANCE = 1e-5

#: Numbers each kind of string carries after its letter.
_FIELDS = {"v": 1, "e": 2, "f": 4}


class GeometryCentralIndex:
    """Element numbering of the geometry-central mesh built from a :class:`TriMesh`'s face list, and the
    authors' point strings on it. Build one per mesh and reuse it for many strings.

    Attributes
    ----------
    mesh : TriMesh
    vertex : (n,) int
        geometry-central's index of each of our vertices (-1: no face uses it, so it was stripped).
    vertex_of : (n_used,) int
        Our vertex of each of geometry-central's.
    edge_halfedge : (n_edges,) int
        The halfedge of ours (``3·face + corner``, from ``faces[face, corner]`` to the next corner)
        that created each geometry-central edge: its tail is the edge's first vertex.
    halfedge_edge : (3·m,) int
        geometry-central's edge of each of our halfedges.
    """

    def __init__(self, mesh: TriMesh):
        self.mesh = mesh
        used = np.zeros(mesh.n_vertices, bool)
        used[mesh.faces.ravel()] = True
        self.vertex_of = np.flatnonzero(used)
        self.vertex = np.full(mesh.n_vertices, -1, np.int64)
        self.vertex[self.vertex_of] = np.arange(len(self.vertex_of))
        h = np.arange(3 * mesh.n_faces)
        twin = mesh.twin
        creates = (twin < 0) | (
            h < twin
        )  # of a halfedge pair, the one met first in face order creates the edge
        self.edge_halfedge = h[creates]
        number = np.cumsum(creates) - 1
        self.halfedge_edge = np.where(creates, number, number[np.maximum(twin, 0)])
        for a in (self.vertex_of, self.vertex, self.edge_halfedge, self.halfedge_edge):
            a.setflags(write=False)

    @property
    def n_edges(self) -> int:
        return len(self.edge_halfedge)

    @property
    def edges(self) -> np.ndarray:
        """(n_edges, 2) each edge's first and second vertex, in geometry-central's vertex numbering (as
        potpourri3d's ``edges(V, F)`` lists them)."""
        h = self.edge_halfedge
        F = self.mesh.faces
        return self.vertex[np.stack([F.ravel()[h], F[h // 3, (h % 3 + 1) % 3]], axis=1)]

    def format(self, points: SurfacePoints) -> list[str]:
        """The authors' string of each point: ``v`` on a vertex, ``e`` inside an edge, ``f`` inside a face.

        Parameters
        ----------
        points : SurfacePoints
            k points on the mesh.

        Returns
        -------
        list of k str
        """
        mesh = self.mesh
        points.validate(mesh)
        nonzero = np.count_nonzero(points.bary, axis=1)
        out = np.empty(len(points), dtype=object)

        on_vertex = np.flatnonzero(nonzero == 1)
        v = self.vertex[points.vertex_ids(mesh)[on_vertex]]
        out[on_vertex] = [f"v {i}" for i in v.tolist()]

        on_edge = np.flatnonzero(nonzero == 2)
        h = points.edge_halfedges(mesh)[on_edge]
        edge = self.halfedge_edge[h]
        tail = points.bary[on_edge, h % 3]
        head = points.bary[on_edge, (h % 3 + 1) % 3]
        # t is the weight of the edge's second vertex: our halfedge's head, unless ours runs the other way.
        t = np.where(self.edge_halfedge[edge] == h, head, tail) / (head + tail)
        out[on_edge] = [f"e {e} {x!r}" for e, x in zip(edge.tolist(), t.tolist(), strict=True)]

        inside = np.flatnonzero(nonzero == 3)
        rows = zip(points.faces[inside].tolist(), points.bary[inside].tolist(), strict=True)
        out[inside] = [f"f {f} {b[0]!r} {b[1]!r} {b[2]!r}" for f, b in rows]
        return out.tolist()

    def parse(self, strings: Sequence[str], where: str = "points") -> SurfacePoints:
        """Surface points from the authors' strings (the inverse of :meth:`format`).

        Parameters
        ----------
        strings : sequence of str
        where : str
            What the strings are, for error messages (``"frame 12's contacts"``).

        Returns
        -------
        SurfacePoints
            One point per string, in order.

        Raises
        ------
        MeshError
            Naming the entry (its position in ``strings``) and what is wrong: not a string, an unknown
            kind, the wrong count of numbers, an index out of range or not an integer, ``t`` outside
            [0, 1], barycentric coordinates that are negative or do not sum to one.
        """
        strings = list(strings)
        for i, s in enumerate(strings):
            if not isinstance(s, str):
                raise MeshError(f"{where}: entry {i} is {type(s).__name__} {s!r}, not a point string")
        kinds = np.array([s[:1] for s in strings], dtype="<U1")
        unknown = np.flatnonzero(~np.isin(kinds, list(_FIELDS)))
        if unknown.size:
            i = int(unknown[0])
            raise MeshError(
                f"{where}: entry {i} ({strings[i]!r}) is not a point: it should start with 'v', 'e' or "
                f"'f' ({len(unknown)} such entries)"
            )
        faces = np.zeros(len(strings), np.int64)
        bary = np.zeros((len(strings), 3))
        for kind, count in _FIELDS.items():
            rows = np.flatnonzero(kinds == kind)
            if rows.size == 0:
                continue
            values = _numbers(strings, rows, count, where)
            element = _indices(values[:, 0], rows, where, strings)
            if kind == "v":
                _check_range(element, len(self.vertex_of), rows, where, strings, "a vertex", "vertices")
                p = SurfacePoints.from_vertices(self.mesh, self.vertex_of[element])
                faces[rows], bary[rows] = p.faces, p.bary
            elif kind == "e":
                _check_range(element, self.n_edges, rows, where, strings, "an edge", "edges")
                t = values[:, 1]
                _blame(~((t >= 0) & (t <= 1)), rows, where, strings, "has t outside [0, 1]")
                h = self.edge_halfedge[element]
                faces[rows] = h // 3
                bary[rows, h % 3] = 1.0 - t
                bary[rows, (h % 3 + 1) % 3] = t
            else:
                _check_range(element, self.mesh.n_faces, rows, where, strings, "a face", "faces")
                b = values[:, 1:]
                _blame(
                    ~np.all(np.isfinite(b), axis=1)
                    | (b.min(1) < -PRINTED_TOLERANCE)
                    | (np.abs(b.sum(1) - 1) > PRINTED_TOLERANCE),
                    rows, where, strings, "has barycentric coordinates below zero or not summing to one",
                )  # fmt: skip
                # Rows off by more than rounding are renormalized; exact ones keep their bits.
                b = np.maximum(b, 0.0)
                off = np.abs(b.sum(1) - 1) > 1e-14
                b[off] /= b[off].sum(1, keepdims=True)
                faces[rows], bary[rows] = element, b
        return SurfacePoints(faces, bary)


def format_points(mesh: TriMesh, points: SurfacePoints) -> list[str]:
    """The authors' strings of ``points`` on ``mesh`` (see :meth:`GeometryCentralIndex.format`)."""
    return GeometryCentralIndex(mesh).format(points)


def parse_points(mesh: TriMesh, strings: Sequence[str], where: str = "points") -> SurfacePoints:
    """Surface points of ``mesh`` from the authors' strings (see :meth:`GeometryCentralIndex.parse`)."""
    return GeometryCentralIndex(mesh).parse(strings, where)


def _numbers(strings: list[str], rows: np.ndarray, count: int, where: str) -> np.ndarray:
    """The numbers after the letter of the strings at ``rows`` (all of one kind), as (k, count)."""
    picked = [strings[i] for i in rows]
    tokens = " ".join(picked).split()
    if len(tokens) == len(picked) * (count + 1):
        table = np.array(tokens, dtype=object).reshape(len(picked), count + 1)
        try:
            if np.all(table[:, 0] == picked[0][:1]):
                return table[:, 1:].astype(np.float64)
        except ValueError:
            pass
    for row, s in zip(rows, picked, strict=True):  # find the entry to blame
        parts = s.split()
        try:
            numbers = [float(x) for x in parts[1:]]
        except ValueError:
            numbers = None
        if parts[0] != s[:1] or numbers is None or len(numbers) != count:
            plural = "s" if count > 1 else ""
            raise MeshError(
                f"{where}: entry {int(row)} ({s!r}) should be '{s[:1]}' and {count} number{plural}"
            )
    raise AssertionError("unreachable: every entry parsed")  # pragma: no cover


def _blame(bad: np.ndarray, rows: np.ndarray, where: str, strings, what: str) -> None:
    """Raise naming the first entry where ``bad`` holds, and how many do."""
    bad = np.flatnonzero(bad)
    if bad.size:
        i = int(rows[bad[0]])
        raise MeshError(f"{where}: entry {i} ({strings[i]!r}) {what} ({bad.size} such entries)")


def _indices(values: np.ndarray, rows: np.ndarray, where: str, strings) -> np.ndarray:
    _blame(~np.isfinite(values) | (values != np.round(values)), rows, where, strings,
           "has an index that is not an integer")  # fmt: skip
    return values.astype(np.int64)


def _check_range(element, n: int, rows, where: str, strings, what: str, whats: str) -> None:
    _blame((element < 0) | (element >= n), rows, where, strings,
           f"names {what} the mesh does not have (it has {n} {whats})")  # fmt: skip
