"""Evaluation metrics of a retargeted motion (§4.2 of Kinematic Motion Retargeting) and their plots.

**Distance metrics** (Fig. 11): per frame, the mean Euclidean distance between posed target-hand marker
points and their source markers, and between posed hand contact points and their object contacts
(:func:`mean_distances`, on flattened per-frame point lists with frame offsets).

**Intersection metrics** (Fig. 12), as §4.2 defines them: (1) find the penetrating hand vertices; (2)
cluster them by depth-first search on the hand mesh, i.e. into connected components of the subgraph of
mesh edges whose two ends both penetrate (:func:`vertex_clusters`); (3) take the convex hull of each
cluster (``scipy.spatial.ConvexHull``; a cluster of fewer than four points or a flat one has volume 0)
and (4) sum the hull volumes, relative to the hand's volume, in percent (:func:`intersection_volume`).
The hand's volume is the signed volume of its closed posed mesh (divergence theorem,
:func:`mesh_volume`), frame by frame. The paper notes these are overestimates (hulls of curved clusters).
Three kinds, each clustered on its own:

* **hand-object**: hand vertices inside the object: the sign of the exact signed distance to the closed
  object mesh (:class:`solver.sdf.MeshSDF`, angle-weighted pseudonormals).
* **table**: hand vertices inside the table box (its analytic SDF, :class:`solver.sdf.Box`).
* **self**: hand vertices inside the hand itself (:func:`self_penetrating`). A vertex v lies on the
  surface, so "inside" must leave out v's own sheet. Definition: v penetrates the hand if the point just
  outside v's own surface, ``v + ε n_v`` for an infinitesimal ε (n_v the area-weighted posed vertex
  normal), is enclosed by the posed hand surface: its winding number is nonzero (at least 1; it is 2
  where two overlapping parts enclose it, which a parity rule would miss). The winding number comes from
  the signed crossings of a ray (+1 leaving through a face, -1 entering). We cast the ray from v itself,
  leaving v's sheet outwards, and do not count the faces of v's one ring (they meet the ray at v,
  t = 0): exactly the crossings of a ray from ``v + ε n_v``, unless the
  surface folds back within the one ring (a crease sharper than the ray's angle to it, which is at least
  35°, see below). A finger pushed through the palm then has its tip's vertices inside the palm (and
  the palm's vertices there inside the finger); a hand that does not intersect itself has none.

**Ray casting, vectorized.** Rays run along three fixed, generic (not axis-aligned) orthogonal directions;
each vertex uses the one most aligned with its normal (at least 1/√3, i.e. 35° off the tangent plane),
signed to leave the surface outwards. For one direction, every triangle and query point is projected
onto the orthogonal plane; a uniform grid over that plane pairs each query with the triangles whose
bounding boxes cover its cell (all in numpy: no per-point loop), and an exact 2D point-in-triangle test
decides crossings. Edge functions are computed once per edge in a canonical vertex order and ties
(a ray through an edge or vertex) are broken by one symbolic perturbation of the query point, so two
triangles sharing an edge never both or neither count a crossing through it where the surface passes
(and count both, with opposite signs, or neither where it folds): the winding number is exact.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull, QhullError

from geodesics import TriMesh
from geodesics.arrays import ranges
from geodesics.files import atomic_file

from ..errors import SolverError
from ..sdf import Box, MeshSDF

__all__ = [
    "FrameIntersections",
    "IntersectionMeter",
    "Intersections",
    "cluster_volumes",
    "intersection_volume",
    "mean_distances",
    "mesh_volume",
    "plot_metrics",
    "ray_winding",
    "self_penetrating",
    "vertex_clusters",
]

#: Three generic orthonormal ray directions (rows): a fixed rotation of the coordinate axes, so that
#: axis-aligned geometry (boxes, grids) never lines up with a ray.
RAY_DIRECTIONS = np.linalg.qr(np.array([[0.83, -0.31, 0.47], [0.29, 0.91, -0.21], [-0.48, 0.17, 0.86]]))[0].T
#: Grid cells are this many median triangle extents wide.
CELL_FACTOR = 1.0


# ------------------------------------------------------------------------------------ distances


def mean_distances(positions, targets, offsets) -> np.ndarray:
    """(F,) mean distance between paired points, frame by frame; NaN for frames without points.

    Parameters
    ----------
    positions, targets : (K, 3) array_like
        Paired points of all frames, flattened: frame f's are rows ``offsets[f]:offsets[f+1]``.
    offsets : (F + 1,) array_like of int
        Non-decreasing, ``offsets[0] == 0`` and ``offsets[-1] == K``.
    """
    P = np.asarray(positions, dtype=np.float64)
    T = np.asarray(targets, dtype=np.float64)
    o = np.asarray(offsets, dtype=np.int64).reshape(-1)
    if P.ndim != 2 or P.shape[1:] != (3,) or T.shape != P.shape:
        raise SolverError(f"positions and targets must both have shape (K, 3), got {P.shape} and {T.shape}")
    if o.size < 1 or o[0] != 0 or o[-1] != len(P) or np.any(np.diff(o) < 0):
        raise SolverError(f"offsets must rise from 0 to the number of points ({len(P)}) without decreasing")
    counts = np.diff(o)
    frame = np.repeat(np.arange(counts.size), counts)
    sums = np.bincount(frame, np.linalg.norm(P - T, axis=1), minlength=counts.size)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(counts > 0, sums / counts, np.nan)


# ------------------------------------------------------------------------------------ volumes


def mesh_volume(vertices, faces) -> np.ndarray | float:
    """Signed volume of a closed, outward-oriented mesh: ``Σ det(a, b, c) / 6`` over its faces.

    ``vertices`` may be (n, 3) (a float is returned) or (F, n, 3) (one volume per frame, (F,));
    ``faces`` are (m, 3).
    """
    V = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    a, b, c = V[..., f[:, 0], :], V[..., f[:, 1], :], V[..., f[:, 2], :]
    vol = np.einsum("...k,...k->...", a, np.cross(b, c)).sum(-1) / 6.0
    return float(vol) if V.ndim == 2 else vol


def vertex_clusters(faces, n_vertices: int, penetrating) -> np.ndarray:
    """(n,) cluster label of each vertex flagged in ``penetrating`` (n,) bool (0, 1, ...), -1 for the
    others; ``faces`` (m, 3) are the mesh's, n = ``n_vertices``.

    Clusters are the connected components of the mesh-edge graph restricted to penetrating vertices
    (the paper's depth-first search on the hand mesh).
    """
    f = np.asarray(faces, dtype=np.int64)
    pen = np.asarray(penetrating, dtype=bool).reshape(-1)
    if pen.size != n_vertices:
        raise SolverError(f"penetrating needs {n_vertices} flags (one per vertex), got {pen.size}")
    i = f.ravel()
    j = f[:, [1, 2, 0]].ravel()
    both = pen[i] & pen[j]
    graph = coo_matrix((np.ones(both.sum()), (i[both], j[both])), shape=(n_vertices, n_vertices))
    _, comp = connected_components(graph, directed=False)
    labels = np.full(n_vertices, -1, np.int64)
    if pen.any():
        _, labels[pen] = np.unique(comp[pen], return_inverse=True)
    return labels


def cluster_volumes(vertices, labels) -> np.ndarray:
    """(c,) convex-hull volume of each cluster of points ``vertices`` (n, 3) by ``labels`` (n,) (0..c-1;
    -1: none, as :func:`vertex_clusters` gives); 0 for degenerate clusters."""
    V = np.asarray(vertices, dtype=np.float64)
    lab = np.asarray(labels, dtype=np.int64).reshape(-1)
    n = int(lab.max()) + 1 if lab.size else 0
    out = np.zeros(max(n, 0))
    if n <= 0:
        return out
    order = np.argsort(lab, kind="stable")
    order = order[lab[order] >= 0]
    bounds = np.searchsorted(lab[order], np.arange(n + 1))
    for k in np.flatnonzero(np.diff(bounds) >= 4):
        pts = V[order[bounds[k] : bounds[k + 1]]]
        try:
            out[k] = ConvexHull(pts).volume
        except QhullError:  # flat or otherwise degenerate: no volume
            out[k] = 0.0
    return out


def intersection_volume(vertices, faces, penetrating, hand_volume: float | None = None) -> float:
    """Intersection as §4.2 defines it: summed hull volume of penetrating clusters, % of the hand's volume.

    Parameters
    ----------
    vertices : (n, 3)
        The posed hand.
    faces : (m, 3)
    penetrating : (n,) bool
    hand_volume : float, optional
        Default: :func:`mesh_volume` of the posed hand.
    """
    V = np.asarray(vertices, dtype=np.float64)
    labels = vertex_clusters(faces, len(V), penetrating)
    if not (labels >= 0).any():
        return 0.0
    volume = mesh_volume(V, faces) if hand_volume is None else float(hand_volume)
    if not volume > 0:
        raise SolverError(f"the hand's volume must be positive (a closed, outward mesh), got {volume}")
    return float(100.0 * cluster_volumes(V, labels).sum() / volume)


# ------------------------------------------------------------------------------------ ray casting


def _vertex_normals(V: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(n, 3) area-weighted unit vertex normals of a posed mesh."""
    a, b, c = V[faces[:, 0]], V[faces[:, 1]], V[faces[:, 2]]
    cr = np.cross(b - a, c - a)
    idx = faces.ravel()
    N = np.stack([np.bincount(idx, np.repeat(cr[:, k], 3), minlength=len(V)) for k in range(3)], 1)
    norm = np.linalg.norm(N, axis=1, keepdims=True)
    return np.divide(N, norm, out=np.zeros_like(N), where=norm > 0)


def ray_winding(points, signs, direction_frame, vertices, faces, exclude=None) -> np.ndarray:
    """(q,) winding number of a closed mesh around each ray's start, from the crossings of that ray.

    Ray i starts at ``points[i]`` and runs along ``signs[i] * direction_frame[2]``; triangles are the
    mesh's ``faces`` on ``vertices``. Each crossing counts +1 where the ray leaves through a face (its
    normal along the ray) and -1 where it enters; for a closed, outward mesh the sum is the winding
    number of the start point (0 outside, 1 inside, 2 inside two overlapping parts, ...). Crossings
    are exact (see the module docstring); a crossing at the start point itself (t = 0) does not count.

    Parameters
    ----------
    points : (q, 3)
    signs : (q,) of ±1
    direction_frame : (3, 3)
        Orthonormal rows: two axes of the projection plane, then the ray direction.
    vertices : (n, 3)
    faces : (m, 3) int
    exclude : (q,) int, optional
        A vertex per ray whose incident faces are skipped (-1: none).
    """
    Q = np.asarray(points, dtype=np.float64)
    s = np.asarray(signs, dtype=np.float64).reshape(-1)
    R = np.asarray(direction_frame, dtype=np.float64)
    V = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    q = len(Q)
    ex = np.full(q, -1, np.int64) if exclude is None else np.asarray(exclude, dtype=np.int64).reshape(-1)
    out = np.zeros(q, np.int64)
    if q == 0 or len(f) == 0:
        return out
    W = V @ R.T  # (n, 3): plane coordinates and depth
    P2, zq = Q @ R[:2].T, Q @ R[2]
    T2 = W[f][:, :, :2]  # (m, 3, 2)
    e1, e2 = T2[:, 1] - T2[:, 0], T2[:, 2] - T2[:, 0]
    g = np.sign(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])  # NumPy 2 has no cross product of 2-D vectors
    live = np.flatnonzero(g != 0)

    # Uniform grid over the plane: pair each query with the triangles whose boxes cover its cell.
    box_lo, box_hi = T2.min(1), T2.max(1)
    lo, hi = box_lo[live], box_hi[live]
    cell = CELL_FACTOR * float(np.median((hi - lo).max(1)))
    if not cell > 0:
        cell = 1.0
    origin = np.minimum(lo.min(0), P2.min(0))
    ilo = np.floor((lo - origin) / cell).astype(np.int64)
    ihi = np.floor((hi - origin) / cell).astype(np.int64)
    iq = np.floor((P2 - origin) / cell).astype(np.int64)
    ny = int(max(ihi[:, 1].max(), iq[:, 1].max())) + 1
    span = ihi - ilo + 1
    tri_of, k = ranges(np.zeros(len(live), np.int64), span[:, 0] * span[:, 1])
    key = (ilo[tri_of, 0] + k // span[tri_of, 1]) * ny + ilo[tri_of, 1] + k % span[tri_of, 1]
    order = np.argsort(key, kind="stable")
    key, tri_sorted = key[order], live[tri_of[order]]
    qkey = iq[:, 0] * ny + iq[:, 1]
    start = np.searchsorted(key, qkey, "left")
    count = np.searchsorted(key, qkey, "right") - start
    qi, pos = ranges(start, count)
    ti = tri_sorted[pos]
    # Only queries within the triangle's box can be inside it (ties on the box edge stay in).
    blo, bhi = box_lo[ti], box_hi[ti]
    p = P2[qi]
    keep = np.all((p >= blo) & (p <= bhi), axis=1)
    qi, ti = qi[keep], ti[keep]
    corners = f[ti]  # (c, 3)
    keep = ~(corners == ex[qi, None]).any(1)
    qi, ti, corners = qi[keep], ti[keep], corners[keep]
    if qi.size == 0:
        return out

    # Edge k is opposite corner k, directed corner k+1 -> k+2; evaluated in canonical (low id first) order.
    p = P2[qi]
    a_id, b_id = corners[:, [1, 2, 0]], corners[:, [2, 0, 1]]
    flip = a_id > b_id
    lo_id, hi_id = np.where(flip, b_id, a_id), np.where(flip, a_id, b_id)
    W2 = np.ascontiguousarray(W[:, :2])
    Plo, Phi = W2[lo_id], W2[hi_id]
    dvec = Phi - Plo
    rel = p[:, None, :] - Plo
    e_hat = dvec[..., 0] * rel[..., 1] - dvec[..., 1] * rel[..., 0]
    # Ties: perturb the query by (ε, ε²): the sign of cross(d, δ).
    tie = np.where(dvec[..., 1] != 0, -np.sign(dvec[..., 1]), np.sign(dvec[..., 0]))
    e_eff = np.where(e_hat != 0, e_hat, tie)
    sgn = np.where(flip, -1.0, 1.0)
    inside = np.all(g[ti, None] * sgn * e_eff > 0, axis=1)
    e = sgn * e_hat
    total = e.sum(1)
    hit = inside & (total != 0)
    lam = np.divide(e, total[:, None], out=np.zeros_like(e), where=hit[:, None])
    z_hit = (lam * W[:, 2][corners]).sum(1)
    hit &= s[qi] * (z_hit - zq[qi]) > 0
    # Leaving through a face: its normal n has n . (s d) > 0; g = sign(n . d) in a right-handed frame.
    facing = g[ti] * np.sign(np.linalg.det(R))
    return np.rint(np.bincount(qi[hit], (s[qi] * facing)[hit], minlength=q)).astype(np.int64)


def self_penetrating(vertices, faces) -> np.ndarray:
    """(n,) bool: vertices of a posed closed mesh that lie inside the mesh itself (module docstring).

    Parameters
    ----------
    vertices : (n, 3)
        The posed hand.
    faces : (m, 3) int
        Its closed, outward-oriented faces.
    """
    V = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    N = _vertex_normals(V, f)
    dots = N @ RAY_DIRECTIONS.T  # (n, 3)
    axis = np.argmax(np.abs(dots), axis=1)
    used = np.zeros(len(V), bool)
    used[f.ravel()] = True
    out = np.zeros(len(V), bool)
    for a in range(3):
        ids = np.flatnonzero((axis == a) & used)
        if ids.size == 0:
            continue
        frame = RAY_DIRECTIONS[[(a + 1) % 3, (a + 2) % 3, a]]
        signs = np.where(dots[ids, a] >= 0, 1.0, -1.0)
        out[ids] = ray_winding(V[ids], signs, frame, V, f, exclude=ids) > 0
    return out


# ------------------------------------------------------------------------------------ per frame, per motion


@dataclass(frozen=True, eq=False)
class FrameIntersections:
    """One frame's intersection volumes (% of the hand's volume) and penetrating vertices ((n,) bool)."""

    hand_object: float
    self_intersection: float
    table: float
    hand_volume: float
    object_vertices: np.ndarray
    self_vertices: np.ndarray
    table_vertices: np.ndarray


@dataclass(frozen=True, eq=False)
class Intersections:
    """Intersection volumes of every frame, (F,) each, in % of the hand's (posed) volume."""

    hand_object: np.ndarray
    self_intersection: np.ndarray
    table: np.ndarray
    hand_volume: np.ndarray


class IntersectionMeter:
    """Measures a hand's intersections with an object, a table and itself, frame by frame.

    Holds what every frame shares (the object's signed distance structure, the table box), so one meter
    serves many frames; it pickles, so :meth:`frame` calls can run in worker processes.

    Parameters
    ----------
    hand_mesh : TriMesh
        The hand's topology (closed, outward); its posed vertices come per frame.
    object_mesh : TriMesh, optional
        Closed, in object space (poses come per frame).
    table : (4, 4) array_like, optional
        World pose of the table box's centre (rigid).
    table_size : (3,) array_like, optional
        Full extents of the table box; required with ``table``.
    """

    def __init__(self, hand_mesh: TriMesh, object_mesh: TriMesh | None = None, table=None, table_size=None):
        if not isinstance(hand_mesh, TriMesh):
            raise SolverError(f"hand_mesh must be a geodesics.TriMesh, got {type(hand_mesh).__name__}")
        if np.any(hand_mesh.twin < 0):
            raise SolverError("the hand mesh must be closed (its volume and inside are undefined otherwise)")
        self.hand_faces = np.asarray(hand_mesh.faces)
        self.n_vertices = hand_mesh.n_vertices
        self.object_sdf = None if object_mesh is None else MeshSDF(object_mesh)
        self.table = None
        if (table is None) != (table_size is None):
            raise SolverError("give both the table pose and its size, or neither")
        if table is not None:
            T = np.asarray(table, dtype=np.float64)
            size = np.asarray(table_size, dtype=np.float64).reshape(-1)
            if T.shape != (4, 4) or size.size != 3:
                raise SolverError(f"table must be (4, 4) and table_size (3,), got {T.shape} and {size.shape}")
            self.table = Box(T[:3, 3], size / 2, T[:3, :3])

    def frame(self, hand_vertices, object_pose=None) -> FrameIntersections:
        """Intersections of one frame: posed hand vertices (n, 3), the object's pose (4, 4) (default
        identity; ignored without an object)."""
        V = np.asarray(hand_vertices, dtype=np.float64)
        if V.shape != (self.n_vertices, 3):
            raise SolverError(f"hand vertices must have shape ({self.n_vertices}, 3), got {V.shape}")
        volume = mesh_volume(V, self.hand_faces)
        if not volume > 0:
            raise SolverError(f"the posed hand's volume must be positive (closed, outward), got {volume}")
        n = self.n_vertices
        obj = np.zeros(n, bool)
        if self.object_sdf is not None:
            M = np.eye(4) if object_pose is None else np.asarray(object_pose, dtype=np.float64)
            local = (V - M[:3, 3]) @ M[:3, :3]  # rigid: inverse rotation is the transpose
            obj = self.object_sdf(local, max_distance=0.0) < 0
        table = np.zeros(n, bool) if self.table is None else self.table.evaluate(V)[0] < 0
        own = self_penetrating(V, self.hand_faces)

        def percent(mask):
            return intersection_volume(V, self.hand_faces, mask, volume)

        return FrameIntersections(percent(obj), percent(own), percent(table), volume, obj, own, table)

    def motion(
        self, hand_vertices, object_poses=None, progress: Callable[[int, int], object] | None = None
    ) -> Intersections:
        """Intersections of every frame: hand vertices (F, n, 3), object poses (F, 4, 4) or None.

        ``progress(done, total)`` is called after each frame.
        """
        V = np.asarray(hand_vertices, dtype=np.float64)
        if V.ndim != 3:
            raise SolverError(f"hand vertices must have shape (F, n, 3), got {V.shape}")
        F = len(V)
        poses = None if object_poses is None else np.asarray(object_poses, dtype=np.float64)
        if poses is not None and poses.shape != (F, 4, 4):
            raise SolverError(f"object poses must have shape ({F}, 4, 4), got {poses.shape}")
        out = np.zeros((4, F))
        for i in range(F):
            r = self.frame(V[i], None if poses is None else poses[i])
            out[:, i] = r.hand_object, r.self_intersection, r.table, r.hand_volume
            if progress is not None:
                progress(i + 1, F)
        return Intersections(*out)


# ------------------------------------------------------------------------------------ plots


def plot_metrics(
    path,
    fps: float,
    *,
    marker_distance=None,
    contact_distance=None,
    contact_count=None,
    intersections: Intersections | None = None,
    size: tuple[int, int] = (1200, 800),
    dpi: int = 100,
    title: str | None = None,
) -> Path:
    """Plot the metrics over time to a PNG (written atomically); returns its path.

    The top panel shows mean marker (orange) and contact (blue) distances in centimetres on its left
    axis and the number of contacts per frame (light pink band) on its own right axis, as the paper's
    Fig. 11; the bottom panel the hand-object (green), self (red) and table (blue) intersection volumes
    in % of the hand's volume, as its Fig. 12. A panel without data is left out. Needs matplotlib
    (optional, imported here only): SolverError without it.

    Parameters
    ----------
    path : str or Path
    fps : float
        Frame rate (the x axis is in seconds).
    marker_distance, contact_distance, contact_count : (F,) array_like, optional
        Distances in metres (NaN: no data that frame); contact counts.
    intersections : Intersections, optional
    size : (int, int)
        Width and height of the image in pixels.
    dpi : int
    title : str, optional
        The figure's title (default: the frame count, duration and frame rate; ``""``: none).
    """
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise SolverError(
            f"{path}: plotting needs matplotlib, which is optional: pip install -e '.[plots]' in the checkout"
        ) from None

    w, h = (int(v) for v in size)
    if w < 16 or h < 16:
        raise SolverError(f"the image must be at least 16 x 16 pixels, got {w} x {h}")
    series = [
        np.asarray(x, dtype=np.float64).reshape(-1)
        for x in (marker_distance, contact_distance)
        if x is not None
    ]
    panels = int(bool(series)) + int(intersections is not None)
    if panels == 0:
        raise SolverError("nothing to plot: give distances and/or intersections")
    fig = Figure(figsize=(w / dpi, h / dpi), dpi=dpi)
    FigureCanvasAgg(fig)
    axes = list(np.atleast_1d(fig.subplots(panels, 1, sharex=True)))
    bottom = axes[-1]  # (fig.axes also holds the contact count's twin axis)
    if title is None:
        title = _default_title(series, intersections, fps)
    if title:
        fig.suptitle(title)
    if series:
        _plot_distances(axes.pop(0), fps, marker_distance, contact_distance, contact_count)
    if intersections is not None:
        _plot_intersections(axes.pop(0), fps, intersections)
    bottom.set_xlabel("time (s)")
    fig.tight_layout()

    target = Path(path)
    with atomic_file(target) as fh:
        fig.savefig(fh, format="png", dpi=dpi)
    return target


def _default_title(series: list[np.ndarray], intersections: Intersections | None, fps: float) -> str:
    """The frame count, duration and frame rate of the longest curve."""
    lengths = [v.size for v in series]
    if intersections is not None:
        lengths.append(np.asarray(intersections.hand_object).size)
    frames = max(lengths)
    return f"retargeting metrics: {frames} frames ({frames / fps:.1f} s at {fps:g} fps)"


def _plot_distances(ax, fps: float, marker_distance, contact_distance, contact_count) -> None:
    """The top panel (Fig. 11): marker and contact distances in centimetres, and the contact count per
    frame on its own right axis, behind them."""
    for values, label, color in (
        (marker_distance, "marker distance", "tab:orange"),
        (contact_distance, "contact distance", "tab:blue"),
    ):
        if values is None:
            continue
        cm = 100.0 * np.asarray(values, dtype=np.float64).reshape(-1)
        ax.plot(np.arange(cm.size) / fps, cm, color=color, lw=1.0, label=label)
    ax.set_ylabel("distance (cm)")
    ax.set_ylim(bottom=0.0)
    handles, labels = ax.get_legend_handles_labels()
    if contact_count is not None:
        # A count, not a distance: on its own axis, drawn behind the distance curves.
        count = np.asarray(contact_count, dtype=np.float64).reshape(-1)
        twin = ax.twinx()
        twin.fill_between(
            np.arange(count.size) / fps,
            count,
            color="pink",
            alpha=0.5,
            lw=0,
            label="contacts (right axis)",
        )
        top = float(np.nanmax(count)) if count.size and np.nanmax(count) > 0 else 1.0
        twin.set_ylim(0.0, 1.05 * top)
        twin.set_ylabel("contacts per frame (count)")
        ax.set_zorder(twin.get_zorder() + 1)
        ax.patch.set_visible(False)
        more, names = twin.get_legend_handles_labels()
        handles, labels = handles + more, labels + names
    ax.legend(handles, labels, loc="upper right", fontsize="small")
    ax.grid(alpha=0.3)


def _plot_intersections(ax, fps: float, intersections: Intersections) -> None:
    """The bottom panel (Fig. 12): hand-object, self and table intersection volumes, in % of the hand's."""
    for values, label, color in (
        (intersections.hand_object, "hand-object", "tab:green"),
        (intersections.self_intersection, "self", "tab:red"),
        (intersections.table, "table", "tab:blue"),
    ):
        v = np.asarray(values, dtype=np.float64).reshape(-1)
        ax.plot(np.arange(v.size) / fps, v, color=color, lw=1.0, label=label)
    ax.set_ylabel("intersection (% of hand volume)")
    ax.legend(loc="upper right", fontsize="small")
    ax.grid(alpha=0.3)
