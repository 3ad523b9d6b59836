"""Exact geodesics on triangle meshes: the geometry every contact operation stands on.

* :class:`TriMesh` — a validated manifold mesh with halfedges and intrinsic face frames.
* :class:`SurfacePoints` — batched (face, barycentric) points.
* :func:`exp_map` — straightest geodesics (Polthier–Schmies), many rays at once.
* :func:`log_map`, :func:`geodesic_path`, :class:`GeodesicField` — exact polyhedral geodesics (window
  propagation), with exact distances and initial and final directions.
* :func:`transport`, :func:`closest_points`, :func:`tangent_axes` and the basis conversions in
  :mod:`geodesics.tangent`.
* :class:`ClosestPoints` — exact closest points of the surface to points in space, for batches of
  queries (:mod:`geodesics.closest`).

The contact model (Contact Edit §4, Algorithms 1-5) is built on them:

* :class:`Axis` — a piecewise geodesic carrying a patch; :class:`ContactPatch` — a patch parameterized by
  its axis, with transfer, translate, rotate and bend; :func:`farthest_pair_axis`, :func:`medial_axis`,
  :func:`directed_axis`.
* :class:`ContactSet` — named patches with parent links and pairs, saved as JSON contact files.
* :class:`ContactAtlas` — charts around axial curves for moving contacts between different hands.
* :mod:`geodesics.sampling` (even surface samples at a density) and :mod:`geodesics.brush` (the area
  brush that paints and erases them: :class:`Dab`, :func:`paint`, :func:`erase`).
* :class:`MirrorMap`, :func:`mirror_contacts` and :func:`flip_name` — contacts carried to the other side
  of a mirror plane (:mod:`geodesics.mirror`).

:func:`load_mesh` and :func:`save_mesh` read and write OBJ, PLY, OFF, STL and glTF/GLB files, keeping the
file's vertex and face numbering (:mod:`geodesics.meshio`). Files the other packages write share
:func:`write_atomically` and :func:`read_json`, their checks :class:`Fields` (:mod:`geodesics.schema`) and
errors naming elements :func:`describe_ids`. :mod:`geodesics.benchmark` times it all beside its peers.

Tangent vectors are complex numbers in each point's tangent basis (see :mod:`geodesics.tangent`).
"""

from . import benchmark
from .atlas import AtlasCoordinates, ContactAtlas
from .axis import Axis
from .brush import Dab, erase, paint
from .closest import Closest, ClosestPoints
from .contacts import ContactSet, Link
from .default_axes import directed_axis, farthest_pair_axis, medial_axis
from .errors import ContactError, GeodesicError, MeshError, MeshWarning, describe_ids
from .exact import GeodesicField, GeodesicQuery, Path
from .files import read_json, write_atomically
from .maps import closest_points, geodesic_path, log_map, transport
from .mesh import TriMesh
from .meshio import load_mesh, save_mesh
from .mirror import MirrorMap, flip_name, mirror_contacts
from .patch import ContactPatch
from .points import SurfacePoints
from .schema import Fields
from .tangent import change_basis, tangent_axes, tangent_from_3d, tangent_to_3d
from .trace import Trace, exp_map

__all__ = [
    "AtlasCoordinates",
    "Axis",
    "Closest",
    "ClosestPoints",
    "ContactAtlas",
    "ContactError",
    "ContactPatch",
    "ContactSet",
    "Dab",
    "Fields",
    "GeodesicError",
    "GeodesicField",
    "GeodesicQuery",
    "Link",
    "MeshError",
    "MeshWarning",
    "MirrorMap",
    "Path",
    "SurfacePoints",
    "Trace",
    "TriMesh",
    "benchmark",
    "change_basis",
    "closest_points",
    "describe_ids",
    "directed_axis",
    "erase",
    "exp_map",
    "farthest_pair_axis",
    "flip_name",
    "geodesic_path",
    "load_mesh",
    "log_map",
    "medial_axis",
    "mirror_contacts",
    "paint",
    "read_json",
    "save_mesh",
    "tangent_axes",
    "tangent_from_3d",
    "tangent_to_3d",
    "transport",
    "write_atomically",
]
