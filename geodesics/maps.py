"""The log map, shortest paths, parallel transport and closest points, on the exact solver."""

from __future__ import annotations

import numpy as np

from .errors import GeodesicError
from .exact import GeodesicField, Path
from .mesh import TriMesh
from .points import SurfacePoints


def _single(points: SurfacePoints, what: str) -> SurfacePoints:
    if len(points) != 1:
        raise GeodesicError(f"{what} must be a single surface point, got {len(points)}")
    return points


def log_map(mesh: TriMesh, origin: SurfacePoints, targets: SurfacePoints) -> np.ndarray:
    """Exact log map: where each target is, seen from ``origin``.

    Returns
    -------
    (k,) complex
        ``r * exp(iθ)``: r the exact geodesic distance, θ the initial direction of the shortest geodesic
        in the origin's tangent basis (0 for a target at the origin).
    """
    _single(origin, "the origin")
    q = GeodesicField(mesh, origin, targets).query(targets)
    return np.where(q.distances > 0, q.distances * q.initial_directions, 0)


def geodesic_path(mesh: TriMesh, a: SurfacePoints, b: SurfacePoints) -> Path:
    """The exact shortest geodesic from point ``a`` to point ``b``."""
    _single(a, "the start")
    _single(b, "the end")
    return GeodesicField(mesh, a, b).path(b)


def transport(mesh: TriMesh, path: Path, z) -> np.ndarray:
    """(...) complex: tangent vectors ``z`` (...) complex (any shape, a scalar too) in the path's start
    basis, parallel-transported to its end basis.

    Along each straight segment the angle to the path is kept (Levi-Civita transport across faces and
    edges); at a vertex the path bends around, vectors keep their coordinates in the vertex's basis.
    """
    z = np.asarray(z, dtype=np.complex128)
    t, s = path.segment_directions[:, 0], path.segment_directions[:, 1]
    if np.any(t == 0) or np.any(s == 0):  # zero-length path: nothing to transport along
        return z.copy()
    return z * np.prod(s / t)


def closest_points(mesh: TriMesh, sources: SurfacePoints, targets: SurfacePoints) -> np.ndarray:
    """(k,) index of the geodesically nearest source to each target (exact distances).

    Targets on a component with no source get -1.
    """
    comps = mesh.face_components
    reachable = np.isin(comps[targets.faces], comps[sources.faces])
    out = np.full(len(targets), -1, np.int64)
    if np.any(reachable):
        t = targets[np.flatnonzero(reachable)]
        out[reachable] = GeodesicField(mesh, sources, t).query(t).sources
    return out
