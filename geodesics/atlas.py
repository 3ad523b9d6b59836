"""The contact atlas: moving contacts between different hands through charts around axial curves
(Kinematic Motion Retargeting §3.3.2, Appendix A.2).

The points of a few named axial curves on the source hand are landmarks. Each contact belongs to the
chart of its geodesically nearest landmark (a geodesic Voronoi partition, exact here) and is stored as the
exact log map from that landmark, its angle measured from the curve's tangent there. On the target hand
each curve is laid out again from a start point and direction with its segment lengths scaled by λ_A,
and contacts are traced back out from the corresponding landmarks with their distances scaled by λ_S.
Curves without a counterpart on the target (a three-fingered hand) are left out: their contacts fall to
the nearest remaining landmark, and those farther than a threshold from it are dropped.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from .axis import Axis
from .errors import ContactError
from .exact import GeodesicField
from .mesh import TriMesh
from .points import SurfacePoints
from .trace import exp_map

#: Contacts are located in chunks of this many, to bound memory on very large batches.
CHUNK = 20_000


@dataclass(frozen=True, eq=False)
class AtlasCoordinates:
    """Contacts in chart coordinates.

    Attributes
    ----------
    curves : tuple of str
        The curves the contacts were bound against.
    curve : (k,) int
        Index into ``curves`` of each contact's chart.
    landmark : (k,) int
        Index of the landmark (axis point) along that curve.
    coords : (k,) complex
        Log map from the landmark, angle from the curve's tangent there.
    """

    curves: tuple[str, ...]
    curve: np.ndarray
    landmark: np.ndarray
    coords: np.ndarray

    @property
    def distances(self) -> np.ndarray:
        """(k,) geodesic distance of each contact from its landmark."""
        return np.abs(self.coords)


class ContactAtlas:
    """Charts around named axial curves on a source surface.

    Parameters
    ----------
    mesh : TriMesh
        The source surface (e.g. the source hand's rest mesh).
    curves : mapping of name -> Axis
        Axial curves on ``mesh``; their points are the landmarks.
    """

    def __init__(self, mesh: TriMesh, curves: Mapping[str, Axis]):
        if not curves:
            raise ContactError("a contact atlas needs at least one axial curve")
        for name, axis in curves.items():
            if axis.mesh is not mesh:
                raise ContactError(f"axial curve '{name}' lies on another mesh than the atlas")
        self.mesh = mesh
        self.curves = dict(curves)

    def parameterize(self, contacts: SurfacePoints, curves=None) -> AtlasCoordinates:
        """Bind each contact to its nearest landmark among ``curves`` (default: all) and record its log
        map there. Tens of thousands of contacts (all frames of a motion) go through in one call."""
        names = tuple(self.curves if curves is None else curves)
        unknown = [n for n in names if n not in self.curves]
        if unknown or not names:
            raise ContactError(f"unknown or no curves to bind to: {unknown or 'none given'}")
        axes = [self.curves[n] for n in names]
        landmarks = SurfacePoints.concatenate([a.points for a in axes])
        owner = np.repeat(np.arange(len(axes)), [len(a) for a in axes])
        first = np.concatenate([[0], np.cumsum([len(a) for a in axes])[:-1]])
        tangents = np.concatenate([a.tangents for a in axes])
        k = len(contacts)
        source = np.empty(k, np.int64)
        coords = np.empty(k, np.complex128)
        if k:
            field = GeodesicField(self.mesh, landmarks, contacts)
            for start in range(0, k, CHUNK):
                part = contacts[np.arange(start, min(start + CHUNK, k))]
                query = field.query(part)
                source[start : start + len(part)] = query.sources
                coords[start : start + len(part)] = query.distances * query.initial_directions
        coords = coords / tangents[source]
        return AtlasCoordinates(names, owner[source], source - first[owner[source]], coords)

    def lay_out(
        self,
        target: TriMesh,
        placements: Mapping[str, tuple[SurfacePoints, complex]],
        axis_scale: Mapping[str, float] | None = None,
    ) -> dict[str, Axis]:
        """Lay the named curves out on ``target``: each from its placement's start point along its
        direction (in the start's basis), with segment lengths times ``axis_scale[name]`` (λ_A, default 1).
        Curves not placed are left out of the target."""
        axis_scale = axis_scale or {}
        out = {}
        for name, (start, direction) in placements.items():
            if name not in self.curves:
                raise ContactError(f"there is no axial curve named '{name}'")
            out[name] = self.curves[name].trace(target, start, direction, scale=axis_scale.get(name, 1.0))
        return out

    def transfer(
        self,
        contacts: SurfacePoints,
        target_curves: Mapping[str, Axis],
        radial_scale: Mapping[str, float] | None = None,
        threshold: float = np.inf,
    ) -> tuple[SurfacePoints, np.ndarray]:
        """Move contacts onto the surface of ``target_curves`` (curves laid out by :meth:`lay_out`).

        Contacts bind to the landmarks of the curves present on the target; each is traced from the
        matching target landmark with its distance times ``radial_scale[curve]`` (λ_S, default 1).

        Returns
        -------
        points : SurfacePoints
            The transferred contacts that were kept.
        kept : (k,) bool
            Which contacts were kept: those within ``threshold`` (geodesic distance on the source) of
            their landmark, and whose trace did not run off the target's boundary.
        """
        if not target_curves:
            raise ContactError("no target curves: lay out at least one curve on the target")
        names = tuple(target_curves)
        for name in names:
            if name not in self.curves:
                raise ContactError(f"there is no axial curve named '{name}' in the atlas")
            if len(target_curves[name]) != len(self.curves[name]):
                raise ContactError(
                    f"target curve '{name}' has {len(target_curves[name])} points, "
                    f"the source curve {len(self.curves[name])}"
                )
        meshes = {id(axis.mesh) for axis in target_curves.values()}
        if len(meshes) != 1:
            raise ContactError("the target curves lie on different meshes")
        target = next(iter(target_curves.values())).mesh
        coords = self.parameterize(contacts, names)
        radial_scale = radial_scale or {}
        scale = np.array([radial_scale.get(n, 1.0) for n in names])[coords.curve]
        axes = [target_curves[n] for n in names]
        first = np.concatenate([[0], np.cumsum([len(a) for a in axes])[:-1]])
        landmarks = SurfacePoints.concatenate([a.points for a in axes])
        tangents = np.concatenate([a.tangents for a in axes])
        at = first[coords.curve] + coords.landmark
        near = coords.distances <= threshold
        index = np.flatnonzero(near)
        trace = exp_map(
            target, landmarks[at[index]], coords.coords[index] * scale[index] * tangents[at[index]]
        )
        kept = np.zeros(len(contacts), bool)
        kept[index] = ~trace.hit_boundary
        return trace.points[np.flatnonzero(~trace.hit_boundary)], kept
