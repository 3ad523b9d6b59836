"""The spaces constraints work in (``BKE_constraint_mat_convertspace``, ``constraint.cc``), and the armature
object's world matrix that joins pose space to world space."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..errors import SolverError
from .bones import Bone, BoneStack
from .math_matrix import LAST_ROW, inverse_affine
from .parenting import Parenting
from .stack import constant, from_single_stack, matmul, to_single_stack

#: Constraint spaces (``owner_space``/``target_space``) modelled by :class:`Spaces`.
SPACES = ("WORLD", "CUSTOM", "POSE", "LOCAL_WITH_PARENT", "LOCAL", "LOCAL_OWNER_ORIENT")


def _frozen(value) -> np.ndarray:
    array = np.array(value, dtype=np.float64).reshape(4, 4)
    array.setflags(write=False)
    return array


@dataclass(frozen=True, eq=False)
class World:
    """The armature object's ``matrix_world`` with what the constraint solver precomputes of it.

    Attributes
    ----------
    matrix, inverse : (4, 4) ndarray
    identity : bool
        The world matrix is the identity (world and pose space coincide).
    similarity : bool
        A uniform scale times a rotation (of either handedness) plus a translation: constraints that
        only compare lengths read the same in world and pose space.
    proper : bool
        A similarity with a positive determinant: constraints that also turn by cross products read the
        same in world and pose space.
    """

    matrix: np.ndarray
    inverse: np.ndarray
    identity: bool
    similarity: bool
    proper: bool

    @classmethod
    def of(cls, matrix) -> World:
        """The world matrix (4, 4) as a :class:`World` (a World is returned as is)."""
        if isinstance(matrix, World):
            return matrix
        M = _frozen(matrix)
        if not np.all(np.isfinite(M)) or np.any(M[3] != LAST_ROW):
            raise SolverError("the armature's world matrix must be a finite affine matrix")
        gram = M[:3, :3].T @ M[:3, :3]
        scale = gram.trace() / 3.0
        similarity = bool(scale > 0 and np.abs(gram - scale * np.eye(3)).max() <= 1e-12 * scale)
        proper = similarity and np.linalg.det(M[:3, :3]) > 0
        inverse = _frozen(np.linalg.inv(M))
        identity = bool(np.array_equal(M, np.eye(4)))
        return cls(M, inverse, identity, similarity, bool(proper))


class Spaces:
    """``BKE_constraint_mat_convertspace`` for a stack of pose bones (stack layout).

    Parameters
    ----------
    parenting : Parenting
        The bones' parent transforms.
    world : World
    diff : ((g, 1, 4, 4), (g, 1, 4, 4)), optional
        For ``LOCAL_OWNER_ORIENT``: the bones' rest orientations in their constraint owner's rest frame
        (translation dropped) and its inverse (:func:`owner_orientation`); None for the identity (the
        bones are the owners).
    custom : (g, K, 4, 4), optional
        The world matrices of the ``CUSTOM`` space.
    """

    def __init__(self, parenting: Parenting, world: World, diff=None, custom=None):
        self.parenting = parenting
        self.stack = parenting.stack
        self.world = world
        self.diff = diff
        self.custom = custom

    @cached_property
    def _custom_inverse(self):
        return inverse_affine(self.custom)

    def _world_times(self, M):
        return M if self.world.identity else matmul(self.world.matrix, M)

    def _world_inverse_times(self, M):
        return M if self.world.identity else matmul(self.world.inverse, M)

    def convert(self, M, from_space: str, to_space: str):
        """(g, K, 4, 4) ``M`` from one space to another (both in :data:`SPACES`)."""
        for space in (from_space, to_space):
            if space not in SPACES:
                raise SolverError(f"bone {self.stack.names[0]!r}: unknown constraint space {space!r}")
        if "CUSTOM" in (from_space, to_space) and self.custom is None:
            raise SolverError(f"bone {self.stack.names[0]!r}: the CUSTOM space needs its matrix")
        while from_space != to_space:
            M, from_space = self._step(M, from_space, to_space)
        return M

    def _step(self, M, from_space, to_space):
        """One step of ``BKE_constraint_mat_convertspace``'s state machine: (matrix, its new space)."""
        if from_space == "WORLD":
            if to_space == "CUSTOM":
                return matmul(self._custom_inverse, M), "CUSTOM"
            return self._world_inverse_times(M), "POSE"
        if from_space == "POSE":
            if to_space in ("LOCAL", "LOCAL_OWNER_ORIENT"):
                return self.parenting.to_local(M), "LOCAL"
            if to_space == "LOCAL_WITH_PARENT":
                return matmul(self.stack.rest_inverse, M), "LOCAL_WITH_PARENT"
            return self._world_times(M), "WORLD"
        if from_space == "LOCAL":
            if to_space == "LOCAL_OWNER_ORIENT":
                if self.diff is not None:
                    M = matmul(matmul(self.diff[0], M), self.diff[1])
                return M, "LOCAL_OWNER_ORIENT"
            return self.parenting.to_pose(M), "POSE"
        if from_space == "LOCAL_OWNER_ORIENT":
            if self.diff is not None:
                M = matmul(matmul(self.diff[1], M), self.diff[0])
            return M, "LOCAL"
        if from_space == "LOCAL_WITH_PARENT":
            return matmul(self.stack.rest, M), "POSE"
        # CUSTOM
        return matmul(self.custom, M), "WORLD"


def owner_orientation(rests, owner_rests=None):
    """(diff, inverse), each (g, 1, 4, 4): ``LOCAL_OWNER_ORIENT``'s change of frame, the rest matrices
    ``rests`` (g, 4, 4) seen from the owners' ``owner_rests`` (g, 4, 4) (or as they are when None), their
    translations dropped."""
    diff = np.array(rests, dtype=np.float64).reshape(-1, 4, 4)
    if owner_rests is not None:
        diff = np.linalg.inv(np.asarray(owner_rests, dtype=np.float64).reshape(-1, 4, 4)) @ diff
    diff[..., :3, 3] = 0.0
    return constant(diff), constant(np.linalg.inv(diff))


def convert_space(
    matrix,
    from_space: str,
    to_space: str,
    bone: Bone,
    parent: Bone | None,
    parent_pose,
    world,
    *,
    owner: Bone | None = None,
    custom=None,
) -> np.ndarray:
    """(..., 4, 4) ``BKE_constraint_mat_convertspace`` for a pose bone: ``matrix`` from one space to another.

    Parameters
    ----------
    matrix : (..., 4, 4) array_like
    from_space, to_space : str
        One of :data:`SPACES`.
    bone, parent, parent_pose
        The bone whose spaces these are, its parent's rest data and pose matrix (for ``LOCAL``).
    world : (4, 4) array_like or World
        The armature object's ``matrix_world``.
    owner : Bone, optional
        The constraint's owner, whose rest orientation ``LOCAL_OWNER_ORIENT`` uses (default: ``bone``).
    custom : (..., 4, 4) array_like, optional
        The world matrix of the ``CUSTOM`` space.
    """
    stack = BoneStack.of([bone], [parent])
    lead, (M, P, C) = to_single_stack(matrix, None if parent is None else parent_pose, custom)
    diff = owner_orientation([bone.matrix_local], None if owner is None else [owner.matrix_local])
    spaces = Spaces(Parenting(stack, P), World.of(world), diff, C)
    return from_single_stack(spaces.convert(M, from_space, to_space), lead)
