"""Small shared meshes (session-scoped: TriMesh is immutable), and the README's demo, run once."""

import importlib.util
import os

# One BLAS thread in every process of the suite (its subprocesses inherit it): on two cores shared with
# other work, OpenBLAS threads waiting for each other made small solves several times slower, and
# these small problems gain nothing from them. Set before numpy loads; a value already given wins.
for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from geodesics.mesh import TriMesh  # noqa: E402
from geodesics.primitives import cone, grid_plane  # noqa: E402


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


@pytest.fixture(scope="session")
def demo(tmp_path_factory):
    """The README's first command after its install, ``.venv/bin/contact-edit demo --out demo``, run as
    written in a fresh folder: (the demo's folder, what it printed on stdout)."""
    if importlib.util.find_spec("bpy") is None:
        pytest.skip("needs bpy (the dev extra)")
    from . import readme
    from .blender import fresh_process

    install, pip, line = readme.block("The two commands", "sh", 0).lines()[0].split(" && ")
    assert (install, pip) == ("python3 -m venv .venv", '.venv/bin/pip install -e ".[blender]"')
    folder = tmp_path_factory.mktemp("readme-demo")
    done = fresh_process(readme.command(line), user_dir=folder / "user", cwd=folder)
    assert done.returncode == 0, done.stderr
    return folder / "demo", done.stdout
