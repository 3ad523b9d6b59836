"""A starting annotation for any skinned hand, proposed from its bones (Kinematic Motion Retargeting §3.3).

The paper's artist draws each hand's axial curves and markers by hand. :func:`propose_patches` draws a
first version from the hand's armature so that the artist edits rather than starts from nothing: it finds
the finger chains under the wrist bone, names them (the thumb is the chain that starts nearest the wrist,
then index, middle, ring and pinky in order away from it), takes each finger's palmar side to be the side
it curls to at rest (so the bones' roll, which riggers set their own way, does not matter), and then lays
out the curves and markers as the built-in annotation of the procedural hands does
(:func:`.annotate.hand_curves`, :func:`.annotate.hand_markers`; a curve's ends where rays from its bones
leave the skin), on a view of the rig shaped like a procedural hand: bone 0 the forearm (everything outside
the wrist's subtree), bone 1 the palm (the wrist bone and every bone under it that is in no finger), then
each finger's bones, with every bone's frame turned so that its z axis points palmar.

The result is a :class:`geodesics.ContactSet` for :func:`.drawn.annotation_from_patches`: each curve a
strip of skin along its axis (half as wide as the finger's girth), each marker a small area of skin; and
each curve's girth, whose ratio between two hands is their λ_S as in the built-in annotation (the strips'
widths measure it less well: a strip across the palm takes in whatever skin is near).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

from geodesics import ContactPatch, ContactSet, SurfacePoints, TriMesh

from ..errors import SolverError
from ..hands import Hand
from ..rig import Rig
from .annotate import MARKER_RADIUS_PER_LENGTH, area_marker, hand_curves, hand_markers
from .annotations import AnnotationError

#: Finger names in order from the thumb.
FINGERS = ("thumb", "index", "middle", "ring", "pinky")
#: Palmar-side choices: a bone's local axis, with a sign.
PALMAR_SIDES = ("+Z", "-Z", "+X", "-X")
#: Least summed rest curl of a finger (radians, about) from which its palmar side is told.
MIN_CURL = np.radians(2.0)
#: A turn of a finger's frame smaller than this (radians) is rounding, and not made.
ROUNDING = 1e-9


@dataclass(frozen=True)
class Skeleton:
    """A hand's bones in its mesh's space.

    Attributes
    ----------
    names : tuple of str
    parents : (b,) int
        -1 for roots.
    matrices : (b, 4, 4)
        Rest frames (x, y, z columns orthonormal, y along the bone; the head in the last column).
    lengths : (b,)
    weights : (n, b) sparse
        Skin weights of the mesh's vertices.
    """

    names: tuple[str, ...]
    parents: np.ndarray
    matrices: np.ndarray
    lengths: np.ndarray
    weights: sparse.csr_matrix

    def children(self, b: int) -> np.ndarray:
        return np.flatnonzero(self.parents == b)

    def subtree(self, b: int) -> list[int]:
        out, todo = [], [b]
        while todo:
            out.append(todo.pop())
            todo.extend(self.children(out[-1]).tolist())
        return out


@dataclass(frozen=True)
class Proposal:
    """A proposed annotation of one hand: the patches, which of them are markers, and how it was read."""

    contacts: ContactSet
    markers: tuple[str, ...]
    wrist: str
    chains: dict[str, tuple[str, ...]]
    palmar: str
    #: Each curve's girth: the mean distance of its bones' skin from their lines (λ_S of two hands is the
    #: ratio of their girths, as in the built-in annotation).
    girths: dict[str, float]


def propose_patches(mesh: TriMesh, skeleton: Skeleton, wrist: str | None = None, palmar: str | None = None):
    """Curves and markers drawn on a skinned hand from its bones.

    Parameters
    ----------
    mesh : TriMesh
        The hand's rest mesh (the skeleton in its space).
    skeleton : Skeleton
    wrist : str, optional
        The wrist bone; default: the one bone under which two to five finger chains meet (a whole body's
        armature has two hands: name it then).
    palmar : str, optional
        The fingers' palmar side as a local bone axis (:data:`PALMAR_SIDES`), for rigs whose fingers are
        straight at rest; default: the side each finger curls to at rest.

    Returns
    -------
    Proposal

    Raises
    ------
    AnnotationError
        Naming what could not be read: no or too many finger chains, a wrist bone that is not there,
        fingers straight at rest with no palmar side given.
    """
    if wrist:
        if wrist not in skeleton.names:
            raise AnnotationError(f"the armature has no bone '{wrist}' to take as the wrist")
        root = skeleton.names.index(wrist)
    else:
        root = _find_wrist(skeleton)
    chains = _name_chains(skeleton, root, _finger_chains(skeleton, root))
    if palmar is not None and palmar not in PALMAR_SIDES:
        raise AnnotationError(f"the palmar side must be one of {', '.join(PALMAR_SIDES)}, got {palmar!r}")
    hand = _hand_view(mesh, skeleton, root, chains, palmar)
    contacts, markers, girths = _patches(hand)
    names = {f: tuple(skeleton.names[b] for b in c) for f, c in chains.items()}
    return Proposal(contacts, markers, skeleton.names[root], names, palmar or "curl", girths)


def _finger_chains(skeleton: Skeleton, root: int) -> list[list[int]]:
    """Under ``root`` (-1: anywhere), each weighted leaf's unbranched run of weighted bones upwards, of
    at least two bones, proximal first."""
    weighted = np.asarray(skeleton.weights.sum(axis=0)).ravel() > 0
    n_children = np.bincount(skeleton.parents[skeleton.parents >= 0], minlength=len(skeleton.names))
    below = np.zeros(len(skeleton.names), bool)  # a bone with a weighted bone below it is no leaf
    for b in np.flatnonzero(weighted):
        p = skeleton.parents[b]
        while p >= 0 and not below[p]:
            below[p] = True
            p = skeleton.parents[p]
    inside = set(skeleton.subtree(root)) - {root} if root >= 0 else set(range(len(skeleton.names)))
    out = []
    for leaf in sorted(inside):
        if not weighted[leaf] or below[leaf]:
            continue
        chain = [leaf]
        while (p := int(skeleton.parents[chain[-1]])) in inside and n_children[p] == 1 and weighted[p]:
            chain.append(p)
        if len(chain) >= 2:
            out.append(chain[::-1])
    return out


def _find_wrist(skeleton: Skeleton) -> int:
    """The bone under which the most finger chains (two to five) meet, the lowest such; refused when a bone
    above holds twice as many (two hands)."""
    count = np.zeros(len(skeleton.names), np.int64)
    for chain in _finger_chains(skeleton, -1):
        p = skeleton.parents[chain[0]]
        while p >= 0:
            count[p] += 1
            p = skeleton.parents[p]
    hands = np.flatnonzero((count >= 2) & (count <= len(FINGERS)))
    if hands.size == 0:
        raise AnnotationError(
            "no bone of the armature has two to five finger chains under it (runs of at least two weighted "
            "bones): name the wrist bone"
        )
    most = count[hands].max()
    if count.max() >= 2 * most:
        raise AnnotationError(
            f"the armature holds more than one hand ({count.max()} finger chains): name the wrist bone"
        )
    candidates = hands[count[hands] == most]
    return int(min(candidates, key=lambda b: len(skeleton.subtree(b))))


def _name_chains(skeleton: Skeleton, root: int, chains: list[list[int]]) -> dict[str, list[int]]:
    if not 2 <= len(chains) <= len(FINGERS):
        raise AnnotationError(
            f"'{skeleton.names[root]}' has {len(chains)} finger chains under it; an annotation is proposed "
            f"for two to {len(FINGERS)}"
        )
    heads = skeleton.matrices[:, :3, 3]
    wrist = heads[root]
    bases = np.array([heads[c[0]] for c in chains])
    thumb = int(np.argmin(np.linalg.norm(bases - wrist, axis=1)))
    order = np.argsort(np.linalg.norm(bases - bases[thumb], axis=1), kind="stable")
    return {name: chains[i] for name, i in zip(FINGERS, order, strict=False)}


def _curl(M: np.ndarray, chain: list[int]) -> np.ndarray:
    """(x, z): how far a chain's bones bend towards their first bone's local x and z axes at rest, summed
    (each bend as the next bone's direction across the bone before it, in that bone's frame)."""
    total = np.zeros(2)
    for a, b in itertools.pairwise(chain):
        bend = M[b, :3, 1] - (M[b, :3, 1] @ M[a, :3, 1]) * M[a, :3, 1]
        total += [bend @ M[a, :3, 0], bend @ M[a, :3, 2]]
    return total


def _palmar_frames(
    skeleton: Skeleton, chains: dict[str, list[int]], palmar: str | None
) -> dict[int, np.ndarray]:
    """Each finger bone's frame turned about its length so that its z axis points palmar: to ``palmar``
    (a local axis) if given; else a finger's to the side its chain curls to at rest, whatever the bones'
    roll. The thumb's pad faces between its own curl and the palm's side (the fingers' mean: on the
    procedural hands its pad side lies within a few degrees of that bisector, its curl and the palm's
    side some 45° to either side of it); a straight chain faces the palm's side."""
    M = skeleton.matrices
    if palmar is not None:
        new_z = {"+Z": (0.0, 1.0), "-Z": (0.0, -1.0), "+X": (1.0, 0.0), "-X": (-1.0, 0.0)}[palmar]
        return {b: _rolled(M[b], *new_z) for chain in chains.values() for b in chain}
    curls = {name: _curl(M, chain) for name, chain in chains.items()}
    curled = [name for name, c in curls.items() if np.hypot(*c) >= MIN_CURL]
    if not curled:
        raise AnnotationError(
            "the fingers are straight in the rest pose, so the palm's side cannot be told from how they "
            f"curl: choose it ({', '.join(PALMAR_SIDES)})"
        )
    frames = {}
    for name in curled:
        x, z = curls[name] / np.hypot(*curls[name])
        if abs(x) < ROUNDING and z > 0:  # curls along z but for rounding: keep the frame as it is
            x, z = 0.0, 1.0
        frames.update({b: _rolled(M[b], x, z) for b in chains[name]})
    fingers = [name for name in curled if name != "thumb"] or curled
    palm_side = np.mean([frames[chains[name][0]][:3, 2] for name in fingers], axis=0)
    for name in chains.keys() - set(fingers):
        for b in chains[name]:
            z = palm_side - (palm_side @ M[b, :3, 1]) * M[b, :3, 1]
            z /= np.linalg.norm(z)
            if b in frames:  # a curled thumb: halfway between its curl and the palm's side
                z += frames[b][:3, 2]
                z /= np.linalg.norm(z)
            frames[b] = _rolled(M[b], z @ M[b, :3, 0], z @ M[b, :3, 2])
    return frames


def _rolled(M: np.ndarray, x: float, z: float) -> np.ndarray:
    """The frame turned about its y axis so that its z axis is the unit direction ``x`` X + ``z`` Z (the
    frame itself, bit for bit, for (0, 1))."""
    norm = np.hypot(x, z)
    x, z = x / norm, z / norm
    out = M.copy()
    out[:3, 0] = z * M[:3, 0] - x * M[:3, 2]
    out[:3, 2] = x * M[:3, 0] + z * M[:3, 2]
    return out


def _hand_view(mesh: TriMesh, skeleton: Skeleton, root: int, chains, palmar: str | None) -> Hand:
    """The hand as :mod:`.annotate` reads a procedural one (see the module's docstring)."""
    M = skeleton.matrices
    frames = _palmar_frames(skeleton, chains, palmar)
    # The palm's palmar side: the fingers' first bones' mean (the thumb's too only if it is alone), across
    # the palm bone.
    y = M[root, :3, 1]
    fingers = [c for name, c in chains.items() if name != "thumb"] or list(chains.values())
    z = np.mean([frames[c[0]][:3, 2] for c in fingers], axis=0)
    z -= (z @ y) * y
    palm = M[root].copy()
    palm[:3, 2] = z / np.linalg.norm(z)
    palm[:3, 0] = np.cross(y, palm[:3, 2])
    forearm = palm.copy()
    forearm[:3, 3] -= skeleton.lengths[root] * y
    names, parents, matrices, columns = ["forearm", "hand"], [-1, 0], [forearm, palm], []
    lengths = [skeleton.lengths[root], skeleton.lengths[root]]
    index = {}
    for finger, chain in chains.items():
        for i, b in enumerate(chain):
            index[b] = len(names)
            names.append(f"{finger}_{i + 1}")
            parents.append(1 if i == 0 else len(names) - 2)
            matrices.append(frames[b])
            lengths.append(skeleton.lengths[b])
            columns.append(b)
    # Each bone's skin goes to its view bone: a finger bone's (with any bones under it that are in no
    # finger), the palm's (the wrist's other bones), or the forearm's (all else, and unweighted skin).
    column = np.zeros(len(skeleton.names), np.int64)
    column[skeleton.subtree(root)] = 1
    for b in columns:
        for c in skeleton.subtree(b):
            column[c] = index.get(c, index[b])
    assign = sparse.csr_matrix(
        (np.ones(column.size), (np.arange(column.size), column)), shape=(column.size, len(names))
    )
    weights = (skeleton.weights @ assign).tolil()
    weights[:, 0] = np.clip(1.0 - np.asarray(weights[:, 1:].sum(axis=1)).ravel(), 0, None)[:, None]
    weights = weights.tocsr()
    # As the procedural hands measure it: from the wrist to the farthest skin of the hand, along the palm.
    hand_skin = np.asarray(weights.argmax(axis=1)).ravel() > 0
    length = float(((mesh.vertices[hand_skin] - palm[:3, 3]) @ y).max())
    chain_ids = {finger: tuple(index[b] for b in chain) for finger, chain in chains.items()}
    try:
        rig = Rig(names, parents, np.array(matrices), lengths)
        return Hand(mesh, rig, weights, None, length, chain_ids)
    except SolverError as err:
        raise AnnotationError(f"the hand's bones cannot be read as a hand: {err}") from None


def _patches(hand: Hand) -> tuple[ContactSet, tuple[str, ...], dict[str, float]]:
    mesh = hand.mesh
    patches = {}
    curves = hand_curves(hand, strict=False, rays=True)
    for name, (axis, girth) in curves.items():
        d, _ = cKDTree(axis.points.positions(mesh)).query(mesh.vertices, distance_upper_bound=0.5 * girth)
        near = np.flatnonzero(np.isfinite(d))
        points = SurfacePoints.from_vertices(mesh, near) if near.size else axis.points
        patches[name] = ContactPatch(mesh, points, axis)
    some_axis = next(iter(curves.values()))[0]
    radius = MARKER_RADIUS_PER_LENGTH * hand.length
    markers = hand_markers(hand)
    for i, (name, centre) in enumerate(markers.items()):
        patches[name] = ContactPatch(mesh, area_marker(hand, centre, radius, seed=i), some_axis)
    return ContactSet(mesh, patches), tuple(markers), {name: girth for name, (_, girth) in curves.items()}
