"""Exact geodesics on triangle meshes: the geometry every contact operation stands on.

* :class:`TriMesh` — a validated manifold mesh with halfedges and intrinsic face frames.
* :class:`SurfacePoints` — batched (face, barycentric) points.
* :func:`tangent_axes` and the basis conversions in :mod:`geodesics.tangent`.

Tangent vectors are complex numbers in each point's tangent basis (see :mod:`geodesics.tangent`).
"""

from .errors import GeodesicError, MeshError, MeshWarning
from .mesh import TriMesh
from .points import SurfacePoints
from .tangent import change_basis, tangent_axes, tangent_from_3d, tangent_to_3d

__all__ = [
    "GeodesicError",
    "MeshError",
    "MeshWarning",
    "SurfacePoints",
    "TriMesh",
    "change_basis",
    "tangent_axes",
    "tangent_from_3d",
    "tangent_to_3d",
]
