"""An area brush on a surface: the points a stroke of spherical dabs covers (Contact Edit §4.2 asks for
a brush with a size; ours has a radius and paints points inside faces at a chosen density).

A dab is a ball about a point on the surface (where the mouse ray hit it), as Blender's own paint
brushes are: it covers the surface inside the ball that is connected to the hit face through faces
that meet the ball (so a dab on a fingertip does not reach the next finger across the gap) and, when
a viewer is given, that faces the viewer. Painting collects the even samples of
:func:`geodesics.sampling.surface_samples` a stroke covers, each once; erasing tells which of a patch's
points a stroke covers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from .mesh import TriMesh
from .points import SurfacePoints, distances_to_faces
from .sampling import surface_samples


@dataclass(frozen=True)
class Dab:
    """One touch of the brush.

    Attributes
    ----------
    face : int
        The face the brush's ray hit.
    centre : (3,) float
        Where it hit (mesh coordinates).
    radius : float
        The ball's radius (mesh units).
    eye : (3,) float or None
        The viewer's position (a perspective view): only surface facing it is covered.
    direction : (3,) float or None
        The view direction (an orthographic view), instead of ``eye``.
    """

    face: int
    centre: tuple
    radius: float
    eye: tuple | None = None
    direction: tuple | None = None

    def __post_init__(self):
        if not np.isfinite(self.radius) or self.radius <= 0:
            raise ValueError(f"a brush dab needs a positive radius, got {self.radius}")
        if not np.all(np.isfinite(self.centre)):
            raise ValueError("a brush dab's centre must be finite")

    def region(self, mesh: TriMesh) -> np.ndarray:
        """(f,) the faces that meet the ball and connect to the hit face through faces that meet it."""
        centre = np.asarray(self.centre, np.float64)
        near = np.flatnonzero(
            np.linalg.norm(mesh.face_centroids - centre, axis=1) <= self.radius + mesh.face_radii
        )
        gap = distances_to_faces(mesh, np.zeros(near.size, np.int64), near, centre[None])
        meeting = np.union1d(near[gap <= self.radius], [self.face])
        inside = np.zeros(mesh.n_faces, bool)
        inside[meeting] = True
        h = 3 * meeting[:, None] + np.arange(3)
        twin = mesh.twin[h.ravel()]
        linked = (twin >= 0) & inside[np.maximum(twin, 0) // 3]
        index = np.full(mesh.n_faces, -1, np.int64)
        index[meeting] = np.arange(meeting.size)
        rows = np.repeat(np.arange(meeting.size), 3)[linked]
        graph = coo_matrix((np.ones(rows.size), (rows, index[twin[linked] // 3])), (meeting.size,) * 2)
        _, label = connected_components(graph, directed=False)
        return meeting[label == label[index[self.face]]]

    def covers(self, mesh: TriMesh, points: SurfacePoints, region: np.ndarray | None = None) -> np.ndarray:
        """(k,) bool: which points lie in the dab (``region``: its faces, if already known)."""
        region = self.region(mesh) if region is None else region
        inside = np.isin(points.faces, region)
        where = points.positions(mesh)
        inside &= np.linalg.norm(where - np.asarray(self.centre), axis=1) <= self.radius
        if self.eye is not None or self.direction is not None:
            toward = (
                np.asarray(self.eye, np.float64) - where
                if self.eye is not None
                else -np.broadcast_to(np.asarray(self.direction, np.float64), where.shape)
            )
            inside &= np.einsum("kd,kd->k", mesh.face_normals[points.faces], toward) > 0
        return inside


def paint(mesh: TriMesh, dabs, density: float, seed: int = 0) -> tuple[SurfacePoints, np.ndarray]:
    """The surface samples (``density`` per unit area) that a stroke of dabs covers, each once.

    Returns the points, SurfacePoints (k) in increasing sample-id order, and their (k,) int64 sample ids
    (see :func:`surface_samples`).
    """
    found_points, found_ids = [], []
    for dab in dabs:
        region = dab.region(mesh)
        points, ids = surface_samples(mesh, density, region, seed)
        keep = dab.covers(mesh, points, region)
        found_points.append(points[np.flatnonzero(keep)])
        found_ids.append(ids[keep])
    if not found_ids:
        return SurfacePoints(np.empty(0, np.int64), np.empty((0, 3))), np.empty(0, np.int64)
    ids, first = np.unique(np.concatenate(found_ids), return_index=True)
    return SurfacePoints.concatenate(found_points)[first], ids


def erase(mesh: TriMesh, points: SurfacePoints, dabs) -> np.ndarray:
    """(k,) bool: the points no dab of the stroke covers (those an eraser stroke keeps)."""
    keep = np.ones(len(points), bool)
    for dab in dabs:
        keep &= ~dab.covers(mesh, points)
    return keep
