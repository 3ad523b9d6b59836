"""Dense contact pairing by ray casting (Kinematic Motion Retargeting §3.2, Fig. 3).

When a motion has dense contacts on only one side (the object, as in GRAB), the other side's contacts
are found by casting a ray from each contact along the source surface's normal to the opposite mesh,
both posed at the contact's frame:

* the ray meets the opposite mesh an odd number of times ahead of the contact (the paper's "single
  intersection", B in Fig. 3): the contact lies inside the opposite mesh (penetration), so the ray is
  inverted and the first hit behind the contact is taken (C) — status ``INVERTED``;
* an even, nonzero number of times ("two or more", E and F): the nearer hit is taken (E) — ``PAIRED``;
* the chosen hit is farther than the cutoff ε (H, I): discarded — ``TOO_FAR``;
* no hit in the direction that counts (G): discarded — ``NO_HIT``.

The paper states the rule for one and for two hits; counting hits by parity is the same rule for those
and stays right when a ray from inside one finger goes on through another (three hits: still inside).
Parity needs a closed opposite mesh, which the solver's hands and objects are.

Hits are exact ray-triangle intersections (Möller–Trumbore) found through a bounding volume hierarchy
built per posed mesh, all rays of a frame traversed together level by level (:class:`RayCaster`). The
paired points are returned as surface points (face, barycentric coordinates) of the opposite mesh's
topology, so they pose with it. A source contact's normal is its posed face's normal ("element
normals", §3.2).

The caster is ours rather than trimesh's pure-Python ``trimesh.ray.ray_triangle.RayMeshIntersector``,
which is the independent oracle of the tests (``tests/test_trimesh_oracle.py``: the same hits, faces and
distances, and the same hit parities for rays through vertices and edges): trimesh casts half-lines only
(an inverted ray needs the hits behind the contact too), finds candidate triangles with an r-tree query
per ray in a Python loop and needs ``rtree``, which the Blender extension does not ship. Both work in
float64 and report a crossing through an edge or a vertex once, which the parity rule needs.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from geodesics import SurfacePoints, TriMesh

from ..errors import SolverError

if TYPE_CHECKING:  # pragma: no cover
    from .motion import Contacts, Motion

#: Status of each source contact after pairing.
PAIRED, INVERTED, TOO_FAR, NO_HIT = 0, 1, 2, 3
STATUS_NAMES = ("paired", "inverted", "too far", "no hit")
#: Default ε, in scene units (metres): 1 cm, about a finger's half thickness.
DEFAULT_CUTOFF = 0.01
#: Triangles per BVH leaf (at least this many, fewer than twice as many).
LEAF_SIZE = 8
#: Rays traversed together; bounds the traversal's memory.
RAY_CHUNK = 4096
#: Barycentric slack of the ray-triangle test, so a ray through an edge is never lost between two faces
#: (it is then found twice, and the duplicate dropped).
BARY_SLACK = 1e-12


class RayCaster:
    """A bounding volume hierarchy over a posed triangle mesh, answering many line queries at once.

    Parameters
    ----------
    vertices : (n, 3) array_like
        Posed vertex positions.
    faces : (m, 3) array_like of int
    leaf_size : int

    Notes
    -----
    The tree is a complete binary tree in heap layout, built by median splits along each node's longest
    centroid extent, one numpy sort per level; leaves hold ``leaf_size`` to ``2 leaf_size`` triangles.
    """

    def __init__(self, vertices, faces, leaf_size: int = LEAF_SIZE):
        V = np.asarray(vertices, dtype=np.float64)
        F = np.asarray(faces, dtype=np.int64)
        if V.ndim != 2 or V.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3 or len(F) == 0:
            raise SolverError(
                f"a ray caster needs vertices (n, 3) and faces (m, 3); got {V.shape}, {F.shape}"
            )
        if not np.all(np.isfinite(V)):
            raise SolverError("posed vertices contain NaN or infinite values")
        self.vertices, self.faces = V, F
        T = V[F]
        self._a, self._e1, self._e2 = T[:, 0], T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]
        m = len(F)
        depth = int(np.floor(np.log2(max(m / max(int(leaf_size), 1), 1.0))))
        self.depth = depth
        n_leaves = 1 << depth
        centroid = T.mean(1)
        order = np.arange(m)
        position = np.arange(m)
        for level in range(depth):
            segment = (position * (1 << level)) // m
            starts = np.flatnonzero(np.r_[True, segment[1:] != segment[:-1]])
            c = centroid[order]
            extent = np.maximum.reduceat(c, starts) - np.minimum.reduceat(c, starts)
            axis = np.argmax(extent, axis=1)[segment]
            order = order[np.lexsort((c[position, axis], segment))]
        self._order = order
        leaf_start = (np.arange(n_leaves + 1) * m) // n_leaves
        lo, hi = T.min(1)[order], T.max(1)[order]
        pad = 1e-9 * max(float(np.ptp(V, axis=0).max()), 1e-300)
        n_nodes = 2 * n_leaves - 1
        node_lo, node_hi = np.empty((n_nodes, 3)), np.empty((n_nodes, 3))
        first_leaf = n_leaves - 1
        node_lo[first_leaf:] = np.minimum.reduceat(lo, leaf_start[:-1]) - pad
        node_hi[first_leaf:] = np.maximum.reduceat(hi, leaf_start[:-1]) + pad
        for level in range(depth - 1, -1, -1):
            nodes = np.arange((1 << level) - 1, (1 << (level + 1)) - 1)
            node_lo[nodes] = np.minimum(node_lo[2 * nodes + 1], node_lo[2 * nodes + 2])
            node_hi[nodes] = np.maximum(node_hi[2 * nodes + 1], node_hi[2 * nodes + 2])
        self._lo, self._hi = node_lo, node_hi
        size = np.diff(leaf_start)
        table = np.full((n_leaves, int(size.max())), -1, np.int64)
        column = np.arange(m) - np.repeat(leaf_start[:-1], size)
        table[np.repeat(np.arange(n_leaves), size), column] = order
        self._leaves = table

    def intersect(self, origins, directions, t_min: float = -np.inf, t_max: float = np.inf):
        """Every intersection of the lines ``origins + t directions`` (t in [t_min, t_max]) with the mesh.

        Parameters
        ----------
        origins, directions : (k, 3) array_like
            Directions need not be unit; ``t`` is in their units.

        Returns
        -------
        ray : (h,) int
            The query each hit belongs to; hits are sorted by ray, then by t.
        face : (h,) int
        t : (h,) float
        bary : (h, 3) float
            Barycentric coordinates of the hit in its face.

        A line through an edge or vertex meets it once (duplicates at the same t are dropped).
        """
        O = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        D = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
        if O.shape != D.shape:
            raise SolverError(f"got {len(O)} origins but {len(D)} directions")
        parts = [
            self._intersect(O[s : s + RAY_CHUNK], D[s : s + RAY_CHUNK], t_min, t_max, s)
            for s in range(0, len(O), RAY_CHUNK)
        ]
        if not parts:
            return np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0), np.empty((0, 3))
        ray, face, t, bary = (np.concatenate(p) for p in zip(*parts, strict=True))
        if ray.size:
            order = np.lexsort((t, ray))
            ray, face, t, bary = ray[order], face[order], t[order], bary[order]
            scale = np.linalg.norm(D[ray], axis=1)
            tol = 1e-9 * max(float(np.ptp(self.vertices, axis=0).max()), 1e-300)
            duplicate = np.r_[False, (ray[1:] == ray[:-1]) & ((t[1:] - t[:-1]) * scale[1:] <= tol)]
            keep = ~duplicate
            ray, face, t, bary = ray[keep], face[keep], t[keep], bary[keep]
        return ray, face, t, bary

    def _intersect(self, O, D, t_min, t_max, offset):
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            safe = np.where(np.abs(D) < 1e-300, np.where(D < 0, -1e-300, 1e-300), D)
            inv = 1.0 / safe
            ray = np.arange(len(O))
            node = np.zeros(len(O), np.int64)
            for level in range(self.depth + 1):
                t1 = (self._lo[node] - O[ray]) * inv[ray]
                t2 = (self._hi[node] - O[ray]) * inv[ray]
                near = np.minimum(t1, t2).max(axis=1)
                far = np.maximum(t1, t2).min(axis=1)
                hit = (near <= far) & (far >= t_min) & (near <= t_max)
                ray, node = ray[hit], node[hit]
                if level < self.depth:
                    ray = np.repeat(ray, 2)
                    node = (2 * np.repeat(node, 2) + 1) + np.tile([0, 1], node.size)
        leaf = node - ((1 << self.depth) - 1)
        width = self._leaves.shape[1]
        face = self._leaves[leaf].reshape(-1)
        ray = np.repeat(ray, width)
        ray, face = ray[face >= 0], face[face >= 0]
        d, e1, e2 = D[ray], self._e1[face], self._e2[face]
        p = _cross(d, e2)
        det = np.einsum("ij,ij->i", e1, p)
        ok = np.abs(det) > 1e-300
        inv_det = np.divide(1.0, det, out=np.zeros_like(det), where=ok)
        s = O[ray] - self._a[face]
        u = np.einsum("ij,ij->i", s, p) * inv_det
        q = _cross(s, e1)
        v = np.einsum("ij,ij->i", d, q) * inv_det
        t = np.einsum("ij,ij->i", e2, q) * inv_det
        good = ok & (u >= -BARY_SLACK) & (v >= -BARY_SLACK) & (u + v <= 1 + BARY_SLACK)
        good &= (t >= t_min) & (t <= t_max)
        u, v = np.clip(u[good], 0.0, 1.0), np.clip(v[good], 0.0, 1.0)
        total = np.maximum(u + v, 1.0)
        u, v = u / total, v / total
        bary = np.stack([1.0 - u - v, u, v], 1)
        return ray[good] + offset, face[good], t[good], bary


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.stack(
        [
            a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
            a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
            a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0],
        ],
        1,
    )


@dataclass(frozen=True, eq=False)
class RayPairing:
    """The outcome of pairing k source contacts with an opposite mesh.

    Attributes
    ----------
    status : (k,) int8
        ``PAIRED``, ``INVERTED``, ``TOO_FAR`` or ``NO_HIT`` (see :data:`STATUS_NAMES`).
    faces : (k,) int
        Face of the opposite mesh that was hit, -1 where nothing was (``NO_HIT``).
    bary : (k, 3) float
        Barycentric coordinates of the hit in that face (zeros where nothing was hit).
    distance : (k,) float
        Distance from the contact to the hit (NaN where nothing was hit); ``TOO_FAR`` rows keep theirs.
    positions : (k, 3) float
        The hit in space (NaN where nothing was hit).
    """

    status: np.ndarray
    faces: np.ndarray
    bary: np.ndarray
    distance: np.ndarray
    positions: np.ndarray

    @property
    def kept(self) -> np.ndarray:
        """(k,) bool: contacts that were paired (directly or by inversion)."""
        return self.status <= INVERTED

    @property
    def points(self) -> SurfacePoints:
        """The paired points of the kept contacts, in order, on the opposite mesh."""
        keep = self.kept
        return SurfacePoints(self.faces[keep], self.bary[keep])

    def counts(self) -> dict[str, int]:
        """How many contacts ended with each status."""
        n = np.bincount(self.status.astype(np.int64), minlength=len(STATUS_NAMES))
        return {name: int(c) for name, c in zip(STATUS_NAMES, n, strict=True)}


def pair_rays(origins, normals, caster: RayCaster, cutoff: float = DEFAULT_CUTOFF) -> RayPairing:
    """Pair contacts at ``origins`` (k, 3) with the mesh of ``caster`` along ``normals`` (k, 3).

    The rule of Fig. 3 (see the module docstring); ``cutoff`` is ε in scene units.
    """
    O = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    N = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    if O.shape != N.shape:
        raise SolverError(f"got {len(O)} contact positions but {len(N)} normals")
    if not (np.all(np.isfinite(O)) and np.all(np.isfinite(N))):
        raise SolverError("contact positions or normals contain NaN or infinite values")
    length = np.linalg.norm(N, axis=1)
    bad = np.flatnonzero(length == 0)
    if bad.size:
        raise SolverError(f"contacts {bad[:5].tolist()} have zero normals; their faces are degenerate")
    if not cutoff > 0:
        raise SolverError(f"the pairing cutoff ε must be positive, got {cutoff!r}")
    N = N / length[:, None]
    k = len(O)
    ray, face, t, bary = caster.intersect(O, N)
    ahead = t >= 0
    n_ahead = np.bincount(ray[ahead], minlength=k)
    inside = n_ahead % 2 == 1
    # Hits are sorted by (ray, t): the first hit ahead and the last hit behind of each ray.
    first_ahead = np.full(k, -1, np.int64)
    idx = np.flatnonzero(ahead)
    first_ahead[ray[idx[::-1]]] = idx[::-1]
    last_behind = np.full(k, -1, np.int64)
    idx = np.flatnonzero(~ahead)
    last_behind[ray[idx]] = idx
    chosen = np.where(inside, last_behind, first_ahead)
    found = chosen >= 0
    status = np.full(k, NO_HIT, np.int8)
    faces = np.full(k, -1, np.int64)
    B = np.zeros((k, 3))
    distance = np.full(k, np.nan)
    positions = np.full((k, 3), np.nan)
    h = chosen[found]
    faces[found] = face[h]
    B[found] = bary[h]
    distance[found] = np.abs(t[h])
    positions[found] = O[found] + t[h, None] * N[found]
    status[found] = np.where(inside[found], INVERTED, PAIRED)
    status[found & (distance > cutoff)] = TOO_FAR
    return RayPairing(status, faces, B, distance, positions)


def face_normals(vertices: np.ndarray, faces: np.ndarray, which: np.ndarray) -> np.ndarray:
    """(k, 3) unit normals of the faces ``which`` (k,) of ``faces`` (m, 3) posed at ``vertices`` (n, 3)
    (counter-clockwise corners face outward)."""
    T = vertices[faces[which]]
    n = _cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def pair_frame(
    source_mesh: TriMesh,
    source_vertices,
    contacts: SurfacePoints,
    target_mesh: TriMesh,
    target_vertices,
    cutoff: float = DEFAULT_CUTOFF,
) -> RayPairing:
    """Pair contacts on one posed mesh with another posed mesh (one frame).

    Parameters
    ----------
    source_mesh : TriMesh
        The topology the contacts are on (e.g. the object's rest mesh).
    source_vertices : (n, 3) array_like
        Its posed vertices at the frame (world space).
    contacts : SurfacePoints
        Contacts on ``source_mesh``.
    target_mesh : TriMesh
        The opposite mesh's topology (e.g. the hand's rest mesh).
    target_vertices : (m, 3) array_like
        Its posed vertices at the frame.
    cutoff : float
        ε, in scene units.

    Returns
    -------
    RayPairing
        One row per contact; ``points`` are on ``target_mesh``.
    """
    contacts.validate(source_mesh)
    VS = _posed(source_vertices, source_mesh, "source")
    VT = _posed(target_vertices, target_mesh, "target")
    caster = RayCaster(VT, target_mesh.faces)
    if len(contacts) == 0:
        return pair_rays(np.empty((0, 3)), np.empty((0, 3)), caster, cutoff)
    origins = np.einsum("kj,kjd->kd", contacts.bary, VS[source_mesh.faces[contacts.faces]])
    normals = face_normals(VS, source_mesh.faces, contacts.faces)
    return pair_rays(origins, normals, caster, cutoff)


def _posed(vertices, mesh: TriMesh, what: str) -> np.ndarray:
    V = np.asarray(vertices, dtype=np.float64)
    if V.shape != (mesh.n_vertices, 3):
        raise SolverError(f"posed {what} vertices must have shape ({mesh.n_vertices}, 3), got {V.shape}")
    return V


def object_vertices(mesh: TriMesh, pose) -> np.ndarray:
    """(n, 3) the object's rest vertices moved by a rigid pose (4, 4)."""
    P = np.asarray(pose, dtype=np.float64)
    return mesh.vertices @ P[:3, :3].T + P[:3, 3]


@dataclass(frozen=True, eq=False)
class MotionPairing:
    """Dense pairs for every frame of a motion.

    Attributes
    ----------
    object_contacts, hand_contacts : Contacts
        The kept pairs, row for row, frame by frame.
    status : (K,) int8
        Status of every source contact (all frames, flattened as the source :class:`Contacts`).
    distance : (K,) float
        Distance to its hit (NaN: no hit).
    source : str
        ``"object"`` or ``"hand"``: the side the rays were cast from.
    """

    object_contacts: Contacts
    hand_contacts: Contacts
    status: np.ndarray
    distance: np.ndarray
    source: str

    def counts(self) -> dict[str, int]:
        """How many source contacts (of all frames) ended with each status."""
        n = np.bincount(self.status.astype(np.int64), minlength=len(STATUS_NAMES))
        return {name: int(c) for name, c in zip(STATUS_NAMES, n, strict=True)}

    def apply(self, motion: Motion) -> Motion:
        """The motion with these paired contacts in place of its own."""
        from dataclasses import replace

        return replace(motion, object_contacts=self.object_contacts, hand_contacts=self.hand_contacts)


def pair_motion(
    motion: Motion,
    source: str = "object",
    cutoff: float = DEFAULT_CUTOFF,
    progress: Callable[[int, int], None] | None = None,
) -> MotionPairing:
    """Pair one side's dense contacts with the other side for every frame (§3.2).

    Parameters
    ----------
    motion : Motion
        Needs ``object_contacts`` (``source="object"``) or ``hand_contacts`` (``source="hand"``).
    source : str
        The side whose contacts the rays start from.
    cutoff : float
        ε in scene units (default :data:`DEFAULT_CUTOFF`, 1 cm).
    progress : callable, optional
        Called as ``progress(done, total)`` after each frame.

    Returns
    -------
    MotionPairing
    """
    from .motion import Contacts

    if source not in ("object", "hand"):
        raise SolverError(f"source must be 'object' or 'hand', got {source!r}")
    contacts = motion.object_contacts if source == "object" else motion.hand_contacts
    if contacts is None:
        raise SolverError(f"the motion has no {source} contacts to pair from")
    F = motion.n_frames
    kept_frames, paired_frames = [], []
    status = np.empty(len(contacts.faces), np.int8)
    distance = np.empty(len(contacts.faces))
    for f in range(F):
        points = contacts.frame(f)
        obj = object_vertices(motion.object_mesh, motion.object_poses[f])
        hand = motion.hand_vertices[f]
        if source == "object":
            pairing = pair_frame(motion.object_mesh, obj, points, motion.hand_mesh, hand, cutoff)
        else:
            pairing = pair_frame(motion.hand_mesh, hand, points, motion.object_mesh, obj, cutoff)
        rows = slice(int(contacts.offsets[f]), int(contacts.offsets[f + 1]))
        status[rows], distance[rows] = pairing.status, pairing.distance
        kept_frames.append(points[np.flatnonzero(pairing.kept)])
        paired_frames.append(pairing.points)
        if progress is not None:
            progress(f + 1, F)
    kept, paired = Contacts.from_frames(kept_frames), Contacts.from_frames(paired_frames)
    if source == "object":
        return MotionPairing(kept, paired, status, distance, source)
    return MotionPairing(paired, kept, status, distance, source)
