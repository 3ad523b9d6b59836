"""What the skinning, the contact IK and the retargeting need of a rig, written once: :class:`RigLike`, which
:class:`~.kinematics.Rig` (a tree of directly posed bones) and :class:`~.control_rig.ControlRig` (a
production rig posed through its controls) both implement, and :class:`PosedRig`, what one pose of either
gives."""

from __future__ import annotations

from typing import Protocol

import numpy as np
from scipy import sparse


class PosedRig(Protocol):
    """One pose of a rig: what each deformer does to a rest point, and the chain rule back to the DOFs."""

    #: (s, 3, 4) per deformer (a deform bone, or one B-Bone joint), ``posed = S [rest; 1]``.
    skinning: np.ndarray

    def pullback(self, sums: np.ndarray) -> np.ndarray:
        """(d,) the gradient of a function of the skinning matrices whose gradient with respect to them is
        ``sums`` (s, 3, 4)."""
        ...

    def jacobian(self, weights: np.ndarray, rest: np.ndarray) -> np.ndarray:
        """(m, 3, d) derivatives of the points ``Σ_s weights[v, s] S_s [rest_v; 1]`` (weights (m, s) dense,
        rest (m, 3)) with respect to θ."""
        ...


class RigLike(Protocol):
    """A rig the solver poses: named bones in a tree, a DOF vector θ with limits and locks, and forward
    kinematics with exact derivatives.

    Attributes
    ----------
    names : tuple of str
        The posed bones, parents first.
    parents : (b,) int
        Each bone's parent (-1 for the root).
    deform_bones : tuple of str
        The bones a skin's weights name, one column each.
    dof_bone, dof_component : (d,) int
        The bone and the axis (0, 1, 2) of each DOF.
    dof_names : tuple of str
        ``"bone.rotation.x"`` and the like, per DOF.
    is_rotation : (d,) bool
        Rotation DOFs (the others translate).
    lower, upper : (d,) float
        DOF limits.
    locked : (d,) bool
        DOFs that solves never change.
    """

    names: tuple[str, ...]
    parents: np.ndarray
    deform_bones: tuple[str, ...]
    dof_bone: np.ndarray
    dof_component: np.ndarray
    dof_names: tuple[str, ...]
    is_rotation: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    locked: np.ndarray

    @property
    def n_bones(self) -> int:
        """The number of posed bones."""
        ...

    @property
    def n_dofs(self) -> int:
        """d, the length of θ."""
        ...

    @property
    def rest(self) -> np.ndarray:
        """(d,) the pose the rig was read in (the rest pose for a plain rig)."""
        ...

    @property
    def deform_owner(self) -> np.ndarray:
        """(s,) the posed bone that moves each deformer."""
        ...

    def bone_index(self, name: str) -> int:
        """Index of the posed bone called ``name``."""
        ...

    def rotation_dof(self, bone: int, component: int) -> int:
        """Index of the DOF turning posed bone ``bone`` about its axis ``component``."""
        ...

    def check_theta(self, theta, what: str = "theta") -> np.ndarray:
        """(d,) float64 copy of θ; raises SolverError unless it has one finite value per DOF."""
        ...

    def clip(self, theta) -> np.ndarray:
        """θ (d,), or poses (F, d), within the limits."""
        ...

    def segment_weights(self, weights, rest_vertices) -> sparse.csr_matrix:
        """(n, s) the skin's weights (n, deform bones) per deformer, given the rest vertices (n, 3)."""
        ...

    def root_transform(self, theta) -> np.ndarray:
        """(4, 4) the rigid motion θ gives the hand's root from where θ = 0 puts it, armature space."""
        ...

    def root_dofs(self, G, compatible=None) -> np.ndarray:
        """(6,) root DOFs whose :meth:`root_transform` is the rigid motion ``G`` (4, 4); ``compatible``
        (3,): of equal rotations, the one nearest to these root rotation DOFs."""
        ...

    def kinematics(self, theta, derivatives: bool = True, dofs=None) -> PosedRig:
        """Forward kinematics of θ (d,), with derivatives for the DOFs ``dofs`` (default all) unless
        ``derivatives`` is False."""
        ...
