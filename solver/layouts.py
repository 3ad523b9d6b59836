"""Contact layouts a person would make, around grips known to exist: the measuring stick of a solve.

A person posing a hand paints a pad on each fingertip that should touch, paints where on the object it
should go, and asks the solve for the pose. Their patches are near, not exactly, where a real grip
would put them, and the object is wherever the scene has it, not in the resting hand's palm. This
module makes such layouts with a known answer:

1. **A grip that exists** (:func:`known_grip`). The object (:data:`OBJECTS`: a cylinder, a ball, a
   box, the mug) is put in the palm of the hand at rest (:func:`solver.grasp.in_palm`) and the fingers
   are wrapped around it by flex-to-contact, one joint at a time (:func:`solver.grasp.grasp`, ``curl=
   "in turn"``). Of the hand's palm-side patches (:meth:`solver.hands.Hand.contact_patches`, one per
   bone), a patch *touches* when at least :data:`MIN_SHARE` of its points end within :data:`CONTACT`
   of the object; its touching points are the *pad* (a round finger meets the object along a strip
   of its palm side, and a person paints the part that touches, not the whole side of the bone).
2. **Which pads** (at most :data:`MAX_PADS`), as a person would place them: per finger and the thumb,
   the pad of its most distal touching segment (the fingertip where it touches, else the segment
   nearest the tip that does), then the palm if it touches. A layout needs :data:`MIN_PADS`; grips
   that give fewer are kept but not :attr:`Grip.usable`.
3. **Targets** (:func:`make_layout`): each pad point's closest point on the object, then *slid* over
   the surface as a hand placing patches by eye would: one seeded slide per pad, a length drawn from
   :data:`SLIDE` in a direction drawn at the pad's centre target, parallel-transported (exactly, along
   the shortest geodesic) to each of the pad's targets, which then move along the straightest geodesic
   of that vector (:func:`geodesics.exp_map`). On a developable surface the pad moves rigidly.
4. **The object carried away**: a seeded rigid motion G, a turn by an angle drawn in a bin of
   :data:`BINS` about a random axis through the grip's contact centroid, then a shift of that centroid
   by up to the hand's length, applied to the object (and so to its targets and normals). The hand stays
   at rest: a solve from rest must travel and turn the wrist. The known grip moved by G
   (:attr:`Layout.reference`: its root moved rigidly, :func:`carried`)
   is a pose that reaches the unslid targets.

:func:`turned` is the edit a person makes next: one pad's targets turned on the surface about its
centre. :func:`judge` measures a pose against the thresholds of issue 41 (each pad's median distance to
the surface within :data:`CONTACT`, to its targets within :data:`REACH`, no skin deeper than
:data:`DEPTH` inside the object), and :func:`judge_edit` whether an edit flipped the hand (turned it by
more than :data:`TURN_LIMIT`, or dropped a pad that touched). Everything random takes a seed.
:mod:`solver.layout_benchmark` runs solves over these layouts.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from geodesics import GeodesicField, SurfacePoints, TriMesh, exp_map, log_map
from geodesics.rigid import rigid_fit
from geodesics.tangent import change_basis

from . import objects
from .errors import SolverError
from .grasp import grasp, in_palm
from .hands import Hand
from .rig import RigLike, SkinnedMesh
from .rotations import axis_angle_to_matrix, matrix_to_axis_angle
from .sdf import MeshSDF

#: The objects a hand grips, by name: closed meshes in metres, as :mod:`solver.objects` makes them.
OBJECTS: dict[str, Callable[[], TriMesh]] = {
    "cylinder": objects.cylinder,
    "sphere": objects.sphere,
    "box": objects.box,
    "mug": objects.mug,
}
#: Bins of the object's turn (degrees), as issue 41 asks: small, large and about-face wrist turns.
BINS: tuple[tuple[float, float], ...] = ((0.0, 45.0), (45.0, 100.0), (100.0, 180.0))
#: Range of each pad's slide over the surface (metres): a few millimetres, a patch placed by eye.
SLIDE = (0.002, 0.005)
#: A pad touches when its median distance to the surface is at most this (metres; issue 41: 2 mm).
CONTACT = 0.002
#: A pad meets its patch when its median distance to its targets is at most this (metres; 8 mm).
REACH = 0.008
#: No skin vertex may be deeper than this inside the object (metres; 1 mm).
DEPTH = 0.001
#: An edit flips the hand when it turns the palm by more than this (degrees).
TURN_LIMIT = 30.0
#: Palm-side points drawn per bone patch before the touching ones are kept.
POINTS_PER_PATCH = 40
#: A patch touches when at least this share of its points end within :data:`CONTACT` in the grip.
MIN_SHARE = 0.15
#: At most this many pads per layout (five digits and the palm).
MAX_PADS = 6
#: A layout needs at least this many pads (one pad fixes no grip).
MIN_PADS = 2


@dataclass(frozen=True, eq=False)
class Grip:
    """A grip that exists and the pads a person would paint on it (see :func:`known_grip`).

    Attributes
    ----------
    hand : Hand
    name : str
        The object's name in :data:`OBJECTS`.
    object : TriMesh
        The object in the hand's armature space, where the grip holds it.
    sdf : MeshSDF
        Its signed distance.
    theta : (d,) ndarray
        The grip (the root at rest, the fingers wrapped).
    pads : tuple of str
        The pads' bone names, in the order of :meth:`Hand.contact_patches`'s chains.
    points : SurfacePoints
        (k) the pads' points on ``hand.mesh``, pad by pad.
    pad_index : (k,) int ndarray
        Each point's pad (index into ``pads``), non-decreasing.
    """

    hand: Hand
    name: str
    object: TriMesh
    sdf: MeshSDF
    theta: np.ndarray
    pads: tuple[str, ...]
    points: SurfacePoints
    pad_index: np.ndarray

    @property
    def patches(self) -> list[tuple[str, int]]:
        """The pads as :class:`~solver.ContactIK` takes its ``patches``: (name, number of points)."""
        return _patches(self.pads, self.pad_index)

    @property
    def usable(self) -> bool:
        """Whether the grip has the :data:`MIN_PADS` pads a layout needs."""
        return len(self.pads) >= MIN_PADS


@dataclass(frozen=True, eq=False)
class Layout:
    """What a solve and its judge need: a hand at rest, an object somewhere, pads and their targets.

    Attributes
    ----------
    hand : SkinnedMesh
        The hand to pose (solved from its rest pose).
    name : str
        The object's name in :data:`OBJECTS`.
    object : TriMesh
        The object, carried away by ``motion``, in the hand's armature space.
    sdf : MeshSDF
        Its signed distance (the solve's ``keep_out`` and the judge's surface).
    pads : tuple of str
        The pads' names (bones of the hand they are painted on).
    points : SurfacePoints
        (k) pad points on ``hand.mesh``.
    pad_index : (k,) int ndarray
        Each point's pad, non-decreasing.
    targets : SurfacePoints
        (k) each point's target on ``object`` (valid on the unmoved object too: same faces).
    centres : (p,) int ndarray
        Per pad, the index of its centre target (the one nearest the mean of its targets before the
        slide), the pivot of :func:`turned`.
    positions : (k, 3) ndarray
        The targets in space.
    normals : (k, 3) ndarray
        The object's outward unit normals there (their faces' normals).
    slides : (p,) complex ndarray
        Per pad, the slide at its centre target, in that target's tangent basis (metres).
    motion : (4, 4) ndarray
        G, the rigid motion that carried the object (and its targets) from the grip.
    pivot : (3,) ndarray
        The point G turns about (the unslid targets' centroid in the grip); G moves it by at most
        ``hand.length``.
    bin : (2,) tuple of float
        The bin of G's turn, degrees.
    reference : (d,) ndarray or None
        The known grip moved by G: it reaches the unslid targets (None for a hand the grip was not
        made on, see :func:`on_hand`).
    palm : int
        The deformer whose turn is the hand's (:func:`palm_deformer`, :func:`judge_edit`).
    """

    hand: SkinnedMesh
    name: str
    object: TriMesh
    sdf: MeshSDF
    pads: tuple[str, ...]
    points: SurfacePoints
    pad_index: np.ndarray
    targets: SurfacePoints
    centres: np.ndarray
    positions: np.ndarray
    normals: np.ndarray
    slides: np.ndarray
    motion: np.ndarray
    pivot: np.ndarray
    bin: tuple[float, float]
    reference: np.ndarray | None
    palm: int

    @property
    def patches(self) -> list[tuple[str, int]]:
        """The pads as :class:`~solver.ContactIK` takes its ``patches``: (name, number of points)."""
        return _patches(self.pads, self.pad_index)

    @property
    def angle(self) -> float:
        """The turn of ``motion`` in degrees, in [0, 180]."""
        return float(np.degrees(matrix_to_axis_angle(self.motion[:3, :3])[0]))

    @property
    def shift(self) -> float:
        """How far ``motion`` moves ``pivot`` (metres)."""
        return float(np.linalg.norm(self.motion[:3, :3] @ self.pivot + self.motion[:3, 3] - self.pivot))


@dataclass(frozen=True)
class Verdict:
    """How a pose meets a layout (see :func:`judge`); distances in metres.

    Attributes
    ----------
    theta : (d,) ndarray
        The pose judged.
    contact : (p,) ndarray
        Per pad, the median |signed distance| of its posed points to the object's surface.
    reach : (p,) ndarray
        Per pad, the median distance of its posed points to their targets.
    depth : float
        How deep the deepest skin vertex is inside the object (0 when none is).
    touching : (p,) bool ndarray
        ``contact <= CONTACT``.
    success : bool
        Every pad touches and reaches its patch (``reach <= REACH``), and ``depth <= DEPTH``.
    """

    theta: np.ndarray
    contact: np.ndarray
    reach: np.ndarray
    depth: float
    touching: np.ndarray
    success: bool


@dataclass(frozen=True)
class EditVerdict:
    """What an edit's re-solve did to the hand (see :func:`judge_edit`).

    Attributes
    ----------
    turn : float
        How far the palm turned between the two poses, degrees.
    dropped : tuple of int
        Pads that touched before and no longer do.
    flip : bool
        ``turn > TURN_LIMIT`` or a pad dropped.
    """

    turn: float
    dropped: tuple[int, ...]
    flip: bool


# ------------------------------------------------------------------------------------------- grips


def _patches(pads: tuple[str, ...], pad_index: np.ndarray) -> list[tuple[str, int]]:
    """(name, number of points) per pad, in order."""
    return list(zip(pads, np.bincount(pad_index, minlength=len(pads)).tolist(), strict=True))


def object_named(name: str) -> TriMesh:
    """The object :data:`OBJECTS` names, upright around the z axis as :mod:`solver.objects` makes it."""
    if name not in OBJECTS:
        raise SolverError(f"unknown object {name!r}; choose one of {', '.join(OBJECTS)}")
    return OBJECTS[name]()


def _touching_parts(
    hand: Hand, theta: np.ndarray, sdf: MeshSDF, patches: dict[str, SurfacePoints]
) -> dict[str, SurfacePoints]:
    """Per patch that touches at ``theta`` (:data:`MIN_SHARE` of its points within :data:`CONTACT`), its
    touching points."""
    names = list(patches)
    points = SurfacePoints.concatenate(patches.values())
    owner = np.repeat(np.arange(len(names)), [len(p) for p in patches.values()])
    positions, _ = hand.posed_points(theta, points)
    near = np.abs(sdf(positions, CONTACT)) <= CONTACT
    share = np.bincount(owner, weights=near, minlength=len(names)) / np.bincount(owner, minlength=len(names))
    return {
        name: points[np.flatnonzero(near & (owner == i))]
        for i, name in enumerate(names)
        if share[i] >= MIN_SHARE
    }


def _person_pads(hand: Hand, touching: dict[str, SurfacePoints]) -> list[str]:
    """The pads a person would paint: per digit (in the hand's chain order) its most distal touching
    segment, then the palm's patches (bones in no chain) that touch; at most :data:`MAX_PADS`."""
    names = hand.rig.names
    pads = []
    for chain in hand.chains.values():
        tips = [names[b] for b in reversed(chain) if names[b] in touching]
        pads += tips[:1]
    in_chains = {names[b] for chain in hand.chains.values() for b in chain}
    pads += [name for name in touching if name not in in_chains]
    return pads[:MAX_PADS]


def known_grip(hand: Hand, name: str, points_per_patch: int = POINTS_PER_PATCH, seed: int = 0) -> Grip:
    """The object ``name`` in the palm of ``hand``, the fingers wrapped around it, and its pads.

    Parameters
    ----------
    hand : Hand
        A procedural hand (:func:`solver.hands.make_hand`): its chains name the digits.
    name : str
        One of :data:`OBJECTS`.
    points_per_patch : int
        Points drawn on each bone's palm-side patch (:meth:`Hand.contact_patches`).
    seed : int
        Seeds the patches' points.

    Returns
    -------
    Grip
        Possibly with fewer than :data:`MIN_PADS` pads (then not :attr:`Grip.usable`).
    """
    if not isinstance(hand, Hand):
        raise SolverError(
            "a known grip needs a solver.hands.Hand (its fingers are wrapped by flex-to-contact)"
        )
    if int(points_per_patch) < 1:
        raise SolverError(f"points_per_patch must be at least 1, got {points_per_patch!r}")
    obj = in_palm(hand, object_named(name))
    sdf = MeshSDF(obj)
    theta = grasp(hand, sdf, curl="in turn").theta
    touching = _touching_parts(hand, theta, sdf, hand.contact_patches(int(points_per_patch), seed))
    pads = _person_pads(hand, touching)
    parts = [touching[pad] for pad in pads]
    pad_index = np.repeat(np.arange(len(pads)), [len(p) for p in parts]).astype(np.int64)
    return Grip(hand, name, obj, sdf, theta, tuple(pads), SurfacePoints.concatenate(parts), pad_index)


# ------------------------------------------------------------------------------------------- targets


def _closest_targets(grip: Grip) -> tuple[SurfacePoints, np.ndarray]:
    """(k) each pad point's closest point on the object in the grip, and (p,) per pad the index of the
    target nearest the mean of its targets (its centre)."""
    posed, _ = grip.hand.posed_points(grip.theta, grip.points)
    _, closest, faces = grip.sdf.query(posed)
    targets = SurfacePoints.from_positions(grip.object, faces, closest)
    n = len(grip.pads)
    count = np.bincount(grip.pad_index, minlength=n)
    mean = np.stack([np.bincount(grip.pad_index, closest[:, j], n) for j in range(3)], 1) / count[:, None]
    gap = np.linalg.norm(closest - mean[grip.pad_index], axis=1)
    first = np.concatenate([[0], np.cumsum(count)[:-1]])
    order = np.lexsort((gap, grip.pad_index))  # by pad, nearest first: each pad's first is its centre
    return targets, order[first]


def _transported(mesh: TriMesh, origin: SurfacePoints, points: SurfacePoints, z) -> np.ndarray:
    """(k,) complex: the tangent vector ``z`` at ``origin`` parallel-transported along the shortest
    geodesic to each of ``points`` (k), in their bases (the angle to the geodesic is kept). Points on
    the origin get ``z`` in their own basis."""
    found = GeodesicField(mesh, origin, points).query(points)
    out = np.empty(len(points), np.complex128)
    away = found.distances > 0
    out[away] = z * found.final_directions[away] / found.initial_directions[away]
    here = np.flatnonzero(~away)
    if here.size:
        out[here] = change_basis(mesh, z, origin[np.zeros(here.size, np.int64)], points[here])
    return out


def _slid(
    mesh: TriMesh, targets: SurfacePoints, pad_index: np.ndarray, centres: np.ndarray, slides: np.ndarray
) -> SurfacePoints:
    """The targets (k) moved pad by pad: each pad's slide (p,) complex at its centre target, transported to
    its other targets and traced along straightest geodesics from each."""
    z = np.zeros(len(targets), np.complex128)
    for pad, (centre, slide) in enumerate(zip(centres, slides, strict=True)):
        rows = np.flatnonzero(pad_index == pad)
        z[rows] = _transported(mesh, targets[int(centre)], targets[rows], slide)
    return exp_map(mesh, targets, z).points


def _rigid_motion(rng: np.random.Generator, bin: tuple[float, float], length: float, pivot) -> np.ndarray:
    """(4, 4) a turn by an angle uniform in ``bin`` (degrees) about a uniformly random axis through
    ``pivot`` (3,), then a shift of the pivot in a uniformly random direction by a length uniform in
    [0, ``length``]."""
    angle = np.radians(rng.uniform(*bin))
    axis = rng.normal(size=3)
    shift = rng.normal(size=3)
    shift *= rng.uniform(0.0, length) / np.linalg.norm(shift)
    R = axis_angle_to_matrix(np.concatenate([[angle], axis]))
    G = np.eye(4)
    G[:3, :3] = R
    G[:3, 3] = pivot + shift - R @ pivot
    return G


def _moved(mesh: TriMesh, G: np.ndarray) -> TriMesh:
    """The mesh moved by the rigid transform G (4, 4)."""
    return TriMesh(mesh.vertices @ G[:3, :3].T + G[:3, 3], mesh.faces)


def _range(value, what: str, upper: float) -> tuple[float, float]:
    """(low, high) from two numbers with ``0 <= low <= high <= upper`` (finite); SolverError names
    ``what`` otherwise."""
    try:
        lo, hi = (float(x) for x in value)
    except (TypeError, ValueError):
        raise SolverError(f"{what} is two numbers (low, high), got {value!r}") from None
    if not (0.0 <= lo <= hi <= upper and np.isfinite(hi)):
        raise SolverError(f"{what} must satisfy 0 <= low <= high <= {upper:g}, got {value!r}")
    return lo, hi


def carried(rig: RigLike, theta, G) -> np.ndarray:
    """(d,) the pose θ (d,) with the whole hand carried by the rigid transform G (4, 4): the root's rigid
    motion becomes ``G`` after θ's (:meth:`~solver.rig.RigLike.root_dofs`), the joints kept."""
    theta = rig.check_theta(theta)
    out = theta.copy()
    out[:6] = rig.root_dofs(np.asarray(G) @ rig.root_transform(theta), compatible=theta[3:6])
    return out


def make_layout(grip: Grip, bin=BINS[0], seed=0, slide=SLIDE) -> Layout:
    """A person's layout around ``grip``: its pads' targets slid over the object, which is carried away.

    Parameters
    ----------
    grip : Grip
        A :attr:`Grip.usable` grip (:func:`known_grip`).
    bin : (2,) array_like of float
        The object's turn is drawn uniformly in this range of degrees (within [0, 180]).
    seed : int or sequence of int
        Seeds the slides and the motion (separate streams: the same seed with ``slide=(0, 0)`` gives the
        same motion, unslid).
    slide : (2,) array_like of float
        Each pad's slide length is drawn uniformly in this range (metres).

    Returns
    -------
    Layout
    """
    if not grip.usable:
        raise SolverError(
            f"the {grip.hand.kind} hand's grip of the {grip.name} has {len(grip.pads)} pad(s); a layout "
            f"needs {MIN_PADS}"
        )
    bin, slide = _range(bin, "a bin of turn (degrees)", 180.0), _range(slide, "the slide (metres)", np.inf)
    slide_rng, motion_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    targets, centres = _closest_targets(grip)
    pivot = targets.positions(grip.object).mean(axis=0)
    n = len(grip.pads)
    slides = slide_rng.uniform(*slide, n) * np.exp(2j * np.pi * slide_rng.random(n))
    targets = _slid(grip.object, targets, grip.pad_index, centres, slides)
    G = _rigid_motion(motion_rng, bin, grip.hand.length, pivot)
    moved = _moved(grip.object, G)
    return Layout(
        hand=grip.hand,
        name=grip.name,
        object=moved,
        sdf=MeshSDF(moved),
        pads=grip.pads,
        points=grip.points,
        pad_index=grip.pad_index,
        targets=targets,
        centres=centres,
        positions=targets.positions(moved),
        normals=moved.face_normals[targets.faces],
        slides=slides,
        motion=G,
        pivot=pivot,
        bin=bin,
        reference=carried(grip.hand.rig, grip.theta, G),
        palm=palm_deformer(grip.hand),
    )


def _pad(layout: Layout, pad) -> int:
    """The index of ``pad`` (an index or a name) among the layout's pads."""
    if isinstance(pad, str):
        if pad not in layout.pads:
            raise SolverError(f"the layout has no pad {pad!r}; it has {', '.join(layout.pads)}")
        return layout.pads.index(pad)
    index = int(pad)
    if not 0 <= index < len(layout.pads):
        raise SolverError(f"pad index {pad!r} is out of range 0..{len(layout.pads) - 1}")
    return index


def turned(layout: Layout, pad, degrees: float) -> Layout:
    """The layout with one pad's targets turned on the surface about its centre target.

    Each of the pad's targets is where the exact log map from the centre target says it is (a tangent
    offset r·e^{iα}); the offset is turned to r·e^{i(α + φ)} and traced back with the exp map, so
    distances from the centre are kept. Normals are those of the new targets' faces.

    Parameters
    ----------
    layout : Layout
    pad : int or str
        The pad's index or name.
    degrees : float
        φ, counter-clockwise seen from outside the object.

    Returns
    -------
    Layout
    """
    p = _pad(layout, pad)
    mesh = layout.object
    rows = np.flatnonzero(layout.pad_index == p)
    centre = layout.targets[int(layout.centres[p])]
    z = log_map(mesh, centre, layout.targets[rows]) * np.exp(1j * np.radians(float(degrees)))
    ends = exp_map(mesh, centre, z).points
    faces, bary = layout.targets.faces.copy(), layout.targets.bary.copy()
    faces[rows], bary[rows] = ends.faces, ends.bary
    targets = SurfacePoints(faces, bary)
    return replace(
        layout, targets=targets, positions=targets.positions(mesh), normals=mesh.face_normals[targets.faces]
    )


def on_hand(layout: Layout, hand: SkinnedMesh) -> Layout:
    """The layout for another skin of the same mesh (a Rigify rig skinning the procedural hand): its rest
    mesh must be the layout hand's moved rigidly (found by a least-squares fit, Kabsch), and the object,
    targets and motion move with it. The reference is dropped (the grip was made on the other rig); the
    palm is the new skin's deformer that weighs most on the layout hand's palm vertices.

    Raises
    ------
    SolverError
        If the meshes differ in size or are not one rigid motion apart (to 1e-6 of the hand's size).
    """
    source, target = layout.hand.mesh.vertices, hand.mesh.vertices
    if source.shape != target.shape or not np.array_equal(layout.hand.mesh.faces, hand.mesh.faces):
        raise SolverError("the hand does not skin the layout hand's mesh (other vertices or faces)")
    M = rigid_fit(source, target)
    off = np.linalg.norm(source @ M[:3, :3].T + M[:3, 3] - target, axis=1)
    if off.max() > 1e-6 * layout.hand.size:
        raise SolverError(
            f"the hand's mesh is not the layout hand's moved rigidly (vertex {int(np.argmax(off))} is "
            f"{off.max():.3g} off)",
            vertices=np.flatnonzero(off > 1e-6 * layout.hand.size),
        )
    moved = _moved(layout.object, M)
    return replace(
        layout,
        hand=hand,
        object=moved,
        sdf=MeshSDF(moved),
        positions=layout.targets.positions(moved),
        normals=moved.face_normals[layout.targets.faces],
        motion=M @ layout.motion @ np.linalg.inv(M),
        pivot=M[:3, :3] @ layout.pivot + M[:3, 3],
        reference=None,
        palm=palm_deformer(hand, palm_vertices(layout.hand)),
    )


# ------------------------------------------------------------------------------------------- judge


def _pad_medians(values: np.ndarray, pad_index: np.ndarray, n: int) -> np.ndarray:
    """(n,) the median of ``values`` (k,) over each pad's rows."""
    return np.array([np.median(values[pad_index == p]) for p in range(n)])


def judge(hand: SkinnedMesh, theta, layout: Layout) -> Verdict:
    """How the pose θ (d,) of ``hand`` meets the layout, by issue 41's thresholds.

    Contact and reach are per pad medians (a pad whose rim lifts off a curved surface still touches);
    the depth is exact (:class:`MeshSDF`) at every posed skin vertex.

    Returns
    -------
    Verdict
    """
    theta = hand.rig.check_theta(theta)
    n = len(layout.pads)
    posed, _ = hand.posed_points(theta, layout.points)
    contact = _pad_medians(np.abs(layout.sdf(posed)), layout.pad_index, n)
    reach = _pad_medians(np.linalg.norm(posed - layout.positions, axis=1), layout.pad_index, n)
    depth = max(0.0, -float(layout.sdf(hand.posed_vertices(theta)).min()))
    touching = contact <= CONTACT
    success = bool(touching.all() and np.all(reach <= REACH) and depth <= DEPTH)
    return Verdict(theta, contact, reach, depth, touching, success)


def palm_vertices(hand: SkinnedMesh) -> np.ndarray:
    """(m,) the vertices skinned mostly to the deform bone that carries the most skin: a procedural
    hand's palm (its ``hand`` bone)."""
    W = hand.weights.tocsr()
    heaviest = int(np.argmax(np.asarray(W.sum(axis=0)).ravel()))
    return np.flatnonzero(np.asarray(W.argmax(axis=1)).ravel() == heaviest)


def palm_deformer(hand: SkinnedMesh, vertices=None) -> int:
    """The deformer (column of ``hand.deformer_weights``) that carries the most weight over the palm's
    ``vertices`` (m,) (default :func:`palm_vertices`): a procedural hand's ``hand`` bone; on a Rigify
    skin of its mesh, given its palm's vertices, the palm's deform bone that weighs most there."""
    rows = palm_vertices(hand) if vertices is None else np.asarray(vertices, dtype=np.int64)
    return int(np.argmax(np.asarray(hand.deformer_weights[rows].sum(axis=0)).ravel()))


def hand_turn(hand: SkinnedMesh, theta_a, theta_b, palm: int | None = None) -> float:
    """The angle (degrees, in [0, 180]) between the palm's orientations at poses θa and θb (d,): the
    rotation of its deformer's skinning matrix at one relative to the other. ``palm`` is a deformer index
    (default :func:`palm_deformer`; a layout's is :attr:`Layout.palm`)."""
    palm = palm_deformer(hand) if palm is None else int(palm)
    rig = hand.rig
    Ra = rig.kinematics(rig.check_theta(theta_a), derivatives=False).skinning[palm, :, :3]
    Rb = rig.kinematics(rig.check_theta(theta_b), derivatives=False).skinning[palm, :, :3]
    return float(np.degrees(matrix_to_axis_angle(Ra.T @ Rb)[0]))


def judge_edit(hand: SkinnedMesh, before: Verdict, after: Verdict, palm: int | None = None) -> EditVerdict:
    """Whether re-solving after an edit flipped the hand: the palm (deformer ``palm``, as in
    :func:`hand_turn`) turned by more than :data:`TURN_LIMIT` from ``before.theta`` to ``after.theta``, or a
    pad that touched before (any pad, the edited one too) no longer touches."""
    turn = hand_turn(hand, before.theta, after.theta, palm)
    dropped = tuple(int(p) for p in np.flatnonzero(before.touching & ~after.touching))
    return EditVerdict(turn, dropped, bool(turn > TURN_LIMIT or dropped))
