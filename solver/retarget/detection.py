"""Contacts of a motion that has none, found where the datasets the retargeting paper reads mark them: on
the object, where the skin touches it (GRAB's contact map, whose hand side the paper finds by ray casting).

Area-uniform samples of the object's surface (seeded; :data:`SPACING_FRACTION` of the hand's size apart on
average) that lie within ``contact_distance`` of the posed hand surface, or inside the hand (no deeper than
the pairing cutoff ε, when the hand mesh is closed and has an inside), are the frame's object contacts;
each is then paired with the hand by ray casting along the object's normal (:func:`.pairing.pair_motion`,
§3.2), which discards the few whose ray misses the hand or meets it farther than ε. The add-on reads
motions from Blender scenes this way (``contact_edit_addon.retarget.motion``).

The hand's size is the square root of its surface area in the motion's first frame (0.245 m for the
procedural human hand with its forearm), so the defaults follow the motion's scale.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from geodesics import MeshError, SurfacePoints, TriMesh
from geodesics.closest import ClosestPoints

from ..errors import SolverError
from ..sdf import MeshSDF
from .motion import Contacts, Motion
from .pairing import pair_motion

__all__ = [
    "CONTACT_FRACTION",
    "CUTOFF_FACTOR",
    "SPACING_FRACTION",
    "detect_contacts",
    "hand_size",
    "with_contacts",
]

#: Default contact distance, as a fraction of the hand's size: 2.45 mm for the life-size human hand,
#: about the synthetic motions' 2 mm (``solver.retarget.synthetic.CONTACT_TOLERANCE``).
CONTACT_FRACTION = 0.01
#: Mean spacing of the object's surface samples, as a fraction of the hand's size: 1.5 mm for the human
#: hand, about 45 samples per cm² (43,000 on a mug 12 cm across), some 500 contacts where it holds the mug
#: with the fingertips and palm. Sparser contacts let the retargeting's markers outweigh them, and a
#: larger target hand then ends farther from the object.
SPACING_FRACTION = 0.006
#: Default pairing cutoff ε, in contact distances: 9.8 mm for the human hand, about the paper's 1 cm
#: (``solver.retarget.pairing.DEFAULT_CUTOFF``). Contacts deeper inside the hand than ε are not sought:
#: their rays would meet the skin farther than ε, and the pairing would discard them.
CUTOFF_FACTOR = 4.0

Progress = Callable[[int, int], None]


def with_contacts(
    motion: Motion,
    names: tuple[str, str],
    frames,
    *,
    contact_distance: float | None = None,
    cutoff: float | None = None,
    spacing: float | None = None,
    seed: int = 0,
    progress: Progress | None = None,
) -> Motion:
    """The motion with its dense contacts found and paired (see the module docstring).

    Parameters
    ----------
    motion : Motion
        Its contacts, if any, are replaced.
    names : (str, str)
        The hand's and the object's names, for messages.
    frames : sequence of int
        The scene frame of each motion frame, for messages.
    contact_distance : float, optional
        Object points this close to the hand's skin (scene units) are contacts (default
        :data:`CONTACT_FRACTION` of :func:`hand_size`).
    cutoff : float, optional
        The pairing's ε (default :data:`CUTOFF_FACTOR` contact distances).
    spacing : float, optional
        Mean distance between the object's surface samples (default :data:`SPACING_FRACTION` of the
        hand's size).
    seed : int
        Draws the object's surface samples.
    progress : callable, optional
        ``progress(done, 2 * frames)`` after each frame searched for contacts and each frame paired.

    Raises
    ------
    SolverError
        For a hand that never comes near the object, or contacts none of which pair.
    """
    hand_name, object_name = names
    size = hand_size(motion)
    distance = _positive("contact_distance", contact_distance, CONTACT_FRACTION * size)
    epsilon = _positive("cutoff", cutoff, CUTOFF_FACTOR * distance)
    gap = _positive("spacing", spacing, SPACING_FRACTION * size)
    F = motion.n_frames
    found = detect_contacts(
        motion,
        distance,
        epsilon,
        gap,
        seed,
        frames,
        hand_name,
        progress=None if progress is None else lambda done, _: progress(done, 2 * F),
    )
    if len(found) == 0:
        raise SolverError(
            f"'{hand_name}' never comes within {distance * 1e3:.3g} mm of '{object_name}' in frames "
            f"{frames[0]}-{frames[-1]}, so there are no contacts to retarget; give a larger contact "
            "distance, another frame range, or read the motion without contacts (markers only)",
        )
    motion = replace(motion, object_contacts=found, hand_contacts=None)
    pairing = pair_motion(
        motion,
        "object",
        cutoff=epsilon,
        progress=None if progress is None else lambda done, _: progress(F + done, 2 * F),
    )
    if len(pairing.object_contacts) == 0:
        counts = ", ".join(f"{n} {name}" for name, n in pairing.counts().items() if n)
        raise SolverError(
            f"none of the {len(found)} points of '{object_name}' near '{hand_name}' pair with the "
            f"hand along the object's normals ({counts}; cutoff {epsilon * 1e3:.3g} mm): do the normals "
            "of both meshes point outwards?",
        )
    return pairing.apply(motion)


def hand_size(motion: Motion) -> float:
    """The source hand's size: the square root of its surface area in the motion's first frame."""
    T = motion.hand_vertices[0][motion.hand_mesh.faces]
    return float(np.sqrt(0.5 * np.linalg.norm(np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]), axis=1).sum()))


def detect_contacts(
    motion: Motion,
    contact_distance: float,
    cutoff: float,
    spacing: float,
    seed: int = 0,
    frames=None,
    hand_name: str = "hand",
    progress: Progress | None = None,
) -> Contacts:
    """Object contacts of every frame: the object's surface samples within ``contact_distance`` of the
    posed hand, or inside it no deeper than ``cutoff`` (closed hands only; sought in the frames where
    some sample is found more than half ``contact_distance`` inside the skin, i.e. where the surfaces
    cross that deep, since looking deeper is costly).

    Parameters
    ----------
    motion : Motion
        The hand and the object (any contacts it has are ignored).
    contact_distance, cutoff, spacing : float
        Scene units; ``spacing`` is the samples' mean distance apart (one per ``spacing²`` of surface).
    seed : int
        Draws the samples (area-uniform on the object's rest mesh, the same ones every frame).
    frames : sequence of int, optional
        The scene frame of each motion frame, for messages (default: 0, 1, ...).
    hand_name : str
        For messages.
    progress : callable, optional
        ``progress(done, total)`` after each frame.

    Returns
    -------
    Contacts
        On ``motion.object_mesh``, one set per frame.
    """
    frames = range(motion.n_frames) if frames is None else frames
    samples = _surface_samples(motion.object_mesh, spacing, seed)
    local = samples.positions(motion.object_mesh)
    closed = not np.any(motion.hand_mesh.twin < 0)
    per_frame = []
    for f, frame in enumerate(frames):
        pose = motion.object_poses[f]
        Y = local @ pose[:3, :3].T + pose[:3, 3]
        try:
            posed = TriMesh(motion.hand_vertices[f], motion.hand_mesh.faces)
        except MeshError as err:
            raise SolverError(f"'{hand_name}' is not a valid mesh at frame {frame}: {err}") from None
        if closed:
            sdf = MeshSDF(posed)
            signed, _, face = sdf.query(Y, contact_distance, contact_distance)
            if np.any((face >= 0) & (signed < -0.5 * contact_distance)):  # the object is deep inside
                depth = max(cutoff, contact_distance)
                signed, _, face = sdf.query(Y, depth, depth)
        else:
            found = ClosestPoints(posed).query(Y, contact_distance)
            signed, face = found.distances, found.faces
        per_frame.append(samples[np.flatnonzero((face >= 0) & (signed <= contact_distance))])
        if progress is not None:
            progress(f + 1, motion.n_frames)
    return Contacts.from_frames(per_frame)


def _surface_samples(mesh: TriMesh, spacing: float, seed: int) -> SurfacePoints:
    """Area-uniform random points on a mesh, one per ``spacing²`` of its area (at least one)."""
    rng = np.random.default_rng(seed)
    area = mesh.face_areas
    count = max(1, math.ceil(area.sum() / spacing**2))
    faces = np.sort(rng.choice(mesh.n_faces, size=count, p=area / area.sum()))
    return SurfacePoints(faces, rng.dirichlet([1.0, 1.0, 1.0], count))


def _positive(name: str, value, default: float) -> float:
    if value is None:
        return float(default)
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise SolverError(f"{name} must be a number, got {type(value).__name__}")
    if not (math.isfinite(value) and value > 0):
        raise SolverError(f"{name} must be finite and positive, got {value!r}")
    return float(value)
