"""Hand-pair annotations and bulk contact transfer (Kinematic Motion Retargeting §3.3, Appendix A).

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

:class:`HandPairAnnotation` holds both, is stored as JSON next to the target hand
(``format: contact-edit/hand-pair``, version 1; written atomically, validated on load, refused for a
hand of another topology), and :func:`default_annotation` builds deterministic ones for the procedural
hands from their bone chains, the way the paper's artist was asked to work: each finger's curve runs
along its palmar side from the knuckle crease to the finger pad, two palm curves cover the palm; λ_A is
the ratio of the target's and the source's curve lengths, λ_S the ratio of their girths; markers sit on
the back of every finger joint, at the fingertips, at the knuckles and at the wrist, as in a
motion-capture marker set (19 on a five-fingered hand, 13 on the three-fingered one, as Table 2), the
wrist pair on the forearm so that the root is observed apart from the wrist joint.

:class:`ContactTransfer` moves contacts through :class:`geodesics.ContactAtlas`: all frames' contacts in
one parameterize-and-trace call (duplicates across frames are traced once), then split back into frames
with a kept mask, so the object's contacts stay paired with the hand's row for row.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from geodesics import Axis, ContactAtlas, MeshError, SurfacePoints, TriMesh
from geodesics.files import read_json, write_atomically
from geodesics.schema import Fields

from ..errors import SolverError
from ..hands import Hand

if TYPE_CHECKING:  # pragma: no cover
    from .motion import Contacts, Motion

FORMAT = "contact-edit/hand-pair"
VERSION = 1
#: Default ε_g as a fraction of the source hand's length (about 2.8 cm on the human hand): the contacts of
#: a dropped finger lie farther than this from every remaining landmark, the others nearer.
THRESHOLD_PER_LENGTH = 0.15
#: Default radius of a target area marker as a fraction of the target hand's length (about 7.5 mm).
MARKER_RADIUS_PER_LENGTH = 0.04
#: Points per area marker: area-uniform samples of the skin around the marker (Appendix C: about 60).
MARKER_POINTS = 60
#: Palmar or dorsal probe offset (fraction of the hand length) for placing points by nearest surface point.
PROBE_PER_LENGTH = 0.1


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


# ------------------------------------------------------------------------------ default annotations


def _bone_frame(hand: Hand, bone: int):
    M = hand.rig.matrix_local[bone]
    return M[:3, 0], M[:3, 1], M[:3, 2]


def _nearest(hand: Hand, position) -> SurfacePoints:
    return SurfacePoints.nearest(hand.mesh, np.asarray(position, float)[None])


def _owner(hand: Hand) -> np.ndarray:
    """(n,) the bone each rest vertex is skinned to most."""
    W = hand.weights.tocsr()
    return np.asarray(W.argmax(axis=1)).reshape(-1)


def _girth(hand: Hand, bones) -> float:
    """Mean distance of the vertices skinned mostly to ``bones`` from those bones' lines (rest)."""
    owner = _owner(hand)
    V = hand.mesh.vertices
    out = []
    for b in bones:
        head, tail = hand.rig.heads[b], hand.rig.tails[b]
        y = (tail - head) / np.linalg.norm(tail - head)
        X = V[owner == b] - head
        out.append(np.linalg.norm(X - np.outer(X @ y, y), axis=1))
    return float(np.mean(np.concatenate(out)))


def _has_palm(hand: Hand) -> bool:
    return "hand" in hand.rig.names and hand.kind != "tentacle"


def _palm_sides(hand: Hand) -> tuple[float, float]:
    """Coordinates along the palm bone's x axis of the palm's radial (thumb) and ulnar edges (rest)."""
    b = hand.rig.bone_index("hand")
    x, _, _ = _bone_frame(hand, b)
    head = hand.rig.heads[b]
    along = (hand.mesh.vertices[_owner(hand) == b] - head) @ x
    if "thumb" in hand.chains:
        thumb_side = np.sign((hand.rig.heads[hand.chains["thumb"][0]] - head) @ x)
    else:
        thumb_side = -np.sign(x[0]) or 1.0  # the procedural hands' thumb side is -x
    return (along.max(), along.min()) if thumb_side > 0 else (along.min(), along.max())


def hand_curves(hand: Hand) -> dict[str, tuple[Axis, float]]:
    """The default axial curves of a procedural hand, and each curve's girth.

    One curve per chain along its palmar side (finger base crease to finger pad; the thumb from its
    metacarpal's middle); on palmed hands also ``palm`` (wrist crease to the middle of the knuckle row)
    and ``palm_across`` (radial to ulnar edge across the middle of the palm). Each is the shortest
    geodesic between its end points, with every edge crossing an axis point (Appendix A.2), nudged
    sideways by a fraction of an edge (:data:`NUDGES`) until laying it out again from its start
    reproduces it: a shortest geodesic drawn to a line of saddle vertices (the palmar midline of the
    procedural fingers) is not reproduced by tracing (the straightest geodesic through a vertex differs
    from the shortest one), so it could not move contacts faithfully even onto its own hand.
    """
    rig = hand.rig
    probe = PROBE_PER_LENGTH * hand.length
    ends = {}
    for name, chain in hand.chains.items():
        first, last = chain[0], chain[-1]
        x0, _, z0 = _bone_frame(hand, first)
        _, yl, zl = _bone_frame(hand, last)
        head = rig.heads[first]
        if name == "thumb" or hand.kind == "tentacle":
            head = 0.5 * (rig.heads[first] + rig.tails[first])
        ends[name] = (
            head + probe * z0,
            rig.tails[last] - 0.3 * rig.lengths[last] * yl + probe * zl,
            x0,
            _girth(hand, chain),
        )
    if _has_palm(hand):
        b = rig.bone_index("hand")
        x, y, z = _bone_frame(hand, b)
        head, length = rig.heads[b], rig.lengths[b]
        girth = _girth(hand, [b])
        ends["palm"] = (head + 0.12 * length * y + probe * z, head + 0.9 * length * y + probe * z, x, girth)
        radial, ulnar = _palm_sides(hand)
        mid = head + 0.55 * length * y + probe * z
        ends["palm_across"] = (mid + 0.8 * radial * x, mid + 0.8 * ulnar * x, y, girth)
    return {name: (_clean_axis(hand, a, b, side), girth) for name, (a, b, side, girth) in ends.items()}


#: Sideways nudges (in mean edge lengths) tried in turn until a default curve avoids every vertex.
NUDGES = (0.5, -0.5, 0.65, -0.65, 0.8, -0.8, 0.35, -0.35, 1.0, -1.0)


def _clean_axis(hand: Hand, a, b, side) -> Axis:
    mesh = hand.mesh
    step = mesh.mean_edge_length
    for nudge in NUDGES:
        axis = Axis.between(
            mesh, _nearest(hand, a + nudge * step * side), _nearest(hand, b + nudge * step * side)
        )
        again = axis.trace(mesh, axis.start, axis.direction)
        if np.abs(again.points.positions(mesh) - axis.points.positions(mesh)).max() <= 1e-9 * hand.length:
            return axis
    raise AnnotationError(f"no default curve from {a} to {b} on the {hand.kind} hand can be laid out again")


def hand_markers(hand: Hand) -> dict[str, SurfacePoints]:
    """Centres of the default virtual markers of a procedural hand, one surface point each.

    On each chain, on the back of the tails of its last three bones: ``<chain>_joint1``,
    ``<chain>_joint2`` and ``<chain>_tip`` (the tip marker at the end of the finger); on palmed hands
    ``knuckle_radial`` and ``knuckle_ulnar`` on the back of the palm at the knuckles, and
    ``wrist_radial`` and ``wrist_ulnar`` on the forearm's sides just before the wrist (radial: the
    thumb's side).
    """
    rig = hand.rig
    probe = PROBE_PER_LENGTH * hand.length
    out = {}
    for name, chain in hand.chains.items():
        for label, b in zip(("joint1", "joint2", "tip"), chain[-3:], strict=True):
            _, y, z = _bone_frame(hand, b)
            tail = rig.tails[b]
            where = tail + probe * y if label == "tip" else tail - probe * z
            out[f"{name}_{label}"] = _nearest(hand, where)
    if _has_palm(hand):
        b = rig.bone_index("hand")
        x, y, z = _bone_frame(hand, b)
        head, length = rig.heads[b], rig.lengths[b]
        radial, ulnar = _palm_sides(hand)
        for label, along, across in (
            ("knuckle_radial", 0.88, 0.75 * radial),
            ("knuckle_ulnar", 0.88, 0.75 * ulnar),
        ):
            out[label] = _nearest(hand, head + along * length * y + across * x - probe * z)
        # The wrist markers sit on the forearm's sides just before the wrist (the styloid processes, as in
        # motion-capture marker sets): they fix the root (the forearm) apart from the wrist joint.
        wrist = head - 0.4 * rig.lengths[0] * rig.matrix_local[0, :3, 1]
        for label, edge in (("wrist_radial", radial), ("wrist_ulnar", ulnar)):
            out[label] = _nearest(hand, wrist + (edge + np.sign(edge) * probe) * x)
    return out


def _area(hand: Hand, centre: SurfacePoints, radius: float, seed: int) -> SurfacePoints:
    """An area marker: :data:`MARKER_POINTS` area-uniform samples (seeded) of the faces within ``radius``
    of a marker centre whose normals face its way."""
    mesh = hand.mesh
    c = centre.positions(mesh)[0]
    n = mesh.face_normals[centre.faces[0]]
    T = mesh.vertices[mesh.faces]
    d = np.linalg.norm(T.mean(1) - c, axis=1)
    facing = mesh.face_normals @ n > 0.3
    faces = np.flatnonzero((d <= radius) & facing)
    if faces.size == 0:
        faces = centre.faces
    area = mesh.face_areas[faces]
    rng = np.random.default_rng(seed)
    pick = rng.choice(faces, size=MARKER_POINTS, p=area / area.sum())
    return SurfacePoints(pick, rng.dirichlet([1.0, 1.0, 1.0], MARKER_POINTS))


def _single_vertex(hand: Hand, centre: SurfacePoints) -> SurfacePoints:
    c = centre.positions(hand.mesh)[0]
    return SurfacePoints.from_vertices(
        hand.mesh, [int(np.argmin(np.linalg.norm(hand.mesh.vertices - c, axis=1)))]
    )


def default_annotation(
    source: Hand,
    target: Hand,
    correspondence: Mapping[str, str | None] | None = None,
    threshold: float | None = None,
    marker_radius: float | None = None,
) -> HandPairAnnotation:
    """A deterministic annotation for a pair of procedural hands.

    Parameters
    ----------
    source, target : Hand
        From :func:`solver.hands.make_hand` (any kinds and scales).
    correspondence : mapping, optional
        Source curve name -> target curve name (or None to drop it). Default: curves of the same name
        (thumb, index, middle, ring, pinky, palm, palm_across); those the target lacks are dropped (a
        three-fingered hand's ring and pinky). Markers follow their chain: ``<source chain>_<label>``
        pairs with ``<target chain>_<label>``.
    threshold : float, optional
        ε_g (default :data:`THRESHOLD_PER_LENGTH` times the source hand's length).
    marker_radius : float, optional
        Radius of the target area markers (default :data:`MARKER_RADIUS_PER_LENGTH` times the target's
        length).

    Returns
    -------
    HandPairAnnotation
        λ_A = target curve length / source curve length and λ_S = target girth / source girth per
        curve. Markers: for two hands of the same kind (any scales), 1:1 area markers on the same skin
        spots; otherwise the paper's many-to-one markers (a single source vertex, an area
        on the target).
    """
    src_curves, tgt_curves = hand_curves(source), hand_curves(target)
    if correspondence is None:
        correspondence = {name: (name if name in tgt_curves else None) for name in src_curves}
    curves = []
    for name, (axis, girth) in src_curves.items():
        other = correspondence.get(name)
        if other is None:
            curves.append(CurveAnnotation(name, axis.points))
            continue
        if other not in tgt_curves:
            raise AnnotationError(f"the target hand has no curve '{other}' (it has {', '.join(tgt_curves)})")
        t_axis, t_girth = tgt_curves[other]
        curves.append(
            CurveAnnotation(
                name,
                axis.points,
                t_axis.start,
                t_axis.direction,
                t_axis.length / axis.length,
                t_girth / girth,
            )
        )
    # The same kind at any scale is the same shape: 1:1 area markers on the same skin spots.
    same = source.kind == target.kind and source.mesh.n_vertices == target.mesh.n_vertices
    radius = MARKER_RADIUS_PER_LENGTH * target.length if marker_radius is None else float(marker_radius)
    src_markers, tgt_markers = hand_markers(source), hand_markers(target)
    chain_map = {"wrist": "wrist", "knuckle": "knuckle", **correspondence}
    markers = []
    for name, centre in src_markers.items():
        prefix, label = name.rsplit("_", 1)
        other = chain_map.get(prefix)
        if other is None or f"{other}_{label}" not in tgt_markers:
            continue
        tgt_area = _area(target, tgt_markers[f"{other}_{label}"], radius, seed=len(markers))
        if same and other == prefix:  # the same skin spots on the source (up to the hands' scales)
            spots = tgt_area.positions(target.mesh) * (source.length / target.length)
            src = SurfacePoints.nearest(source.mesh, spots)
        else:
            src = _single_vertex(source, centre)
        markers.append(MarkerAnnotation(name, src, tgt_area))
    return HandPairAnnotation(
        HandRef.of(source.mesh, source.kind, _scale_of(source)),
        HandRef.of(target.mesh, target.kind, _scale_of(target)),
        tuple(curves),
        tuple(markers),
        THRESHOLD_PER_LENGTH * source.length if threshold is None else float(threshold),
    )


def _scale_of(hand: Hand) -> float:
    """The procedural scale of a hand (its length over the life-size one's)."""
    from ..hands import make_hand

    return float(hand.length / make_hand(hand.kind).length) if hand.kind else 1.0


# ---------------------------------------------------------------------------------- bulk transfer


class ContactTransfer:
    """The contact atlas of an annotated hand pair, laid out once, moving contacts in bulk.

    Parameters
    ----------
    annotation : HandPairAnnotation
    source_mesh, target_mesh : TriMesh
        The annotated hands' rest meshes (checked against the annotation).

    Raises
    ------
    AnnotationError
        If the meshes are not the annotated ones, or a curve cannot be laid out on the target.
    """

    def __init__(self, annotation: HandPairAnnotation, source_mesh: TriMesh, target_mesh: TriMesh):
        from geodesics import ContactError

        annotation.check(source_mesh, target_mesh)
        self.annotation = annotation
        self.source_mesh, self.target_mesh = source_mesh, target_mesh
        try:
            curves = {c.name: Axis(source_mesh, c.source) for c in annotation.curves}
            self.atlas = ContactAtlas(source_mesh, curves)
            kept = [c for c in annotation.curves if not c.dropped]
            self.target_curves = self.atlas.lay_out(
                target_mesh,
                {c.name: (c.target_start, c.target_direction) for c in kept},
                {c.name: c.axis_scale for c in kept},
            )
        except ContactError as e:
            raise AnnotationError(f"the annotation's curves cannot be laid out: {e}") from None
        self.radial_scale = {c.name: c.radial_scale for c in kept}

    def points(self, contacts: SurfacePoints) -> tuple[SurfacePoints, np.ndarray]:
        """Transfer surface points of the source hand.

        Returns the kept points on the target (in order) and the (k,) kept mask. Repeated points (the
        same face and barycentric coordinates, as across frames of a motion) are traced once.
        """
        contacts.validate(self.source_mesh)
        k = len(contacts)
        if k == 0:
            return SurfacePoints(np.empty(0, np.int64), np.empty((0, 3))), np.zeros(0, bool)
        key = np.column_stack([contacts.faces.astype(np.float64), contacts.bary])
        unique, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
        inverse = inverse.reshape(-1)
        moved, kept_unique = self.atlas.transfer(
            contacts[first], self.target_curves, self.radial_scale, self.annotation.threshold
        )
        slot = np.full(len(unique), -1, np.int64)
        slot[kept_unique] = np.arange(int(kept_unique.sum()))
        kept = kept_unique[inverse]
        rows = slot[inverse[kept]]
        return SurfacePoints(moved.faces[rows], moved.bary[rows]), kept

    def contacts(self, contacts: Contacts, progress: Callable[[int, int], None] | None = None):
        """Transfer every frame's hand contacts in one call.

        Returns
        -------
        moved : Contacts
            The kept contacts on the target hand, frame by frame.
        kept : (K,) bool
            Which of the input rows were kept; apply it to the paired object contacts with
            :func:`keep_rows` so they stay paired row for row.
        """
        from .motion import Contacts as _Contacts

        points = SurfacePoints(contacts.faces, contacts.bary)
        if progress is not None:
            progress(0, 1)
        moved, kept = self.points(points)
        if progress is not None:
            progress(1, 1)
        offsets = _kept_offsets(np.asarray(contacts.offsets), kept)
        return _Contacts(offsets, moved.faces, moved.bary), kept


def _kept_offsets(offsets: np.ndarray, kept: np.ndarray) -> np.ndarray:
    counts = np.diff(offsets)
    frame = np.repeat(np.arange(counts.size), counts)
    kept_counts = np.bincount(frame[kept], minlength=counts.size)
    return np.concatenate([[0], np.cumsum(kept_counts)]).astype(np.int64)


def keep_rows(contacts: Contacts, kept) -> Contacts:
    """The rows of ``contacts`` where ``kept`` (K,) is True, frames preserved."""
    from .motion import Contacts as _Contacts

    kept = np.asarray(kept, dtype=bool)
    if kept.shape != (len(contacts.faces),):
        raise AnnotationError(
            f"kept must have one flag per contact ({len(contacts.faces)}), got {kept.shape}"
        )
    return _Contacts(
        _kept_offsets(np.asarray(contacts.offsets), kept), contacts.faces[kept], contacts.bary[kept]
    )


@dataclass(frozen=True, eq=False)
class TransferredContacts:
    """A motion's contacts moved to the target hand.

    Attributes
    ----------
    hand_contacts : Contacts
        On the target hand's mesh.
    object_contacts : Contacts or None
        The motion's object contacts that stay paired with them, row for row.
    kept : (K,) bool
        Which of the motion's hand contacts were kept.
    """

    hand_contacts: Contacts
    object_contacts: Contacts | None
    kept: np.ndarray


def transfer_motion(
    motion: Motion,
    annotation: HandPairAnnotation,
    target_mesh: TriMesh,
    progress: Callable[[int, int], None] | None = None,
) -> TransferredContacts:
    """Transfer a motion's hand contacts (all frames at once) onto the target hand (§3.3.2)."""
    if motion.hand_contacts is None:
        raise AnnotationError("the motion has no hand contacts; pair them first (pairing.pair_motion)")
    transfer = ContactTransfer(annotation, motion.hand_mesh, target_mesh)
    moved, kept = transfer.contacts(motion.hand_contacts, progress)
    obj = None if motion.object_contacts is None else keep_rows(motion.object_contacts, kept)
    return TransferredContacts(moved, obj, kept)
