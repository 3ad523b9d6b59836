"""The exception of the solver package.

Every error names what is wrong and where (which bone, which DOF, which vertex, which contact); the
offending indices are also kept as arrays so that a user interface can select them.
"""

from __future__ import annotations

import numpy as np

from geodesics.errors import describe_ids

__all__ = ["SolverError", "describe_ids"]


def _ids(values) -> np.ndarray:
    if values is None:
        return np.empty(0, np.int64)
    return np.unique(np.asarray(values, dtype=np.int64).ravel())


class SolverError(ValueError):
    """A rig, a skin, a contact set or a solver setting is not valid input.

    Attributes ``bones``, ``dofs``, ``vertices`` and ``contacts`` hold the indices of the offending
    elements, empty when they do not apply.
    """

    def __init__(self, message: str, *, bones=None, dofs=None, vertices=None, contacts=None):
        super().__init__(message)
        self.bones = _ids(bones)
        self.dofs = _ids(dofs)
        self.vertices = _ids(vertices)
        self.contacts = _ids(contacts)
