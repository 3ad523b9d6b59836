"""Default axes for a freshly painted patch, the two methods of Contact Edit §6.2.

* :func:`farthest_pair_axis` — the geodesic between the patch's two farthest points.
* :func:`medial_axis` — an approximate (smoothed) medial axis: the heat-method distance from the patch
  boundary, points where its gradient turns by more than π/2 between neighbouring faces, joined greedily
  in order of Dijkstra distance.
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
    a = int(np.argmax(sweep([0])[0]))
    from_a = sweep([a])[0]
    sources = np.unique(np.r_[a, np.argsort(from_a)[-CANDIDATES:]])
    estimate = sweep(sources)
    row, far = np.unravel_index(int(np.argmax(estimate)), estimate.shape)
    if estimate[row, far] == 0:
        raise ContactError("all patch points coincide; paint a larger area or pick an axis by hand")
    end = _exactly_farthest(mesh, points, int(sources[row]), estimate[row])[0]
    start, field = _exactly_farthest(mesh, points, end, sweep([end])[0])
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
    """``sweep(sources)``: the (s, k) shortest-path lengths from the patch points ``sources`` (s,) to all k
    patch points over the mesh edges plus straight lines from each patch point to its face's corners:
    an upper bound on the geodesic distance (8 % over it in the median on a jittered grid, whatever the
    resolution: the error is the edges' zigzag). One C Dijkstra a sweep."""
    n, k = mesh.n_vertices, len(points)
    corners = mesh.faces[points.faces]  # (k, 3)
    spokes = np.linalg.norm(mesh.vertices[corners] - points.positions(mesh)[:, None], axis=2)
    edges = _edge_graph(mesh)
    rows = np.r_[edges.row, np.repeat(n + np.arange(k), 3)]
    cols = np.r_[edges.col, corners.ravel()]
    weights = np.r_[edges.data, np.maximum(spokes.ravel(), 1e-300)]  # a zero weight would drop the edge
    graph = coo_matrix((weights, (rows, cols)), shape=(n + k, n + k)).tocsr()

    def sweep(sources) -> np.ndarray:
        return dijkstra(graph, directed=False, indices=n + np.asarray(sources, np.int64))[:, n:]

    return sweep


@per_mesh
def _edge_graph(mesh: TriMesh) -> coo_matrix:
    """The mesh's edges once each, weighted by their lengths."""
    h = np.flatnonzero((mesh.twin < 0) | (np.arange(3 * mesh.n_faces) < mesh.twin))
    tail, head = mesh.halfedge_tail[h], mesh.halfedge_tail[mesh.halfedge_next[h]]
    return coo_matrix((mesh.halfedge_lengths[h], (tail, head)), shape=(mesh.n_vertices, mesh.n_vertices))


def medial_axis(mesh: TriMesh, points: SurfacePoints, spacing: float | None = None) -> Axis:
    """Axis through the patch's smoothed medial axis (§6.2); falls back to :func:`farthest_pair_axis`
    when the patch is too thin or small to have one.

    Parameters
    ----------
    spacing : float, optional
        Minimum distance between consecutive axis points along the chain (default: two mean edge lengths).
    """
    import potpourri3d

    region = _region_faces(mesh, points)
    if region.size < 4:
        return farthest_pair_axis(mesh, points)
    F = mesh.faces[region]
    used, local = np.unique(F, return_inverse=True)
    local = local.reshape(-1, 3)
    boundary = _boundary_vertices(local)
    if boundary.size == 0 or boundary.size == used.size:
        return farthest_pair_axis(mesh, points)
    solver = potpourri3d.MeshHeatMethodDistanceSolver(mesh.vertices[used], local)
    u = solver.compute_distance_multisource(boundary)
    medial = _turning_edges(mesh, region, u[local])
    if medial.size < 2:
        return farthest_pair_axis(mesh, points)
    chain = _greedy_chain(mesh, used, local, medial, spacing or 2 * mesh.mean_edge_length)
    if len(chain) < 2:
        return farthest_pair_axis(mesh, points)
    k = chain % 3
    bary = np.zeros((chain.size, 3))
    bary[np.arange(chain.size), k] = 0.5
    bary[np.arange(chain.size), (k + 1) % 3] = 0.5
    return Axis(mesh, SurfacePoints(chain // 3, bary))


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


def _turning_edges(mesh: TriMesh, region: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Halfedges between two region faces across which the distance gradient turns by more than π/2.

    ``u`` (r, 3) holds the distance at each region face's corners.
    """
    P = mesh.face_points[region]
    twice_area = (np.conj(P[:, 1] - P[:, 0]) * (P[:, 2] - P[:, 0])).imag
    grad_b = 1j * (np.roll(P, -2, axis=1) - np.roll(P, -1, axis=1)) / twice_area[:, None]
    grad = (u * grad_b).sum(1)  # the gradient of u in each region face's frame
    in_region = np.full(mesh.n_faces, -1)
    in_region[region] = np.arange(region.size)
    h = (3 * region[:, None] + np.arange(3)).ravel()
    t = mesh.twin[h]
    other = np.where(t >= 0, in_region[np.maximum(t, 0) // 3], -1)
    interior = (other >= 0) & (h < t)  # each edge between two region faces, once
    here = grad[np.repeat(np.arange(region.size), 3)[interior]]
    there = grad[other[interior]] / mesh.halfedge_rotation[h[interior]]  # into this face's frame
    return h[interior][(np.conj(here) * there).real < 0]


def _greedy_chain(mesh, used, local, halfedges, spacing) -> np.ndarray:
    """Order medial edge midpoints into a chain: start at one end of the farthest pair (Dijkstra distance
    over the region's edges), then repeatedly step to the nearest unvisited one, keeping points at least
    ``spacing`` apart."""
    V = mesh.vertices[used]
    edges = np.concatenate([local[:, [0, 1]], local[:, [1, 2]], local[:, [2, 0]]])
    w = np.linalg.norm(V[edges[:, 0]] - V[edges[:, 1]], axis=1)
    n = used.size
    graph = coo_matrix((w, (edges[:, 0], edges[:, 1])), shape=(n, n)).tocsr()
    where = np.searchsorted(used, mesh.halfedge_tail[halfedges])  # each midpoint's nearest corner
    d = dijkstra(graph, directed=False, indices=np.unique(where))
    index = np.searchsorted(np.unique(where), where)
    between = d[index][:, where]
    start = int(np.argmax(between.max(1)))
    order = [start]
    unvisited = np.ones(halfedges.size, bool)
    unvisited[start] = False
    while unvisited.any():
        cand = np.where(unvisited, between[order[-1]], np.inf)
        nxt = int(np.argmin(cand))
        if not np.isfinite(cand[nxt]):
            break
        unvisited[nxt] = False
        if between[order[-1], nxt] >= spacing:
            order.append(nxt)
    return halfedges[np.array(order)]
