"""Contact patches parameterized by an axis (Contact Edit §4.1–4.3, Algorithms 2, 4 and 5).

Every patch point is stored as the index of its geodesically closest axis point and the exact log map
from there, with the angle measured from the axis tangent at that point. Moving, turning, bending or
transferring the axis, then tracing those log maps again from the new axis points, moves the patch.
"""

from __future__ import annotations

import numpy as np

from .axis import Axis
from .errors import ContactError, describe_ids
from .exact import GeodesicField
from .mesh import TriMesh
from .points import SurfacePoints
from .trace import exp_map


class ContactPatch:
    """A contact area: surface points, an axis, and each point's place relative to the axis.

    Parameters
    ----------
    mesh : TriMesh
    points : SurfacePoints
        The patch's points (k ≥ 1), anywhere on the surface.
    axis : Axis
        An axis on the same mesh and connected component.

    Attributes
    ----------
    points : SurfacePoints (k)
    axis : Axis
    binding : (k,) int
        Index of each point's closest axis point (exact geodesic distance).
    coords : (k,) complex
        Each point's log map from its axis point, ``r * exp(iθ)``, with θ measured from the axis tangent
        there (Algorithm 2).

    Patches are values: every edit returns a new patch and leaves this one as it was.
    """

    def __init__(self, mesh: TriMesh, points: SurfacePoints, axis: Axis):
        if len(points) == 0:
            raise ContactError("a contact patch needs at least one point; the selection is empty")
        if axis.mesh is not mesh:
            raise ContactError("the axis lies on a different mesh than the patch")
        points.validate(mesh)
        component = mesh.face_components[axis.points.faces[0]]
        apart = np.flatnonzero(mesh.face_components[points.faces] != component)
        if apart.size:
            raise ContactError(
                f"patch points {describe_ids(apart)} lie on another connected component than the axis; "
                "a patch must lie on one piece of surface"
            )
        query = GeodesicField(mesh, axis.points, points).query(points)
        binding = query.sources
        coords = query.distances * query.initial_directions / axis.tangents[binding]
        self._set(mesh, points, axis, binding, coords)

    def _set(self, mesh, points, axis, binding, coords) -> None:
        self.mesh, self.points, self.axis = mesh, points, axis
        for name, value in (("binding", binding), ("coords", coords)):
            value = np.array(value)
            value.setflags(write=False)
            setattr(self, name, value)

    @classmethod
    def _on(cls, axis: Axis, binding, coords, keep: SurfacePoints | None = None) -> ContactPatch:
        """Reconstruct a patch from its parameterization around ``axis`` (Algorithm 4). Points where
        ``keep`` (surface points of the old patch) is given and the axis is unchanged keep those."""
        redo = np.arange(len(binding)) if keep is None else np.flatnonzero(binding >= _unchanged(keep, axis))
        trace = exp_map(axis.mesh, axis.points[binding[redo]], coords[redo] * axis.tangents[binding[redo]])
        if trace.hit_boundary.any():
            lost = np.flatnonzero(trace.hit_boundary)
            reach = trace.lengths[lost] / np.maximum(np.abs(coords[redo][lost]), 1e-300)
            raise ContactError(
                f"{lost.size} of {len(binding)} patch points would fall off the surface's boundary "
                f"(e.g. point {int(redo[lost[0]])} gets {reach[0]:.0%} of the way); move the axis inward"
            )
        if keep is None:
            points = trace.points
        else:
            faces, bary = keep.points.faces.copy(), keep.points.bary.copy()
            faces[redo], bary[redo] = trace.points.faces, trace.points.bary
            points = SurfacePoints(faces, bary)
        return cls.parameterized(axis, points, binding, coords)

    @classmethod
    def parameterized(cls, axis: Axis, points: SurfacePoints, binding, coords) -> ContactPatch:
        """A patch from its parameterization as stored (a contact file, a subset): for the k ``points`` (on
        ``axis.mesh``), ``binding`` (k,) int, the index of each one's axis point, and ``coords`` (k,)
        complex, its offset in that point's tangent frame. Nothing is traced; the shapes and indices are
        checked."""
        binding, coords = np.asarray(binding), np.asarray(coords, np.complex128)
        k, m = len(points), len(axis)
        if (
            binding.shape != (k,)
            or coords.shape != (k,)
            or not np.issubdtype(binding.dtype, np.integer)
            or np.any((binding < 0) | (binding >= m))
        ):
            raise ContactError(
                f"binding and coords must give one axis point index in 0..{m - 1} and one complex "
                f"number per patch point ({k})"
            )
        patch = cls.__new__(cls)
        patch._set(axis.mesh, points, axis, binding, coords)
        return patch

    def __len__(self) -> int:
        return len(self.points)

    def __repr__(self) -> str:
        return f"ContactPatch({len(self)} points, {self.axis!r})"

    def positions(self) -> np.ndarray:
        """(k, 3) the patch points in space."""
        return self.points.positions(self.mesh)

    # ------------------------------------------------------------------ operations

    def transfer(
        self,
        target: TriMesh,
        start: SurfacePoints,
        direction: complex,
        *,
        axis_scale: float = 1.0,
        radial_scale: float = 1.0,
        mirror: bool = True,
    ) -> ContactPatch:
        """The mirror image of this patch embedded on ``target`` (Algorithm 5), its axis starting at
        ``start`` along ``direction`` (in start's basis), so the two patches face each other.

        ``axis_scale`` and ``radial_scale`` stretch the axis and the distances from it (the
        retargeting paper's λ_A and λ_S); both are 1 for an as-isometric-as-possible transfer.
        ``mirror=False`` embeds the patch itself instead of its mirror image: for a target whose
        surface orientation is reversed against this one's where they meet (one mesh placed mirrored).
        """
        axis = self.axis.trace(target, start, direction, mirror=mirror, scale=axis_scale)
        coords = np.conj(self.coords) if mirror else self.coords
        return ContactPatch._on(axis, self.binding, coords * radial_scale)

    def translate(self, to: SurfacePoints) -> ContactPatch:
        """Slide the patch so its axis starts at ``to`` (parallel transport along the shortest geodesic)."""
        return ContactPatch._on(self.axis.translate(to), self.binding, self.coords)

    def rotate(self, angle: float) -> ContactPatch:
        """Turn the patch about its axis's first point by ``angle`` radians (counter-clockwise)."""
        return ContactPatch._on(self.axis.rotate(angle), self.binding, self.coords)

    def bend(self, index: int, angle: float) -> ContactPatch:
        """Turn the part of the patch bound to axis points ``index`` … m-1 about axis point ``index``;
        the points bound to earlier axis points stay exactly where they are."""
        return ContactPatch._on(self.axis.bend(index, angle), self.binding, self.coords, keep=self)

    def with_axis(self, axis: Axis) -> ContactPatch:
        """The same points, parameterized against another axis (the axis tool)."""
        return ContactPatch(self.mesh, self.points, axis)

    def subset(self, keep) -> ContactPatch:
        """The patch with only the points ``keep`` selects ((k,) bool mask or (j,) indices), around the same
        axis."""
        index = np.arange(len(self))[np.asarray(keep)]
        if index.size == 0:
            raise ContactError("that would leave the patch without points")
        return ContactPatch.parameterized(
            self.axis, self.points[index], self.binding[index], self.coords[index]
        )

    def mirrored_onto(self, axis: Axis) -> ContactPatch:
        """This patch's mirror image around ``axis``: the axis of an earlier transfer of it, however that
        has been moved, turned or bent since (so points added here can be carried over to it)."""
        if len(axis) != len(self.axis):
            raise ContactError(
                f"the axis has {len(axis)} points but this patch's has {len(self.axis)}: it is not the axis "
                "of a transfer of this patch"
            )
        return ContactPatch._on(axis, self.binding, np.conj(self.coords))

    def moved_to(self, axis: Axis) -> ContactPatch:
        """This patch rebuilt around ``axis`` (an axis of the same shape, e.g. one carried by a parent)."""
        if len(axis) != len(self.axis):
            raise ContactError(f"the new axis has {len(axis)} points, the patch's has {len(self.axis)}")
        return ContactPatch._on(axis, self.binding, self.coords)


def _unchanged(old: ContactPatch, axis: Axis) -> int:
    """How many leading axis points (with their tangents) ``axis`` shares exactly with ``old``'s axis."""
    a, b = old.axis, axis
    same = (a.points.faces == b.points.faces) & np.all(a.points.bary == b.points.bary, axis=1)
    same &= a.tangents == b.tangents
    return int(np.argmin(same)) if not same.all() else len(same)
