"""The bridge's exception."""

from __future__ import annotations

import numpy as np


class BridgeError(RuntimeError):
    """Blender data that cannot be turned into what the libraries need, in an animator's words.

    ``object_name``, ``polygons`` and ``vertices`` say where, so the interface can select them.
    """

    def __init__(self, message: str, object_name: str = "", polygons=(), vertices=()):
        super().__init__(message)
        self.object_name = object_name
        self.polygons = np.asarray(polygons, np.int64)
        self.vertices = np.asarray(vertices, np.int64)
