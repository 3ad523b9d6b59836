"""Motions exported from the GRAB dataset by the Kinematic Motion Retargeting authors: read and written.

The authors (Lakshmipathy et al., https://github.com/lakshmipathyarjun6/kinematic-motion-retargeting)
turn a GRAB sequence (Taheri et al. 2020) into three self-contained files with
``grab/exportRhandFullSequence.py`` of their fork of GRAB (lakshmipathyarjun6/GRAB): the subject's
right MANO hand and the object, each an OBJ written by ``trimesh.Trimesh(vertices, faces).export`` in
rest pose, and the motion, an ``.npz`` written by ``np.savez`` (uncompressed). Their Maya plugin
``src/GRABMotionSequenceIO/GRABMotionSequenceIO.cpp`` (as of commit b9c7c8e, "Cleanup joint info")
reads that ``.npz`` back. This module reads the ``.npz`` into a :class:`~solver.retarget.Motion`
(:func:`load_grab`; the meshes are loaded by the caller, e.g. with ``geodesics.meshio.load_mesh``) and
writes one (:func:`save_grab`) that their plugin imports.

Format
------
Every array is one-dimensional (``.flatten()`` in the exporter), C order; ``F`` is the frame count,
``n`` the hand OBJ's vertex count, ``C`` the frames with contacts, ``K`` the contacts in all.

================================  =======  ==========  ================================================
member                            dtype    shape       meaning (units)
================================  =======  ==========  ================================================
``numFrames``                     int64    ()          F (the plugin reads it as a 32-bit int)
``handVertices``                  float32  (F*n*3,)    MANO hand vertices in world space, frame by
                                                       frame, vertex by vertex, x y z (metres)
``objectRotations``               float32  (F*3,)      the object's GRAB ``global_orient``, an
                                                       axis-angle vector per frame (radians); see below
``objectTranslations``            float32  (F*3,)      its ``transl`` (metres)
``tableRotations``                float32  (F*3,)      the same for GRAB's table
``tableTranslations``             float32  (F*3,)      (metres)
``contactFrames``                 uint16   (C,)        the frames with object contacts, increasing
``objectContactFrameCounts``      uint16   (C,)        contacts in each of those frames
``objectContactLocations``        uint32   (K,)        their object VERTEX indices (into the object
                                                       OBJ), frame after frame, increasing per frame
``handJointHierarchy``            uint8    (16,)       MANO joint parents (255: the root)
``handRootOrientations``          float    (F*3,)      MANO ``global_orient`` (axis-angle, radians)
``handRootTranslations``          float    (F*3,)      MANO ``transl`` plus the rest wrist (metres)
``handJointOrientations``         float    (F*45,)     MANO ``fullpose``: 15 joints' axis-angles
``handJointsRestConfiguration``   float32  (J*3,)      rest joints relative to their parents (metres;
                                                       the first 16 of MANO's J joints are used)
================================  =======  ==========  ================================================

Units: GRAB is in metres and nothing in the exporter scales (the plugin multiplies by 100 for Maya's
centimetres, ``SCALE_MULT``); a :class:`Motion` is in metres too. Frame rate: GRAB's 120 fps, stored
nowhere (the plugin keys frames with ``MTime::k120FPS``). Contacts: GRAB's per-vertex object contact
map, sparse: frame ``contactFrames[i]`` has the next ``objectContactFrameCounts[i]`` entries of
``objectContactLocations``; the exporter lists only frames with contacts, their vertices increasing
(``np.where``). The hand has no contacts in the file; the paper finds them by ray casting (§3.2,
:func:`~solver.retarget.pair_motion`).

Rotations. GRAB's ``ObjectModel`` (``tools/objectmodel.py``) poses rest vertices as row vectors,
``vertices = v_template @ batch_rodrigues(global_orient) + transl``, so a column vector ``v`` goes to
``R(a)ᵀ v + t`` with ``R(a)`` the Rodrigues matrix of the axis-angle ``a``: the transpose, i.e. the
rotation by ``-|a|`` about ``a``. That is the "inverted theta" of the plugin
(``otf.setToRotationAxis(axis, -theta)``, line 352; ``ttf`` for the table, line 372), whose
``// TODO: Why inverted theta?`` this answers. Hence object space -> world is
``[[R(a)ᵀ, t], [0, 0, 0, 1]]``, with ``R(a)ᵀ = Rotation.from_rotvec(-a)``.

What is read and what is not
----------------------------
:func:`load_grab` reads the nine members the plugin reads: ``numFrames``, ``handVertices``, the four
rotation and translation members and the three contact members, and validates every one (presence,
dtype kind, one dimension, sizes consistent with ``numFrames`` and the meshes' vertex counts, finite
values, contact frames increasing and below ``numFrames``, counts summing to the locations' length,
vertex indices on the object mesh); the table members are validated although unused (see below). The
five ``handJoint*``/``handRoot*`` members describe MANO's skeleton, which a :class:`Motion` does not
hold (its hand is vertices), and the plugin no longer reads them: they are ignored, not even opened.

The table: the export poses GRAB's table mesh, which it does not contain; that mesh is thin and not a
box, and the authors replace it by hand with a box fitted to the scene (the plugin's README). Its pose
is the origin of GRAB's mesh, not a box's centre, so no box follows from the file: the motion has no
table. Add the box you fitted with ``dataclasses.replace(motion, table=pose, table_size=size)``.

Frame numbers: the plugin keys the file's frame ``f`` at Maya time ``f`` for ``f`` = 0 … F-1
(``MTime newFrame((double)frame, MTime::k120FPS)``, lines 257-261) and names each frame's contact set
with that same number (``CONTACT_GROUP_PREFIX + shapeName + "_" + frame``, lines 494-495); the tools
used afterwards in that scene name their sets by the current time too (``m_frame``, the time's value:
``contactRaytraceContext.cpp`` lines 21 and 184-190 for the paired hand contacts,
``contactTransferEditContext.cpp`` lines 61 and 296-298 for the transferred ones), and the contact
exporter writes each set's number as its ``"frame"`` (``contactSequenceIO.cpp`` lines
54-74). So the contact files of a GRAB scene number its frames from 0, not from the 1 of a fresh Maya
timeline: the loaded motion says so (``first_frame`` is :data:`GRAB_FIRST_FRAME`, 0), and
:meth:`ContactSequence.load(…, motion=motion) <solver.retarget.ContactSequence.load>` reads a contact
file onto its frames with that numbering. (That exporter starts its loop at frame 1, line 54, so a
GRAB scene's frame 0 never reaches a contact file.)

Contacts are vertex indices, so the OBJs must keep GRAB's vertex order, as the plugin assumes too:
``trimesh`` keeps it unless two vertices coincide (its default processing merges them); a contact
index past the object mesh's vertices is refused, with that hint.
"""

from __future__ import annotations

import io
from collections.abc import Callable
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from geodesics import TriMesh
from geodesics.errors import describe_ids
from geodesics.files import write_atomically

from .motion import Contacts, Motion, MotionError, read_npz
from .pairing import DEFAULT_CUTOFF, pair_motion

__all__ = [
    "GRAB_FIRST_FRAME",
    "GRAB_FPS",
    "GrabError",
    "grab_poses",
    "grab_rotations",
    "load_grab",
    "save_grab",
]

#: GRAB's capture rate, which the export does not store.
GRAB_FPS = 120.0
#: The Maya frame number of a GRAB export's first frame: the plugin keys frame ``f`` at time ``f``
#: (``GRABMotionSequenceIO.cpp`` lines 257-261), so a GRAB scene runs 0 … F-1, and so do the frame
#: numbers of every contact file made in it. A loaded motion's ``first_frame``.
GRAB_FIRST_FRAME = 0

#: The members :func:`load_grab` reads: dtype kind ("i" integer, "f" floating point).
MEMBERS = {
    "numFrames": "i",
    "handVertices": "f",
    "objectRotations": "f",
    "objectTranslations": "f",
    "tableRotations": "f",
    "tableTranslations": "f",
    "contactFrames": "i",
    "objectContactFrameCounts": "i",
    "objectContactLocations": "i",
}
#: Members of the authors' export that :func:`load_grab` ignores and :func:`save_grab` leaves out.
IGNORED = (
    "handJointHierarchy",
    "handRootOrientations",
    "handRootTranslations",
    "handJointOrientations",
    "handJointsRestConfiguration",
)
_KINDS = {"i": ("iu", "integers"), "f": ("f", "floating point numbers")}
_UINT16, _UINT32 = np.iinfo(np.uint16).max, np.iinfo(np.uint32).max


class GrabError(MotionError):
    """A GRAB export is not valid (or a motion cannot be written as one). ``field`` names the member
    (``"file"`` when the archive itself cannot be read)."""


def load_grab(
    path,
    hand_mesh: TriMesh,
    object_mesh: TriMesh,
    *,
    fps: float = GRAB_FPS,
    pair: bool = True,
    cutoff: float = DEFAULT_CUTOFF,
    progress: Callable[[int, int], None] | None = None,
) -> Motion:
    """Read the authors' GRAB export (``*_right_full_export_motion.npz``) as a motion.

    Parameters
    ----------
    path : str or Path
        The ``.npz`` (read without pickle).
    hand_mesh : TriMesh
        The exported hand OBJ (``*_full_export_handmesh.obj``): the subject's MANO template, its
        vertex count that of ``handVertices``.
    object_mesh : TriMesh
        The exported object OBJ (``*_full_export_objectmesh.obj``), in object space; contacts index
        its vertices.
    fps : float
        Frame rate (GRAB's 120 by default; the file does not store it).
    pair : bool
        Find the hand contacts by ray casting from the object contacts (:func:`pair_motion`,
        ``source="object"``); the motion then holds the kept pairs only. Without it the motion has
        the object contacts and no hand contacts.
    cutoff : float
        ε of the pairing in metres (default :data:`~solver.retarget.pairing.DEFAULT_CUTOFF`).
    progress : callable, optional
        ``progress(done, total)`` after each frame of the pairing.

    Returns
    -------
    Motion
        No table (see the module docstring), ``source_scale`` 1, ``first_frame`` 0 (the Maya frame
        of its first frame, :data:`GRAB_FIRST_FRAME`). Each object contact is its vertex,
        as a surface point of the first face (lowest index) using it, barycentric weight 1 on it; a
        vertex listed twice in a frame is one contact.

    Raises
    ------
    GrabError
        For an unreadable archive, a missing or malformed member (named by ``field``), meshes that do
        not fit the file, or invalid arguments; nothing else escapes for bad file content.
    """
    for name, mesh in (("hand_mesh", hand_mesh), ("object_mesh", object_mesh)):
        if not isinstance(mesh, TriMesh):
            raise GrabError(f"{name} must be a geodesics.TriMesh, got {type(mesh).__name__}", name)
    if isinstance(cutoff, bool) or not isinstance(cutoff, (int, float, np.integer, np.floating)):
        raise GrabError(f"cutoff must be a number, got {type(cutoff).__name__}", "cutoff")
    if not (np.isfinite(cutoff) and cutoff > 0):
        raise GrabError(f"cutoff must be finite and positive, got {cutoff!r}", "cutoff")
    path = Path(path)
    arrays = _read_members(path)
    poses, hand_vertices, contacts = _validate(arrays, hand_mesh, object_mesh, str(path))
    try:
        motion = Motion(
            fps=fps,
            object_mesh=object_mesh,
            object_poses=poses,
            hand_mesh=hand_mesh,
            hand_vertices=hand_vertices,
            object_contacts=contacts,
            first_frame=GRAB_FIRST_FRAME,
        )
    except MotionError as err:
        raise GrabError(f"{path}: {err}", err.field) from None
    if pair:
        motion = pair_motion(motion, "object", cutoff=float(cutoff), progress=progress).apply(motion)
    return motion


def grab_poses(rotations, translations) -> np.ndarray:
    """(F, 4, 4) object space -> world from GRAB axis-angles (F, 3) and translations (F, 3), as
    GRAB's ``ObjectModel`` and the authors' plugin apply them: rotation ``R(a)ᵀ`` (see the module
    docstring)."""
    a = np.asarray(rotations, dtype=np.float64).reshape(-1, 3)
    t = np.asarray(translations, dtype=np.float64).reshape(-1, 3)
    poses = np.zeros((len(a), 4, 4))
    poses[:, :3, :3] = Rotation.from_rotvec(-a).as_matrix()
    poses[:, :3, 3] = t
    poses[:, 3, 3] = 1.0
    return poses


def grab_rotations(poses) -> np.ndarray:
    """(F, 3) the GRAB axis-angles of rigid poses (F, 4, 4): the inverse of :func:`grab_poses`."""
    R = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)[:, :3, :3]
    return Rotation.from_matrix(R).inv().as_rotvec()


def _vertex_contacts(mesh: TriMesh, offsets, vertices) -> Contacts:
    """Contacts at mesh vertices: each vertex a surface point of the first face using it.

    Parameters
    ----------
    mesh : TriMesh
    offsets : (F + 1,) array_like of int
        CSR offsets of ``vertices``.
    vertices : (K,) array_like of int
        Vertex indices, all used by some face.
    """
    slots = mesh.faces.reshape(-1)
    used, first = np.unique(slots, return_index=True)  # first: the lowest slot holding each vertex
    slot = first[np.searchsorted(used, np.asarray(vertices, dtype=np.int64))]
    bary = np.zeros((len(slot), 3))
    bary[np.arange(len(slot)), slot % 3] = 1.0
    return Contacts(offsets, slot // 3, bary)


def _read_members(path: Path) -> dict[str, np.ndarray]:
    """The members of :data:`MEMBERS` from an ``.npz`` (without pickle; others are not read), each
    checked to be present and of its dtype kind and dimension."""
    arrays = read_npz(path, "GRAB export", MEMBERS, strict=False, error=GrabError)
    for name, kind in MEMBERS.items():
        if name not in arrays:
            raise GrabError(
                f"{path}: the member {name!r} is missing (not an export of exportRhandFullSequence.py?)", name
            )
        kinds, what = _KINDS[kind]
        a = arrays[name]
        if a.dtype.kind not in kinds:
            raise GrabError(f"{path}: {name} must hold {what}, got dtype {a.dtype}", name)
        if name == "numFrames" and a.shape not in ((), (1,)):
            raise GrabError(f"{path}: numFrames must be a single integer, got shape {a.shape}", name)
        if name != "numFrames" and a.ndim != 1:
            raise GrabError(
                f"{path}: {name} must be one-dimensional (flattened, as the exporter writes it), "
                f"got shape {a.shape}",
                name,
            )
    return arrays


def _validate(arrays: dict, hand_mesh: TriMesh, object_mesh: TriMesh, source: str):
    """Check the members against each other and the meshes; (poses, hand vertices, contacts)."""

    def fail(name: str, message: str):
        return GrabError(f"{source}: {name}: {message}", name)

    F = int(arrays["numFrames"].reshape(-1)[0])
    if F < 1:
        raise fail("numFrames", f"a motion needs at least one frame, got {F}")
    floats = {}
    for name, per_frame, what in (
        ("handVertices", 3 * hand_mesh.n_vertices, f"{hand_mesh.n_vertices} hand mesh vertices * 3"),
        ("objectRotations", 3, "3"),
        ("objectTranslations", 3, "3"),
        ("tableRotations", 3, "3"),
        ("tableTranslations", 3, "3"),
    ):
        a = arrays[name]
        if a.size != F * per_frame:
            hint = ""
            if name == "handVertices" and a.size % (3 * F) == 0:
                hint = (
                    f" (the file's hand has {a.size // (3 * F)} vertices: is the hand OBJ the exported one?)"
                )
            raise fail(
                name, f"holds {a.size} values, expected numFrames {F} * {what} = {F * per_frame}{hint}"
            )
        a = a.astype(np.float64).reshape(F, -1, 3)
        bad = np.flatnonzero(~np.isfinite(a).all(axis=(1, 2)))
        if bad.size:
            raise fail(name, f"contains NaN or infinite values (frames {describe_ids(bad)})")
        floats[name] = a
    frames, counts, locations = (
        arrays[n] for n in ("contactFrames", "objectContactFrameCounts", "objectContactLocations")
    )
    if len(counts) != len(frames):
        raise fail(
            "objectContactFrameCounts",
            f"has {len(counts)} entries but contactFrames lists {len(frames)} frames",
        )
    bad = np.flatnonzero((frames < 0) | (frames >= F))
    if bad.size:
        raise fail(
            "contactFrames",
            f"entries {describe_ids(bad)} are outside 0..{F - 1} (e.g. {int(frames[bad[0]])})",
        )
    frames = frames.astype(np.int64)
    bad = np.flatnonzero(np.diff(frames) <= 0)
    if bad.size:
        raise fail("contactFrames", f"must be strictly increasing; entries {describe_ids(bad + 1)} are not")
    bad = np.flatnonzero((counts < 0) | (counts > len(locations)))
    if bad.size:
        raise fail(
            "objectContactFrameCounts",
            f"entries {describe_ids(bad)} are negative or exceed the {len(locations)} contact locations",
        )
    counts = counts.astype(np.int64)
    if counts.sum() != len(locations):
        raise fail(
            "objectContactFrameCounts",
            f"sums to {int(counts.sum())} but objectContactLocations holds {len(locations)} vertices",
        )
    n = object_mesh.n_vertices
    bad = np.flatnonzero((locations < 0) | (locations >= n))
    if bad.size:
        raise fail(
            "objectContactLocations",
            f"entries {describe_ids(bad)} are outside the object mesh's vertices 0..{n - 1} "
            f"(e.g. {int(locations[bad[0]])}; is the object OBJ the exported one?)",
        )
    locations = locations.astype(np.int64)
    isolated = np.isin(locations, object_mesh.isolated_vertices)
    if isolated.any():
        raise fail(
            "objectContactLocations",
            f"vertices {describe_ids(locations[isolated])} are on no face of the object mesh",
        )
    # One contact per (frame, vertex), frames in order, vertices increasing within a frame.
    frame_of = np.repeat(frames, counts)
    keys = np.unique(frame_of * n + locations)
    frame_of, vertices = keys // n, keys % n
    offsets = np.searchsorted(frame_of, np.arange(F + 1))
    contacts = _vertex_contacts(object_mesh, offsets, vertices)
    poses = grab_poses(floats["objectRotations"], floats["objectTranslations"])
    return poses, floats["handVertices"], contacts


def save_grab(motion: Motion, path) -> None:
    """Write a motion as the authors' GRAB export, which their Maya plugin imports.

    Only what the format holds is written: ``numFrames``, ``handVertices``, the object's rotations
    and translations (the inverse of :func:`load_grab`'s convention, float32 as the plugin reads
    them), the table's (the motion's table centre pose in every frame; zeros, the identity at the
    origin, without a table) and the object contacts: each contact becomes its face's vertex of the
    largest barycentric weight (the first on ties), one per vertex per frame, vertices increasing;
    frames without contacts are left out, as the exporter does. The five ``handJoint*``/``handRoot*``
    members are left out: they describe MANO's skeleton, which a motion does not have, and the plugin
    does not read them (since commit b9c7c8e; earlier versions also needed MANO's joints in the
    scene). Hand contacts, the table's size, the frame rate (the plugin assumes 120 fps), the
    frame numbering (the plugin keys from 0 whatever the motion's ``first_frame``) and the source rig
    are not in the format. The file is written atomically (complete or untouched).

    Raises
    ------
    GrabError
        If the contacts do not fit the format's integer types (a contact frame past 65535, more than
        65535 contacts in a frame).
    """
    if not isinstance(motion, Motion):
        raise GrabError(f"save_grab needs a Motion, got {type(motion).__name__}", "motion")
    F = motion.n_frames
    frames = np.empty(0, np.int64)
    counts = np.empty(0, np.int64)
    locations = np.empty(0, np.int64)
    contacts = motion.object_contacts
    if contacts is not None and len(contacts):
        corner = np.argmax(contacts.bary, axis=1)
        vertex = motion.object_mesh.faces[contacts.faces, corner]
        n = motion.object_mesh.n_vertices
        keys = np.unique(contacts.frame_index() * n + vertex)
        frame_of, locations = keys // n, keys % n
        frames, counts = np.unique(frame_of, return_counts=True)
    if frames.size and frames[-1] > _UINT16:
        raise GrabError(
            f"contacts in frames past {_UINT16} (e.g. {int(frames[-1])}) do not fit contactFrames (uint16)",
            "contactFrames",
        )
    if counts.size and counts.max() > _UINT16:
        raise GrabError(
            f"frame {int(frames[np.argmax(counts)])} has {int(counts.max())} contact vertices; "
            f"objectContactFrameCounts (uint16) holds at most {_UINT16}",
            "objectContactFrameCounts",
        )
    if locations.size and locations.max() > _UINT32:
        raise GrabError(
            "object vertex indices do not fit objectContactLocations (uint32)", "objectContactLocations"
        )
    table = np.eye(4) if motion.table is None else motion.table
    table = np.broadcast_to(table, (F, 4, 4))
    members = {
        "numFrames": np.array(F, np.int64),
        "handVertices": motion.hand_vertices.astype(np.float32).reshape(-1),
        "objectRotations": grab_rotations(motion.object_poses).astype(np.float32).reshape(-1),
        "objectTranslations": motion.object_poses[:, :3, 3].astype(np.float32).reshape(-1),
        "tableRotations": grab_rotations(table).astype(np.float32).reshape(-1),
        "tableTranslations": table[:, :3, 3].astype(np.float32).reshape(-1),
        "contactFrames": frames.astype(np.uint16),
        "objectContactFrameCounts": counts.astype(np.uint16),
        "objectContactLocations": locations.astype(np.uint32),
    }
    buffer = io.BytesIO()
    np.savez(buffer, **members)
    write_atomically(Path(path), buffer.getvalue())
