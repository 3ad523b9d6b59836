"""The default annotation of a pair of procedural hands (Kinematic Motion Retargeting §3.3, Appendix A).

:func:`default_annotation` builds deterministic annotations for the procedural hands from their bone
chains, the way the paper's artist was asked to work: each finger's curve runs along its palmar side
from the knuckle crease to the finger pad, two palm curves cover the palm; λ_A is the ratio of the
target's and the source's curve lengths, λ_S the ratio of their girths; markers sit on the back of
every finger joint, at the fingertips, at the knuckles and at the wrist, as in a motion-capture marker
set (19 on a five-fingered hand, 13 on the three-fingered one, as Table 2), the
wrist pair on the forearm so that the root is observed apart from the wrist joint.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from geodesics import Axis, SurfacePoints, TriMesh

from ..hands import KINDS, Hand, make_hand
from .annotations import AnnotationError, CurveAnnotation, HandPairAnnotation, HandRef, MarkerAnnotation

#: Default ε_g as a fraction of the source hand's length (about 2.8 cm on the human hand): the contacts of
#: a dropped finger lie farther than this from every remaining landmark, the others nearer.
THRESHOLD_PER_LENGTH = 0.15
#: Default radius of a target area marker as a fraction of the target hand's length (about 7.5 mm).
MARKER_RADIUS_PER_LENGTH = 0.04
#: Points per area marker: area-uniform samples of the skin around the marker (Appendix C: about 60).
MARKER_POINTS = 60
#: Palmar or dorsal probe offset (fraction of the hand length) for placing points by nearest surface point.
PROBE_PER_LENGTH = 0.1


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


def hand_curves(hand: Hand, strict: bool = True, rays: bool = False) -> dict[str, tuple[Axis, float]]:
    """The default axial curves of a procedural hand, and each curve's girth.

    One curve per chain along its palmar side (finger base crease to finger pad; the thumb from its
    metacarpal's middle); on palmed hands also ``palm`` (wrist crease to the middle of the knuckle row)
    and ``palm_across`` (radial to ulnar edge across the middle of the palm). Each is the shortest
    geodesic between its end points, with every edge crossing an axis point (Appendix A.2), nudged
    sideways by a fraction of an edge (:data:`NUDGES`) until laying it out again from its start
    reproduces it: a shortest geodesic drawn to a line of saddle vertices (the palmar midline of the
    procedural fingers) is not reproduced by tracing (the straightest geodesic through a vertex differs
    from the shortest one), so it could not move contacts faithfully even onto its own hand. Where no
    nudge is reproduced, ``strict`` refuses the hand; otherwise the curve whose tracing strays least is
    taken (a proposal for a hand the user brings, which the user then edits).

    Each end is the skin point nearest a probe point on the palmar side of a bone; with ``rays``, where a
    ray from the bone towards that side leaves the skin instead. Rays are the better conditioned (a probe
    point as near two pieces of skin, the thenar eminence and the thumb, jumps between them as the bone's
    side turns by a degree); the built-in annotation keeps the probe points it was made with.
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
            (z0, zl),
        )
    if _has_palm(hand):
        b = rig.bone_index("hand")
        x, y, z = _bone_frame(hand, b)
        head, length = rig.heads[b], rig.lengths[b]
        girth = _girth(hand, [b])
        ends["palm"] = (
            head + 0.12 * length * y + probe * z,
            head + 0.9 * length * y + probe * z,
            x,
            girth,
            (z, z),
        )
        radial, ulnar = _palm_sides(hand)
        mid = head + 0.55 * length * y + probe * z
        ends["palm_across"] = (mid + 0.8 * radial * x, mid + 0.8 * ulnar * x, y, girth, (z, z))
    skin = _Skin(hand.mesh) if rays else None

    def end(point, side_of_bone):
        if skin is None:
            return lambda nudge: _nearest(hand, point + nudge)
        start = point - probe * side_of_bone  # on the bone
        return lambda nudge: skin.leaving(start + nudge, side_of_bone)

    return {
        name: (_clean_axis(hand, end(a, sides[0]), end(b, sides[1]), side, strict), girth)
        for name, (a, b, side, girth, sides) in ends.items()
    }


class _Skin:
    """Where rays from inside a mesh leave it (Möller-Trumbore against every face at once)."""

    def __init__(self, mesh: TriMesh):
        self.mesh = mesh
        T = mesh.vertices[mesh.faces]
        self.corner, self.e1, self.e2 = T[:, 0], T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]

    def leaving(self, origin, direction) -> SurfacePoints:
        """The first surface point along the ray (the nearest surface point to ``origin`` if none)."""
        p = np.cross(direction, self.e2)
        det = np.einsum("ij,ij->i", self.e1, p)
        usable = np.abs(det) > 1e-300
        inverse = 1.0 / np.where(usable, det, 1.0)
        s = origin - self.corner
        u = np.einsum("ij,ij->i", s, p) * inverse
        q = np.cross(s, self.e1)
        v = (q @ direction) * inverse
        t = np.einsum("ij,ij->i", q, self.e2) * inverse
        hit = np.flatnonzero(usable & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0))
        if hit.size == 0:
            return SurfacePoints.nearest(self.mesh, np.asarray(origin, float)[None])
        f = hit[np.argmin(t[hit])]
        return SurfacePoints([f], [[1.0 - u[f] - v[f], u[f], v[f]]])


#: Sideways nudges (in mean edge lengths) tried in turn until a default curve avoids every vertex.
NUDGES = (0.5, -0.5, 0.65, -0.65, 0.8, -0.8, 0.35, -0.35, 1.0, -1.0)


def _clean_axis(hand: Hand, a, b, side, strict: bool) -> Axis:
    """The first nudged curve that tracing reproduces; ``a(offset)`` and ``b(offset)`` give its ends with
    their probe point (or ray) moved by ``offset``."""
    mesh = hand.mesh
    step = mesh.mean_edge_length
    tried = []
    for nudge in NUDGES:
        axis = Axis.between(mesh, a(nudge * step * side), b(nudge * step * side))
        again = axis.trace(mesh, axis.start, axis.direction)
        if len(again) == len(axis):
            stray = np.abs(again.points.positions(mesh) - axis.points.positions(mesh)).max()
        else:
            stray = np.abs(again.points.positions(mesh)[-1] - axis.points.positions(mesh)[-1]).max()
        if stray <= 1e-9 * hand.length:
            return axis
        tried.append((stray, axis))
    if not strict:
        return min(tried, key=lambda t: t[0])[1]
    ends = [end(np.zeros(3)).positions(mesh)[0].round(4).tolist() for end in (a, b)]
    raise AnnotationError(
        f"no default curve from {ends[0]} to {ends[1]} on the {hand.kind} hand can be laid out again"
    )


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


def area_marker(hand: Hand, centre: SurfacePoints, radius: float, seed: int) -> SurfacePoints:
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
        tgt_area = area_marker(target, tgt_markers[f"{other}_{label}"], radius, seed=len(markers))
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


def procedural_hand(mesh: TriMesh) -> Hand | None:
    """The procedural hand that ``mesh`` is, at its size (:func:`procedural_kind`), scaled so that its rest
    mesh is as large; None when it is none of them.

    Parameters
    ----------
    mesh : TriMesh
        A hand's rest mesh.
    """
    kind = procedural_kind(mesh)
    if kind is None:
        return None
    return make_hand(kind, mesh.bounding_diagonal / make_hand(kind).mesh.bounding_diagonal)


def procedural_kind(mesh: TriMesh) -> str | None:
    """The kind of procedural hand whose mesh has ``mesh``'s topology (its vertices and faces in the same
    order, as the add-on's *Add › Contact Edit* makes it, wherever it is placed and however it is scaled
    or posed), or None."""
    digest = mesh.topology_hash
    return next((kind for kind in KINDS if _topology(kind) == digest), None)


def make_next_procedural_topology() -> bool:
    """Make the next kind of hand that :func:`procedural_kind` compares with, so that its first call need
    not make them all at once; False once every kind is made. The add-on calls it on timer ticks after
    start-up."""
    missing = [kind for kind in KINDS if kind not in _TOPOLOGIES]
    if missing:
        _topology(missing[0])
    return len(missing) > 1


#: Each kind of procedural hand's topology hash, as :func:`_topology` makes them (once per process).
_TOPOLOGIES: dict[str, str] = {}


def _topology(kind: str) -> str:
    if kind not in _TOPOLOGIES:
        _TOPOLOGIES[kind] = make_hand(kind).mesh.topology_hash
    return _TOPOLOGIES[kind]


def _scale_of(hand: Hand) -> float:
    """The procedural scale of a hand (its length over the life-size one's)."""
    return float(hand.length / make_hand(hand.kind).length) if hand.kind else 1.0
