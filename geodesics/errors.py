"""Exceptions and warnings of the geodesics package.

Every error names what is wrong and where; the offending element indices are also kept as arrays so
that a user interface can select them.
"""

from __future__ import annotations

import numpy as np


def _ids(values) -> np.ndarray:
    return (
        np.unique(np.asarray(values, dtype=np.int64).ravel()) if values is not None else np.empty(0, np.int64)
    )


def describe_ids(ids, limit: int = 10) -> str:
    """``"3, 7, 12"`` or ``"3, 7, 12, … (40 in all)"`` for messages: the distinct ``ids`` (any shape)."""
    ids = np.unique(np.asarray(ids).ravel())
    shown = ", ".join(str(int(i)) for i in ids[:limit])
    return shown if ids.size <= limit else f"{shown}, … ({ids.size} in all)"


class MeshError(ValueError):
    """A mesh, or a surface point on it, is not valid input.

    Attributes ``vertices``, ``faces`` and ``edges`` hold the indices of the offending elements
    (edges as ``(k, 2)`` vertex pairs), empty when they do not apply.
    """

    def __init__(self, message: str, *, vertices=None, faces=None, edges=None):
        super().__init__(message)
        self.vertices = _ids(vertices)
        self.faces = _ids(faces)
        self.edges = (
            np.asarray(edges, dtype=np.int64).reshape(-1, 2)
            if edges is not None
            else np.empty((0, 2), np.int64)
        )


class GeodesicError(ValueError):
    """A geodesic query cannot be answered, e.g. its points lie on different connected components."""


class MeshWarning(UserWarning):
    """Something in a mesh was tolerated but is worth knowing (e.g. vertices no face uses)."""


class ContactError(ValueError):
    """A contact operation cannot be carried out: an empty patch, a degenerate axis, a transfer or edit
    that runs off the surface, a malformed contact file. The input is never modified."""
