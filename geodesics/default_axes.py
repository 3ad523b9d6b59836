"""Default axes for a freshly painted patch, the two methods of Contact Edit §6.2.

* :func:`farthest_pair_axis` — the geodesic between the patch's two farthest points.
* :func:`medial_axis` — an approximate (smoothed) medial axis: the heat-method distance from the patch
  boundary, the vertices where its gradient turns by more than π/2 between the faces around them,
  joined greedily in order of Dijkstra distance.

And one for patches whose shape does not say which way they run: :func:`directed_axis`, along a
direction given (on a hand, the bone under the patch: a round fingertip pad's axis then runs along the
finger, where its farthest pair lies anywhere around its rim).
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from .axis import Axis
from .errors import ContactError
from .exact import GeodesicField
from .mesh import TriMesh, per_mesh
from .points import SurfacePoints

#: Patch points (farthest from the first sweep's end) swept from when searching the farthest pair.
CANDIDATES = 8
#: Patch points, the farthest from an end by the edge-graph estimate, whose exact distances decide the
#: other end.
SHORTLIST = 16
#: The heat method's time step for the medial axis, as a multiple of the mean edge length squared (the
#: heat method's own default is 1). At 4 the distance is smoothed over about two edge lengths, the
#: chain's spacing: enough that a patch's corners (where the gradient turns by π/2 exactly) leave no
#: spurs, little enough that an elongated patch keeps most of its axis.
MEDIAL_SMOOTHING = 2.0


def farthest_pair_axis(mesh: TriMesh, points: SurfacePoints) -> Axis:
    """Axis along the shortest geodesic between the two farthest patch points.

    The search runs on an estimate, then exact distances decide between the few points it leaves:

    * Estimate: shortest paths along the mesh edges, with each patch point joined to its face's
      corners by straight lines (:func:`_graph_sweeps`, one C Dijkstra per sweep). Sweeps from an
      arbitrary point, from the farthest point a from it, and from the ``CANDIDATES`` points farthest
      from a give the estimated farthest pair (i, j).
    * Exact: the exact distances (:class:`GeodesicField`) from i to the ``SHORTLIST`` points the
      estimate puts farthest from i pick the far end j; those from j to its own shortlist pick i again.

    Two exact fields (the second also gives the path), where an all-exact search needs ten. Diameter
    endpoints of convex-ish patches are found exactly (the estimate's error is nearly the same along
    nearly parallel paths, so it keeps their order); for odd shapes the pair is near-diametral.
    """
    if len(points) < 2:
        raise ContactError(f"a default axis needs at least two patch points, got {len(points)}")
    sweep = _graph_sweeps(mesh, points)
    from_first = sweep([0])[0]
    a = int(np.argmax(from_first))
    # Every two patch points are at most twice that far apart (through point 0): the other sweeps stop
    # there instead of covering the whole mesh.
    limit = 2 * from_first[a] * (1 + 1e-9)
    from_a = sweep([a], limit)[0]
    sources = np.unique(np.r_[a, np.argsort(from_a)[-CANDIDATES:]])
    estimate = sweep(sources, limit)
    row, far = np.unravel_index(int(np.argmax(estimate)), estimate.shape)
    if estimate[row, far] == 0:
        raise ContactError("all patch points coincide; paint a larger area or pick an axis by hand")
    end = _exactly_farthest(mesh, points, int(sources[row]), estimate[row])[0]
    start, field = _exactly_farthest(mesh, points, end, sweep([end], limit)[0])
    back = Axis.along(mesh, field.path(points[[start]]))  # from the end: its field is there already
    return Axis(mesh, back.points[np.arange(len(back))[::-1]])


def _exactly_farthest(
    mesh: TriMesh, points: SurfacePoints, i: int, estimate: np.ndarray
) -> tuple[int, GeodesicField]:
    """The point, of the :data:`SHORTLIST` farthest from point i by the ``estimate`` (k,) of distances
    from it, that is farthest from it exactly; and the exact field from point i."""
    shortlist = np.argsort(estimate)[-SHORTLIST:]
    field = GeodesicField(mesh, points[[i]], points[shortlist])
    return int(shortlist[np.argmax(field.query(points[shortlist]).distances)]), field


def _graph_sweeps(mesh: TriMesh, points: SurfacePoints):
    """``sweep(sources, limit=inf)``: the (s, k) shortest-path lengths from the patch points ``sources``
    (s,) to all k patch points over the mesh edges plus straight lines from each patch point to its
    face's corners: an upper bound on the geodesic distance, whose relative error does not shrink with
    the resolution (it is the edges' zigzag). One C Dijkstra a source, which goes no farther than
    ``limit`` (inf beyond it)."""
    n, k = mesh.n_vertices, len(points)
    corners = mesh.faces[points.faces]  # (k, 3)
    spokes = np.linalg.norm(mesh.vertices[corners] - points.positions(mesh)[:, None], axis=2)
    edges = _edge_graph(mesh)
    rows = np.r_[edges.row, np.repeat(n + np.arange(k), 3)]
    cols = np.r_[edges.col, corners.ravel()]
    weights = np.r_[edges.data, np.maximum(spokes.ravel(), 1e-300)]  # a zero weight would drop the edge
    graph = coo_matrix((weights, (rows, cols)), shape=(n + k, n + k)).tocsr()

    def sweep(sources, limit: float = np.inf) -> np.ndarray:
        return dijkstra(graph, directed=False, indices=n + np.asarray(sources, np.int64), limit=limit)[:, n:]

    return sweep


@per_mesh
def _edge_graph(mesh: TriMesh) -> coo_matrix:
    """The mesh's edges once each, weighted by their lengths."""
    h = np.flatnonzero((mesh.twin < 0) | (np.arange(3 * mesh.n_faces) < mesh.twin))
    tail, head = mesh.halfedge_tail[h], mesh.halfedge_tail[mesh.halfedge_next[h]]
    return coo_matrix((mesh.halfedge_lengths[h], (tail, head)), shape=(mesh.n_vertices, mesh.n_vertices))


def directed_axis(mesh: TriMesh, points: SurfacePoints, direction) -> Axis:
    """Axis along ``direction`` (3,) down the patch's middle: ``direction`` is taken in the patch's mean
    tangent plane, and the axis is the shortest geodesic between the surface points nearest the two ends
    of the patch's extent along it through its centroid, from the end it points away from to the one it
    points to.

    Raises ContactError for a direction that is not finite and non-zero or along the patch's normal, or
    a patch with no extent along it.
    """
    direction = np.asarray(direction, float)
    if direction.shape != (3,) or not np.all(np.isfinite(direction)) or not np.any(direction):
        raise ContactError(f"an axis direction must be a finite, non-zero 3-vector, got {direction.tolist()}")
    if len(points) < 2:
        raise ContactError(f"a default axis needs at least two patch points, got {len(points)}")
    normal = mesh.face_normals[points.faces].sum(axis=0)
    normal /= np.linalg.norm(normal)
    tangent = direction / np.linalg.norm(direction)
    tangent = tangent - (tangent @ normal) * normal
    if np.linalg.norm(tangent) < 1e-6:
        raise ContactError("the axis direction is the patch's normal; pick an axis by hand")
    tangent /= np.linalg.norm(tangent)
    X = points.positions(mesh)
    centroid = X.mean(axis=0)
    along = (X - centroid) @ tangent
    if along.max() <= along.min():
        raise ContactError("the patch has no extent along the axis direction; pick an axis by hand")
    ends = SurfacePoints.nearest(mesh, centroid + np.outer([along.min(), along.max()], tangent))
    return Axis.between(mesh, ends[[0]], ends[[1]])


def medial_axis(mesh: TriMesh, points: SurfacePoints, spacing: float | None = None) -> Axis:
    """Axis through the patch's smoothed medial axis (§6.2); falls back to :func:`farthest_pair_axis`
    when the patch is too small to have one (under four faces, or no interior vertex).

    The heat-method distance u from the patch boundary is smoothed, so a round patch's medial axis is
    short (a disc's is its centre) and an elongated one's runs along its middle.

    Parameters
    ----------
    spacing : float, optional
        Minimum distance between consecutive axis points along the chain (default: two mean edge
        lengths); the chain's two ends are always kept.
    """
    import potpourri3d

    region = _region_faces(mesh, points)
    if region.size < 4:
        return farthest_pair_axis(mesh, points)
    used, local = np.unique(mesh.faces[region], return_inverse=True)
    local = local.reshape(-1, 3)
    boundary = _boundary_vertices(local)
    if boundary.size == 0 or boundary.size == used.size:
        return farthest_pair_axis(mesh, points)
    solver = potpourri3d.MeshHeatMethodDistanceSolver(mesh.vertices[used], local, t_coef=MEDIAL_SMOOTHING)
    u = solver.compute_distance_multisource(boundary)
    medial = np.setdiff1d(_turning_vertices(mesh, region, local, u[local]), boundary)
    chain = _greedy_chain(mesh.vertices[used], local, medial, spacing or 2 * mesh.mean_edge_length)
    if len(chain) < 2:
        return farthest_pair_axis(mesh, points)
    return Axis(mesh, SurfacePoints.from_vertices(mesh, used[chain]))


def _region_faces(mesh: TriMesh, points: SurfacePoints) -> np.ndarray:
    """Faces the patch covers: those holding a patch point inside them, and those whose three corners are
    all patch vertices (for patches painted by selecting vertices)."""
    inside = points.faces[points.vertex_ids(mesh) < 0]
    selected = np.zeros(mesh.n_vertices, bool)
    selected[points.vertex_ids(mesh)[points.vertex_ids(mesh) >= 0]] = True
    full = np.flatnonzero(selected[mesh.faces].all(axis=1))
    return np.union1d(inside, full)


def _boundary_vertices(F: np.ndarray) -> np.ndarray:
    """Vertices on edges used by only one face of F."""
    edges = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    unique, count = np.unique(edges, axis=0, return_counts=True)
    return np.unique(unique[count == 1])


def _turning_vertices(mesh: TriMesh, region: np.ndarray, local: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Local vertices where the gradient of u turns by more than π/2: those shared by two region faces
    whose gradients point more than π/2 apart.

    ``local`` (r, 3) holds the region faces' corners as local vertex ids, ``u`` (r, 3) the distance
    there. Faces around a vertex, not only across an edge, are compared: the ridge of u usually runs
    through faces, where neighbours across one edge each see half the turn.
    """
    P = mesh.face_points[region]
    twice_area = (np.conj(P[:, 1] - P[:, 0]) * (P[:, 2] - P[:, 0])).imag
    grad_b = 1j * (np.roll(P, -2, axis=1) - np.roll(P, -1, axis=1)) / twice_area[:, None]
    grad = (u * grad_b).sum(1)  # the gradient of u in each region face's frame
    axes = mesh.face_axes(region)
    grad = grad.real[:, None] * axes[:, 0] + grad.imag[:, None] * axes[:, 1]  # (r, 3), in 3D
    r = region.size
    incidence = coo_matrix((np.ones(3 * r), (local.ravel(), np.repeat(np.arange(r), 3)))).tocsr()
    pairs = (incidence.T @ incidence).tocoo()  # faces sharing at least one vertex
    f, g = pairs.row, pairs.col
    turning = (f < g) & (np.einsum("ij,ij->i", grad[f], grad[g]) < 0)
    Ff, Fg = local[f[turning]], local[g[turning]]
    return np.unique(Ff[(Ff[:, :, None] == Fg[:, None, :]).any(2)])


def _greedy_chain(V: np.ndarray, local: np.ndarray, medial: np.ndarray, spacing: float) -> np.ndarray:
    """Order the ``medial`` local vertices into a chain, as Dijkstra distances over the region's edges
    (vertices ``V``, faces ``local``) say: start at one end of their farthest pair, then repeatedly visit
    the unvisited point nearest the last kept one, keeping it if it is at least ``spacing`` away (so the
    points near each kept one are used up, and the chain does not double back along a wide band). The
    last point visited is always kept, as the chain's far end."""
    if medial.size < 2:
        return medial
    edges = np.concatenate([local[:, [0, 1]], local[:, [1, 2]], local[:, [2, 0]]])
    w = np.linalg.norm(V[edges[:, 0]] - V[edges[:, 1]], axis=1)
    graph = coo_matrix((w, (edges[:, 0], edges[:, 1])), shape=(len(V), len(V))).tocsr()
    between = dijkstra(graph, directed=False, indices=medial)[:, medial]
    kept = [int(np.argmax(between.max(1)))]
    unvisited = np.ones(medial.size, bool)
    unvisited[kept[0]] = False
    last = kept[0]
    while unvisited.any():
        candidates = np.where(unvisited, between[kept[-1]], np.inf)
        last = int(np.argmin(candidates))
        if not np.isfinite(candidates[last]):
            break
        unvisited[last] = False
        if candidates[last] >= spacing:
            kept.append(last)
    if kept[-1] != last:
        kept.append(last)
    return medial[np.array(kept)]
