"""Small shared meshes (session-scoped: TriMesh is immutable)."""

import numpy as np
import pytest

from geodesics.mesh import TriMesh
from geodesics.primitives import cone, grid_plane


@pytest.fixture(scope="session")
def flat_grid() -> TriMesh:
    """An irregular (jittered, random diagonals) triangulation of the rectangle [0, 1.2] x [0, 1] in z = 0."""
    return grid_plane(6, 5, size=(1.2, 1.0), jitter=0.2, seed=3)


@pytest.fixture(scope="session")
def bumpy() -> TriMesh:
    """A small irregular, non-flat mesh with a boundary: a jittered grid whose vertices get random heights.

    Its interior vertices have angle sums both below and above 2π, its boundary vertices sums other than π.
    """
    base = grid_plane(5, 5, jitter=0.2, seed=7)
    V = base.vertices.copy()
    V[:, 2] = 0.3 * np.random.default_rng(11).random(len(V))
    return TriMesh(V, base.faces)


@pytest.fixture(scope="session")
def sharp_cone() -> TriMesh:
    """A tall cone with its apex as the last vertex: apex angle sum 2π sin(atan(1/4)) ≈ 1.52 < π."""
    return cone(base_radius=1.0, height=4.0, top_radius=0.0, n_around=16, n_along=4, jitter=0.15, seed=5)


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: a long test that runs by default (deselect: -m 'not slow')")
