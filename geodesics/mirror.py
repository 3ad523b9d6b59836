"""Mirror images through a plane: vertex, face and surface-point correspondences, and mirrored contact sets.

A :class:`MirrorMap` pairs each vertex of a source mesh with the vertex of a target mesh at its mirror
image: the same mesh for a body symmetric in itself (each left vertex pairs with a right one, vertices on
the plane with themselves), or a separate mirrored copy. Through it, surface points, tangent directions
and whole contact sets (:func:`mirror_contacts`) go to the other side.

Conventions:

* The plane passes through ``point`` with unit ``normal``; the default is x = 0 of the meshes' common
  space (Blender's X mirror). ``reflect(X) = X - 2 ((X - point) · normal) normal``.
* A mirror reverses orientation, so source face ``(a, b, c)`` goes to the target face whose corners are
  ``(a', c', b')`` up to rotation; halfedge ``a → b`` goes to the target halfedge ``b' → a'``. A target
  whose faces do not wind that way (normals pointing inwards after mirroring) is refused.
* A surface point keeps its barycentric weights, carried to the mirrored corners, so vertices, edge
  points and face points map exactly; a tangent direction keeps its coefficients on the face's edge
  vectors (exact on a symmetric mesh) and its length.

How vertices are paired (``method``):

* ``"spatial"`` — the nearest target vertex to each reflected source vertex, within ``tolerance`` times
  the bounding diagonal (Blender's X-mirror lookup, ``ED_mesh_mirror_spatial_table_lookup``, which uses a
  KD-tree and an absolute threshold).
* ``"topology"`` — for meshes symmetric in topology but not exactly in positions (hand-modelled meshes):
  vertices are first told apart by their topology alone, by the iterated neighbour hashing of Blender's
  topology mirror (``ED_mesh_mirrtopo_init`` in ``editors/mesh/mesh_mirror.cc``), and vertices that
  topology cannot tell apart (a left/right pair) are assigned by their reflected positions, as Blender
  does for its hash pairs. When that leaves faces that do not map onto faces, the map is grown face by
  face from a seed face whose correspondence is certain: given one halfedge pair, an orientation-reversing
  isomorphism of a connected mesh is unique, so this gives the exact combinatorial mirror or a clear
  conflict. Every vertex must then lie within ``max_deviation`` (times the bounding diagonal) of its
  partner's mirror image, so that a mesh with an accidental combinatorial symmetry is not mirrored wrongly.
* ``"auto"`` (default) — spatial, falling back to topology when some vertex has no spatial partner.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterable

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from .arrays import readonly
from .axis import Axis
from .contacts import ContactSet, Link
from .errors import ContactError, MeshError, describe_ids
from .mesh import TriMesh
from .patch import ContactPatch
from .points import SurfacePoints
from .tangent import from_face_frame, to_face_frame

__all__ = [
    "MAX_DEVIATION",
    "TOLERANCE",
    "MirrorMap",
    "flip_name",
    "mirror_contacts",
    "reflect",
    "topology_classes",
]

#: Spatial matching tolerance, relative to the bounding diagonal.
TOLERANCE = 1e-5
#: Largest distance, relative to the bounding diagonal, between a vertex's mirror image and its partner
#: that a topological match accepts.
MAX_DEVIATION = 0.05
#: Classes of topologically indistinguishable vertices up to this size are assigned optimally (Hungarian
#: method); larger ones by nearest neighbours.
_ASSIGNMENT_LIMIT = 1000


# ---------------------------------------------------------------------------------------------- names

_SEPARATORS = b". -_"
_SIDES = {ord("l"): b"r", ord("r"): b"l", ord("L"): b"R", ord("R"): b"L"}
_DIGITS = b"0123456789"


def flip_name(name: str, strip_digits: bool = False, max_bytes: int | None = None) -> str:
    """The name of the other side, exactly as Blender flips bone names (``bpy.utils.flip_name``).

    A port of ``BLI_string_flip_side_name`` (``blenlib/intern/string_utils.cc``) as bpy 5.0.1 has it,
    which works on the UTF-8 bytes:

    * names shorter than 3 bytes are returned unchanged;
    * a trailing ``.<digits>`` number (``"hand.L.001"``) is set aside and appended again (or dropped with
      ``strip_digits``);
    * then the first rule that applies: a separator (``.``, space, ``-``, ``_``) and ``l``/``r``/``L``/``R``
      at the end (``"hand.L"`` → ``"hand.R"``); one of those letters and a separator at the start
      (``"L_hand"`` → ``"R_hand"``); in names longer than 5 bytes, ``right`` (any case) at the very start or
      end (only its first occurrence is examined) becomes ``left``/``Left``/``LEFT``, else ``left`` at the
      start or end becomes ``right``/``Right``/``RIGHT`` (the case follows the first one or two letters).

    Blender's development version also flips markers inside names (``"bip001-L-UpperArm"``,
    ``"ManLeftHand"``); 5.0.1 leaves those unchanged, and so does this function.

    Parameters
    ----------
    name : str
    strip_digits : bool
        Drop the ``.###`` number instead of keeping it (Blender's ``strip_digits``).
    max_bytes : int, optional
        Size of Blender's destination buffer including the terminating NUL: the result is cut to
        ``max_bytes - 1`` bytes (64 for bone names, ``MAXBONENAME``). None: no limit, as ``bpy.utils``.
    """
    src = name.encode("utf-8").split(b"\0", 1)[0]
    if max_bytes is not None:
        src = src[: max(max_bytes - 1, 0)]
    if len(src) < 3:
        return src.decode("utf-8", errors="ignore")
    body, number = src, b""
    if body[-1] in _DIGITS:
        dot = body.rfind(b".")
        if dot >= 0 and dot + 1 < len(body) and body[dot + 1] in _DIGITS:
            number = b"" if strip_digits else body[dot:]
            body = body[:dot]
    n = len(body)
    prefix, replace, suffix = body, b"", b""
    if n > 1 and body[n - 2] in _SEPARATORS and body[n - 1] in _SIDES:
        prefix, replace = body[: n - 1], _SIDES[body[n - 1]]
    elif n > 1 and body[1] in _SEPARATORS and body[0] in _SIDES:
        prefix, replace, suffix = b"", _SIDES[body[0]], body[1:]
    elif n > 5:
        lower = body.lower()  # ASCII only, as C's tolower in the "C" locale
        at = lower.find(b"right")
        if at == 0 or (at >= 0 and at == n - 5):
            replace = b"left" if body[at] == ord("r") else (b"LEFT" if body[at + 1] == ord("I") else b"Left")
            prefix, suffix = body[:at], body[at + 5 :]
        else:
            at = lower.find(b"left")
            if at == 0 or (at >= 0 and at == n - 4):
                replace = (
                    b"right" if body[at] == ord("l") else (b"RIGHT" if body[at + 1] == ord("E") else b"Right")
                )
                prefix, suffix = body[:at], body[at + 4 :]
    out = prefix + replace + suffix + number
    if max_bytes is not None:
        out = out[: max(max_bytes - 1, 0)]
    return out.decode("utf-8", errors="ignore")


# ---------------------------------------------------------------------------------------------- geometry


def _plane(point, normal) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(point, dtype=np.float64).reshape(-1)
    n = np.asarray(normal, dtype=np.float64).reshape(-1)
    if p.shape != (3,) or n.shape != (3,) or not (np.all(np.isfinite(p)) and np.all(np.isfinite(n))):
        raise MeshError(f"a mirror plane needs a finite point and normal of 3 coordinates, got {p} and {n}")
    length = np.linalg.norm(n)
    if length == 0:
        raise MeshError("the mirror plane's normal is zero")
    return p, n / length


def reflect(X, point=(0.0, 0.0, 0.0), normal=(1.0, 0.0, 0.0)) -> np.ndarray:
    """(..., 3) mirror images of positions X (..., 3) through the plane at ``point`` with ``normal``.

    ``point`` and ``normal`` are (3,). Through a coordinate plane (the default x = 0) this only negates one
    coordinate, exactly.
    """
    p, n = _plane(point, normal)
    X = np.asarray(X, dtype=np.float64)
    axis = np.flatnonzero(n != 0)
    if axis.size == 1:  # a coordinate plane: exact
        out = X.copy()
        k = int(axis[0])
        out[..., k] = 2 * p[k] - X[..., k] if p[k] != 0 else -X[..., k]
        return out
    return X - 2 * ((X - p) @ n)[..., None] * n


def _reflect_vectors(D: np.ndarray, n: np.ndarray) -> np.ndarray:
    return D - 2 * (D @ n)[..., None] * n


def _mix(x: np.ndarray) -> np.ndarray:
    """splitmix64's finalizer: a bijective scrambling of 64-bit words (wrapping arithmetic)."""
    x = x ^ (x >> np.uint64(30))
    x = x * np.uint64(0xBF58476D1CE4E5B9)
    x = x ^ (x >> np.uint64(27))
    x = x * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


def topology_classes(n: int, edges: np.ndarray) -> np.ndarray:
    """(n,) uint64 labels equal for vertices that iterated neighbour hashing cannot tell apart.

    Blender's topology mirror (``ED_mesh_mirrtopo_init``): start from each vertex's edge count and
    repeatedly add the (scrambled) labels of its neighbours, until a pass makes no new distinctions.
    Vertices related by a symmetry of the graph always share a label.

    Parameters
    ----------
    n : int
        Number of vertices.
    edges : (e, 2) array_like of int
        Each undirected edge once.
    """
    E = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    h = np.bincount(E.ravel(), minlength=n).astype(np.uint64)
    count = np.unique(h).size
    for _ in range(n + 1):
        around = np.zeros(n, np.uint64)
        np.add.at(around, E[:, 0], _mix(h[E[:, 1]]))
        np.add.at(around, E[:, 1], _mix(h[E[:, 0]]))
        new = _mix(h * np.uint64(0x9E3779B97F4A7C15) + around)
        new_count = np.unique(new).size
        if new_count <= count:
            break
        h, count = new, new_count
    return h


def _edges(mesh: TriMesh) -> np.ndarray:
    h = np.flatnonzero((mesh.twin < 0) | (np.arange(mesh.twin.size) < mesh.twin))
    return np.stack([mesh.halfedge_tail[h], mesh.halfedge_head[h]], 1)


class _HalfedgeIndex:
    """Find a mesh's halfedge by its (tail, head) vertices."""

    def __init__(self, mesh: TriMesh):
        self.n = mesh.n_vertices
        key = mesh.halfedge_tail * self.n + mesh.halfedge_head
        self.order = np.argsort(key)
        self.keys = key[self.order]

    def find(self, tail: np.ndarray, head: np.ndarray) -> np.ndarray:
        """(k,) halfedge from tail to head, -1 where there is none (or an index is -1)."""
        ok = (tail >= 0) & (head >= 0)
        key = np.where(ok, tail * self.n + head, -1)
        pos = np.minimum(np.searchsorted(self.keys, key), self.keys.size - 1)
        return np.where(ok & (self.keys[pos] == key), self.order[pos], -1)


# ---------------------------------------------------------------------------------------------- the map


class MirrorMap:
    """The correspondence between a mesh and its mirror image through a plane.

    Parameters
    ----------
    source : TriMesh
    target : TriMesh, optional
        The mesh holding the mirror images: ``source`` itself (the default) for a body symmetric in
        itself, or a separate mirrored copy (in the same space).
    point, normal : (3,) array_like
        The mirror plane; default x = 0.
    method : {"auto", "spatial", "topology"}
        How vertices are paired (see the module notes).
    tolerance : float
        Spatial matching tolerance, relative to the source's bounding diagonal.
    max_deviation : float
        Topological matching: largest accepted distance between a vertex's mirror image and its
        partner, relative to the bounding diagonal.

    Attributes
    ----------
    vertex_map : (n,) int
        The target vertex at each source vertex's mirror image (-1 for vertices no face uses).
    face_map : (m,) int
        The target face holding the mirror image of each source face.
    face_corners : (m, 3) int
        ``face_corners[f, j]`` is the corner of ``face_map[f]`` at the image of corner j of face f.
    halfedge_map : (3m,) int
        The target halfedge ``b' → a'`` of each source halfedge ``a → b``.
    deviation : (n,) float
        Distance between each vertex's mirror image and its partner (0 on an exactly symmetric mesh;
        NaN for unused vertices): where a mesh is not quite symmetric.
    method : str
        ``"spatial"`` or ``"topology"``: what paired the vertices.

    Raises
    ------
    MeshError
        When the meshes are not mirror images: names the vertices without a partner (``vertices``
        attribute), or the faces whose image is not a face.

    Examples
    --------
    >>> body = MirrorMap(mesh)                       # a body symmetric in itself through x = 0
    >>> right = body.map_points(left)                # SurfacePoints at the mirror images
    >>> hands = MirrorMap(left_hand, right_hand)     # a separate mirrored copy
    >>> contacts_r = mirror_contacts(contacts_l, hands)
    >>> back = hands.inverse().map_points(hands.map_points(points))   # the same points, bit for bit
    """

    def __init__(
        self,
        source: TriMesh,
        target: TriMesh | None = None,
        *,
        point=(0.0, 0.0, 0.0),
        normal=(1.0, 0.0, 0.0),
        method: str = "auto",
        tolerance: float = TOLERANCE,
        max_deviation: float = MAX_DEVIATION,
    ):
        if method not in ("auto", "spatial", "topology"):
            raise MeshError(f"unknown mirror method {method!r}; use 'auto', 'spatial' or 'topology'")
        target = source if target is None else target
        self.source, self.target = source, target
        self.point, self.normal = _plane(point, normal)
        scale = source.bounding_diagonal
        used = np.zeros(source.n_vertices, bool)
        used[source.faces.ravel()] = True
        self._used = used
        image = reflect(source.vertices, self.point, self.normal)
        halfedges = _HalfedgeIndex(target)

        failure = None
        if method in ("auto", "spatial"):
            vm = self._spatial(image, tolerance * scale)
            hm, problem = self._halfedges_from(vm, halfedges)
            if problem is None:
                self._set(hm, "spatial")
                return
            failure = problem
            if method == "spatial":
                raise failure
        vm = self._topological(image)
        hm, problem = self._halfedges_from(vm, halfedges)
        if problem is not None:
            hm = self._grow(vm, image, halfedges, max_deviation * scale)
        if hm is not None:
            self._set(hm, "topology")
            deviation = np.nanmax(self.deviation) if used.any() else 0.0
            if deviation <= max_deviation * scale:
                return
            problem = MeshError(
                f"the meshes are symmetric in topology, but vertices "
                f"{describe_ids(np.flatnonzero(self.deviation > max_deviation * scale))} lie up to "
                f"{deviation:.4g} from their partners' mirror images (more than max_deviation "
                f"{max_deviation:g} of the size {scale:.4g})",
                vertices=np.flatnonzero(self.deviation > max_deviation * scale),
            )
            raise problem  # symmetric in topology, but too far from symmetric in shape
        raise failure if failure is not None else problem

    # ------------------------------------------------------------------ pairing

    def _spatial(self, image: np.ndarray, tol: float) -> np.ndarray:
        target = self.target
        t_used = np.unique(target.faces.ravel())
        dist, nearest = cKDTree(target.vertices[t_used]).query(image)
        return np.where(self._used & (dist <= tol), t_used[nearest], -1)

    def _topological(self, image: np.ndarray) -> np.ndarray:
        """Candidate partners: topology classes, resolved by reflected positions inside each class."""
        source, target = self.source, self.target
        ns, nt = source.n_vertices, target.n_vertices
        edges = np.concatenate([_edges(source), _edges(target) + ns])
        labels = topology_classes(ns + nt, edges)
        t_used = np.zeros(nt, bool)
        t_used[target.faces.ravel()] = True
        members = np.flatnonzero(np.concatenate([self._used, t_used]))
        order = members[np.argsort(labels[members], kind="stable")]
        cuts = np.flatnonzero(np.diff(labels[order])) + 1
        vm = np.full(ns, -1, np.int64)
        for group in np.split(order, cuts):
            s, t = group[group < ns], group[group >= ns] - ns
            if s.size == 0 or s.size != t.size:
                continue
            if s.size == 1:
                vm[s[0]] = t[0]
            elif s.size <= _ASSIGNMENT_LIMIT:
                cost = np.linalg.norm(image[s][:, None] - target.vertices[t][None], axis=2)
                rows, cols = linear_sum_assignment(cost)
                vm[s[rows]] = t[cols]
            else:
                _, nearest = cKDTree(target.vertices[t]).query(image[s])
                vm[s] = t[nearest]
        return vm

    def _halfedges_from(self, vm: np.ndarray, index: _HalfedgeIndex) -> tuple[np.ndarray, MeshError | None]:
        """The halfedge map a vertex map implies, or the reason it is not a mirror map."""
        source = self.source
        missing = np.flatnonzero(self._used & (vm < 0))
        if missing.size:
            return None, self._unmatched_error(missing)
        v = np.flatnonzero(self._used)
        if np.unique(vm[v]).size != v.size:
            _, inverse, counts = np.unique(vm[v], return_inverse=True, return_counts=True)
            shared = v[counts[inverse] > 1]
            return None, MeshError(
                f"vertices {describe_ids(shared)} would share mirror partners", vertices=shared
            )
        hm = index.find(vm[source.halfedge_head], vm[source.halfedge_tail])
        per_face = hm.reshape(-1, 3)
        bad = np.flatnonzero(~_whole_faces(per_face))
        if bad.size:
            return None, self._face_error(bad, vm)
        return hm, None

    def _unmatched_error(self, missing: np.ndarray) -> MeshError:
        return MeshError(
            f"the mesh is not mirror-symmetric through the plane at {self.point.tolist()} with normal "
            f"{self.normal.tolist()}: vertices {describe_ids(missing)} have no counterpart at their mirror "
            "images",
            vertices=missing,
        )

    def _face_error(self, bad: np.ndarray, vm: np.ndarray) -> MeshError:
        same_winding = _HalfedgeIndex(self.target).find(
            vm[self.source.halfedge_tail[3 * bad]], vm[self.source.halfedge_head[3 * bad]]
        )
        hint = (
            " (the target's faces wind the same way as the source's: flip its normals)"
            if np.all(same_winding >= 0)
            else ""
        )
        return MeshError(
            f"the mirror images of faces {describe_ids(bad)} are not faces of the target mesh{hint}",
            faces=bad,
            vertices=np.unique(self.source.faces[bad]),
        )

    def _grow(self, vm: np.ndarray, image: np.ndarray, index: _HalfedgeIndex, limit: float):
        """Grow an orientation-reversing face correspondence over each source component from seed faces
        that the candidate vertex map pairs with certainty; None if no component seed grows cleanly."""
        source, target = self.source, self.target
        safe = np.maximum(vm, 0)
        hm0 = index.find(vm[source.halfedge_head], vm[source.halfedge_tail])
        per_face = hm0.reshape(-1, 3)
        seeds = np.flatnonzero(_whole_faces(per_face))
        error = np.linalg.norm(image[source.faces] - target.vertices[safe[source.faces]], axis=2).sum(1)
        seeds = seeds[np.argsort(error[seeds], kind="stable")]
        hm = np.full(3 * source.n_faces, -1, np.int64)
        used_target = np.zeros(target.n_faces, bool)
        component = source.face_components
        for c in range(source.n_components):
            for tried, f in enumerate(seeds[component[seeds] == c]):
                if tried >= 8:
                    return None
                grown = _grow_component(source, target, 3 * f, per_face[f, 0], used_target)
                if grown is not None:
                    faces = np.flatnonzero(grown >= 0)
                    vm_c = np.full(source.n_vertices, -1, np.int64)
                    vm_c[source.halfedge_tail[faces]] = target.halfedge_head[grown[faces]]
                    v = np.unique(source.halfedge_tail[faces])
                    if np.linalg.norm(image[v] - target.vertices[vm_c[v]], axis=1).max() <= limit:
                        hm[faces] = grown[faces]
                        used_target[grown[faces] // 3] = True
                        break
            else:
                return None
        return hm

    def _set(self, hm: np.ndarray, method: str) -> None:
        source, target = self.source, self.target
        vm = np.full(source.n_vertices, -1, np.int64)
        vm[source.halfedge_tail] = target.halfedge_head[hm]
        deviation = np.full(source.n_vertices, np.nan)
        v = np.flatnonzero(vm >= 0)
        deviation[v] = np.linalg.norm(
            reflect(source.vertices[v], self.point, self.normal) - target.vertices[vm[v]], axis=1
        )
        self.method = method
        self.halfedge_map = readonly(hm)
        self.vertex_map = readonly(vm)
        self.face_map = readonly(hm[0::3] // 3)
        self.face_corners = readonly((hm.reshape(-1, 3) % 3 + 1) % 3)
        self.deviation = readonly(deviation)

    def __repr__(self) -> str:
        where = "itself" if self.target is self.source else repr(self.target)
        return (
            f"MirrorMap({self.source!r} onto {where}, plane through {self.point.tolist()} normal "
            f"{self.normal.tolist()}, by {self.method})"
        )

    # ------------------------------------------------------------------ queries

    def inverse(self) -> MirrorMap:
        """The map from the target back to the source (the same plane)."""
        if np.unique(self.halfedge_map).size != 3 * self.target.n_faces:
            missing = np.setdiff1d(np.arange(self.target.n_faces), self.face_map)
            raise MeshError(
                f"target faces {describe_ids(missing)} are the image of no source face: the map has no "
                "inverse",
                faces=missing,
            )
        inv = MirrorMap.__new__(MirrorMap)
        inv.source, inv.target, inv.point, inv.normal = self.target, self.source, self.point, self.normal
        hm = np.empty_like(self.halfedge_map)
        hm[self.halfedge_map] = np.arange(self.halfedge_map.size)
        used = np.zeros(self.target.n_vertices, bool)
        used[self.target.faces.ravel()] = True
        inv._used = used
        inv._set(hm, self.method)
        return inv

    def reflect(self, X) -> np.ndarray:
        """(..., 3) mirror images of positions X (..., 3) through this map's plane."""
        return reflect(X, self.point, self.normal)

    def map_points(self, points: SurfacePoints) -> SurfacePoints:
        """The points at the mirror images of ``points`` (on the source) on the target: same
        barycentric weights, carried to the mirrored corners."""
        points.validate(self.source)
        corners = self.face_corners[points.faces]
        bary = np.empty_like(points.bary)
        bary[np.arange(len(points))[:, None], corners] = points.bary
        # Permuted valid coordinates are valid: skip the constructor's renormalization so that mapping
        # there and back returns the very same bits.
        mapped = SurfacePoints.__new__(SurfacePoints)
        object.__setattr__(mapped, "faces", readonly(self.face_map[points.faces]))
        object.__setattr__(mapped, "bary", readonly(bary))
        return mapped

    def map_directions(self, points: SurfacePoints, z) -> np.ndarray:
        """(k,) complex: tangent directions ``z`` at ``points`` (each in its point's basis on the source),
        mirrored, in the bases of the mirrored points on the target.

        A direction keeps its coefficients on the edge vectors of the face it points into, and its
        length; on a symmetric mesh that is its exact mirror image.
        """
        z = np.broadcast_to(np.asarray(z, dtype=np.complex128), (len(points),))
        faces, zf = to_face_frame(self.source, points, z)
        P = self.source.face_points[faces]
        e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]

        def cross(a, b):
            return (np.conj(a) * b).imag

        area = cross(e1, e2)
        alpha, beta = cross(zf, e2) / area, cross(e1, zf) / area
        images = self.face_map[faces]
        Q = np.take_along_axis(self.target.face_points[images], self.face_corners[faces], axis=1)
        out = alpha * (Q[:, 1] - Q[:, 0]) + beta * (Q[:, 2] - Q[:, 0])
        size = np.abs(out)
        out = np.where(size > 0, out * (np.abs(zf) / np.where(size > 0, size, 1)), 0)
        return from_face_frame(self.target, self.map_points(points), images, out)


def _whole_faces(per_face: np.ndarray) -> np.ndarray:
    """(m,) whether the three halfedge images of each face (m, 3) exist and lie in one target face."""
    return np.all(per_face >= 0, axis=1) & np.all(per_face // 3 == per_face[:, :1] // 3, axis=1)


def _grow_component(
    source: TriMesh, target: TriMesh, h0: int, g0: int, taken: np.ndarray
) -> np.ndarray | None:
    """(3m,) the halfedge map of the orientation-reversing isomorphism that takes source halfedge h0 to
    target halfedge g0 over h0's component (-1 elsewhere), grown face by face across edges; None on any
    conflict (a face reached twice differently, a boundary edge against an inner one, a target face used
    twice or by another component, vertices that do not map consistently)."""
    hm = np.full(3 * source.n_faces, -1, np.int64)
    owner = np.full(target.n_faces, -1, np.int64)  # target face -> source face
    H, G = np.array([h0]), np.array([g0])
    while H.size:
        f, k = H // 3, H % 3
        # The image of the face's first halfedge: next(h) maps to prev(g), so undo k steps.
        g_first = 3 * (G // 3) + (G % 3 + k) % 3
        order = np.lexsort((g_first, f))
        f, g_first = f[order], g_first[order]
        first = np.r_[True, f[1:] != f[:-1]]
        if np.any(~first & (g_first != np.roll(g_first, 1))):
            return None
        f, g_first = f[first], g_first[first]
        known = hm[3 * f] >= 0
        if np.any(known & (hm[3 * f] != g_first)):
            return None
        f, g_first = f[~known], g_first[~known]
        if f.size == 0:
            break
        tf = g_first // 3
        if np.any(taken[tf]) or np.any(owner[tf] >= 0) or np.unique(tf).size != tf.size:
            return None
        owner[tf] = f
        j = np.arange(3)
        h = (3 * f[:, None] + j).ravel()
        g = (3 * tf[:, None] + (g_first[:, None] % 3 - j) % 3).ravel()
        hm[h] = g
        th, tg = source.twin[h], target.twin[g]
        if np.any((th < 0) != (tg < 0)):
            return None
        inner = th >= 0
        H, G = th[inner], tg[inner]
    faces = np.flatnonzero(hm >= 0)
    tail = source.halfedge_tail[faces]
    image = target.halfedge_head[hm[faces]]
    vm = np.full(source.n_vertices, -1, np.int64)
    vm[tail] = image
    if np.any(vm[tail] != image):
        return None
    v = np.unique(tail)
    if np.unique(vm[v]).size != v.size:
        return None
    return hm


# ---------------------------------------------------------------------------------------------- contacts


def mirror_contacts(
    contacts: ContactSet,
    mirror: MirrorMap,
    *,
    names: Iterable[str] | None = None,
    rename: Callable[[str], str] = flip_name,
    pairs: str = "drop",
    into: ContactSet | None = None,
    overwrite: bool = False,
) -> ContactSet:
    """Mirror contact patches to the other side: their points, axes, names and parent links.

    Each patch's points and axis points go to their mirror images (exactly, see :class:`MirrorMap`); the
    axis keeps its shape mirrored (segment lengths, negated turning angles, mirrored tangents) and the
    patch is parameterized anew around it on the target mesh. Names are flipped by ``rename`` (Blender's
    rule by default: ``"index.L"`` → ``"index.R"``; a name without a side stays as it is).

    Parameters
    ----------
    contacts : ContactSet
        Patches on ``mirror.source``.
    mirror : MirrorMap
    names : iterable of str, optional
        The patches to mirror (default: all).
    rename : callable
        New name of each mirrored patch.
    pairs : {"drop", "keep", "flip"}
        Pairs name patches of another set (an object's), which is not mirrored: drop them (default), keep
        the same counterpart, or pair with the counterpart's flipped name.
    into : ContactSet, optional
        A set on ``mirror.target`` to add the mirrored patches to (e.g. ``contacts`` itself on a body
        symmetric in itself); default a new set.
    overwrite : bool
        Replace patches of ``into`` with the same names (otherwise that is an error).

    Returns
    -------
    ContactSet
        On ``mirror.target``. A mirrored child whose parent was mirrored along hangs off the parent's
        mirror image with the mirrored link; one whose parent was not, off the patch named
        ``rename(parent)`` if the result has one (the link measured anew), else it has no parent. Patches
        of ``into`` linked to a replaced patch are linked to its replacement, measured anew.

    Raises
    ------
    ContactError
        For unknown names, names that collide, or a set or ``into`` on the wrong mesh. Nothing changes.
    """
    if contacts.mesh is not mirror.source:
        raise ContactError("the contact set lies on another mesh than the mirror map's source")
    if pairs not in ("drop", "keep", "flip"):
        raise ContactError(f"pairs must be 'drop', 'keep' or 'flip', not {pairs!r}")
    target = mirror.target
    base = ContactSet(target) if into is None else into
    if base.mesh is not target:
        raise ContactError("'into' lies on another mesh than the mirror map's target")
    new = _mirrored_names(contacts, base, names, rename, overwrite)
    names = list(new)

    patches = dict(base.patches)
    for name in names:
        patches[new[name]] = _mirrored_patch(contacts[name], mirror)
    links, relink = _mirrored_links(contacts, base, new, rename, patches)
    paired = {k: v for k, v in base.pairs.items() if k not in new.values()}
    if pairs != "drop":
        for name in names:
            if name in contacts.pairs:
                other = contacts.pairs[name]
                paired[new[name]] = other if pairs == "keep" else rename(other)
    result = ContactSet(target, patches, links, paired)
    for child, parent in relink:
        # Coincident start points (or a cycle) leave the child without a parent.
        with contextlib.suppress(ContactError):
            result = result.parent(child, parent)
    return result


def _mirrored_names(
    contacts: ContactSet,
    base: ContactSet,
    names: Iterable[str] | None,
    rename: Callable[[str], str],
    overwrite: bool,
) -> dict[str, str]:
    """Each patch to mirror (all by default, in order, once) and its new name; a ContactError for an
    unknown name, names that collide, or names ``base`` has unless ``overwrite``."""
    names = list(contacts.patches) if names is None else list(dict.fromkeys(names))
    for name in names:
        contacts[name]  # a clear error for an unknown name
    new = {name: rename(name) for name in names}
    if len(set(new.values())) != len(new):
        raise ContactError(f"flipping {', '.join(names)} gives repeated names {', '.join(new.values())}")
    taken = [n for n in new.values() if n in base]
    if taken and not overwrite:
        raise ContactError(
            f"the target already has patches named {', '.join(taken)}; pass overwrite to replace them"
        )
    return new


def _mirrored_patch(patch: ContactPatch, mirror: MirrorMap) -> ContactPatch:
    """The patch's points and axis on the target: the axis keeps its shape mirrored (segment lengths,
    negated turning angles, mirrored tangents) and the patch is parameterized anew around it."""
    axis = patch.axis
    tangents = mirror.map_directions(axis.points, axis.tangents)
    mirrored_axis = Axis.embedded(
        mirror.target, mirror.map_points(axis.points), axis.lengths, np.conj(axis.turning), tangents
    )
    return ContactPatch(mirror.target, mirror.map_points(patch.points), mirrored_axis)


def _mirrored_links(
    contacts: ContactSet,
    base: ContactSet,
    new: dict[str, str],
    rename: Callable[[str], str],
    patches: dict[str, ContactPatch],
) -> tuple[dict[str, Link], list[tuple[str, str]]]:
    """The parent links of the mirrored set: ``base``'s that neither start nor end at a replaced patch,
    and each mirrored child's mirrored link when its parent was mirrored along; and the (child, parent)
    pairs to link anew (measured on the result): ``base``'s children of a replaced patch, and mirrored
    children whose parent was not mirrored but whose parent's flipped name is among ``patches``."""
    replaced = set(new.values())
    kept = {c: link for c, link in base.links.items() if c not in replaced}
    links = {c: link for c, link in kept.items() if link.parent not in replaced}
    relink = [(c, link.parent) for c, link in kept.items() if link.parent in replaced]
    for name in new:
        link = contacts.links.get(name)
        if link is None:
            continue
        if link.parent in new:
            links[new[name]] = Link(new[link.parent], link.length, np.conj(link.leave), np.conj(link.arrive))
        elif rename(link.parent) in patches:
            relink.append((new[name], rename(link.parent)))
    return links, relink
