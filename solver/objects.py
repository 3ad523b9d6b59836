"""Procedural closed test objects to grasp: sphere, cylinder, box, mug (genus 1), plate with two holes
(genus 2), and a scan-like irregular remesh of any of them.

Every function returns a validated, closed, outward-oriented :class:`~geodesics.TriMesh` in metres,
centred on the origin (the mug and plate stand on z = 0), deterministic for equal arguments. Smooth
shapes with handles and holes are box-modelled cages subdivided twice by Catmull-Clark (see
:mod:`solver.subdivision`); the sphere reuses :func:`geodesics.primitives.icosphere` and the cylinder
:func:`geodesics.primitives.cylinder`.
"""

from __future__ import annotations

import numpy as np

from geodesics import TriMesh
from geodesics.primitives import cylinder as open_tube
from geodesics.primitives import icosphere

from .errors import SolverError
from .subdivision import Cage, catmull_clark, quads_to_triangles

#: scan_like flips an edge only where its two faces' normals differ by less than this (degrees).
MAX_FLIP_BEND = 4.0


def _positive(value, name: str) -> float:
    value = float(value)
    if not (np.isfinite(value) and value > 0):
        raise SolverError(f"{name} must be a positive finite number, got {value!r}")
    return value


def sphere(radius: float = 0.04, subdivisions: int = 3) -> TriMesh:
    """An icosphere of the given radius around the origin (``20 * 4**subdivisions`` faces)."""
    return icosphere(subdivisions, _positive(radius, "radius"))


def cylinder(radius: float = 0.03, height: float = 0.15, n_around: int = 32, n_along: int = 12) -> TriMesh:
    """A closed cylinder around the z axis from ``-height/2`` to ``height/2``, capped by triangle fans."""
    radius, height = _positive(radius, "radius"), _positive(height, "height")
    tube = open_tube(radius, height, n_around, n_along, seed=None)
    V = tube.vertices - [0.0, 0.0, height / 2]
    bottom = np.arange(n_around)
    top = n_along * n_around + np.arange(n_around)
    c0, c1 = len(V), len(V) + 1
    caps = np.concatenate(
        [
            np.stack([np.roll(bottom, -1), bottom, np.full(n_around, c0)], 1),
            np.stack([top, np.roll(top, -1), np.full(n_around, c1)], 1),
        ]
    )
    V = np.concatenate([V, [[0.0, 0.0, -height / 2], [0.0, 0.0, height / 2]]])
    return TriMesh(V, np.concatenate([tube.faces, caps]))


def box(size=(0.06, 0.06, 0.12), cells: int = 8) -> TriMesh:
    """A closed box of side lengths ``size`` (3,) around the origin, each side a ``cells`` x ``cells`` grid
    of quads split into two triangles."""
    size = np.array([_positive(s, "size") for s in size])
    if size.size != 3:
        raise SolverError(f"size needs three side lengths, got {size.size}")
    n = int(cells)
    if n < 1:
        raise SolverError(f"cells must be at least 1, got {cells!r}")
    ids = -np.ones((n + 1,) * 3, np.int64)
    grid = np.indices((n + 1,) * 3).reshape(3, -1).T
    on_surface = np.any((grid == 0) | (grid == n), axis=1)
    ids[tuple(grid[on_surface].T)] = np.arange(on_surface.sum())
    V = (grid[on_surface] / n - 0.5) * size
    faces = []
    a, b = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a, b = a.ravel(), b.ravel()
    for axis in range(3):
        u, v = (axis + 1) % 3, (axis + 2) % 3
        for side, flip in ((0, True), (n, False)):

            def at(i, j, axis=axis, u=u, v=v, side=side):
                idx = [0, 0, 0]
                idx[axis], idx[u], idx[v] = np.full_like(i, side), i, j
                return ids[tuple(idx)]

            quad = np.stack([at(a, b), at(a + 1, b), at(a + 1, b + 1), at(a, b + 1)], 1)
            if flip:
                quad = quad[:, ::-1]
            faces.append(quads_to_triangles(V, quad))
    return TriMesh(V, np.concatenate(faces))


def mug(radius: float = 0.04, height: float = 0.095, wall: float = 0.007, n_around: int = 12) -> TriMesh:
    """A mug (genus 1): a hollow cylinder with a thick bottom and a C-shaped handle on its +x side.

    Box-modelled: a revolved profile (outer wall, rim, inner wall, inside bottom) whose two outer faces
    facing +x are joined by an arched tube, then two Catmull-Clark levels.
    """
    R, H, t = _positive(radius, "radius"), _positive(height, "height"), _positive(wall, "wall")
    base = 1.3 * t
    # (r, z) profile from the outside bottom centre to the inside bottom centre; CC rounds every corner.
    profile = [
        (0.55 * R, 0.0), (R, 0.0), (R, 0.2 * H), (R, 0.38 * H), (R, 0.62 * H), (R, 0.8 * H), (R, H),
        (R - t, H), (R - t, 0.6 * H), (R - t, base + 0.15 * H), (R - t, base), (0.55 * (R - t), base),
    ]  # fmt: skip
    cage = Cage(1)
    angles = 2 * np.pi * (np.arange(n_around) + 0.5) / n_around
    ring = []
    for r, z in profile:
        pts = np.stack([r * np.cos(angles), r * np.sin(angles), np.full(n_around, z)], 1)
        ring.append(cage.add_vertices(pts, [1.0]))
    bottom_pole = cage.add_vertices([[0.0, 0.0, 0.0]], [1.0])[0]
    inner_pole = cage.add_vertices([[0.0, 0.0, base]], [1.0])[0]
    faces = {}
    for k in range(len(profile) - 1):
        for i in range(n_around):
            j = (i + 1) % n_around
            faces[k, i] = cage.add_face((ring[k][i], ring[k][j], ring[k + 1][j], ring[k + 1][i]))
    for i in range(n_around):
        j = (i + 1) % n_around
        cage.add_face((bottom_pole, ring[0][j], ring[0][i]))
        cage.add_face((inner_pole, ring[-1][i], ring[-1][j]))
    # The handle: extrude the outer face between profile rows 4-5 (upper) along an arch, bridge it to the
    # face between rows 2-3 (lower). Faces k = n_around - 1 and 0 straddle the +x direction.
    upper, lower = faces[4, n_around - 1], faces[2, n_around - 1]
    zu, zl = 0.71 * H, 0.29 * H
    reach, half = 0.8 * R, 0.16 * R
    for phi in np.linspace(np.pi / 2, -np.pi / 2, 7)[1:-1]:
        c = np.array(
            [
                R * np.cos(np.pi / n_around) + reach * np.cos(phi),
                0.0,
                0.5 * (zu + zl) + 0.5 * (zu - zl) * np.sin(phi),
            ]
        )
        tangent = np.array([-reach * np.sin(phi), 0.0, 0.5 * (zu - zl) * np.cos(phi)])
        tangent /= np.linalg.norm(tangent)
        side = np.cross(tangent, [0.0, 1.0, 0.0])
        corners = [
            c + a * half * side + b * 1.3 * half * np.array([0, 1.0, 0])
            for a, b in ((1, 1), (-1, 1), (-1, -1), (1, -1))
        ]
        cage.extrude([upper], corners, [1.0])  # fmt: skip
    cage.bridge(upper, lower)
    points, quads, _ = catmull_clark(cage.points, cage.faces, cage.attributes, 2)
    return TriMesh(points, quads_to_triangles(points, quads))


def plate(radius: float = 0.1, thickness: float = 0.014, cells: int = 7) -> TriMesh:
    """A round slab with two holes (genus 2), lying on z = 0.

    Box-modelled: a ``cells`` x ``cells`` slab of quads mapped onto a disk, two cells left open on the
    x axis, their walls joining top and bottom, then two Catmull-Clark levels.
    """
    R, T = _positive(radius, "radius"), _positive(thickness, "thickness")
    n = int(cells)
    if n < 5 or n % 2 == 0:
        raise SolverError(f"cells must be an odd number of at least 5, got {cells!r}")
    mid = n // 2
    holes = {(mid - 1 - (n > 5), mid), (mid + 1 + (n > 5), mid)}
    u = np.linspace(-1.0, 1.0, n + 1)
    U, V = np.meshgrid(u, u, indexing="ij")
    X = R * U * np.sqrt(1 - V**2 / 2)
    Y = R * V * np.sqrt(1 - U**2 / 2)
    cage = Cage(1)
    ids = np.empty((n + 1, n + 1, 2), np.int64)
    for k, z in ((0, 0.0), (1, T)):
        pts = np.stack([X.ravel(), Y.ravel(), np.full(X.size, z)], 1)
        ids[:, :, k] = cage.add_vertices(pts, [1.0]).reshape(n + 1, n + 1)
    for i in range(n):
        for j in range(n):
            if (i, j) in holes:
                continue
            cage.add_face((ids[i, j, 1], ids[i + 1, j, 1], ids[i + 1, j + 1, 1], ids[i, j + 1, 1]), (0, 0, 1))
            cage.add_face(
                (ids[i, j, 0], ids[i + 1, j, 0], ids[i + 1, j + 1, 0], ids[i, j + 1, 0]), (0, 0, -1)
            )
    walls = []  # (edge of the top grid, outward direction): the rim and the hole walls
    for i in range(n):
        walls += [((i, 0), (i + 1, 0), (0, -1)), ((i, n), (i + 1, n), (0, 1))]
        walls += [((0, i), (0, i + 1), (-1, 0)), ((n, i), (n, i + 1), (1, 0))]
    for i, j in holes:
        walls += [((i, j), (i + 1, j), (0, 1)), ((i, j + 1), (i + 1, j + 1), (0, -1))]
        walls += [((i, j), (i, j + 1), (1, 0)), ((i + 1, j), (i + 1, j + 1), (-1, 0))]
    for a, b, out in walls:
        quad = (ids[a][0], ids[b][0], ids[b][1], ids[a][1])
        cage.add_face(quad, (*out, 0.0))
    points, quads, _ = catmull_clark(cage.points, cage.faces, cage.attributes, 2)
    return TriMesh(points, quads_to_triangles(points, quads))


def scan_like(
    mesh: TriMesh, seed: int = 0, split: float = 0.5, flips: int = 3, noise: float = 0.0
) -> TriMesh:
    """An irregular remesh of a surface, like a scan: random face splits and edge flips.

    Parameters
    ----------
    mesh : TriMesh
    seed : int
        Seed of ``np.random.default_rng``; equal arguments give identical meshes.
    split : float
        Fraction of the faces split in three at a random interior point (the surface is unchanged).
    flips : int
        Rounds of random edge flips, each flipping up to half the edges whose two faces are nearly
        coplanar (bend below :data:`MAX_FLIP_BEND`): skinny triangles and irregular valences.
    noise : float
        Vertices move along their normals by up to this fraction of the mean edge length.

    Returns
    -------
    TriMesh
        Same topology (genus, components) as ``mesh``.
    """
    if not 0 <= split <= 1:
        raise SolverError(f"split must be in [0, 1], got {split!r}")
    rng = np.random.default_rng(seed)
    V, F = mesh.vertices.copy(), mesh.faces.copy()
    chosen = np.flatnonzero(rng.random(len(F)) < split)
    centre = np.einsum("kc,kcd->kd", rng.dirichlet([3.0, 3.0, 3.0], chosen.size), V[F[chosen]])
    c = len(V) + np.arange(chosen.size)
    V = np.concatenate([V, centre])
    a, b, d = F[chosen].T
    F = np.concatenate(
        [np.delete(F, chosen, axis=0), np.stack([a, b, c], 1), np.stack([b, d, c], 1), np.stack([d, a, c], 1)]
    )
    for _ in range(int(flips)):
        F = _random_flips(V, F, rng)
    if noise > 0:
        current = TriMesh(V, F)
        step = noise * current.mean_edge_length * rng.uniform(-1.0, 1.0, len(V))
        V = V + step[:, None] * current.vertex_normals
    return TriMesh(V, F)


def _random_flips(V: np.ndarray, F: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Flip a random set of edges no two of which share a face, where the flip is valid."""
    mesh = TriMesh(V, F)
    h = np.flatnonzero(mesh.twin > np.arange(mesh.twin.size))  # one halfedge per interior edge
    h = h[rng.permutation(h.size)[: h.size // 2]]
    t = mesh.twin[h]
    f1, f2 = h // 3, t // 3
    a, b = mesh.halfedge_tail[h], mesh.halfedge_head[h]
    c = F[f1, (h % 3 + 2) % 3]
    d = F[f2, (t % 3 + 2) % 3]
    n1, n2 = mesh.face_normals[f1], mesh.face_normals[f2]
    ok = np.einsum("ij,ij->i", n1, n2) > np.cos(np.radians(MAX_FLIP_BEND))
    new1, new2 = np.stack([c, a, d], 1), np.stack([d, b, c], 1)
    for new in (new1, new2):
        e1, e2 = V[new[:, 1]] - V[new[:, 0]], V[new[:, 2]] - V[new[:, 0]]
        normal = np.cross(e1, e2)
        area2 = np.linalg.norm(normal, axis=1)
        longest = np.max(
            [np.linalg.norm(e1, axis=1), np.linalg.norm(e2, axis=1), np.linalg.norm(e2 - e1, axis=1)], axis=0
        )
        ok &= (area2 > 1e-3 * longest**2) & (np.einsum("ij,ij->i", normal, n1 + n2) > 0)
    existing = set(zip(*np.sort(np.stack([mesh.halfedge_tail, mesh.halfedge_head]), axis=0), strict=True))
    used = np.zeros(len(F), bool)
    new_faces = F.copy()
    for k in np.flatnonzero(ok):
        edge = (min(c[k], d[k]), max(c[k], d[k]))
        if used[f1[k]] or used[f2[k]] or edge in existing:
            continue
        used[f1[k]] = used[f2[k]] = True
        existing.add(edge)
        new_faces[f1[k]], new_faces[f2[k]] = new1[k], new2[k]
    return new_faces
