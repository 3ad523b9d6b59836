"""Evenly spread, deterministic sample points of a surface at a given density (points per unit area).

Each face gets its share of ``area × density`` by stratifying the running total of face areas (so the
count over any set of faces is within one of its area times the density, and the whole surface gets
exactly ``ceil(total area × density − u)`` points for a random offset u), and lays its points out along
a randomly shifted R2 low-discrepancy sequence (Roberts 2018): the first points of the sequence that
fall in the triangle's half of the unit square, so that points within a face keep their distance from
each other (folding the other half over instead would put reflected points next to unreflected ones).
A face's samples depend only on the face, the density and the seed: sampling some faces gives exactly
the samples of the whole surface that lie in them, which is what lets a brush sample the area it covers
and nothing else.
"""

from __future__ import annotations

import numpy as np

from .mesh import TriMesh
from .points import SurfacePoints

#: The plastic number; (1/g, 1/g²) generates the R2 sequence.
PLASTIC = 1.324717957244746
R2_STEP = np.array([1.0 / PLASTIC, 1.0 / PLASTIC**2])


def surface_samples(
    mesh: TriMesh, density: float, faces=None, seed: int = 0
) -> tuple[SurfacePoints, np.ndarray]:
    """Sample points spread evenly over the surface (or the given faces of it).

    Parameters
    ----------
    mesh : TriMesh
    density : float
        Points per unit area (mesh units squared), > 0.
    faces : (f,) array_like of int, optional
        Only the samples that lie in these faces (default: all faces).
    seed : int
        Chooses the offsets; the same seed gives the same points.

    Returns
    -------
    points : SurfacePoints (k)
        Face by face, in increasing face order.
    ids : (k,) int
        Each sample's index among all samples of the surface (the same point has the same id however
        the faces are chosen).
    """
    density = float(density)
    if not np.isfinite(density) or density <= 0:
        raise ValueError(
            f"the sample density must be a positive number of points per unit area, got {density}"
        )
    rng = np.random.default_rng(seed)
    offset = rng.random()
    shifts = rng.random((mesh.n_faces, 2))
    running = np.concatenate([[0.0], np.cumsum(mesh.face_areas)]) * density
    first = np.ceil(running - offset).astype(np.int64)  # first[f]: the id of face f's first sample
    chosen = np.arange(mesh.n_faces) if faces is None else np.unique(np.asarray(faces, np.int64))
    if chosen.size and (chosen[0] < 0 or chosen[-1] >= mesh.n_faces):
        raise ValueError(f"face indices must lie in 0..{mesh.n_faces - 1}")
    counts = first[chosen + 1] - first[chosen]
    face = np.repeat(chosen, counts)
    local = np.arange(face.size) - np.repeat(_starts(counts), counts)
    uv = _first_in_triangle(shifts[chosen], counts)
    bary = np.column_stack([1.0 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]])
    return SurfacePoints(face, bary), first[face] + local


def _starts(counts: np.ndarray) -> np.ndarray:
    """Where each run of ``counts[i]`` consecutive items starts."""
    return np.cumsum(counts) - counts


def _first_in_triangle(shifts: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """(sum(wanted), 2): for each face in turn, the first ``wanted[f]`` points (u, v) of its R2 sequence
    shifted by ``shifts[f]`` that lie in the triangle u + v <= 1."""
    out = np.empty((int(wanted.sum()), 2))
    slots = _starts(wanted)
    todo = np.flatnonzero(wanted > 0)
    tries = 2 * wanted + 16  # about half the unit square's points fall in the triangle
    while todo.size:
        n = tries[todo]
        owner = np.repeat(todo, n)
        k = np.arange(owner.size) - np.repeat(_starts(n), n) + 1
        uv = (shifts[owner] + k[:, None] * R2_STEP) % 1.0
        inside = uv.sum(axis=1) <= 1.0
        seen = np.cumsum(inside)
        rank = seen - np.repeat((seen - inside)[_starts(n)], n) - 1
        got = np.bincount(owner[inside], minlength=len(wanted))[todo]
        enough = np.zeros(len(wanted), bool)
        enough[todo[got >= wanted[todo]]] = True
        take = inside & (rank < wanted[owner]) & enough[owner]
        out[slots[owner[take]] + rank[take]] = uv[take]
        todo = todo[got < wanted[todo]]
        tries[todo] *= 2
    return out
