"""The exception of the solver package.

Every error names what is wrong and where (which bone, which DOF, which vertex, which contact); the
offending indices are also kept as arrays so that a user interface can select them.
"""

from __future__ import annotations

from numbers import Integral

import numpy as np

from geodesics.errors import describe_ids

__all__ = ["SolverError", "check_count", "describe_ids"]


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


def check_count(value, name: str, least: int = 1, note: str = "") -> int:
    """``value`` as an int, refused (:class:`SolverError`) unless it is a whole number of at least ``least``
    (an ``Integral``, not a bool: 2.0 is not a count); ``note`` ends the message (what the bound is for,
    what else is accepted)."""
    if isinstance(value, bool) or not isinstance(value, Integral) or value < least:
        raise SolverError(f"{name} must be a whole number of at least {least}{note}, got {value!r}")
    return int(value)
