"""Signed distances: to a closed triangle mesh (exact), to a half-space and to a box (analytic).

Sign convention: negative inside, positive outside, zero on the surface.

:class:`MeshSDF` is the sign on top of :class:`geodesics.ClosestPoints` (each query's exact closest
point, face and feature: corner, edge or interior): the sign of the angle-weighted pseudonormal of the
closest feature, Bærentzen and Aanæs, *Signed distance computation using the angle weighted
pseudonormal*, IEEE TVCG 11(3), 2005, which is exact for closed, manifold, consistently oriented meshes
(what :class:`~geodesics.TriMesh` validates, plus no boundary). Meshes share one closest-point solver
(``ClosestPoints.of``), with :meth:`geodesics.SurfacePoints.nearest` too.

Ours rather than ``trimesh.proximity.signed_distance``, which is the independent oracle of the tests
(``tests/test_trimesh_oracle.py``): trimesh decides a point's region of a triangle and settles between
competing faces with absolute tolerances (1e-13 on dot products, 1e-8 on squared distances), so on a mug
in metres, a tenth of a millimetre from its surface, it can return a neighbouring face's point several
percent farther (the tests compare it on meshes scaled up until its tolerances vanish, and check that
ours are scale-invariant); it signs points whose closest point is on an edge or a vertex by ray-cast
containment and leaves points within 1e-8 of the surface unsigned, where the pseudonormal is exact.

:class:`NarrowBand` follows a point set that moves a little at a time (a solve's skin) within a band of a
surface, querying again only the points that may have come within it.

:class:`HalfSpace` and :class:`Box` are the table or ground of the retargeting paper's Eq. 6, with
gradients for the solver (Inigo Quilez's box distance).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from geodesics import ClosestPoints, TriMesh

from .errors import SolverError, check_count, describe_ids


def _points(x) -> np.ndarray:
    X = np.asarray(x, dtype=np.float64)
    if X.ndim == 1:
        X = X[None]
    if X.ndim != 2 or X.shape[1] != 3:
        raise SolverError(f"query points must have shape (k, 3), got {X.shape}")
    return X


class MeshSDF:
    """Exact signed distance to a closed triangle mesh.

    Parameters
    ----------
    mesh : TriMesh
        Closed (no boundary edges), outward oriented.

    Raises
    ------
    SolverError
        If the mesh has boundary edges (inside and outside are then undefined).
    """

    def __init__(self, mesh: TriMesh):
        open_edges = np.flatnonzero(mesh.twin < 0)
        if open_edges.size:
            faces = describe_ids(open_edges // 3)
            raise SolverError(f"signed distance needs a closed mesh; faces {faces} have boundary edges")
        self.mesh = mesh
        self._closest = ClosestPoints.of(mesh)
        n = mesh.face_normals
        self._edge_normals = (n[np.arange(3 * mesh.n_faces) // 3] + n[mesh.twin // 3]).reshape(-1, 3, 3)

    def __call__(self, points, max_distance: float = np.inf) -> np.ndarray:
        """(k,) signed distances of points (k, 3); see :meth:`query` for ``max_distance``."""
        return self.query(points, max_distance)[0]

    def evaluate(self, points, band: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """Signed distances (k,) and their gradients (k, 3) at points (k, 3), as :class:`HalfSpace` and
        :class:`Box` give them, so that a closed mesh can be what a hand keeps out of.

        The gradient is the unit vector from the closest point to the query (outwards inside as well
        as outside); on the surface, the closest face's normal. Points provably farther than ``band``
        from the surface get a positive lower bound on their distance and a zero gradient *whether
        they are inside or outside*: a penalty on penetration then acts within ``band`` of the surface
        only, which is what keeps it cheap (a hand mostly away from the object costs one nearest-
        neighbour query per vertex). Outside the mesh's bounding box, the distance to the box is the
        bound (:meth:`query` with ``max_distance = 0``), and the gradient zero. The default band is
        infinite: exact signs everywhere.
        """
        X = _points(points)
        signed, closest, face = self.query(X, 0.0, band)
        gradient = np.zeros_like(X)
        exact = face >= 0
        off = exact & (signed != 0)
        gradient[off] = (X[off] - closest[off]) / signed[off, None]
        on = exact & (signed == 0)
        gradient[on] = self.mesh.face_normals[face[on]]
        return signed, gradient

    def query(
        self, points, max_distance: float = np.inf, band: float = np.inf
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Signed distances (k,), closest points (k, 3) and their faces (k,) for points (k, 3).

        Parameters
        ----------
        points : (k, 3) array_like
        max_distance : float
            Points outside the mesh's bounding box and provably farther than this from the surface get
            a positive lower bound on their distance, greater than ``max_distance``, instead of the
            exact value (their closest point is then NaN and their face -1).
        band : float
            The same for every point, inside the box too: a point provably farther than ``band`` from
            the surface gets a positive lower bound, greater than ``band``, *whether it is inside or
            outside*. The defaults compute every distance exactly.
        """
        X = _points(points)
        if not np.all(np.isfinite(X)):
            raise SolverError("query points must be finite")
        solver = self._closest
        gap = solver.box_gap(X)  # > 0 outside the box, hence outside the mesh
        found = solver.query(X, np.where(gap > 0, min(max_distance, band), band), box_gap=gap)
        signed = found.distances
        exact = np.flatnonzero(found.faces >= 0)
        if exact.size:
            signed[exact] *= self._signs(
                X[exact], found.points[exact], found.faces[exact], found.features[exact]
            )
        return signed, found.points, found.faces

    def _signs(self, X: np.ndarray, closest: np.ndarray, face: np.ndarray, feature: np.ndarray) -> np.ndarray:
        """(j,) -1 or +1 for points X (j, 3) whose closest points (j, 3) are on features (j,) of faces
        (j,): the side of the feature's angle-weighted pseudonormal they are on (+1 on the surface)."""
        normal = self.mesh.face_normals[face].copy()
        on_vertex = feature < 3
        normal[on_vertex] = self.mesh.vertex_normals[self.mesh.faces[face[on_vertex], feature[on_vertex]]]
        on_edge = (feature >= 3) & (feature < 6)
        normal[on_edge] = self._edge_normals[face[on_edge], feature[on_edge] - 3]
        return np.where(np.einsum("kj,kj->k", X - closest, normal) < 0, -1.0, 1.0)


#: Steps along each side of the triangular grid :func:`deepest_in_faces` samples a face on: 8 gives 45
#: points a face, its corners and edge midpoints included.
FACE_STEPS = 8


def deepest_in_faces(solid, vertices, faces, steps: int = FACE_STEPS) -> float:
    """How deep the deepest sampled point of a triangle mesh's faces is inside a solid (0 when none is).

    A solve keeps vertices out (:class:`~solver.ContactIK`'s keep-out term sees vertices), but between
    them a face can cut a sharp edge of the solid, a mug's rim, deeper than any vertex is: this measures
    the faces themselves, on a triangular grid of ``steps`` steps a side.

    Parameters
    ----------
    solid : MeshSDF, Box or HalfSpace
        Anything with ``evaluate(points (k, 3)) -> (signed distances (k,), gradients (k, 3))``, negative
        inside, a true distance (1-Lipschitz), as all three are.
    vertices : (n, 3) array_like
        The mesh's vertex positions, in the solid's space.
    faces : (m, 3) int array_like
        Its triangles, as vertex indices.
    steps : int
        Grid steps along each side of a face: ``(steps + 1)(steps + 2) / 2`` points a face.

    Returns
    -------
    float
        The largest depth among the sampled points, >= 0; exact where the deepest point of the faces is
        a grid point (a vertex, an edge's midpoint for even ``steps``), else within a grid step of it.
        Only faces that can reach inside are sampled: no point of a face is farther from its corners
        than its longest edge, so a face whose corners are all farther out than that is left out.
    """
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces)
    if V.ndim != 2 or V.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3:
        raise SolverError(f"vertices must have shape (n, 3) and faces (m, 3), got {V.shape} and {F.shape}")
    check_count(steps, "steps")
    if F.size == 0:
        return 0.0
    at_vertices = solid.evaluate(V)[0]
    corners = V[F]  # (m, 3, 3)
    longest = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(1)
    near = np.flatnonzero(at_vertices[F].min(1) < longest)
    deepest = max(0.0, -float(at_vertices.min()))
    if near.size:
        i, j = np.meshgrid(np.arange(steps + 1), np.arange(steps + 1), indexing="ij")
        keep = i + j <= steps
        bary = np.stack([i[keep], j[keep], steps - i[keep] - j[keep]], 1) / steps  # (s, 3)
        samples = np.einsum("sc,fcd->fsd", bary, corners[near]).reshape(-1, 3)
        deepest = max(deepest, -float(solid.evaluate(samples)[0].min()))
    return deepest


class NarrowBand:
    """Signed distances of a point set evaluated again and again as it moves (a solve's skin), for a
    penalty of penetration: exact where a point is inside within ``band`` of the surface, else a
    positive lower bound with a zero gradient (beyond the band on either side, as
    ``solid.evaluate(points, band)`` gives where it proves a point that far; a point deeper inside than
    the band counts as beyond it too, so that what the penalty sees depends on the points alone), querying
    only the points that may now be inside within the band.

    A signed distance changes by at most the distance a point moves (it is 1-Lipschitz), so a point last
    found ``|sd|`` from the surface and moved by ``m`` since is still beyond the band when
    ``|sd| - m > band``, and one last found outside at ``sd > 0`` is still outside when ``sd - m > 0``:
    either gets that difference, positive, without a query. Skin resting just off the object, most of
    what lies within the band of a grasp, is then queried only when it has moved as far as it was off.

    Parameters
    ----------
    solid : MeshSDF or any object with ``evaluate(points, band) -> (sd, gradient)``; with an infinite
        band, anything with ``evaluate(points)`` (a :class:`Box`, a :class:`HalfSpace`)
    band : float
    """

    def __init__(self, solid, band: float):
        self.solid = solid
        self.band = float(band)
        self._points: np.ndarray | None = None  # where each point was last queried
        self._signed: np.ndarray | None = None  # and what it got there

    def evaluate(self, points) -> tuple[np.ndarray, np.ndarray]:
        """Signed distances (k,) and gradients (k, 3) at points (k, 3), the same k points (in the same
        order) at each call."""
        X = _points(points)
        if self._points is None or self._points.shape != X.shape:
            self._points, self._signed = X.copy(), np.zeros(len(X))  # 0: every point is queried
        step = X - self._points
        moved = np.sqrt(np.einsum("ki,ki->k", step, step))
        last = self._signed
        beyond = np.abs(last) - moved
        outside = np.where((last > 0) & (last <= self.band), last - moved, -np.inf)
        signed = np.where(beyond > self.band, beyond, outside)
        gradient = np.zeros_like(X)
        near = np.flatnonzero((beyond <= self.band) & (outside <= 0))
        if near.size:
            if np.isfinite(self.band):
                sd, g = self.solid.evaluate(X[near], self.band)
            else:  # exact at every depth: no band to pass
                sd, g = self.solid.evaluate(X[near])
            within = sd >= -self.band
            signed[near] = np.where(within, sd, -sd)
            gradient[near] = np.where(within[:, None], g, 0.0)
            self._points[near] = X[near]
            self._signed[near] = sd
        return signed, gradient


@dataclass(frozen=True)
class HalfSpace:
    """The solid ``(x - point) . normal <= 0`` (a table top or the ground, its free side along normal)."""

    point: np.ndarray = field(default_factory=lambda: np.zeros(3))
    normal: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))

    def __post_init__(self):
        p = np.asarray(self.point, dtype=np.float64).reshape(-1)
        n = np.asarray(self.normal, dtype=np.float64).reshape(-1)
        if p.size != 3 or n.size != 3 or not (np.all(np.isfinite(p)) and np.all(np.isfinite(n))):
            raise SolverError("a half-space needs a finite point (3,) and normal (3,)")
        length = np.linalg.norm(n)
        if length == 0:
            raise SolverError("a half-space needs a nonzero normal")
        object.__setattr__(self, "point", p)
        object.__setattr__(self, "normal", n / length)

    def evaluate(self, x) -> tuple[np.ndarray, np.ndarray]:
        """Signed distances (k,) and their gradients (k, 3) at points (k, 3)."""
        X = _points(x)
        return (X - self.point) @ self.normal, np.broadcast_to(self.normal, X.shape)


@dataclass(frozen=True)
class Box:
    """A solid box (a table): centre (3,), half extents (3,), rotation (3, 3) from box to world axes."""

    center: np.ndarray
    half_extents: np.ndarray
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self):
        c = np.asarray(self.center, dtype=np.float64).reshape(-1)
        h = np.asarray(self.half_extents, dtype=np.float64).reshape(-1)
        R = np.asarray(self.rotation, dtype=np.float64)
        if c.size != 3 or h.size != 3 or R.shape != (3, 3):
            raise SolverError("a box needs a centre (3,), half extents (3,) and a rotation (3, 3)")
        if not (
            np.all(np.isfinite(c)) and np.all(np.isfinite(R)) and np.all(h > 0) and np.all(np.isfinite(h))
        ):
            raise SolverError("a box needs a finite centre and rotation and positive finite half extents")
        if np.abs(R.T @ R - np.eye(3)).max() > 1e-9 or np.linalg.det(R) <= 0:
            raise SolverError("a box's rotation must be a rotation matrix")
        object.__setattr__(self, "center", c)
        object.__setattr__(self, "half_extents", h)
        object.__setattr__(self, "rotation", R)

    def evaluate(self, x) -> tuple[np.ndarray, np.ndarray]:
        """Signed distances (k,) and their gradients (k, 3) at points (k, 3)."""
        local = (_points(x) - self.center) @ self.rotation
        sign = np.where(local < 0, -1.0, 1.0)
        q = np.abs(local) - self.half_extents
        outside = np.maximum(q, 0.0)
        out_len = np.linalg.norm(outside, axis=1)
        inside = np.minimum(q.max(1), 0.0)
        grad_local = np.divide(outside, out_len[:, None], out=np.zeros_like(q), where=out_len[:, None] > 0)
        deepest = np.argmax(q, axis=1)
        interior = out_len == 0
        grad_local[interior] = 0.0
        grad_local[interior, deepest[interior]] = 1.0
        return out_len + inside, (grad_local * sign) @ self.rotation.T
