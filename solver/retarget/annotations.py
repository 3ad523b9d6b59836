"""Hand-pair annotations: the data model and its file (Kinematic Motion Retargeting §3.3, Appendix A).

A retarget from one hand to another needs a one-time artist annotation of the pair:

* **Axial curves** (§3.3.2, Appendix A.2): named curves on the source hand's palmar surface (their
  points are the landmarks of the contact atlas) and, for each curve that has a counterpart, where it is
  laid out on the target: a start point, an initial direction, λ_A (scales the curve's segment lengths
  to the target's finger length) and λ_S (scales each contact's distance from its landmark, to the
  target's girth). A curve without a counterpart (the ring and pinky of a three-fingered hand) is
  dropped: its contacts fall to the nearest remaining landmark and those farther than the geodesic
  distance threshold ε_g are discarded.
* **Virtual markers** (§3.3.1, Fig. 4): corresponding point sets on both hands. A source set of one
  point with a target set of many is the paper's heterogeneous many-to-one marker (every target point
  tracks the one source point); equal-sized sets are area markers matched 1:1, row for row; one point
  each is a classic single marker.

:class:`HandPairAnnotation` holds both and is stored as JSON next to the target hand
(``format: contact-edit/hand-pair``, version 1; written atomically, validated on load, refused for a
hand of another topology). :mod:`.annotate` builds the default annotation of the procedural hands,
:mod:`.transfer` moves contacts through one.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from geodesics import MeshError, SurfacePoints, TriMesh
from geodesics.files import read_json, write_atomically
from geodesics.schema import Fields

from ..errors import SolverError

FORMAT = "contact-edit/hand-pair"
VERSION = 1


class AnnotationError(SolverError):
    """A hand-pair annotation is malformed, or does not fit the hands it is used with."""


# ----------------------------------------------------------------------------------------- values


@dataclass(frozen=True)
class HandRef:
    """Which hand an annotation side belongs to: the procedural kind and scale if any, and the mesh's
    topology (vertex and face counts, :attr:`geodesics.TriMesh.topology_hash`)."""

    kind: str | None
    scale: float
    n_vertices: int
    n_faces: int
    topology: str

    @classmethod
    def of(cls, mesh: TriMesh, kind: str | None = None, scale: float = 1.0) -> HandRef:
        return cls(kind, float(scale), mesh.n_vertices, mesh.n_faces, mesh.topology_hash)

    def check(self, mesh: TriMesh, side: str) -> None:
        """Raise AnnotationError unless ``mesh`` has this topology."""
        if mesh.topology_hash != self.topology:
            raise AnnotationError(
                f"the annotation's {side} hand has {self.n_vertices} vertices and {self.n_faces} faces "
                f"(topology {self.topology[:12]}), the given mesh {mesh.n_vertices} and {mesh.n_faces} "
                f"(topology {mesh.topology_hash[:12]}): it was made for another hand"
            )


@dataclass(frozen=True, eq=False)
class CurveAnnotation:
    """One axial curve: its points on the source hand and its placement on the target.

    Attributes
    ----------
    name : str
    source : SurfacePoints
        The curve's points on the source hand (at least two): the atlas landmarks.
    target_start : SurfacePoints or None
        Where the curve starts on the target (one point); None drops the curve (no counterpart).
    target_direction : complex
        Its initial direction on the target, in ``target_start``'s tangent basis.
    axis_scale : float
        λ_A, multiplies the curve's segment lengths on the target.
    radial_scale : float
        λ_S, multiplies each contact's distance from its landmark on the target.
    """

    name: str
    source: SurfacePoints
    target_start: SurfacePoints | None = None
    target_direction: complex = 1.0 + 0.0j
    axis_scale: float = 1.0
    radial_scale: float = 1.0

    @property
    def dropped(self) -> bool:
        return self.target_start is None


@dataclass(frozen=True, eq=False)
class MarkerAnnotation:
    """A virtual marker: corresponding point sets on the source and target hands (§3.3.1, Fig. 4).

    ``len(source) == len(target)`` pairs them row for row (area markers, or single points);
    one source point with many target points is a many-to-one marker; many source points with one
    target point pull it to their centroid.
    """

    name: str
    source: SurfacePoints
    target: SurfacePoints

    def __post_init__(self):
        s, t = len(self.source), len(self.target)
        if s == 0 or t == 0 or (s != t and s != 1 and t != 1):
            raise AnnotationError(
                f"marker '{self.name}' pairs {s} source points with {t} target points; use equal counts "
                "(area markers) or one point on either side (single or many-to-one markers)"
            )

    @property
    def kind(self) -> str:
        s, t = len(self.source), len(self.target)
        if s == t:
            return "single" if s == 1 else "area"
        return "many-to-one" if s == 1 else "one-to-many"


@dataclass(frozen=True, eq=False)
class MarkerPairs:
    """All markers flattened to target points, each with the source points whose mean it tracks.

    Attributes
    ----------
    target : SurfacePoints (p)
        Marker points on the target hand.
    source : SurfacePoints (s)
        Marker points on the source hand.
    weights : scipy.sparse.csr_matrix (p, s)
        Row i averages the source points target point i tracks: its position at a frame is
        ``weights @ source_positions``.
    marker : (p,) int
        Index of each target point's marker; ``names`` lists them.
    names : tuple of str
    """

    target: SurfacePoints
    source: SurfacePoints
    weights: object
    marker: np.ndarray
    names: tuple[str, ...]

    def targets(self, source_mesh: TriMesh, source_vertices) -> np.ndarray:
        """(p, 3) where each target marker point should be at a frame whose source hand has the posed
        vertices ``source_vertices`` (n, 3); (F, p, 3) for the vertices of F frames (F, n, 3) at once."""
        V = np.asarray(source_vertices, dtype=np.float64)
        if V.ndim not in (2, 3) or V.shape[-2:] != (source_mesh.n_vertices, 3):
            raise AnnotationError(
                f"source vertices must have shape ({source_mesh.n_vertices}, 3) or (F, "
                f"{source_mesh.n_vertices}, 3), got {V.shape}"
            )
        corners = source_mesh.faces[self.source.faces]
        S = np.einsum("kj,...kjd->...kd", self.source.bary, V[..., corners, :])  # (..., s, 3)
        if V.ndim == 2:
            return np.asarray(self.weights @ S)
        F, s = S.shape[:2]
        T = np.asarray(self.weights @ S.transpose(1, 0, 2).reshape(s, 3 * F))  # every frame in one product
        return T.reshape(-1, F, 3).transpose(1, 0, 2)

    def subset(self, names) -> MarkerPairs:
        """Only the named markers (e.g. the fingertips for keypoint tracking)."""
        from scipy import sparse

        wanted = [self.names.index(n) for n in names if n in self.names]
        missing = [n for n in names if n not in self.names]
        if missing:
            raise AnnotationError(f"no markers named {', '.join(missing)}; there are {', '.join(self.names)}")
        rows = np.flatnonzero(np.isin(self.marker, wanted))
        W = sparse.csr_matrix(self.weights)[rows]
        used = np.unique(W.indices)
        remap = np.full(W.shape[1], -1)
        remap[used] = np.arange(used.size)
        W = sparse.csr_matrix((W.data, remap[W.indices], W.indptr), shape=(rows.size, used.size))
        new_index = {m: i for i, m in enumerate(wanted)}
        return MarkerPairs(
            self.target[rows],
            self.source[used],
            W,
            np.array([new_index[m] for m in self.marker[rows]], np.int64),
            tuple(self.names[m] for m in wanted),
        )


@dataclass(frozen=True, eq=False)
class HandPairAnnotation:
    """The one-time annotation of a source-target hand pair: axial curves and virtual markers.

    Attributes
    ----------
    source, target : HandRef
    curves : tuple of CurveAnnotation
    markers : tuple of MarkerAnnotation
    threshold : float
        ε_g: contacts farther than this geodesic distance (on the source) from their landmark are dropped.
    """

    source: HandRef
    target: HandRef
    curves: tuple[CurveAnnotation, ...]
    markers: tuple[MarkerAnnotation, ...] = field(default=())
    threshold: float = np.inf

    def __post_init__(self):
        object.__setattr__(self, "curves", tuple(self.curves))
        object.__setattr__(self, "markers", tuple(self.markers))
        names = [c.name for c in self.curves]
        if len(set(names)) != len(names):
            raise AnnotationError(f"curve names repeat: {names}")
        if not any(not c.dropped for c in self.curves):
            raise AnnotationError("no curve has a counterpart on the target: nothing can be transferred")
        names = [m.name for m in self.markers]
        if len(set(names)) != len(names):
            raise AnnotationError(f"marker names repeat: {names}")
        if not (float(self.threshold) > 0):
            raise AnnotationError(f"the distance threshold must be positive, got {self.threshold!r}")
        for c in self.curves:
            if len(c.source) < 2:
                raise AnnotationError(f"curve '{c.name}' needs at least two source points")
            if not c.dropped:
                if len(c.target_start) != 1:
                    raise AnnotationError(f"curve '{c.name}' needs exactly one target start point")
                if not (np.isfinite(c.target_direction) and abs(c.target_direction) > 0):
                    raise AnnotationError(f"curve '{c.name}' has a zero or non-finite target direction")
                for what, v in (("λ_A", c.axis_scale), ("λ_S", c.radial_scale)):
                    if not (np.isfinite(v) and v > 0):
                        raise AnnotationError(f"curve '{c.name}': {what} must be positive, got {v!r}")

    # ------------------------------------------------------------------ use

    def check(self, source_mesh: TriMesh, target_mesh: TriMesh) -> None:
        """Raise AnnotationError unless the meshes are the annotated hands' and every point is on them."""
        self.source.check(source_mesh, "source")
        self.target.check(target_mesh, "target")
        try:
            for c in self.curves:
                c.source.validate(source_mesh)
                if not c.dropped:
                    c.target_start.validate(target_mesh)
            for m in self.markers:
                m.source.validate(source_mesh)
                m.target.validate(target_mesh)
        except MeshError as e:
            raise AnnotationError(f"annotation points are off the hands' meshes: {e}") from None

    @property
    def curve_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.curves)

    def marker_pairs(self, names=None) -> MarkerPairs:
        """The markers (default: all) as target points and the source points they track."""
        from scipy import sparse

        markers = self.markers if names is None else [m for m in self.markers if m.name in set(names)]
        if not markers:
            raise AnnotationError("the annotation has no virtual markers")
        rows, cols, vals, owner = [], [], [], []
        n_src = n_tgt = 0
        for i, m in enumerate(markers):
            s, t = len(m.source), len(m.target)
            if s == t:
                r, c, v = np.arange(t), np.arange(s), np.ones(t)
            elif s == 1:
                r, c, v = np.arange(t), np.zeros(t, np.int64), np.ones(t)
            else:
                r, c, v = np.zeros(s, np.int64), np.arange(s), np.full(s, 1.0 / s)
            rows.append(r + n_tgt)
            cols.append(c + n_src)
            vals.append(v)
            owner.append(np.full(t, i))
            n_src += s
            n_tgt += t
        W = sparse.csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n_tgt, n_src)
        )
        return MarkerPairs(
            SurfacePoints.concatenate([m.target for m in markers]),
            SurfacePoints.concatenate([m.source for m in markers]),
            W,
            np.concatenate(owner),
            tuple(m.name for m in markers),
        )

    # ------------------------------------------------------------------ files

    def to_dict(self) -> dict:
        """The annotation file's content (JSON-ready: each set of points as ``faces`` (k) and ``bary``
        (k, 3) lists, a direction as ``[real, imaginary]``)."""

        def pts(p: SurfacePoints) -> dict:
            return {"faces": p.faces.tolist(), "bary": p.bary.tolist()}

        def ref(r: HandRef) -> dict:
            return {
                "kind": r.kind,
                "scale": r.scale,
                "vertices": r.n_vertices,
                "faces": r.n_faces,
                "topology": r.topology,
            }

        curves = []
        for c in self.curves:
            target = None
            if not c.dropped:
                target = {
                    "start": pts(c.target_start),
                    "direction": [c.target_direction.real, c.target_direction.imag],
                    "axis_scale": c.axis_scale,
                    "radial_scale": c.radial_scale,
                }
            curves.append({"name": c.name, "source": pts(c.source), "target": target})
        return {
            "format": FORMAT,
            "version": VERSION,
            "source": ref(self.source),
            "target": ref(self.target),
            "threshold": None if not np.isfinite(self.threshold) else float(self.threshold),
            "curves": curves,
            "markers": [
                {"name": m.name, "source": pts(m.source), "target": pts(m.target)} for m in self.markers
            ],
        }

    @classmethod
    def from_dict(cls, data, source: str = "hand-pair annotation") -> HandPairAnnotation:
        """Validate and build from :meth:`to_dict`'s layout; AnnotationError names the offending field
        (``source``: what to call the data in errors, the file's path when loaded)."""
        file = Fields(data, source, AnnotationError)
        file.header(FORMAT, VERSION, "hand-pair annotation")
        hands = {side: _read_ref(file.object(side)) for side in ("source", "target")}
        threshold = file.number("threshold", optional=True)
        curves = []
        for entry in file.objects("curves"):
            entry = entry.renamed(f"{source}: curve '{entry.string('name')}'")
            points = _read_points(entry.object("source"), hands["source"])
            target = entry.object("target", optional=True)
            if target is None:
                curves.append(CurveAnnotation(entry.data["name"], points))
                continue
            start = _read_points(target.object("start"), hands["target"])
            direction = complex(*target.numbers("direction", (2,)))
            scales = (target.number("axis_scale"), target.number("radial_scale"))
            curves.append(CurveAnnotation(entry.data["name"], points, start, direction, *scales))
        markers = []
        for entry in file.objects("markers", optional=True):
            entry = entry.renamed(f"{source}: marker '{entry.string('name')}'")
            pair = (_read_points(entry.object(side), hands[side]) for side in ("source", "target"))
            markers.append(MarkerAnnotation(entry.data["name"], *pair))
        return cls(hands["source"], hands["target"], tuple(curves), tuple(markers), threshold or np.inf)

    def save(self, path) -> None:
        """Write the annotation as JSON, atomically (a complete file or none)."""
        write_atomically(path, json.dumps(self.to_dict(), indent=1))

    @classmethod
    def load(cls, path, source_mesh: TriMesh | None = None, target_mesh: TriMesh | None = None):
        """Read and validate an annotation file; with meshes given, also check it was made for them."""
        annotation = cls.from_dict(read_json(path, "annotation file", AnnotationError), str(path))
        if source_mesh is not None:
            annotation.source.check(source_mesh, "source")
        if target_mesh is not None:
            annotation.target.check(target_mesh, "target")
        if source_mesh is not None and target_mesh is not None:
            annotation.check(source_mesh, target_mesh)
        return annotation


def _read_ref(data: Fields) -> HandRef:
    return HandRef(
        data.string("kind", optional=True),
        data.number("scale", positive=True),
        data.integer("vertices", positive=True),
        data.integer("faces", positive=True),
        data.string("topology"),
    )


def _read_points(data: Fields, hand: HandRef) -> SurfacePoints:
    faces = data.indices("faces", hand.n_faces)
    try:
        return SurfacePoints(faces, data.numbers("bary", (None, 3), finite=False))
    except MeshError as e:
        raise AnnotationError(f"{data.field('bary')}: {e}") from None
