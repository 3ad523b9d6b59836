"""The DOF vector of the rigs a solve poses: the root bone's location and rotation (six DOFs), then three
rotations per other bone, in bone order (``6 + 3 (bones - 1)`` in all)."""

from __future__ import annotations

import numpy as np

from geodesics.arrays import readonly

from ..errors import SolverError
from .protocol import RigLike


def into_limits(theta, is_rotation, lower, upper) -> np.ndarray:
    """θ (..., d) brought within the DOF limits [lower, upper] (d,): a rotation (``is_rotation`` (d,) bool)
    outside them moves by whole turns when that lands it inside (the same pose), then every value is
    clipped.

    Clipping alone would give another pose to an angle a turn away: an unwrapped root angle of
    8.06 rad clipped to the root's 2π limit is 102° off, wrapped back it is exact.
    """
    T = np.array(theta, dtype=np.float64)
    rot = np.asarray(is_rotation, dtype=bool)
    lo, hi = np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)
    V, lo_r, hi_r = T[..., rot], lo[rot], hi[rot]
    turns = np.ceil((lo_r - V) / (2 * np.pi)).clip(min=0) - np.ceil((V - hi_r) / (2 * np.pi)).clip(min=0)
    moved = V + 2 * np.pi * turns
    T[..., rot] = np.where((moved >= lo_r) & (moved <= hi_r), moved, V)
    return np.clip(T, lo, hi)


def clipped(rig: RigLike, theta) -> np.ndarray:
    """θ (d,), or poses (F, d), of ``rig`` within its limits (:func:`into_limits`); raises SolverError for
    poses of another shape or not finite."""
    T = np.asarray(theta, dtype=np.float64)
    if T.ndim == 2:
        if T.shape[1] != rig.n_dofs or not np.isfinite(T).all():
            raise SolverError(f"poses must be finite with shape (F, {rig.n_dofs}), got {T.shape}")
        return into_limits(T, rig.is_rotation, rig.lower, rig.upper)
    return into_limits(rig.check_theta(T), rig.is_rotation, rig.lower, rig.upper)


class EulerDofs:
    """The DOF layout :class:`~.kinematics.Rig` and :class:`~.control_rig.ControlRig` share: per DOF its
    bone (``dof_bone``), whether it turns (``is_rotation``), its axis (``dof_component``) and its name
    (``dof_names``, ``"bone.rotation.x"``), laid out from the posed bones' ``names`` by
    :meth:`_lay_out_dofs`."""

    names: tuple[str, ...]

    def _lay_out_dofs(self) -> None:
        nb = len(self.names)
        nd = 6 + 3 * (nb - 1)
        self.dof_bone = readonly(np.concatenate([[0, 0, 0, 0, 0, 0], np.repeat(np.arange(1, nb), 3)]))
        self.is_rotation = readonly(np.arange(nd) >= 3)
        self.dof_component = readonly(np.concatenate([[0, 1, 2], np.tile([0, 1, 2], nb)]))
        self.dof_names: tuple[str, ...] = tuple(
            f"{self.names[b]}.{'rotation' if rot else 'location'}.{'xyz'[c]}"
            for b, rot, c in zip(self.dof_bone, self.is_rotation, self.dof_component, strict=True)
        )

    @property
    def n_bones(self) -> int:
        """The number of posed bones."""
        return len(self.names)

    @property
    def n_dofs(self) -> int:
        """d, the length of θ."""
        return 6 + 3 * (self.n_bones - 1)

    @property
    def rest(self) -> np.ndarray:
        """(d,) all zeros: a plain rig's rest pose (identity ``matrix_basis``); a control rig's root where it
        was read and every control at rest."""
        return np.zeros(self.n_dofs)

    def rotation_dof(self, bone: int, component: int) -> int:
        """Index of the DOF rotating ``bone`` about its local axis ``component`` (0 = x, 1 = y, 2 = z)."""
        return 3 + 3 * int(bone) + int(component)

    def clip(self: RigLike, theta) -> np.ndarray:
        """θ (d,), or poses (F, d), within the limits: rotations a whole turn out are wrapped back (the
        same pose), the rest clipped (:func:`into_limits`)."""
        return clipped(self, theta)
