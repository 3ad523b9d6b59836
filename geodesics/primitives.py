"""Deterministic procedural surfaces for tests and benchmarks.

Every function returns a validated :class:`~geodesics.mesh.TriMesh` whose faces are counter-clockwise seen
from outside (from +z for the plane, away from the axis for tubes and cones, away from the centre for closed
surfaces). Construction is vectorized with numpy, and all randomness comes from
``np.random.default_rng(seed)``, so equal arguments give identical arrays.

Grid-like surfaces (:func:`grid_plane`, :func:`cylinder`, :func:`cone`) are built on a parameter grid whose
cells are split into two triangles along a diagonal chosen at random per cell (so vertex valences vary
from 4 to 8), and whose vertices may be jittered along the surface by up to ``jitter`` times the cell size.
On the cylinder and the cone, the angle is jittered per generator line (all vertices of a column keep one
angle) and the height per vertex: every strip between two neighbouring generator lines is then planar, so
the meshes stay developable (interior angle sums exactly 2π, apart from the cone's apex) and geodesics on
them can be checked by unrolling.
Pass ``seed=None`` (with ``jitter=0``) for the regular triangulation where every cell is split the same way.
The diagonals are drawn before the jitter, so for one seed they do not depend on ``jitter``. ``jitter`` must
be below 1/4: then every triangle of the parameter grid keeps a positive area (at least ``(1 - 4 jitter) / 2``
cell areas), whichever diagonal it uses.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, Delaunay

from .errors import MeshError
from .mesh import TriMesh

#: Jitter is a fraction of the cell size and must stay below this for every triangle to stay valid.
MAX_JITTER = 0.25
#: Random scan-like surfaces are redrawn (from the same generator, so still deterministic) at most this often.
MAX_ATTEMPTS = 64
#: scan_like_torus needs this many points for its periodic Delaunay triangulation to be a simple torus.
MIN_TORUS_POINTS = 100


# ------------------------------------------------------------------------------------------------- helpers


def _count(value, name: str, minimum: int) -> int:
    if isinstance(value, bool) or int(value) != value or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def _positive(value, name: str) -> float:
    value = float(value)
    if not (np.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return value


def _jitter_rng(jitter, seed) -> tuple[float, np.random.Generator | None]:
    jitter = float(jitter)
    if not 0.0 <= jitter < MAX_JITTER:
        raise ValueError(f"jitter must be in [0, {MAX_JITTER}), got {jitter!r}")
    if seed is None:
        if jitter > 0:
            raise ValueError("jitter needs a seed (seed=None means the regular, unjittered triangulation)")
        return jitter, None
    return jitter, np.random.default_rng(seed)


def _grid_faces(ni: int, nj: int, wrap_i: bool, wrap_j: bool, rng: np.random.Generator | None) -> np.ndarray:
    """Faces of an ``ni`` x ``nj`` cell grid, two triangles per cell, counter-clockwise in (i, j).

    Vertex ``(i, j)`` has index ``j * ni_v + i`` with ``ni_v = ni`` if ``wrap_i`` (i is periodic) else
    ``ni + 1``. Cell ``(i, j)``, with corners a = (i, j), b = (i+1, j), c = (i+1, j+1), d = (i, j+1), becomes
    (a, b, c), (a, c, d) or, when its diagonal is flipped, (a, b, d), (b, c, d). Diagonals are flipped at
    random (``rng``) or never (``rng is None``). Faces are ordered by cell (row-major in j, then i).
    """
    ni_v = ni if wrap_i else ni + 1
    nj_v = nj if wrap_j else nj + 1
    i = np.arange(ni)
    j = np.arange(nj)
    i1 = (i + 1) % ni_v
    j1 = (j + 1) % nj_v
    a = j[:, None] * ni_v + i[None, :]
    b = j[:, None] * ni_v + i1[None, :]
    c = j1[:, None] * ni_v + i1[None, :]
    d = j1[:, None] * ni_v + i[None, :]
    flip = rng.random((nj, ni)) < 0.5 if rng is not None else np.zeros((nj, ni), bool)
    first = np.where(flip[..., None], np.stack([a, b, d], -1), np.stack([a, b, c], -1))
    second = np.where(flip[..., None], np.stack([b, c, d], -1), np.stack([a, c, d], -1))
    return np.stack([first, second], axis=2).reshape(-1, 3).astype(np.int64)


def _grid_params(
    ni_v: int, nj_v: int, jitter: float, rng, fixed_i=(), fixed_j=(), column_u=False
) -> tuple[np.ndarray, np.ndarray]:
    """(nj_v, ni_v) parameter coordinates ``u = i + du``, ``v = j + dv`` with ``|du|, |dv| <= jitter``.

    ``fixed_i`` lists vertex columns whose ``u`` is not jittered, ``fixed_j`` vertex rows whose ``v`` is not.
    With ``column_u``, all vertices of a column share one ``du`` (they stay on one generator line).
    """
    u = np.broadcast_to(np.arange(ni_v, dtype=np.float64)[None, :], (nj_v, ni_v)).copy()
    v = np.broadcast_to(np.arange(nj_v, dtype=np.float64)[:, None], (nj_v, ni_v)).copy()
    if jitter > 0:
        shape = (1, ni_v) if column_u else (nj_v, ni_v)
        du = np.broadcast_to(rng.uniform(-jitter, jitter, shape), (nj_v, ni_v)).copy()
        dv = rng.uniform(-jitter, jitter, (nj_v, ni_v))
        du[:, list(fixed_i)] = 0.0
        dv[list(fixed_j), :] = 0.0
        u += du
        v += dv
    return u.ravel(), v.ravel()


# ------------------------------------------------------------------------------------------- open surfaces


def grid_plane(nx: int, ny: int, size=(1.0, 1.0), jitter=0.0, seed=0) -> TriMesh:
    """The rectangle ``[0, size[0]] x [0, size[1]]`` in the plane z = 0, triangulated on an nx x ny grid.

    Parameters
    ----------
    nx, ny : int
        Number of cells along x and y (at least 1 each).
    size : (2,) float
        Side lengths of the rectangle.
    jitter : float
        In [0, 0.25). Interior vertices move in the plane by a uniform random offset of up to ``jitter``
        cell widths along x and up to ``jitter`` cell heights along y; boundary vertices move only along
        their side of the rectangle, corners not at all.
    seed : int or None
        Seed of ``np.random.default_rng`` for the diagonals (one random diagonal per cell) and the jitter.
        ``None`` gives the regular triangulation (every cell split from its lower-left to its upper-right
        corner) and requires ``jitter == 0``.

    Returns
    -------
    TriMesh
        ``(nx + 1) * (ny + 1)`` vertices, vertex ``(i, j)`` (column i, row j, starting at the origin) at index
        ``j * (nx + 1) + i``; ``2 * nx * ny`` faces, two per cell in row-major cell order, counter-clockwise
        seen from +z. One boundary loop of ``2 * (nx + ny)`` edges.
    """
    nx, ny = _count(nx, "nx", 1), _count(ny, "ny", 1)
    sx, sy = (_positive(s, "size") for s in size)
    jitter, rng = _jitter_rng(jitter, seed)
    faces = _grid_faces(nx, ny, False, False, rng)
    u, v = _grid_params(nx + 1, ny + 1, jitter, rng, fixed_i=(0, nx), fixed_j=(0, ny))
    vertices = np.stack([u / nx * sx, v / ny * sy, np.zeros_like(u)], 1)
    return TriMesh(vertices, faces)


def cylinder(radius=1.0, height=1.0, n_around=32, n_along=8, jitter=0.0, seed=0) -> TriMesh:
    """An open tube of the given radius around the z axis, from z = 0 to z = height.

    Parameters
    ----------
    radius, height : float
    n_around : int
        Cells around the axis (at least 3).
    n_along : int
        Cells along the axis (at least 1).
    jitter : float
        In [0, 0.25). Each column of vertices (a generator line) turns by up to ``jitter`` cells around the
        axis, and each vertex moves along its generator by up to ``jitter`` cells in height, except on the
        two boundary circles, which stay at z = 0 and z = height. Vertices stay exactly on the cylinder and
        the mesh stays developable (see the module docstring).
    seed : int or None
        As for :func:`grid_plane`.

    Returns
    -------
    TriMesh
        ``n_around * (n_along + 1)`` vertices, vertex (i around, j along) at index ``j * n_around + i``
        and, when not jittered, at angle ``2π i / n_around`` and height ``height * j / n_along``;
        ``2 * n_around * n_along`` faces with normals pointing away from the axis; two boundary loops.
        Interior angle sums are exactly 2π (every strip between neighbouring generators is planar).
    """
    radius, height = _positive(radius, "radius"), _positive(height, "height")
    n_around, n_along = _count(n_around, "n_around", 3), _count(n_along, "n_along", 1)
    jitter, rng = _jitter_rng(jitter, seed)
    faces = _grid_faces(n_around, n_along, True, False, rng)
    u, v = _grid_params(n_around, n_along + 1, jitter, rng, fixed_j=(0, n_along), column_u=True)
    theta = 2 * np.pi * u / n_around
    vertices = np.stack([radius * np.cos(theta), radius * np.sin(theta), v / n_along * height], 1)
    return TriMesh(vertices, faces)


def cone(base_radius=1.0, height=1.0, top_radius=0.2, n_around=32, n_along=8, jitter=0.0, seed=0) -> TriMesh:
    """The lateral surface of the right circular cone with apex (0, 0, height) and base circle of radius
    ``base_radius`` at z = 0 (open there), optionally truncated.

    A point at height z lies at distance ``base_radius * (1 - z / height)`` from the axis.

    Parameters
    ----------
    base_radius, height : float
    top_radius : float
        In [0, base_radius). If positive, the cone is cut at the circle of that radius (at height
        ``height * (1 - top_radius / base_radius)``), which is a second boundary loop, and the apex is not
        part of the surface. If 0, the apex is a vertex surrounded by a fan of ``n_around`` triangles; its
        angle sum is about ``2π sin(atan(base_radius / height))`` rather than 2π (a cone point).
    n_around : int
        Cells around the axis (at least 3).
    n_along : int
        Cells from the base to the top circle or apex (at least 1; with an apex, the last row of cells is the
        fan).
    jitter : float
        In [0, 0.25). Each column of vertices (a generator line through the apex) turns by up to ``jitter``
        cells around the axis, and each vertex moves along its generator by up to ``jitter`` cells in height;
        the base circle (and the top circle) keep their height and the apex stays put. All vertices stay
        exactly on the cone and the mesh stays developable away from the apex (see the module docstring).
    seed : int or None
        As for :func:`grid_plane`.

    Returns
    -------
    TriMesh
        Vertex (i around, j along) at index ``j * n_around + i``, the apex (if any) last. Truncated:
        ``n_around * (n_along + 1)`` vertices and ``2 * n_around * n_along`` faces; with apex:
        ``n_around * n_along + 1`` vertices and ``n_around * (2 * n_along - 1)`` faces (the fan last).
        Normals point away from the axis (and up). Interior angle sums are exactly 2π except at the apex
        (every strip between neighbouring generators lies in one plane through the apex).
    """
    base_radius, height = _positive(base_radius, "base_radius"), _positive(height, "height")
    top_radius = float(top_radius)
    if not (np.isfinite(top_radius) and 0 <= top_radius < base_radius):
        raise ValueError(f"top_radius must be in [0, base_radius={base_radius}), got {top_radius!r}")
    n_around, n_along = _count(n_around, "n_around", 3), _count(n_along, "n_along", 1)
    jitter, rng = _jitter_rng(jitter, seed)
    apex = top_radius == 0
    rows = n_along if apex else n_along + 1  # rings of vertices
    faces = _grid_faces(n_around, rows - 1, True, False, rng)
    fixed = (0,) if apex else (0, n_along)
    u, v = _grid_params(n_around, rows, jitter, rng, fixed_j=fixed, column_u=True)
    z_top = height if apex else height * (1 - top_radius / base_radius)
    theta = 2 * np.pi * u / n_around
    z = v / n_along * z_top  # exactly z_top on the top circle, since v == n_along there is not jittered
    r = base_radius * (1 - z / height)
    vertices = np.stack([r * np.cos(theta), r * np.sin(theta), z], 1)
    if apex:
        tip = n_around * rows
        ring = (rows - 1) * n_around + np.arange(n_around)
        fan = np.stack([ring, np.roll(ring, -1), np.full(n_around, tip)], 1)
        faces = np.concatenate([faces, fan])
        vertices = np.concatenate([vertices, [[0.0, 0.0, height]]])
    return TriMesh(vertices, faces)


# ----------------------------------------------------------------------------------------- closed surfaces

_ICOSAHEDRON_FACES = np.array(
    [
        [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
        [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
        [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
        [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1],
    ],
    dtype=np.int64,
)  # fmt: skip


def _icosahedron() -> np.ndarray:
    t = (1 + np.sqrt(5.0)) / 2
    V = np.array(
        [
            [-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0],
            [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
            [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1],
        ]
    )  # fmt: skip
    return V / np.linalg.norm(V, axis=1, keepdims=True)


def icosphere(subdivisions=3, radius=1.0) -> TriMesh:
    """A sphere around the origin: an icosahedron whose faces are split in four ``subdivisions`` times, each
    new edge midpoint being projected onto the sphere.

    Parameters
    ----------
    subdivisions : int
        At least 0 (0 gives the regular icosahedron).
    radius : float

    Returns
    -------
    TriMesh
        ``10 * 4**s + 2`` vertices, all at distance ``radius`` from the origin (12 of valence 5, the others
        of valence 6); ``20 * 4**s`` faces, outward oriented.
    """
    s = _count(subdivisions, "subdivisions", 0)
    radius = _positive(radius, "radius")
    V = _icosahedron()
    F = _ICOSAHEDRON_FACES.copy()
    for _ in range(s):
        n = len(V)
        e = F[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
        lo, hi = e.min(1), e.max(1)
        keys, inv = np.unique(lo * n + hi, return_inverse=True)
        a, b = keys // n, keys % n
        mid = V[a] + V[b]
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        V = np.concatenate([V, mid])
        m = (n + inv).reshape(-1, 3)  # midpoints of edges 01, 12, 20 of each face
        F = np.concatenate(
            [
                np.stack([F[:, 0], m[:, 0], m[:, 2]], 1),
                np.stack([m[:, 0], F[:, 1], m[:, 1]], 1),
                np.stack([m[:, 2], m[:, 1], F[:, 2]], 1),
                m,
            ]
        )
    return TriMesh(V * radius, F)


def _torus_points(u: np.ndarray, v: np.ndarray, major: float, minor: float) -> np.ndarray:
    """Torus parametrization with u around the z axis and v around the tube, both of period 1.

    Counter-clockwise in (u, v) is outward: ``X_u x X_v`` points away from the tube's core circle.
    """
    a, b = 2 * np.pi * u, 2 * np.pi * v
    ring = major + minor * np.cos(b)
    return np.stack([ring * np.cos(a), ring * np.sin(a), minor * np.sin(b)], 1)


def _check_torus_radii(major, minor) -> tuple[float, float]:
    major, minor = _positive(major, "major"), _positive(minor, "minor")
    if minor >= major:
        raise ValueError(f"minor radius {minor} must be smaller than major radius {major}")
    return major, minor


def torus(major=1.0, minor=0.35, n_major=48, n_minor=24) -> TriMesh:
    """A regular torus around the z axis: core circle of radius ``major`` in z = 0, tube radius ``minor``.

    Parameters
    ----------
    major, minor : float
        ``0 < minor < major``.
    n_major : int
        Vertices around the z axis (at least 3).
    n_minor : int
        Vertices around the tube (at least 3).

    Returns
    -------
    TriMesh
        ``n_major * n_minor`` vertices, vertex (i around the axis, j around the tube) at index
        ``j * n_major + i`` and at the parameter angles ``2π i / n_major``, ``2π j / n_minor`` (j = 0 on the
        outer equator); ``2 * n_major * n_minor`` faces, outward oriented.
    """
    major, minor = _check_torus_radii(major, minor)
    n_major, n_minor = _count(n_major, "n_major", 3), _count(n_minor, "n_minor", 3)
    faces = _grid_faces(n_major, n_minor, True, True, None)
    i = np.tile(np.arange(n_major), n_minor)
    j = np.repeat(np.arange(n_minor), n_major)
    return TriMesh(_torus_points(i / n_major, j / n_minor, major, minor), faces)


# -------------------------------------------------------------------------------------- scan-like surfaces


def scan_like_sphere(n_points: int, radius=1.0, seed=0) -> TriMesh:
    """Uniformly random points on a sphere, triangulated by their convex hull: skinny triangles and
    irregular valences, like a scanned surface.

    Parameters
    ----------
    n_points : int
        Number of vertices (at least 4).
    radius : float
    seed : int
        Seed of ``np.random.default_rng``. In the (never observed) event that qhull leaves a point out of the
        hull or produces a degenerate triangle, the points are redrawn from the same generator, so the result
        is still a deterministic function of the seed.

    Returns
    -------
    TriMesh
        ``n_points`` vertices at distance ``radius`` from the origin, ``2 * n_points - 4`` faces oriented
        outward.
    """
    n = _count(n_points, "n_points", 4)
    radius = _positive(radius, "radius")
    rng = np.random.default_rng(seed)
    for _ in range(MAX_ATTEMPTS):
        X = rng.normal(size=(n, 3))
        X /= np.linalg.norm(X, axis=1, keepdims=True)
        hull = ConvexHull(X)
        F = hull.simplices.astype(np.int64)
        if len(F) != 2 * n - 4 or np.unique(F).size != n:
            continue
        normal = np.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]])
        inward = np.einsum("ij,ij->i", normal, hull.equations[:, :3]) < 0
        F[inward] = F[inward][:, ::-1]
        try:
            return TriMesh(X * radius, F)
        except MeshError:
            continue
    raise RuntimeError(f"no valid hull of {n} random points in {MAX_ATTEMPTS} attempts")  # pragma: no cover


def scan_like_torus(n_points: int, major=1.0, minor=0.35, seed=0) -> TriMesh:
    """Uniformly random points of the torus's (u, v) parameter square, triangulated by their periodic
    Delaunay triangulation and mapped onto the torus (see :func:`torus`): skinny triangles and irregular
    valences, like a scanned surface.

    The triangulation is the Delaunay triangulation (scipy.spatial.Delaunay) of the points tiled 3 x 3,
    keeping each periodic triangle once (the copy whose lowest-numbered vertex is in the central tile), with
    vertex indices taken modulo ``n_points``. The Delaunay criterion is evaluated with u scaled by ``major``
    and v by ``minor``, i.e. in the flat metric of the torus's core (in the plain unit square, the u direction
    would be stretched ``major / minor`` times more than v on the surface, and with fewer than about a
    thousand points some long, thin triangles would fold over into the tube). Only the tile copies within a
    few point spacings of the unit square are triangulated, which changes nothing near it and leaves most
    copies out.

    Parameters
    ----------
    n_points : int
        Number of vertices, at least ``MIN_TORUS_POINTS`` (100). Thin tubes need more (a few hundred for
        ``minor / major = 0.1``) to resolve the tube without folds.
    major, minor : float
        ``0 < minor < major``.
    seed : int
        Seed of ``np.random.default_rng``. If the kept triangles do not form a closed manifold torus with all
        points as vertices (qhull resolving near-cocircular points differently in different tiles, or a
        degenerate triangle), or some triangle folds over (its normal pointing into the tube, which happens
        for a few percent of the seeds at 100 points and never at a few hundred), all points are redrawn
        from the same generator, so the result is still a deterministic function of the seed.

    Returns
    -------
    TriMesh
        ``n_points`` vertices, ``2 * n_points`` faces, closed, outward oriented.

    Raises
    ------
    RuntimeError
        If no valid triangulation is found in ``MAX_ATTEMPTS`` draws (too few points for the tube).
    """
    n = _count(n_points, "n_points", MIN_TORUS_POINTS)
    major, minor = _check_torus_radii(major, minor)
    rng = np.random.default_rng(seed)
    scale = np.array([major, minor])
    # Only copies within this margin (in parameter units, per axis) of the unit square matter: in the scaled
    # square of area major * minor, it is 8 mean point spacings, several times the diameter of the largest
    # empty circle among n random points (about 2 sqrt(area log n / (π n))), so far beyond any kept triangle.
    margin = np.minimum(1.0, 8.0 * np.sqrt(major * minor / n) / scale)
    offsets = np.array([[0, 0], [-1, -1], [-1, 0], [-1, 1], [0, -1], [0, 1], [1, -1], [1, 0], [1, 1]], float)
    for _ in range(MAX_ATTEMPTS):
        uv = rng.random((n, 2))
        tiled = (uv[None, :, :] + offsets[:, None, :]).reshape(-1, 2)  # tile t holds points t*n .. t*n + n-1
        near = np.flatnonzero(np.all((tiled > -margin) & (tiled < 1 + margin), axis=1))
        T = near[Delaunay(tiled[near] * scale).simplices].astype(np.int64)
        lowest = np.argmin(T % n, axis=1)
        T = T[T[np.arange(len(T)), lowest] < n]  # the copy whose lowest-numbered vertex is central
        P = tiled[T]
        area = (P[:, 1, 0] - P[:, 0, 0]) * (P[:, 2, 1] - P[:, 0, 1]) - (P[:, 1, 1] - P[:, 0, 1]) * (
            P[:, 2, 0] - P[:, 0, 0]
        )
        T[area < 0] = T[area < 0][:, ::-1]
        F = T % n
        if len(F) != 2 * n or np.unique(F).size != n:
            continue
        try:
            mesh = TriMesh(_torus_points(uv[:, 0], uv[:, 1], major, minor), F)
        except MeshError:
            continue
        if np.all(mesh.twin >= 0) and mesh.n_components == 1 and not np.any(_folded_on_torus(mesh, major)):
            return mesh
    raise RuntimeError(
        f"no valid periodic triangulation of {n} random points on a torus with radii {major}, {minor} after "
        f"{MAX_ATTEMPTS} attempts; use more points"
    )


def _folded_on_torus(mesh: TriMesh, major: float) -> np.ndarray:
    """(m,) whether each face's normal points into the tube: its dot product with the torus's outward normal
    at the point nearest to the face's centroid is not positive."""
    c = mesh.vertices[mesh.faces].mean(1)
    rho = np.hypot(c[:, 0], c[:, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        core = np.stack([c[:, 0] / rho * major, c[:, 1] / rho * major, np.zeros_like(rho)], 1)
    out = np.einsum("ij,ij->i", mesh.face_normals, c - core)
    return ~(out > 0)
