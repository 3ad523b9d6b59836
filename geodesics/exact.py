"""Exact polyhedral geodesics by window propagation (Chen and Han; Xin and Wang's improvements, "ICH").

A *window* is an interval of an edge through which a family of straight (unfolded) geodesics enters a
face from a *pseudosource*: the source point itself, or a saddle or boundary vertex around which
shortest paths bend. It stores the pseudosource's image unfolded into the face's frame, the distance
``sigma`` from the source to the pseudosource, and the rotation from the pseudosource's frame to this
face's, so every query returns the exact distance **and** the exact initial and final directions.

Windows are propagated in bands of increasing distance (delta-stepping), a whole band at a time with
numpy. Exactness does not depend on the processing order: every pruning rule below discards a window
only when a real, strictly shorter path exists everywhere that window could reach.

* Rules 1 and 2 (ICH): an edge endpoint reaches the window's far end more cheaply along the edge. Along
  the edge, (window distance) - (distance via the endpoint) is monotone, so the far end decides.
* Rule 3 (ICH, made exact): the face's third vertex beats the window on the whole interval. We take the
  exact minimum over the interval (the difference of two distances to points on either side of a line
  has at most one interior minimum, found by reflecting the vertex), where ICH checks one endpoint.
* Rules 1-3 judge a window when it leaves the queue, with every vertex distance found by then.
* One angle, one split (ICH): of the windows that see a vertex through the same edge, only the one
  giving the vertex its shortest distance keeps the children on both sides; a worse one keeps only the
  child on the side away from the better path (its other rays would have to cross a shorter path).

A query point's distance is the minimum over the windows entering its face (and the direct segments
from pseudosources in that face); the path is recovered by walking back through parent windows.

A large field keeps every window's halfedge and parent but the rest of its record only every few
generations; a query rebuilds the others from their nearest kept ancestor, bit for bit (``_Windows``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .arrays import ranges, smallest_per_key
from .errors import GeodesicError, describe_ids
from .mesh import TriMesh, per_mesh
from .points import SurfacePoints
from .tangent import arrival_to_basis, corner_halfedges, face_to_vertex

#: Relative margin by which a path must be shorter for a rule to discard a window.
PRUNE_MARGIN = 1e-10
#: Slack, in edge-parameter units, when deciding whether a ray passes through a window.
RAY_SLACK = 1e-9
#: Children narrower than this (edge-parameter units) carry no rays the neighbours do not.
MIN_WIDTH = 1e-12
#: Processing band, in mean edge lengths.
BAND = 3.0
#: At most this many windows' room is reserved before propagating (more grows as needed).
WINDOWS_RESERVED = 1 << 20
#: Every window keeps its whole record until a field has made this many (a field this small answers
#: queries straight from them: a whole-mesh field on an 80k-face torus makes 5.8M); past them, only
#: every :data:`CHECKPOINT_DEPTH`-th generation does, and the others are rebuilt from their nearest kept
#: ancestor when a query needs them (see :class:`_Windows`). The pages of the records held at the switch
#: (62 bytes a window) stay resident: fewer than a million-face field holds at the end.
COMPACT_AFTER = 1 << 23
#: Generations between kept records: the records a large field holds, and the steps a query replays.
CHECKPOINT_DEPTH = 24
#: Windows' records are compacted when their table has grown by this factor since the last time.
COMPACT_GROWTH = 1.25
#: Records are rebuilt for at most this many windows at once (with their ancestors, about
#: CHECKPOINT_DEPTH / 2 times as many): the memory a query of a large field needs beyond its answers.
REBUILT_AT_ONCE = 1 << 17


def _cross(a, b):
    return (np.conj(a) * b).imag


#: NumPy computes ``a * b`` as ``b * a``, in b's buffer, when b is a temporary array of at least this
#: many bytes (it elides the temporary), and its complex product is not bitwise commutative everywhere
#: (AVX-512 rounds the two orders differently). A child's image came from ``rotation * image[s]``: which
#: order it got is part of its bits, so a rebuilt child must get the same one (:func:`_rotated`).
_ELIDE_BYTES = 256 * 1024
_INT32_MAX = int(np.iinfo(np.int32).max)


def _products_swap() -> bool:
    """Whether ``a * temporary`` comes out as ``temporary * a`` here (False where both orders agree)."""
    n = _ELIDE_BYTES // 16
    a = np.full(n, 0.8687067524553922 - 0.4953267388688054j)
    b = np.full(n, 1.6025562025323026 + 0.7826137053557433j)
    elided = a * (b + 0)
    return bool(elided[0] == (b * a)[0] != (a * b)[0])


_PRODUCTS_SWAP = _products_swap()


def _swapped(n: int) -> bool:
    """Whether ``rotation * image[s]`` over ``n`` children is computed as ``image[s] * rotation``."""
    return _PRODUCTS_SWAP and 16 * n >= _ELIDE_BYTES


def _rotated(rotation, image, swapped):
    """``rotation * image`` in the order it was computed when the windows were made (``swapped``: (n,)
    bool or one bool)."""
    if np.ndim(swapped) == 0:
        return np.multiply(image, rotation) if swapped else np.multiply(rotation, image)
    return np.where(swapped, np.multiply(image, rotation), np.multiply(rotation, image))


class _Columns:
    """A growable struct-of-arrays: rows are appended column by column and a column is read as an
    attribute (the rows stored so far)."""

    def __init__(self, fields: dict[str, type], capacity: int):
        self.size = 0
        self.data = {k: np.empty(capacity, t) for k, t in fields.items()}

    def append(self, **cols) -> np.ndarray:
        """Store rows given column by column (the first column an array, the others arrays of its length
        or one value for all) and return their indices."""
        first = next(iter(self.data))
        need = self.size + len(cols[first])
        if need > len(self.data[first]):
            cap = max(need, 2 * len(self.data[first]))
            for k, a in self.data.items():
                grown = np.empty(cap, a.dtype)
                grown[: self.size] = a[: self.size]
                self.data[k] = grown
        for k, column in self.data.items():
            column[self.size : need] = cols[k]
        idx = np.arange(self.size, need)
        self.size = need
        return idx

    def __getattr__(self, name):
        data = self.__dict__.get("data")
        if data is not None and name in data:
            return data[name][: self.size]
        raise AttributeError(name)


#: A window's columns: a family of straight rays from a pseudosource through an interval of an edge.
#: Every window has an id (its creation order) and ``_TREE``'s two columns; ``_RECORD``'s are held only
#: while it is queued, or for good when it is kept (see :class:`_Windows`).
_TREE = {
    "he": np.int32,  # halfedge the window lies on; its rays enter face(he)
    "parent": np.int32,  # id of the window it was propagated from; -1 for a direct segment (starts a chain)
}
_RECORD = {
    "id": np.int32,
    "he": np.int32,
    "u0": np.float64,  # interval along he, 0 at its tail, 1 at its head
    "u1": np.float64,
    "img": np.complex128,  # pseudosource image in face(he)'s frame
    "rot": np.complex128,  # direction in face(he) frame = rot * direction in the pseudosource frame
    "root": np.int32,  # its chain: a row of the chains' table
    "phase": np.uint8,  # generations since its chain's direct segment, modulo CHECKPOINT_DEPTH
    "kept": np.bool_,  # the record stays when the window leaves the queue
}
#: What every window of a chain (propagated from one direct segment) shares.
_CHAIN = {
    "label": np.int64,  # which source
    "sigma": np.float64,  # distance from the source to the pseudosource
    "ps": np.int64,  # pseudosource vertex, or -1 for the source point
    "birth": np.int64,  # the pseudosource's birth count when the chain started
    "corner": np.int64,  # pseudosource frame: face(corner)'s, at vertex tail(corner); -1: source face
}


@dataclass(frozen=True)
class _Records:
    """Windows' whole records, one row per window asked for."""

    he: np.ndarray
    u0: np.ndarray
    u1: np.ndarray
    img: np.ndarray
    rot: np.ndarray
    root: np.ndarray
    parent: np.ndarray


class _HeldRecords:
    """:class:`_Records` of a field that holds every record: each column is read when first asked for
    (a query reads a few of them over millions of windows)."""

    def __init__(self, windows: _Windows, ids: np.ndarray):
        self._windows, self._ids = windows, ids

    def __getattr__(self, name: str) -> np.ndarray:
        if name.startswith("_") or name not in _Records.__dataclass_fields__:
            raise AttributeError(name)
        table = self._windows.tree if name == "parent" else self._windows.rec
        value = table.data[name][self._ids]
        setattr(self, name, value)
        return value


class _Windows:
    """Every window a field creates, stored in bounded memory.

    A whole-mesh field creates a number of windows that grows like n^1.5 (about 70 a face at 80k faces,
    256 at 1M), and nearly all of them are needed later: 98% survive rules 1-3 and have children, and
    most of the rest are the best window somewhere in their face or lie on the way back from one (a path
    walks back through its parents). So none is released; instead each window keeps only its halfedge
    and its parent's id (8 bytes), and its whole record (interval, pseudosource image, rotation, chain:
    62 bytes) is held while it is queued, and, once the field has made :data:`COMPACT_AFTER` windows,
    kept for good only for direct segments and their children (made by other rules), for windows that
    gave a vertex its distance, and for every :data:`CHECKPOINT_DEPTH`-th generation. Any
    other record is rebuilt from its nearest kept ancestor by the very computation that made it
    (:func:`_child`), on the same float64 values, so it comes back bit for bit. The price is paid by
    queries of a large field: a window they read that is not held costs about ``CHECKPOINT_DEPTH / 2``
    such computations (those of its ancestors on the way are shared).

    ``rec`` rows are in increasing id order; the propagation addresses windows by row (``rows``), the
    field's answers by id.
    """

    def __init__(self, mesh: TriMesh, capacity: int):
        self.mesh = mesh
        if 3 * mesh.n_faces >= 2**31:
            tree = {"he": np.int64, "parent": np.int32}
            record = dict(_RECORD, he=np.int64)
        else:
            tree, record = _TREE, _RECORD
        self.tree = _Columns(tree, capacity)
        self.rec = _Columns(record, capacity)
        self._compacted = capacity
        self._clean = 0  # rows before this one are all kept
        self._swapped: list[tuple[int, int]] = []  # id ranges [start, end) made with swapped products

    @property
    def size(self) -> int:
        """How many windows were created."""
        return self.tree.size

    def add(self, he, u0, u1, img, rot, root, parent, phase, kept=False, swapped=False) -> np.ndarray:
        """Store new windows (``parent`` by id; ``phase``, their generation modulo
        :data:`CHECKPOINT_DEPTH`) and return their rows; ``kept`` keeps their records whatever the phase;
        ``swapped``: their images were computed as ``image * rotation`` (see :func:`_rotated`)."""
        he = np.asarray(he)
        if swapped:
            self._swapped.append((self.tree.size, self.tree.size + he.size))
        if self.tree.size + he.size >= _INT32_MAX and self.tree.data["parent"].dtype == np.int32:
            for table, k in ((self.tree, "parent"), (self.rec, "id"), (self.rec, "root")):
                table.data[k] = table.data[k].astype(np.int64)
        ids = self.tree.append(he=he, parent=parent)
        kept = kept | (np.asarray(phase) == 0)
        return self.rec.append(
            id=ids, he=he, u0=u0, u1=u1, img=img, rot=rot, root=root, phase=phase, kept=kept
        )

    def compact(self, queued: np.ndarray, now: bool = False) -> np.ndarray:
        """Drop the records of windows neither kept nor ``queued`` (rows), when the table has grown enough
        since the last time to be worth it (or ``now``); return the queued windows' new rows. Rows before
        the first one that was not kept last time are all kept: only the rest are moved."""
        rec = self.rec
        if self.tree.size <= COMPACT_AFTER or (rec.size < COMPACT_GROWTH * self._compacted and not now):
            return queued
        lo = self._clean
        keep = rec.kept[lo:].copy()
        later = queued >= lo
        keep[queued[later] - lo] = True
        rows = lo + np.flatnonzero(keep)
        n = lo + rows.size
        for a in rec.data.values():
            a[lo:n] = a[rows]  # in place: a table's resident pages are never more than its largest size
        rec.size = int(n)
        moved = queued.copy()
        moved[later] = lo + (np.cumsum(keep) - 1)[queued[later] - lo]
        queued_only = np.flatnonzero(~rec.kept[lo:n])
        self._clean = int(lo + (queued_only[0] if queued_only.size else n - lo))
        self._compacted = max(n, WINDOWS_RESERVED)
        return moved

    def records(self, ids: np.ndarray) -> _Records | _HeldRecords:
        """The whole records of windows ``ids`` (any shape of ints >= 0), rebuilding those not held."""
        rec, tree = self.rec, self.tree
        ids = np.asarray(ids).reshape(-1)
        if rec.size == tree.size:  # every record held: a window's row is its id
            return _HeldRecords(self, ids)
        ids = ids.astype(rec.id.dtype, copy=False)  # searchsorted would cast rec.id
        row = np.minimum(np.searchsorted(rec.id, ids), max(rec.size - 1, 0))
        held = rec.id[row] == ids if rec.size else np.zeros(ids.size, bool)
        out = {k: np.empty(ids.size, rec.data[k].dtype) for k in ("he", "u0", "u1", "img", "rot", "root")}
        for k, a in out.items():
            a[held] = rec.data[k][row[held]]
        missing = np.flatnonzero(~held)
        if missing.size:
            wanted = np.unique(ids[missing])
            for start in range(0, wanted.size, REBUILT_AT_ONCE):
                part = wanted[start : start + REBUILT_AT_ONCE]
                built, order = self._rebuild(part)
                mine = missing[(ids[missing] >= part[0]) & (ids[missing] <= part[-1])]
                at = np.searchsorted(order, ids[mine])
                for k, a in out.items():
                    a[mine] = built[k][at]
        return _Records(**out, parent=tree.parent[ids].astype(np.int64))

    def _rebuild(self, ids: np.ndarray) -> tuple[dict, np.ndarray]:
        """Records of windows ``ids`` (sorted, none held), rebuilt down from their nearest held ancestors;
        returns them and the ids they are for (sorted: ``ids`` and the ancestors on the way)."""
        rec, tree = self.rec, self.tree
        levels, todo = [], ids
        while todo.size:  # every missing window on the way up, a generation a level
            levels.append(todo)
            up = np.unique(tree.parent[todo])
            row = np.minimum(np.searchsorted(rec.id, up), rec.size - 1)
            todo = up[rec.id[row] != up]
        need = np.unique(np.concatenate(levels)) if len(levels) > 1 else ids
        built = {k: np.empty(need.size, rec.data[k].dtype) for k in ("he", "u0", "u1", "img", "rot", "root")}
        built["he"][:] = tree.he[need]
        swapped = np.zeros(need.size, bool)
        if self._swapped:
            start, end = np.array(self._swapped).T
            batch = np.searchsorted(start, need, side="right") - 1
            swapped = (batch >= 0) & (need < end[np.maximum(batch, 0)])
        done = np.zeros(need.size, bool)
        for level in reversed(levels):  # a window's parent is held or one level up, so done already
            now = np.searchsorted(need, level)
            now = now[~done[now]]
            parent = tree.parent[need[now]]
            pos = np.minimum(np.searchsorted(need, parent), need.size - 1)
            p_in = need[pos] == parent
            prow = np.searchsorted(rec.id, parent[~p_in])
            src = {}
            for k in ("he", "u0", "u1", "img", "rot", "root"):
                col = np.empty(now.size, rec.data[k].dtype)
                col[p_in] = built[k][pos[p_in]]
                col[~p_in] = rec.data[k][prow]
                src[k] = col
            u0, u1, img, rot = _child(
                self.mesh,
                src["he"],
                src["u0"],
                src["u1"],
                src["img"],
                src["rot"],
                built["he"][now],
                swapped[now],
            )
            built["u0"][now], built["u1"][now], built["img"][now], built["rot"][now] = u0, u1, img, rot
            built["root"][now] = src["root"]
            done[now] = True
        return built, need


@dataclass(frozen=True, eq=False)
class GeodesicQuery:
    """Exact geodesics from the nearest source to each query point.

    Attributes
    ----------
    distances : (k,) float
        Geodesic distance (inf where unreached, e.g. beyond ``max_distance``).
    sources : (k,) int
        Index of the nearest source.
    initial_directions : (k,) complex
        Unit direction of the geodesic as it leaves its source, in the source's tangent basis
        (0 where the point is the source).
    final_directions : (k,) complex
        Unit direction of travel as the geodesic arrives, in the query point's tangent basis.
    """

    distances: np.ndarray
    sources: np.ndarray
    initial_directions: np.ndarray
    final_directions: np.ndarray


@dataclass(frozen=True, eq=False)
class Path:
    """One exact shortest geodesic.

    Attributes
    ----------
    length : float
    initial_direction : complex
        Unit direction at the start, in the start point's tangent basis.
    final_direction : complex
        Unit direction of travel at the end, in the end point's tangent basis.
    polyline : (N, 3) float
        Positions from start to end: start, every edge crossing, every vertex it bends around, end.
    points : SurfacePoints
        The same N points as surface points (crossings lie on edges, bends on vertices).
    segment_directions : (s, 2) complex
        For each straight segment between bends: its initial direction (start point's basis) and its
        final direction (end point's basis). Used for parallel transport.
    """

    length: float
    initial_direction: complex
    final_direction: complex
    polyline: np.ndarray
    points: SurfacePoints
    segment_directions: np.ndarray

    @property
    def bends(self) -> int:
        """How many saddle or boundary vertices the path bends around."""
        return len(self.segment_directions) - 1


class GeodesicField:
    """Exact geodesic distances and paths from one or more source points.

    Propagation stops as soon as every point in ``targets`` is settled (or at ``max_distance``);
    without targets it covers the sources' components. Queries then cost one vectorized pass.

    Parameters
    ----------
    mesh : TriMesh
    sources : SurfacePoints
        Any points: inside faces, on edges or on vertices.
    targets : SurfacePoints, optional
        Points that later queries will ask about; lets propagation stop early.
    max_distance : float, optional
        Do not propagate beyond this distance.

    Notes
    -----
    A whole-mesh field on n faces makes on the order of n^1.5 windows (256 a face at a million faces).
    Past :data:`COMPACT_AFTER` windows, each costs about 10 bytes (a million-face torus: under 4 GB at
    the peak instead of 19): most windows' records are rebuilt, bit for bit, when a query reads them,
    which makes queries of such a field several times slower than of a smaller one.
    """

    def __init__(
        self,
        mesh: TriMesh,
        sources: SurfacePoints,
        targets: SurfacePoints | None = None,
        max_distance: float = np.inf,
    ):
        if len(sources) == 0:
            raise GeodesicError("no source points were given")
        self.mesh = mesh
        self.sources = sources.validate(mesh)
        self.targets = targets.validate(mesh) if targets is not None else None
        self.max_distance = float(max_distance)
        if targets is not None and len(targets):
            reached = np.isin(mesh.face_components[targets.faces], mesh.face_components[sources.faces])
            bad = np.flatnonzero(~reached)
            if bad.size:
                raise GeodesicError(
                    f"target points {describe_ids(bad)} lie on a connected component that holds no source "
                    f"(mesh component {int(mesh.face_components[targets.faces[bad[0]]])}), "
                    "so no geodesic reaches them"
                )
        n = mesh.n_vertices
        # Room for the windows a whole mesh usually needs (up to a few dozen per face), reserved up front:
        # memory is only touched as it fills, and the arrays are not copied each time they would double.
        self.W = _Windows(mesh, min(48 * mesh.n_faces, WINDOWS_RESERVED))
        self.chains = _Columns(_CHAIN, 1024)
        self.vertex_distance = np.full(n, np.inf)
        self.vertex_parent = np.full(n, -1, np.int64)
        self._vertex_corner = np.full(n, -1, np.int64)  # the vertex's corner in its parent's face
        self._birth = np.zeros(n, np.int64)
        self._split_d = np.full(3 * mesh.n_faces, np.inf)
        self._split_u = np.zeros(3 * mesh.n_faces)
        theta = mesh.angle_sums
        self._bends = np.where(
            mesh.is_boundary_vertex, theta > np.pi * (1 + 1e-9), theta > 2 * np.pi * (1 + 1e-9)
        )
        if targets is not None:  # a target is at most this far beyond each corner of its face
            self._target_corners = np.ascontiguousarray(mesh.faces[targets.faces].T)  # (3, k)
            self._target_gaps = np.abs(mesh.face_points[targets.faces].T - targets.in_face_frame(mesh))
            self._settled_bound = 0.0
        self._pending = np.empty(0, np.int64)
        self._pending_key = np.empty(0)
        self._ps = np.empty(0, np.int64)
        self._ps_birth = np.empty(0, np.int64)
        self._seed_sources()
        self._propagate()

    # ------------------------------------------------------------------ sources

    def _seed_sources(self) -> None:
        mesh = self.mesh
        Pf = mesh.face_points.ravel()
        v, e = self.sources.vertex_ids(mesh), self.sources.edge_halfedges(mesh)
        label, face, pos, rot, corner = _root_faces(mesh, self.sources)
        chain = self.chains.append(label=label, sigma=0.0, ps=-1, birth=0, corner=corner)
        he = np.where(corner >= 0, corner, 3 * face)
        direct = self.W.add(he=he, u0=0.0, u1=1.0, img=pos, rot=rot, root=chain, parent=-1, phase=0)
        # Vertices of root faces are reached by straight segments inside those faces.
        h = 3 * face[:, None] + np.arange(3)
        self._relax(h.ravel(), np.abs(Pf[h.ravel()] - np.repeat(pos, 3)), np.repeat(direct, 3))
        # Windows on the far side of each root face edge that does not hold the source.
        on_edge = np.zeros(h.shape, bool)
        se, sv = e[label], v[label]
        on_edge |= (h == se[:, None]) | (h == np.where(se >= 0, mesh.twin[np.maximum(se, 0)], -2)[:, None])
        on_edge |= (mesh.halfedge_tail[h] == sv[:, None]) | (mesh.halfedge_head[h] == sv[:, None])
        ok = ~on_edge & (mesh.twin[h] >= 0)
        row, col = np.nonzero(ok)
        hh = h[row, col]
        self._queue(
            _to_segment(pos[row], Pf[hh], Pf[mesh.halfedge_next[hh]], 0.0, 1.0),
            he=mesh.twin[hh],
            u0=0.0,
            u1=1.0,
            img=mesh.halfedge_offset[hh] + mesh.halfedge_rotation[hh] * pos[row],
            rot=rot[row] * mesh.halfedge_rotation[hh],
            root=chain[row],
            parent=self.W.rec.id[direct[row]],
            phase=1 % CHECKPOINT_DEPTH,
            kept=True,  # made by another rule than their descendants: they cannot be rebuilt
        )

    # ------------------------------------------------------------------ propagation

    def _propagate(self) -> None:
        band = BAND * self.mesh.mean_edge_length
        while True:
            fresh = self._ps_birth == self._birth[self._ps]
            self._ps, self._ps_birth = self._ps[fresh], self._ps_birth[fresh]
            ps_key = self.vertex_distance[self._ps]
            low = min(self._pending_key.min(initial=np.inf), ps_key.min(initial=np.inf))
            if not np.isfinite(low) or low >= min(self._stop_bound(low), self.max_distance):
                break
            cut = low + band
            take = ps_key < cut
            if np.any(take):
                verts = self._ps[take]
                self._ps, self._ps_birth = self._ps[~take], self._ps_birth[~take]
                self._emit_pseudosources(verts)
            self._pending = self.W.compact(self._pending)
            take = self._pending_key < cut
            batch = self._pending[take]
            self._pending, self._pending_key = self._pending[~take], self._pending_key[~take]
            chain = self.W.rec.root[batch]
            ps = self.chains.ps[chain]
            live = (ps < 0) | (self.chains.birth[chain] == self._birth[np.maximum(ps, 0)])
            batch = batch[live]
            if batch.size:
                self._propagate_batch(batch)
        self._pending = self.W.compact(self._pending, now=True)

    def _stop_bound(self, low: float) -> float:
        """An upper bound on every target's distance (inf until each target's face is reached).

        Targets whose bound is already at most ``low`` are set aside, keeping only the largest such
        bound: bounds only shrink, so the answer stays an upper bound and later calls read fewer."""
        if self.targets is None:
            return np.inf
        bound = np.min(self.vertex_distance.take(self._target_corners) + self._target_gaps, axis=0)
        below = bound <= low
        if below.any():
            self._settled_bound = max(self._settled_bound, float(bound[below].max()))
            still = np.flatnonzero(~below)
            self._target_corners = self._target_corners[:, still]
            self._target_gaps = self._target_gaps[:, still]
            bound = bound[still]
        return max(self._settled_bound, float(bound.max(initial=-np.inf)))

    def _propagate_batch(self, w: np.ndarray) -> None:
        """Propagate windows ``w`` across their faces: drop those a shorter path beats everywhere (rules
        1-3, judged now, with the vertex distances found since they were queued), relax the opposite
        vertex and queue the children on the two far edges.

        The geometry is done in each entry edge's frame (:func:`_edge_frames`): the edge runs from 0 to
        L along the real axis, the face's third corner C is at ``Cl`` above it and the pseudosource's
        image ``Il`` below it (or on its line)."""
        mesh, W = self.mesh, self.W.rec
        tail = mesh.halfedge_tail
        he = W.he[w]
        hn, hp = mesh.halfedge_next[he], mesh.halfedge_prev[he]
        root = W.root[w]
        I, sig, u0, u1 = W.img[w], self.chains.sigma[root], W.u0[w], W.u1[w]
        Il, L, Cl, uc = _entry_frame(mesh, he, I)
        alive = self._unbeaten(Il, Cl, L, sig, u0 * L, u1 * L, tail[he], tail[hn], tail[hp])
        dc = sig + np.abs(Cl - Il)

        sees_c = alive & (uc >= u0 - RAY_SLACK) & (uc <= u1 + RAY_SLACK)
        self._relax(hp[sees_c], dc[sees_c], w[sees_c])

        # One angle, one split.
        keep_left = alive & (uc > u0 + MIN_WIDTH)
        keep_right = alive & (uc < u1 - MIN_WIDTH)
        split = np.flatnonzero(keep_left & keep_right)
        if split.size:
            hs, ds, us = he[split], dc[split], uc[split]
            first = smallest_per_key(hs, ds)
            better = ds[first] < self._split_d[hs[first]]
            self._split_d[hs[first[better]]] = ds[first[better]]
            self._split_u[hs[first[better]]] = us[first[better]]
            best_d, best_u = self._split_d[hs], self._split_u[hs]
            worse = ds > best_d * (1 + PRUNE_MARGIN)
            keep_right[split[worse & (us < best_u - RAY_SLACK)]] = False
            keep_left[split[worse & (us > best_u + RAY_SLACK)]] = False

        # Children: rays between u0 and uc leave through edge C -> A (left), between uc and u1 through
        # edge B -> C (right); where the ray through C bounds a child, it ends exactly at C.
        left, right = np.flatnonzero(keep_left), np.flatnonzero(keep_right)
        s = np.concatenate([left, right])
        if s.size == 0:
            return
        on_right = np.arange(s.size) >= left.size
        Ils = Il[s]
        P0, P1, t_near, t_far = _exits(Ils, Cl[s], L[s], uc[s], u0[s], u1[s], on_right)
        h_out = np.where(on_right, hn[s], hp[s])
        twin = mesh.twin[h_out]
        ok = (twin >= 0) & (t_near - t_far > MIN_WIDTH)
        if not ok.all():  # a boundary edge, or a sliver of a window: rare
            ok = np.flatnonzero(ok)
            s, h_out, twin, t_near, t_far, Ils, P0, P1 = (
                a[ok] for a in (s, h_out, twin, t_near, t_far, Ils, P0, P1)
            )
        ws, rotation = w[s], mesh.halfedge_rotation[h_out]
        self._queue(
            sig[s] + _to_segment(Ils, P0, P1, t_far, t_near),
            he=twin,
            u0=1 - t_near,
            u1=1 - t_far,
            img=mesh.halfedge_offset[h_out] + _rotated(rotation, I[s], _swapped(s.size)),
            rot=W.rot[ws] * rotation,
            root=root[s],
            parent=W.id[ws],
            phase=(W.phase[ws] + 1) % CHECKPOINT_DEPTH,
            swapped=_swapped(s.size),
        )

    def _unbeaten(self, Il, Cl, L, sig, xa, xb, va, vb, vc) -> np.ndarray:
        """(n,) bool: False for edge windows that a strictly shorter path beats everywhere. In the entry
        edge's frame (from 0 to ``L`` on the real axis, facing corner ``Cl``): the pseudosource's image
        ``Il`` at distance ``sig`` from the source, the interval [xa, xb]; the edge's vertices va, vb and
        the corner's vc."""
        vd = self.vertex_distance
        d1, d2, d3 = vd[va], vd[vb], vd[vc]
        # Window distances shrunk by the margin: a path must beat them to discard the window.
        shrink = 1 / (1 + PRUNE_MARGIN)
        wa, wb = (sig + np.abs(Il - xa)) * shrink, (sig + np.abs(Il - xb)) * shrink
        # Rules 1 and 2: an edge endpoint reaches the far end of the interval along the edge.
        dead = (wb > d1 + xb) | (wa > d2 + (L - xa))
        # Rule 3: exact minimum over the interval of (window distance) - (distance via the third vertex).
        # Along the edge it has one interior extremum, where the line from the image to the vertex's
        # mirror image (across the edge) crosses it (where that line runs along the edge, any point is
        # the minimum: fmax/fmin put NaN on the interval's start, and inf on an end).
        xI, yI = Il.real, Il.imag
        with np.errstate(divide="ignore", invalid="ignore"):
            xs = np.fmin(np.fmax(xI + (Cl.real - xI) * yI / (Cl.imag + yI), xa), xb)
        least = np.minimum(wa - np.abs(Cl - xa), wb - np.abs(Cl - xb))
        least = np.minimum(least, (sig + np.abs(Il - xs)) * shrink - np.abs(Cl - xs))
        return ~(dead | (least > d3))

    def _queue(self, key: np.ndarray, **cols) -> None:
        """Store new edge windows and queue them by ``key``, a lower bound on any distance their rays
        give (the pruning rules judge them when they leave the queue)."""
        self._pending = np.concatenate([self._pending, self.W.add(**cols)])
        self._pending_key = np.concatenate([self._pending_key, key])

    def _relax(self, corners: np.ndarray, dist: np.ndarray, parent: np.ndarray) -> None:
        """Lower the distances of the vertices at ``corners`` (halfedges of their ``parent`` windows' faces,
        from the vertex; windows by row) where a candidate is shorter; queue bending vertices as
        pseudosources. A window that gives a vertex its distance keeps its record."""
        if corners.size == 0:
            return
        vertices = self.mesh.halfedge_tail[corners]
        first = smallest_per_key(vertices, dist)
        v, d, p, c = vertices[first], dist[first], parent[first], corners[first]
        better = d < self.vertex_distance[v] * (1 - 1e-14)
        v, d, p, c = v[better], d[better], p[better], c[better]
        if v.size == 0:
            return
        self.vertex_distance[v] = d
        self.vertex_parent[v] = self.W.rec.id[p]
        self.W.rec.kept[p] = True
        self._vertex_corner[v] = c
        self._birth[v] += 1
        bends = v[self._bends[v]]
        self._ps = np.concatenate([self._ps, bends])
        self._ps_birth = np.concatenate([self._ps_birth, self._birth[bends]])

    def _emit_pseudosources(self, verts: np.ndarray) -> None:
        """Start windows from saddle/boundary vertices, covering exactly their shadow cones.

        A shortest path through such a vertex leaves it at least π (measured on the surface) from the
        way it came in, on both sides; only those directions get windows.
        """
        mesh, W = self.mesh, self.W
        Pf = mesh.face_points.ravel()
        to_edge, length, apex = _edge_frames(mesh)
        parent, corner_in = self.vertex_parent[verts], self._vertex_corner[verts]
        back = W.records(parent).img - Pf[corner_in]  # towards where the geodesic came from
        theta = mesh.angle_sums[verts]
        boundary = mesh.is_boundary_vertex[verts]
        a_back = mesh.halfedge_angle[corner_in] + np.angle(back * to_edge[corner_in])
        a_back = np.where(boundary, a_back, np.mod(a_back, theta))
        counts = mesh.ring_start[verts + 1] - mesh.ring_start[verts]
        owner, ring = ranges(mesh.ring_start[verts], counts)
        h = mesh.ring[ring]
        u = verts[owner]
        ab, th, bd = np.repeat(a_back, counts), np.repeat(theta, counts), np.repeat(boundary, counts)
        lo = mesh.halfedge_angle[h]
        spread = mesh.corner_angles.ravel()[h]
        slack = 1e-9
        # The part of each corner inside the cone, as angles [a0, a1] from the corner's first edge.
        # Interior saddle: the cone is [ab+π, ab+θ-π] (mod θ); a corner (< π) meets it in one piece.
        start = np.mod(ab + np.pi - slack, th)
        width = th - 2 * np.pi + 2 * slack
        s = np.mod(lo - start, th)  # the corner's start, in cone coordinates
        wraps = np.minimum(s + spread, width) < s  # its part before the wrap misses the cone
        shift = np.where(wraps, s - th, s)
        a0 = np.maximum(shift, 0.0) - shift
        a1 = np.minimum(shift + spread, width) - shift
        if bd.any():  # boundary vertex: [0, ab-π] and [ab+π, θ]; a corner meets at most one of them
            first_a1 = np.minimum(lo + spread, ab - np.pi + slack) - lo
            second_a0 = np.maximum(lo, ab + np.pi - slack) - lo
            use_first = first_a1 >= 0
            a0 = np.where(bd, np.where(use_first, 0.0, second_a0), a0)
            a1 = np.where(bd, np.where(use_first, first_a1, spread), a1)
        sel = a1 >= a0
        h, u, a0, a1 = h[sel], u[sel], a0[sel], a1[sel]
        if h.size == 0:
            return
        sigma = self.vertex_distance[u]
        label = self.chains.label[W.records(self.vertex_parent[u]).root]
        chain = self.chains.append(label=label, sigma=sigma, ps=u, birth=self._birth[u], corner=h)
        direct = W.add(he=h, u0=0.0, u1=1.0, img=Pf[h], rot=1.0, root=chain, parent=-1, phase=0)
        nxt, prv = mesh.halfedge_next[h], mesh.halfedge_prev[h]
        self._relax(
            np.concatenate([nxt, prv]),
            np.concatenate([sigma + length[h], sigma + length[prv]]),
            np.concatenate([direct, direct]),
        )
        # Windows on the opposite edge (halfedge nxt), between where the cone's bounding rays meet it:
        # in corner h's edge frame the vertex is at 0, the edge runs from L to the apex.
        ok = np.flatnonzero(mesh.twin[nxt] >= 0)
        opp, L, Cl = nxt[ok], length[h[ok]], apex[h[ok]]
        t0 = _hit(0.0, np.exp(1j * a0[ok]), L, Cl)
        t1 = _hit(0.0, np.exp(1j * a1[ok]), L, Cl)
        self._queue(
            sigma[ok] + _to_segment(0.0, L, Cl, t0, t1),
            he=mesh.twin[opp],
            u0=1 - t1,
            u1=1 - t0,
            img=mesh.halfedge_offset[opp] + mesh.halfedge_rotation[opp] * Pf[h[ok]],
            rot=mesh.halfedge_rotation[opp],
            root=chain[ok],
            parent=W.rec.id[direct[ok]],
            phase=1 % CHECKPOINT_DEPTH,
            kept=True,  # made by another rule than their descendants: they cannot be rebuilt
        )

    # ------------------------------------------------------------------ queries

    def _windows_entering(self, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For each of ``faces`` (k,): ``entry`` (n,) its index, ``w`` (n,) a window entering it. Only the
        windows of those faces are sorted: a query usually touches a small part of the mesh."""
        wanted = np.zeros((self.mesh.n_faces, 3), bool)  # per halfedge: each window reads its own
        wanted[faces] = True
        order = np.flatnonzero(wanted.ravel()[self.W.tree.he])
        face = self.W.tree.he[order] // 3
        sort = np.argsort(face, kind="stable")
        order = order[sort]
        start = np.searchsorted(face[sort], np.arange(self.mesh.n_faces + 1))
        counts = start[faces + 1] - start[faces]
        entry, at = ranges(start[faces], counts)
        return entry, order[at]

    def _best_windows(self, faces: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For points z in the frames of ``faces``: the best window entering each face and its distance."""
        entry, w = self._windows_entering(faces)
        W = self.W.records(w)
        p = z[entry]
        I = W.img
        value = self.chains.sigma[W.root] + np.abs(p - I)
        he = W.he
        Pf = self.mesh.face_points.ravel()
        A, B = Pf[he], Pf[self.mesh.halfedge_next[he]]
        d = p - I
        with np.errstate(divide="ignore", invalid="ignore"):
            u = _cross(d, I - A) / _cross(d, B - A)
        through = (u >= W.u0 - RAY_SLACK) & (u <= W.u1 + RAY_SLACK)
        value = np.where((W.parent < 0) | through, value, np.inf)
        best = np.full(faces.size, -1, np.int64)
        dist = np.full(faces.size, np.inf)
        if value.size:
            first = smallest_per_key(entry, value)
            best[entry[first]] = w[first]
            dist[entry[first]] = value[first]
        best[~np.isfinite(dist)] = -1
        return best, dist

    def _locate(self, points: SurfacePoints):
        """For each point: its best window (-1 if unreached), distance, that window's face, and the
        point's position in that face's frame."""
        mesh = self.mesh
        points.validate(mesh)
        k = len(points)
        v = points.vertex_ids(mesh)
        e = points.edge_halfedges(mesh)
        z = points.in_face_frame(mesh)
        best = np.full(k, -1, np.int64)
        dist = np.full(k, np.inf)
        at = v >= 0
        best[at], dist[at] = self.vertex_parent[v[at]], self.vertex_distance[v[at]]
        rest = np.flatnonzero(~at)
        best[rest], dist[rest] = self._best_windows(points.faces[rest], z[rest])
        # A point on an edge is also reached from the other face of that edge.
        other = rest[(e[rest] >= 0) & (mesh.twin[np.maximum(e[rest], 0)] >= 0)]
        if other.size:
            h = e[other]
            b2, d2 = self._best_windows(
                mesh.twin[h] // 3, mesh.halfedge_offset[h] + mesh.halfedge_rotation[h] * z[other]
            )
            better = d2 < dist[other]
            best[other[better]], dist[other[better]] = b2[better], d2[better]
        reached = best >= 0
        face = np.where(reached, self.W.tree.he[np.maximum(best, 0)] // 3, points.faces)
        here = z.copy()
        moved = reached & ~at & (face != points.faces)
        hm = e[moved]
        here[moved] = mesh.halfedge_offset[hm] + mesh.halfedge_rotation[hm] * z[moved]
        here[at] = mesh.face_points.ravel()[corner_halfedges(mesh, face[at], v[at])]
        return best, dist, face, here

    def query(self, points: SurfacePoints) -> GeodesicQuery:
        """Distances, nearest sources and directions at the given points."""
        best, dist, face, here = self._locate(points)
        k = len(points)
        init = np.full(k, np.nan + 0j)
        final = np.full(k, np.nan + 0j)
        src = np.full(k, -1, np.int64)
        r = np.flatnonzero(best >= 0)
        if r.size:
            wr = best[r]
            W = self.W.records(wr)
            unit = _unit(here[r] - W.img)
            init[r] = self._initial_directions(wr, unit)
            final[r] = arrival_to_basis(self.mesh, points[r], face[r], unit)
            src[r] = self.chains.label[W.root]
        return GeodesicQuery(dist, src, init, final)

    def _initial_directions(self, windows: np.ndarray, unit: np.ndarray) -> np.ndarray:
        """Direction at the source of geodesics that leave ``windows``' pseudosources along ``unit``."""
        W, ps = self.W, self.chains.ps
        w, d = windows.copy(), unit.copy()
        root = W.records(w).root
        chained = ps[root] >= 0
        while np.any(chained):  # walk back from pseudosource vertices to the source
            idx = np.flatnonzero(chained)
            u = ps[root[idx]]
            wp = self.vertex_parent[u]
            back = W.records(wp)
            travel = self.mesh.face_points.ravel()[self._vertex_corner[u]] - back.img
            d[idx] = travel / np.abs(travel)
            w[idx] = wp
            root[idx] = back.root
            chained[idx] = ps[back.root] >= 0
        last = W.records(w)
        out = d / last.rot
        corner = self.chains.corner[last.root]
        vc = corner >= 0
        out[vc] = face_to_vertex(self.mesh, corner[vc], out[vc])
        out[unit == 0] = 0
        return out

    def path(self, point: SurfacePoints) -> Path:
        """The exact shortest geodesic from the nearest source to a single point."""
        mesh, W = self.mesh, self.W
        if len(point) != 1:
            raise GeodesicError(f"path() takes one point, got {len(point)}")
        q = self.query(point)
        best, _, _, here = self._locate(point)
        if best[0] < 0:
            raise GeodesicError("the point was not reached by the propagation (beyond max_distance?)")
        w, end = int(best[0]), complex(here[0])
        faces, bary = [int(point.faces[0])], [point.bary[0]]
        segments = []
        final = q.final_directions[0]
        while True:
            # Walk one straight segment back from `end` (in face(w)'s frame) to its pseudosource,
            # recording where it crosses each edge.
            ids = [w]
            while W.tree.parent[ids[-1]] >= 0:
                ids.append(int(W.tree.parent[ids[-1]]))
            rec = W.records(np.array(ids))
            for i in range(len(ids) - 1):
                he = rec.he[i]
                A, B = mesh.face_points.flat[he], mesh.face_points.flat[mesh.halfedge_next[he]]
                u = float(_hit(rec.img[i], end, A, B))
                crossing = np.zeros(3)
                crossing[[he % 3, (he + 1) % 3]] = 1 - u, u
                faces.append(he // 3)
                bary.append(crossing)
                end = mesh.halfedge_offset[he] + mesh.halfedge_rotation[he] * (A + u * (B - A))
            leave = _unit(end - rec.img[-1]) / rec.rot[-1]
            chain = rec.root[-1]
            c = self.chains.corner[chain]
            if c >= 0:
                leave = face_to_vertex(mesh, np.array([c]), np.array([leave]))[0]
                faces.append(c // 3)
                bary.append(np.eye(3)[c % 3])
            else:
                faces.append(self.sources.faces[self.chains.label[chain]])
                bary.append(self.sources.bary[self.chains.label[chain]])
            segments.append((leave, final))
            vertex = self.chains.ps[chain]
            if vertex < 0:
                break
            # The segment started at a vertex the path bends around; continue from how it got there.
            w = int(self.vertex_parent[vertex])
            corner = self._vertex_corner[[vertex]]
            end = complex(mesh.face_points.flat[corner[0]])
            at_vertex = SurfacePoints(corner // 3, np.eye(3)[corner % 3])
            final = arrival_to_basis(mesh, at_vertex, corner // 3, _unit([end - W.records([w]).img[0]]))[0]
        points = SurfacePoints(np.array(faces[::-1]), np.array(bary[::-1]))
        return Path(
            length=float(q.distances[0]),
            initial_direction=complex(q.initial_directions[0]),
            final_direction=complex(q.final_directions[0]),
            polyline=points.positions(mesh),
            points=points,
            segment_directions=np.array(segments[::-1], dtype=np.complex128).reshape(-1, 2),
        )


@per_mesh
def _edge_frames(mesh: TriMesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(3m,) each, per halfedge h: ``to_edge``, the unit complex that turns face(h)'s frame into the
    edge's (a point z is at ``(z - tail) * to_edge`` there, with the edge along the positive real axis
    and the face above it); the edge's length; and the face's third corner in the edge's frame."""
    P = mesh.face_points.ravel()
    edge = P[mesh.halfedge_next] - P
    length = np.abs(edge)
    to_edge = np.conj(edge) / length
    return to_edge, length, (P[mesh.halfedge_prev] - P) * to_edge


def _entry_frame(mesh: TriMesh, he: np.ndarray, img: np.ndarray):
    """Windows on halfedges ``he`` with pseudosource images ``img``, in their entry edge's frame (see
    :func:`_edge_frames`): the image ``Il``, the edge's length ``L``, the face's third corner ``Cl``, and
    ``uc``, where the ray through that corner crosses the edge (edge parameter)."""
    to_edge, length, apex = _edge_frames(mesh)
    Il = (img - mesh.face_points.ravel()[he]) * to_edge[he]
    L, Cl = length[he], apex[he]
    xI, yI = Il.real, Il.imag
    uc = (xI - yI * (Cl.real - xI) / (Cl.imag - yI)) / L
    return Il, L, Cl, uc


def _exits(Il, Cl, L, uc, u0, u1, on_right):
    """Where a window's child leaves its face, in the entry edge's frame: the exit edge from ``P0`` to
    ``P1`` (B -> C for the child on the right of the ray through C, C -> A for the left one) and the
    child's ends along it, ``t_near`` (from the ray through u0) and ``t_far`` (through u1); where the ray
    through C bounds a child, it ends exactly at C."""
    P0, P1 = np.where(on_right, L, Cl), np.where(on_right, Cl, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):  # where C bounds a child, its ray may miss
        t_near = np.where(on_right & (uc > u0), 1.0, _hit(Il, u0 * L, P0, P1))
        t_far = np.where(~on_right & (uc < u1), 0.0, _hit(Il, u1 * L, P0, P1))
    return P0, P1, t_near, t_far


def _child(mesh: TriMesh, he, u0, u1, img, rot, child_he, swapped):
    """The interval (u0, u1), image and rotation of the children on halfedges ``child_he`` of windows
    ``he, u0, u1, img, rot``: the same operations on the same values as when they were propagated, so the
    same bits."""
    Il, L, Cl, uc = _entry_frame(mesh, he, img)
    h_out = mesh.twin[child_he]
    _, _, t_near, t_far = _exits(Il, Cl, L, uc, u0, u1, h_out == mesh.halfedge_next[he])
    rotation = mesh.halfedge_rotation[h_out]
    return (
        1 - t_near,
        1 - t_far,
        mesh.halfedge_offset[h_out] + _rotated(rotation, img, swapped),
        rot * rotation,
    )


def _root_faces(mesh: TriMesh, sources: SurfacePoints):
    """The faces each source lies in: its face; both faces of its edge; every face around its vertex.

    Returns, per (source, face) pair: the source index, the face, the source's position in that face's
    frame, the rotation from the source's own frame to that face's, and for vertex sources the corner
    halfedge at the vertex (-1 otherwise).
    """
    z = sources.in_face_frame(mesh)
    v, e = sources.vertex_ids(mesh), sources.edge_halfedges(mesh)
    parts = []
    inner = np.flatnonzero(v < 0)  # in a face or on an edge: its own face first
    parts.append(
        (inner, sources.faces[inner], z[inner], np.ones(inner.size, complex), -np.ones(inner.size, int))
    )
    across = np.flatnonzero((e >= 0) & (mesh.twin[np.maximum(e, 0)] >= 0))  # the other face of its edge
    h = e[across]
    parts.append(
        (
            across,
            mesh.twin[h] // 3,
            mesh.halfedge_offset[h] + mesh.halfedge_rotation[h] * z[across],
            mesh.halfedge_rotation[h],
            -np.ones(across.size, int),
        )
    )
    at = np.flatnonzero(v >= 0)  # on a vertex: every corner around it, each in its own frame
    counts = mesh.ring_start[v[at] + 1] - mesh.ring_start[v[at]]
    owner, ring = ranges(mesh.ring_start[v[at]], counts)
    h = mesh.ring[ring]
    parts.append((at[owner], h // 3, mesh.face_points[h // 3, h % 3], np.ones(h.size, complex), h))
    return tuple(np.concatenate(column) for column in zip(*parts, strict=True))


def _unit(z):
    """z / |z|, and 0 where z is 0."""
    z = np.asarray(z, dtype=np.complex128)
    length = np.abs(z)
    return np.where(length > 0, z / np.where(length > 0, length, 1.0), 0)


def _to_segment(I, P0, P1, t0, t1):
    """Distance from I to the part of segment P0 -> P1 between parameters t0 and t1 (in either order): a
    window's queue key, which must never exceed the distance to any of its points."""
    D = P1 - P0
    t = ((I - P0) * np.conj(D)).real / (D.real**2 + D.imag**2)
    t = np.minimum(np.maximum(t, np.minimum(t0, t1)), np.maximum(t0, t1))
    return np.abs(I - (P0 + t * D))


def _hit(I, X, P0, P1):
    """Parameter t along P0 -> P1 where the ray from I through X crosses that line (clipped to [0, 1])."""
    d = X - I
    return np.minimum(np.maximum(_cross(d, I - P0) / _cross(d, P1 - P0), 0.0), 1.0)
