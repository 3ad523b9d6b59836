"""Exact geodesics on triangle meshes: the geometry every contact operation stands on.

* :class:`TriMesh` — a validated manifold mesh with halfedges and intrinsic face frames.
* :class:`SurfacePoints` — batched (face, barycentric) points.
* :func:`exp_map` — straightest geodesics (Polthier–Schmies), many rays at once.
* :func:`log_map`, :func:`geodesic_path`, :class:`GeodesicField` — exact polyhedral geodesics (window
  propagation), with exact distances and initial and final directions.
* :func:`transport`, :func:`closest_points`, :func:`tangent_axes` and the basis conversions in
  :mod:`geodesics.tangent`.

Tangent vectors are complex numbers in each point's tangent basis (see :mod:`geodesics.tangent`).
"""

from .errors import GeodesicError, MeshError, MeshWarning
from .exact import GeodesicField, GeodesicQuery, Path
from .maps import closest_points, geodesic_path, log_map, transport
from .mesh import TriMesh
from .points import SurfacePoints
from .tangent import change_basis, tangent_axes, tangent_from_3d, tangent_to_3d
from .trace import Trace, exp_map

__all__ = [
    "GeodesicError",
    "GeodesicField",
    "GeodesicQuery",
    "MeshError",
    "MeshWarning",
    "Path",
    "SurfacePoints",
    "Trace",
    "TriMesh",
    "change_basis",
    "closest_points",
    "exp_map",
    "geodesic_path",
    "log_map",
    "tangent_axes",
    "tangent_from_3d",
    "tangent_to_3d",
    "transport",
]
