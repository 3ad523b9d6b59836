"""Blender meshes as :class:`geodesics.TriMesh` and surface points, and back.

The rest shape of a mesh object (its own vertices, no modifiers) or, when asked, its evaluated
deformed shape, triangulated by :meth:`geodesics.TriMesh.from_polygons` (our triangulation, so that
intrinsic data stays valid however Blender triangulates for display). Meshes are cached by a
fingerprint of their topology and coordinates, so repeated operations on an unchanged mesh are cheap: a
cached mesh keeps what the geodesic and tracing code builds for it (:func:`geodesics.mesh.per_mesh`)
for the session, until the mesh changes. :func:`moved` does the same for a mesh carried into another
space (an object's mesh in its hand's armature space, as each solve needs it).
"""

from __future__ import annotations

import hashlib
from contextlib import contextmanager

import bpy
import numpy as np
from scipy import sparse

from geodesics import MeshError, SurfacePoints, TriMesh

from .errors import BridgeError

#: Relative tolerance for an object's scale to count as uniform.
UNIFORM_SCALE_TOLERANCE = 1e-5

_cache: dict[tuple, TriMesh] = {}
#: Meshes kept: a hand and an object, each at rest and in the armature's space, with room for more.
_CACHE_SIZE = 16


def mesh_arrays(mesh: bpy.types.Mesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertex positions (n, 3), polygon corner vertices (L,) and corner counts (p,) of a mesh."""
    vertices = np.empty(3 * len(mesh.vertices), np.float64)
    mesh.vertices.foreach_get("co", vertices)
    corners = np.empty(len(mesh.loops), np.int64)
    mesh.loops.foreach_get("vertex_index", corners)
    sizes = np.empty(len(mesh.polygons), np.int64)
    mesh.polygons.foreach_get("loop_total", sizes)
    return vertices.reshape(-1, 3), corners, sizes


def trimesh(obj: bpy.types.Object, deformed: bool = False) -> TriMesh:
    """The object's surface as a TriMesh, in object space: its rest shape, or when ``deformed`` its
    vertices where Blender's deform modifiers put them (:func:`deformed_vertices`).

    Raises BridgeError with the object's name and what is wrong (no mesh, no faces, non-manifold...).
    """
    if obj is None or obj.type != "MESH":
        raise BridgeError(f"'{getattr(obj, 'name', None)}' is not a mesh object")
    vertices, corners, sizes = mesh_arrays(obj.data)
    if sizes.size == 0:
        raise BridgeError(f"'{obj.name}' has no faces to put contacts on")
    if deformed:
        vertices = deformed_vertices(obj)
    key = (obj.name, deformed, _fingerprint(vertices, corners, sizes))
    try:
        return _cached(key, lambda: TriMesh.from_polygons(vertices, (corners, sizes)))
    except MeshError as err:
        raise BridgeError(
            f"'{obj.name}' cannot carry contacts: {err}", obj.name, err.faces, err.vertices
        ) from err


def deformed_vertices(obj: bpy.types.Object) -> np.ndarray:
    """(n, 3) the object's own vertices where Blender's evaluation puts them (object space).

    Modifiers shown after its last Armature modifier that change the topology (a Subdivision Surface)
    only refine what the armature deformed: the vertices are then read from an evaluation with them
    switched off (see :func:`armature_cage`). Raises BridgeError if the topology still differs.
    """
    vertices = _evaluated_vertices(obj)
    if vertices is None:
        with armature_cage(obj):
            vertices = _evaluated_vertices(obj)
    if vertices is None:
        raise BridgeError(
            f"the modifiers of '{obj.name}' change its topology, so its deformed shape cannot carry "
            "contacts; use the rest shape or apply the modifiers"
        )
    return vertices


def shaped_vertices(obj: bpy.types.Object) -> np.ndarray:
    """(n, 3) the object's own vertices as its shape keys shape them (object space): the rest shape its
    Armature modifier deforms, read from Blender's evaluation with that modifier and those after it
    switched off (the vertices themselves when no shape key changes them)."""
    keys = obj.data.shape_keys
    if keys is None or not any(k.value != 0 and not k.mute for k in keys.key_blocks[1:]):
        return mesh_arrays(obj.data)[0]
    armatures = _armature_indices(obj)
    with _hidden(obj.modifiers[armatures[0] :] if armatures else []):
        vertices = _evaluated_vertices(obj)
    if vertices is None:
        raise BridgeError(f"the modifiers of '{obj.name}' before its Armature modifier change its topology")
    return vertices


@contextmanager
def armature_cage(obj: bpy.types.Object):
    """Within it, Blender evaluates ``obj`` without the modifiers shown after its last Armature modifier,
    so that its evaluated mesh is the cage those modifiers refine; they are shown again on leaving."""
    with _hidden(after_armature(obj)):
        yield


@contextmanager
def _hidden(modifiers):
    """Within it, the given modifiers that are shown in the viewport are not; they are again on leaving."""
    shown = [m for m in modifiers if m.show_viewport]
    for modifier in shown:
        modifier.show_viewport = False
    try:
        yield
    finally:
        for modifier in shown:
            modifier.show_viewport = True


def after_armature(obj: bpy.types.Object) -> list[bpy.types.Modifier]:
    """The modifiers shown after the object's last shown Armature modifier (none without one)."""
    armatures = _armature_indices(obj)
    return [m for m in obj.modifiers[armatures[-1] + 1 :] if m.show_viewport] if armatures else []


def _armature_indices(obj: bpy.types.Object) -> list[int]:
    """Stack positions of the object's Armature modifiers shown in the viewport."""
    return [i for i, m in enumerate(obj.modifiers) if m.type == "ARMATURE" and m.show_viewport]


def _evaluated_vertices(obj: bpy.types.Object) -> np.ndarray | None:
    """The evaluated mesh's vertex positions (n, 3), or None if its vertex or face count is not the
    object's own."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    evaluated = obj.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    try:
        if len(mesh.vertices) != len(obj.data.vertices) or len(mesh.polygons) != len(obj.data.polygons):
            return None
        vertices = np.empty(3 * len(mesh.vertices), np.float64)
        mesh.vertices.foreach_get("co", vertices)
    finally:
        evaluated.to_mesh_clear()
    return vertices.reshape(-1, 3)


def moved(mesh: TriMesh, M: np.ndarray) -> TriMesh:
    """``mesh`` carried by the (4, 4) matrix ``M`` (same faces, so the same surface points)."""
    return cached_trimesh(mesh.vertices @ M[:3, :3].T + M[:3, 3], mesh.faces)


def moved_solid(mesh: TriMesh, M: np.ndarray) -> TriMesh:
    """``mesh`` carried by the (4, 4) matrix ``M`` with its faces still pointing out: reversed when ``M``
    mirrors. For telling inside from outside only; its surface points are not ``mesh``'s."""
    carried = moved(mesh, M)
    if np.linalg.det(M[:3, :3]) >= 0:
        return carried
    return cached_trimesh(carried.vertices, carried.faces[:, ::-1])


def cached_trimesh(vertices: np.ndarray, faces: np.ndarray) -> TriMesh:
    """``TriMesh(vertices, faces)``, from the cache when the same arrays were given before."""
    return _cached(("arrays", _fingerprint(vertices, faces)), lambda: TriMesh(vertices, faces))


def _cached(key: tuple, build) -> TriMesh:
    """The mesh cached under ``key``, else ``build()`` (kept, the oldest of more than ``_CACHE_SIZE``
    dropped)."""
    if key not in _cache:
        _cache[key] = build()
        while len(_cache) > _CACHE_SIZE:
            _cache.pop(next(iter(_cache)))
    return _cache[key]


def _fingerprint(*arrays: np.ndarray) -> str:
    digest = hashlib.blake2b(digest_size=16)
    for a in arrays:
        digest.update(np.ascontiguousarray(a).tobytes())
    return digest.hexdigest()


def select_elements(obj: bpy.types.Object, polygons: np.ndarray, vertices: np.ndarray) -> None:
    """Select exactly the given polygons and vertices of a mesh object (to show the user a problem)."""
    mesh = obj.data
    polygon_flags = np.zeros(len(mesh.polygons), bool)
    polygon_flags[polygons[(polygons >= 0) & (polygons < len(mesh.polygons))]] = True
    vertex_flags = np.zeros(len(mesh.vertices), bool)
    vertex_flags[vertices[(vertices >= 0) & (vertices < len(mesh.vertices))]] = True
    corners = np.empty(len(mesh.loops), np.int64)
    mesh.loops.foreach_get("vertex_index", corners)
    sizes = np.empty(len(mesh.polygons), np.int64)
    mesh.polygons.foreach_get("loop_total", sizes)
    vertex_flags[corners[np.repeat(polygon_flags, sizes)]] = True
    mesh.polygons.foreach_set("select", polygon_flags)
    mesh.vertices.foreach_set("select", vertex_flags)
    # No edge selected is the absence of the attribute. (Removing it also sidesteps Blender 5.0.1 meshes
    # made by from_pydata, whose ".select_edge" is mistyped INT32_2D and crashes edge.select.)
    edges = mesh.attributes.get(".select_edge")
    if edges is not None:
        mesh.attributes.remove(edges)


def vertex_group_weights(obj: bpy.types.Object) -> sparse.csr_matrix:
    """(n_vertices, n_groups) the weights of a mesh object's vertex groups (column = group index)."""
    entries = [(v.index, g.group, g.weight) for v in obj.data.vertices for g in v.groups]
    data = np.array(entries, np.float64).reshape(-1, 3)
    shape = (len(obj.data.vertices), len(obj.vertex_groups))
    return sparse.csr_matrix(
        (data[:, 2], (data[:, 0].astype(np.int64), data[:, 1].astype(np.int64))), shape=shape
    )


def selected_vertices(obj: bpy.types.Object) -> np.ndarray:
    """Indices of the selected vertices of a mesh object (its stored selection; flush edit mode first)."""
    flags = np.empty(len(obj.data.vertices), bool)
    obj.data.vertices.foreach_get("select", flags)
    return np.flatnonzero(flags)


def points_from_vertices(obj: bpy.types.Object, mesh: TriMesh, vertices: np.ndarray) -> SurfacePoints:
    """Surface points on the given vertices of ``obj``."""
    if len(vertices) == 0:
        raise BridgeError(f"no vertices of '{obj.name}' are selected")
    try:
        return SurfacePoints.from_vertices(mesh, vertices)
    except MeshError as err:
        raise BridgeError(f"'{obj.name}': {err}") from err


def points_from_hits(mesh: TriMesh, polygons: np.ndarray, locations: np.ndarray) -> SurfacePoints:
    """Surface points where rays hit polygons (Blender's ray_cast gives a polygon index and an
    object-space location): each is placed in the triangle of its polygon that holds it. A polygon of -1
    is unknown (a hit on a subdivided surface, whose polygons are not the mesh's): the surface point
    nearest the location is taken."""
    polygons = np.asarray(polygons, np.int64)
    locations = np.asarray(locations, np.float64).reshape(-1, 3)
    unknown = polygons < 0
    if unknown.any():
        faces, bary = np.empty(len(polygons), np.int64), np.empty((len(polygons), 3))
        for rows, found in (
            (unknown, SurfacePoints.nearest(mesh, locations[unknown])),
            (~unknown, points_from_hits(mesh, polygons[~unknown], locations[~unknown])),
        ):
            faces[rows], bary[rows] = found.faces, found.bary
        return SurfacePoints(faces, bary)
    owner = mesh.triangle_polygon
    start = np.searchsorted(owner, polygons)
    count = np.searchsorted(owner, polygons, side="right") - start
    candidates = start[:, None] + np.arange(count.max(initial=1))
    candidates = np.where(np.arange(candidates.shape[1]) < count[:, None], candidates, start[:, None])
    k, c = candidates.shape
    trial = SurfacePoints.from_positions(mesh, candidates.ravel(), np.repeat(locations, c, axis=0))
    gap = np.linalg.norm(trial.positions(mesh) - np.repeat(locations, c, axis=0), axis=1).reshape(k, c)
    best = np.argmin(gap, axis=1)
    pick = np.arange(k) * c + best
    return SurfacePoints(trial.faces[pick], trial.bary[pick])


def uniform_scale(obj: bpy.types.Object) -> float:
    """The object's scale factor (world length per object-space length; the cube root of the volume
    scale, for objects scaled unevenly)."""
    return float(abs(np.linalg.det(np.array(obj.matrix_world)[:3, :3])) ** (1.0 / 3.0))


def uneven_scale(obj: bpy.types.Object) -> str | None:
    """The object's world scale per axis as text ("1, 2, 1") if it is not uniform (scaled unevenly or
    sheared, here or by a parent), else None."""
    A = np.array(obj.matrix_world)[:3, :3]
    columns = np.linalg.norm(A, axis=0)
    gram = A.T @ A
    if np.abs(gram - np.diag(columns**2)).max() > UNIFORM_SCALE_TOLERANCE * columns.max() ** 2 or (
        np.ptp(columns) > UNIFORM_SCALE_TOLERANCE * columns.max()
    ):
        return ", ".join(f"{c:.4g}" for c in columns)
    return None


def handedness(obj: bpy.types.Object) -> int:
    """+1 for an object placed as modelled, -1 for one placed mirrored (its world matrix reverses
    orientation: a scale of -1 on an odd number of axes, here or on a parent)."""
    return 1 if np.linalg.det(np.array(obj.matrix_world)[:3, :3]) >= 0 else -1


def world_to_object(obj: bpy.types.Object, points) -> np.ndarray:
    """World-space positions (k, 3) in the object's local space."""
    M = np.array(obj.matrix_world.inverted())
    X = np.asarray(points, np.float64).reshape(-1, 3)
    return X @ M[:3, :3].T + M[:3, 3]


def object_to_world(obj: bpy.types.Object, points) -> np.ndarray:
    """Object-space positions (k, 3) in world space."""
    M = np.array(obj.matrix_world)
    X = np.asarray(points, np.float64).reshape(-1, 3)
    return X @ M[:3, :3].T + M[:3, 3]
