"""Hand-object motions: what the retargeting reads, and the versioned ``.npz`` file that stores them.

A :class:`Motion` is a source hand manipulating one rigid object over ``F`` frames at a fixed frame
rate: the object's rest mesh and its per-frame pose, the source hand's topology and its per-frame
world-space vertices, optionally dense per-frame contacts on the object and on the hand (paired row
for row when both are given), a box table, and, when the source is one of the procedural rigs of
:mod:`solver.hands`, its ground-truth DOF curves. Everything is in world space, metres and seconds.

Per-frame contacts are flattened as :class:`Contacts`: frame ``f``'s points are rows
``offsets[f]:offsets[f + 1]`` of ``faces`` and ``bary`` (a CSR layout), so a 1,000-frame motion with
1,500 contacts a frame is three arrays, not a thousand objects.

File format (version 1)
-----------------------
An uncompressed (by default) NumPy ``.npz`` archive: a zip file whose members are ``.npy`` arrays, one
per field below. It is read with ``allow_pickle=False``: no member may hold Python objects. Strings
are stored as 0-d NumPy unicode arrays (dtype ``<U``), scalars as 0-d arrays. Members:

===========================  =======  ==========  ==================================================
member                       dtype    shape       meaning (units)
===========================  =======  ==========  ==================================================
``format``                   unicode  ()          ``"contact-edit/motion"``
``version``                  int64    ()          ``1`` (files of other versions are refused)
``fps``                      float64  ()          frames per second (Hz), finite and positive
``object_mesh_vertices``     float64  (n_o, 3)    the object's rest mesh, object space (metres)
``object_mesh_faces``        int64    (m_o, 3)    its triangles, counter-clockwise seen from outside
``object_poses``             float64  (F, 4, 4)   object space -> world per frame: rigid (rotation
                                                  with det +1, translation in metres, last row
                                                  0 0 0 1, to 1e-6); F >= 1
``hand_mesh_vertices``       float64  (n, 3)      the source hand's rest mesh (its topology; metres)
``hand_mesh_faces``          int64    (m, 3)      its triangles
``hand_vertices``            float64  (F, n, 3)   the source hand's world vertices per frame (metres)
``source_scale``             float64  ()          the source rig's scale (1.0 = life size), > 0
===========================  =======  ==========  ==================================================

Optional members (absent means ``None``):

===========================  =======  ==========  ==================================================
member                       dtype    shape       meaning (units)
===========================  =======  ==========  ==================================================
``object_contacts_offsets``  int64    (F + 1,)    CSR offsets of the object contacts: offsets[0] = 0,
                                                  non-decreasing, offsets[F] = K
``object_contacts_faces``    int64    (K,)        face of each contact on the object mesh, 0..m_o-1
``object_contacts_bary``     float64  (K, 3)      its barycentric coordinates (>= 0, sum 1)
``hand_contacts_offsets``    int64    (F + 1,)    the same for contacts on the hand mesh (faces
``hand_contacts_faces``      int64    (K,)        0..m-1); when both sets are present their offsets
``hand_contacts_bary``       float64  (K, 3)      are equal and row i of one is paired with row i
                                                  of the other. The three members of a set come
                                                  together or not at all.
``table``                    float64  (4, 4)      world pose of a box table's centre (rigid, metres)
``table_size``               float64  (3,)        the box's full extents (metres, > 0); present
                                                  exactly when ``table`` is
``source_kind``              unicode  ()          the procedural hand kind of the source
                                                  (:func:`solver.hands.make_hand`; ``"-left"``
                                                  suffix: its mirror image)
``source_theta``             float64  (F, d)      ground-truth DOF curves in :class:`solver.Rig`
                                                  order (root location in metres, Euler angles and
                                                  bone rotations in radians)
``first_frame``              int64    ()          the number frame 0 has in the scene the motion
                                                  came from (:attr:`Motion.first_frame`; absent:
                                                  1; 0 for a GRAB import)
===========================  =======  ==========  ==================================================

Floating members may be stored as any float dtype and integer members as any integer dtype; they are
read as float64 and int64. Every other dtype, a member this version does not define, a missing
member, a wrong shape, a non-finite value, a non-rigid pose, a contact on a face the mesh does not
have or with invalid barycentric coordinates, decreasing offsets, or an unreadable (truncated,
corrupted) archive raises :class:`MotionError` naming the member (its ``field``; ``"file"`` when the
archive itself cannot be read). Members are read without pickle, and each ``.npy`` header is checked
against the stored size before its data is read. :meth:`Motion.save` writes a
temporary file next to the target and renames it over the target (``os.replace``), so a file is
either complete or untouched.
"""

from __future__ import annotations

import contextlib
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.lib import format as npy_format

from geodesics import MeshError, SurfacePoints, TriMesh
from geodesics.arrays import readonly
from geodesics.errors import describe_ids
from geodesics.files import atomic_file

__all__ = ["FORMAT", "VERSION", "Contacts", "Motion", "MotionError"]

#: The ``format`` member of a motion file.
FORMAT = "contact-edit/motion"
#: The version this module writes and reads.
VERSION = 1
#: Object and table poses must be rotations (plus a translation) to this tolerance.
RIGID_TOLERANCE = 1e-6

_REQUIRED = {
    "format": ("U", ()),
    "version": ("i", ()),
    "fps": ("f", ()),
    "object_mesh_vertices": ("f", (None, 3)),
    "object_mesh_faces": ("i", (None, 3)),
    "object_poses": ("f", (None, 4, 4)),
    "hand_mesh_vertices": ("f", (None, 3)),
    "hand_mesh_faces": ("i", (None, 3)),
    "hand_vertices": ("f", (None, None, 3)),
    "source_scale": ("f", ()),
}
_OPTIONAL = {
    "object_contacts_offsets": ("i", (None,)),
    "object_contacts_faces": ("i", (None,)),
    "object_contacts_bary": ("f", (None, 3)),
    "hand_contacts_offsets": ("i", (None,)),
    "hand_contacts_faces": ("i", (None,)),
    "hand_contacts_bary": ("f", (None, 3)),
    "table": ("f", (4, 4)),
    "table_size": ("f", (3,)),
    "source_kind": ("U", ()),
    "source_theta": ("f", (None, None)),
    "first_frame": ("i", ()),
}
_KINDS = {"f": "floating point", "i": "integer", "U": "unicode string"}


class MotionError(ValueError):
    """A motion, its contacts or a motion file is not valid. ``field`` names the offending member
    (e.g. ``"object_poses"``, ``"hand_contacts.bary"``, or ``"file"`` for an unreadable archive)."""

    def __init__(self, message: str, field: str | None = None):
        super().__init__(message)
        self.field = field


def _float_array(value, field: str, shape: tuple) -> np.ndarray:
    """A read-only float64 copy of ``value`` of the given shape (None: any length), all finite."""
    try:
        a = np.array(value, dtype=np.float64, copy=True)
    except (TypeError, ValueError) as err:
        raise MotionError(f"{field} must be an array of numbers: {err}", field) from None
    _check_shape(a, field, shape)
    if not np.all(np.isfinite(a)):
        bad = np.flatnonzero(~np.all(np.isfinite(a.reshape(len(a), -1)), axis=1)) if a.ndim else [0]
        where = f" (rows {describe_ids(bad)})" if a.ndim else ""
        raise MotionError(f"{field} contains NaN or infinite values{where}", field)
    return readonly(a)


def _int_array(value, field: str, shape: tuple) -> np.ndarray:
    a = np.asarray(value)
    if a.dtype.kind not in "iu" and a.size:
        raise MotionError(f"{field} must hold integers, got dtype {a.dtype}", field)
    a = np.array(a, dtype=np.int64, copy=True)
    _check_shape(a, field, shape)
    return readonly(a)


def _check_shape(a: np.ndarray, field: str, shape: tuple) -> None:
    if a.ndim != len(shape) or any(s is not None and n != s for n, s in zip(a.shape, shape, strict=True)):
        expected = (
            "(" + ", ".join("*" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "")
        )
        raise MotionError(f"{field} must have shape {expected}), got {a.shape}", field)


def _check_rigid(M: np.ndarray, field: str) -> None:
    """Raise unless every (4, 4) matrix of M (..., 4, 4) is a rotation plus a translation."""
    M = M.reshape(-1, 4, 4)
    R = M[:, :3, :3]
    off = np.abs(R.transpose(0, 2, 1) @ R - np.eye(3)).max(axis=(1, 2))
    row = np.abs(M[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(axis=1)
    bad = np.flatnonzero((off > RIGID_TOLERANCE) | (np.linalg.det(R) <= 0) | (row > RIGID_TOLERANCE))
    if bad.size:
        raise MotionError(
            f"{field} must be rigid transforms (a rotation with determinant +1, a translation, last row "
            f"0 0 0 1); frames {describe_ids(bad)} are not",
            field,
        )


def _frame_ids(frames, n: int) -> np.ndarray:
    """(k,) frame indices in 0..n-1 from indices (negative count from the end), a boolean mask or a slice."""
    if isinstance(frames, slice):
        return np.arange(n)[frames]
    ids = np.asarray(frames)
    if ids.dtype == bool:
        if ids.shape != (n,):
            raise MotionError(f"a boolean frame mask must have shape ({n},), got {ids.shape}", "frame")
        return np.flatnonzero(ids)
    if ids.size and ids.dtype.kind not in "iu":
        raise MotionError(f"frame indices must be integers, got dtype {ids.dtype}", "frame")
    ids = ids.astype(np.int64).reshape(-1)
    if ids.size and (ids.min() < -n or ids.max() >= n):
        raise MotionError(f"frames {describe_ids(ids)} are out of range for {n} frames", "frame")
    return ids % max(n, 1)


@dataclass(frozen=True, eq=False)
class Contacts:
    """Dense contacts of every frame, flattened: frame f's points are rows offsets[f]:offsets[f+1].

    Parameters
    ----------
    offsets : (F + 1,) array_like of int
        ``offsets[0] == 0``, non-decreasing, ``offsets[F] == K``.
    faces : (K,) array_like of int
        Face of each contact point.
    bary : (K, 3) array_like of float
        Its barycentric coordinates (non-negative, summing to one; snapped as
        :class:`~geodesics.SurfacePoints` does).

    Raises
    ------
    MotionError
        For malformed input, naming the field (``offsets``, ``faces`` or ``bary``).
    """

    offsets: np.ndarray
    faces: np.ndarray
    bary: np.ndarray

    def __post_init__(self):
        offsets = _int_array(self.offsets, "offsets", (None,))
        if offsets.size == 0 or offsets[0] != 0:
            raise MotionError("offsets must start with 0 (one more entry than frames)", "offsets")
        drops = np.flatnonzero(np.diff(offsets) < 0)
        if drops.size:
            raise MotionError(
                f"offsets must be non-decreasing; they drop after frames {describe_ids(drops)}", "offsets"
            )
        faces = _int_array(self.faces, "faces", (None,))
        if offsets[-1] != faces.size:
            raise MotionError(
                f"offsets end at {int(offsets[-1])} but there are {faces.size} contact points", "offsets"
            )
        bary = np.asarray(self.bary)
        if bary.dtype.kind not in "fiu" and bary.size:
            raise MotionError(f"bary must hold numbers, got dtype {bary.dtype}", "bary")
        bary = np.array(bary, dtype=np.float64, copy=True)
        _check_shape(bary, "bary", (faces.size, 3))
        bad = np.flatnonzero(faces < 0)
        if bad.size:
            raise MotionError(
                f"faces must be non-negative; contact points {describe_ids(bad)} are not", "faces"
            )
        try:
            points = SurfacePoints(faces, bary)
        except MeshError as err:
            raise MotionError(f"bary: {err}", "bary") from None
        object.__setattr__(self, "offsets", offsets)
        object.__setattr__(self, "faces", points.faces)
        object.__setattr__(self, "bary", points.bary)

    @property
    def n_frames(self) -> int:
        return len(self.offsets) - 1

    def __len__(self) -> int:
        """Contact points in all frames together."""
        return len(self.faces)

    def frame(self, f: int) -> SurfacePoints:
        """Frame ``f``'s contact points (negative ``f`` counts from the end)."""
        n = self.n_frames
        f = int(f)
        if not -n <= f < n:
            raise MotionError(f"frame {f} is out of range for {n} frames", "frame")
        f %= n
        a, b = self.offsets[f], self.offsets[f + 1]
        return SurfacePoints(self.faces[a:b], self.bary[a:b])

    def count(self) -> np.ndarray:
        """(F,) contact points per frame."""
        return np.diff(self.offsets)

    def frame_index(self) -> np.ndarray:
        """(K,) the frame of each contact point."""
        return np.repeat(np.arange(self.n_frames), self.count())

    def select(self, frames) -> Contacts:
        """The contacts of the given frames ((k,) indices, an (F,) boolean mask or a slice), in that order."""
        ids = _frame_ids(frames, self.n_frames)
        counts = self.count()[ids]
        rows = np.repeat(self.offsets[ids] - np.concatenate([[0], np.cumsum(counts)[:-1]]), counts)
        rows += np.arange(counts.sum())
        return Contacts(np.concatenate([[0], np.cumsum(counts)]), self.faces[rows], self.bary[rows])

    @classmethod
    def from_frames(cls, frames: Sequence[SurfacePoints]) -> Contacts:
        """Flatten one :class:`~geodesics.SurfacePoints` per frame."""
        frames = list(frames)
        for f, points in enumerate(frames):
            if not isinstance(points, SurfacePoints):
                raise MotionError(f"frame {f} is a {type(points).__name__}, not SurfacePoints", "frames")
        counts = np.array([len(p) for p in frames], np.int64)
        merged = SurfacePoints.concatenate(frames)
        return cls(np.concatenate([[0], np.cumsum(counts)]), merged.faces, merged.bary)

    def _validate_on(self, mesh: TriMesh, n_frames: int, field: str) -> None:
        if self.n_frames != n_frames:
            raise MotionError(
                f"{field} covers {self.n_frames} frames but the motion has {n_frames}", f"{field}.offsets"
            )
        bad = np.flatnonzero(self.faces >= mesh.n_faces)
        if bad.size:
            frames = np.searchsorted(self.offsets, bad, side="right") - 1
            raise MotionError(
                f"{field}: contact points {describe_ids(bad)} (frames {describe_ids(frames)}) refer to faces "
                f"outside 0..{mesh.n_faces - 1} (e.g. face {int(self.faces[bad[0]])})",
                f"{field}.faces",
            )


@dataclass(frozen=True, eq=False)
class Motion:
    """A hand-object manipulation: what the retargeting reads. World space, metres, seconds.

    Attributes
    ----------
    fps : float
    object_mesh : TriMesh
        The object's rest shape, in object space.
    object_poses : (F, 4, 4) ndarray
        Object space -> world, rigid.
    hand_mesh : TriMesh
        The source hand's topology (its rest shape).
    hand_vertices : (F, n, 3) ndarray
        The source hand's world-space vertices per frame.
    object_contacts : Contacts or None
        Contacts on ``object_mesh``.
    hand_contacts : Contacts or None
        Contacts on ``hand_mesh``; when both are given, paired row for row (equal offsets).
    table : (4, 4) ndarray or None
        World pose of a box table's centre.
    table_size : (3,) ndarray or None
        That box's full extents.
    source_kind : str or None
        The procedural hand kind of the source (``"human"`` ...), if any.
    source_scale : float
        Its scale (1.0 = life size).
    source_theta : (F, d) ndarray or None
        Ground-truth DOF curves when the source is a procedural rig.
    first_frame : int
        The number frame 0 has in the scene the motion came from, where the reader that made the motion
        knows it (1 otherwise, the default start of Maya's and Blender's timelines). Files made in that
        scene number frames that way: the retargeting authors' contact files (:mod:`.interchange`)
        carry Maya's frame numbers, which are 0, 1, … in a scene their GRAB import keyed
        (:func:`~solver.retarget.load_grab` sets 0). Readers of such files take it from the motion, so
        that the file's frames land on the motion's own.

    Arrays are copied to read-only float64 / int64 on construction; invalid input raises
    :class:`MotionError` naming the field.
    """

    fps: float
    object_mesh: TriMesh
    object_poses: np.ndarray
    hand_mesh: TriMesh
    hand_vertices: np.ndarray
    object_contacts: Contacts | None = None
    hand_contacts: Contacts | None = None
    table: np.ndarray | None = None
    table_size: np.ndarray | None = None
    source_kind: str | None = None
    source_scale: float = 1.0
    source_theta: np.ndarray | None = None
    first_frame: int = 1

    def __post_init__(self):
        fps = self.fps
        if isinstance(fps, np.ndarray) and fps.ndim == 0:
            fps = fps.item()
        if isinstance(fps, bool) or not isinstance(fps, (int, float, np.floating, np.integer)):
            raise MotionError(f"fps must be a number, got {type(fps).__name__}", "fps")
        if not (np.isfinite(fps) and fps > 0):
            raise MotionError(f"fps must be finite and positive, got {fps!r}", "fps")
        object.__setattr__(self, "fps", float(fps))
        for name in ("object_mesh", "hand_mesh"):
            if not isinstance(getattr(self, name), TriMesh):
                raise MotionError(
                    f"{name} must be a geodesics.TriMesh, got {type(getattr(self, name)).__name__}", name
                )
        poses = _float_array(self.object_poses, "object_poses", (None, 4, 4))
        F = len(poses)
        if F == 0:
            raise MotionError("a motion needs at least one frame (object_poses is empty)", "object_poses")
        _check_rigid(poses, "object_poses")
        object.__setattr__(self, "object_poses", poses)
        n = self.hand_mesh.n_vertices
        object.__setattr__(
            self, "hand_vertices", _float_array(self.hand_vertices, "hand_vertices", (F, n, 3))
        )
        for name, mesh in (("object_contacts", self.object_mesh), ("hand_contacts", self.hand_mesh)):
            contacts = getattr(self, name)
            if contacts is None:
                continue
            if not isinstance(contacts, Contacts):
                raise MotionError(f"{name} must be Contacts or None, got {type(contacts).__name__}", name)
            contacts._validate_on(mesh, F, name)
        paired = self.object_contacts is not None and self.hand_contacts is not None
        if paired and not np.array_equal(self.object_contacts.offsets, self.hand_contacts.offsets):
            frames = np.flatnonzero(self.object_contacts.count() != self.hand_contacts.count())
            raise MotionError(
                "object_contacts and hand_contacts must be paired row for row (equal offsets); frames "
                f"{describe_ids(frames)} have different counts",
                "hand_contacts.offsets",
            )
        if (self.table is None) != (self.table_size is None):
            raise MotionError(
                "table and table_size must be given together", "table" if self.table is None else "table_size"
            )
        if self.table is not None:
            table = _float_array(self.table, "table", (4, 4))
            _check_rigid(table, "table")
            size = _float_array(self.table_size, "table_size", (3,))
            if np.any(size <= 0):
                raise MotionError(f"table_size must be positive, got {size.tolist()}", "table_size")
            object.__setattr__(self, "table", table)
            object.__setattr__(self, "table_size", size)
        if self.source_kind is not None:
            kind = self.source_kind
            if isinstance(kind, np.ndarray) and kind.ndim == 0:
                kind = kind.item()
            if not isinstance(kind, str):
                raise MotionError(
                    f"source_kind must be a string or None, got {type(kind).__name__}", "source_kind"
                )
            object.__setattr__(self, "source_kind", str(kind))
        scale = self.source_scale
        if isinstance(scale, np.ndarray) and scale.ndim == 0:
            scale = scale.item()
        if isinstance(scale, bool) or not isinstance(scale, (int, float, np.floating, np.integer)):
            raise MotionError(f"source_scale must be a number, got {type(scale).__name__}", "source_scale")
        if not (np.isfinite(scale) and scale > 0):
            raise MotionError(f"source_scale must be finite and positive, got {scale!r}", "source_scale")
        object.__setattr__(self, "source_scale", float(scale))
        if self.source_theta is not None:
            theta = _float_array(self.source_theta, "source_theta", (F, None))
            object.__setattr__(self, "source_theta", theta)
        first = self.first_frame
        if isinstance(first, np.ndarray) and first.ndim == 0:
            first = first.item()
        if isinstance(first, bool) or not isinstance(first, (int, np.integer)):
            raise MotionError(f"first_frame must be a whole number, got {first!r}", "first_frame")
        object.__setattr__(self, "first_frame", int(first))

    # ------------------------------------------------------------------ access

    @property
    def n_frames(self) -> int:
        return len(self.object_poses)

    @property
    def duration(self) -> float:
        """Seconds from the first frame to the last."""
        return (self.n_frames - 1) / self.fps

    def __repr__(self) -> str:
        contacts = "" if self.object_contacts is None else f", {len(self.object_contacts):,} contacts"
        return (
            f"Motion({self.n_frames} frames at {self.fps:g} fps, object {self.object_mesh.n_faces} faces, "
            f"hand {self.hand_mesh.n_vertices} vertices{contacts})"
        )

    def select(self, frames) -> Motion:
        """The motion restricted to the given frames ((k,) indices, an (F,) boolean mask or a slice), in that
        order. Its ``first_frame`` is the number of the first frame selected, so a window of consecutive
        frames keeps the scene's numbering (other selections have no single numbering to keep)."""
        ids = _frame_ids(frames, self.n_frames)
        if ids.size == 0:
            raise MotionError("select needs at least one frame", "frame")
        return Motion(
            fps=self.fps,
            object_mesh=self.object_mesh,
            object_poses=self.object_poses[ids],
            hand_mesh=self.hand_mesh,
            hand_vertices=self.hand_vertices[ids],
            object_contacts=None if self.object_contacts is None else self.object_contacts.select(ids),
            hand_contacts=None if self.hand_contacts is None else self.hand_contacts.select(ids),
            table=self.table,
            table_size=self.table_size,
            source_kind=self.source_kind,
            source_scale=self.source_scale,
            source_theta=None if self.source_theta is None else self.source_theta[ids],
            first_frame=self.first_frame + int(ids[0]),
        )

    # ------------------------------------------------------------------ file

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The members of the motion file by name, as arrays of the dtypes and shapes of the module
        docstring's tables (``object_poses`` (F, 4, 4), ``hand_vertices`` (F, n, 3), strings and scalars
        0-d); the motion's own read-only arrays, not copies."""
        out = {
            "format": np.array(FORMAT),
            "version": np.array(VERSION, np.int64),
            "fps": np.array(self.fps, np.float64),
            "object_mesh_vertices": self.object_mesh.vertices,
            "object_mesh_faces": self.object_mesh.faces,
            "object_poses": self.object_poses,
            "hand_mesh_vertices": self.hand_mesh.vertices,
            "hand_mesh_faces": self.hand_mesh.faces,
            "hand_vertices": self.hand_vertices,
            "source_scale": np.array(self.source_scale, np.float64),
        }
        for name in ("object_contacts", "hand_contacts"):
            contacts = getattr(self, name)
            if contacts is not None:
                out[f"{name}_offsets"] = contacts.offsets
                out[f"{name}_faces"] = contacts.faces
                out[f"{name}_bary"] = contacts.bary
        if self.table is not None:
            out["table"] = self.table
            out["table_size"] = self.table_size
        if self.source_kind is not None:
            out["source_kind"] = np.array(self.source_kind)
        if self.source_theta is not None:
            out["source_theta"] = self.source_theta
        if self.first_frame != 1:
            out["first_frame"] = np.array(self.first_frame, np.int64)
        return out

    def save(self, path, compressed: bool = False) -> None:
        """Write the motion file atomically (a complete file or none; an existing file is replaced only
        once the new one is complete). ``compressed`` deflates the members (smaller, slower)."""
        with atomic_file(path) as f:
            mode = zipfile.ZIP_DEFLATED if compressed else zipfile.ZIP_STORED
            with zipfile.ZipFile(f, "w", compression=mode, allowZip64=True) as archive:
                for name, value in self.to_arrays().items():  # as np.savez writes them
                    with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
                        npy_format.write_array(member, np.asanyarray(value), allow_pickle=False)

    @classmethod
    def load(cls, path) -> Motion:
        """Read and validate a motion file; :class:`MotionError` (naming the member) if it is not one."""
        path = Path(path)
        arrays = _read_members(path)
        return cls.from_arrays(arrays, source=str(path))

    @classmethod
    def from_arrays(cls, arrays: dict, source: str = "motion data") -> Motion:
        """Validate the members of a motion file (name → array, of the dtypes and shapes of the module
        docstring's tables) and build the motion."""
        unknown = sorted(set(arrays) - set(_REQUIRED) - set(_OPTIONAL))
        if unknown:
            raise MotionError(f"{source}: unexpected members {', '.join(unknown)}", unknown[0])
        for name in _REQUIRED:
            if name not in arrays:
                raise MotionError(f"{source}: the member {name!r} is missing", name)
        for name, value in arrays.items():
            kind, shape = (_REQUIRED | _OPTIONAL)[name]
            a = np.asarray(value)
            ok = a.dtype.kind in ("iu" if kind == "i" else kind)
            if not ok:
                raise MotionError(f"{source}: {name} must be {_KINDS[kind]}, got dtype {a.dtype}", name)
            if a.ndim != len(shape) or any(
                s is not None and n != s for n, s in zip(a.shape, shape, strict=True)
            ):
                raise MotionError(
                    f"{source}: {name} has shape {a.shape}, expected {len(shape)} dimensions {shape}", name
                )
        if str(arrays["format"]) != FORMAT:
            raise MotionError(
                f"{source}: not a motion file (format {str(arrays['format'])!r}, expected {FORMAT!r})",
                "format",
            )
        version = int(arrays["version"])
        if version != VERSION:
            newer = " (written by a newer version)" if version > VERSION else ""
            raise MotionError(
                f"{source}: motion file version {version} is not supported{newer}; this build reads "
                f"{VERSION}",
                "version",
            )
        meshes = {}
        for name in ("object_mesh", "hand_mesh"):
            try:
                vertices = _float_array(arrays[f"{name}_vertices"], f"{name}_vertices", (None, 3))
            except MotionError as err:
                raise MotionError(f"{source}: {err}", err.field) from None
            try:
                with _quiet_mesh_warnings():
                    meshes[name] = TriMesh(vertices, arrays[f"{name}_faces"])
            except MeshError as err:
                field = f"{name}_vertices" if err.vertices.size and not err.faces.size else f"{name}_faces"
                raise MotionError(f"{source}: {name} is not a valid mesh: {err}", field) from None
        contacts = {}
        for name in ("object_contacts", "hand_contacts"):
            parts = [f"{name}_{p}" for p in ("offsets", "faces", "bary")]
            present = [p in arrays for p in parts]
            if any(present) and not all(present):
                missing = [p for p, there in zip(parts, present, strict=True) if not there]
                raise MotionError(f"{source}: {name} is incomplete: {', '.join(missing)} missing", missing[0])
            if all(present):
                try:
                    contacts[name] = Contacts(*(arrays[p] for p in parts))
                except MotionError as err:
                    raise MotionError(f"{source}: {name}.{err.field}: {err}", f"{name}_{err.field}") from None
        try:
            return cls(
                fps=float(arrays["fps"]),
                object_mesh=meshes["object_mesh"],
                object_poses=arrays["object_poses"],
                hand_mesh=meshes["hand_mesh"],
                hand_vertices=arrays["hand_vertices"],
                object_contacts=contacts.get("object_contacts"),
                hand_contacts=contacts.get("hand_contacts"),
                table=arrays.get("table"),
                table_size=arrays.get("table_size"),
                source_kind=None if "source_kind" not in arrays else str(arrays["source_kind"]),
                source_scale=float(arrays["source_scale"]),
                source_theta=arrays.get("source_theta"),
                first_frame=int(arrays.get("first_frame", 1)),
            )
        except MotionError as err:
            field = (err.field or "file").replace(".", "_")
            raise MotionError(f"{source}: {err}", field) from None


@contextlib.contextmanager
def _quiet_mesh_warnings():
    import warnings

    from geodesics import MeshWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MeshWarning)
        yield


def _read_members(path: Path) -> dict[str, np.ndarray]:
    """Every member of a motion file; any member this version does not define is an error."""
    return read_npz(path, "motion file", set(_REQUIRED) | set(_OPTIONAL), strict=True)


def read_npz(
    path: Path, what: str, names, strict: bool, error: type[MotionError] = MotionError
) -> dict[str, np.ndarray]:
    """The members ``names`` of an ``.npz`` archive, read without pickle; each header's promised size is
    checked against the stored size before any data is allocated.

    Parameters
    ----------
    path : Path
    what : str
        What the file should be, for messages (``"motion file"``).
    names : collection of str
        The members to read (absent ones are the caller's to report).
    strict : bool
        Whether any other member is an error (else it is skipped unread).
    error : type
        The :class:`MotionError` subclass to raise; its ``field`` names the member, or ``"file"``.

    Returns
    -------
    dict of str to ndarray
        Each member present, by name, with the shape and dtype it is stored with (not checked here).
    """
    try:
        archive = zipfile.ZipFile(path)
    except FileNotFoundError:
        raise error(f"{path}: no such file", "file") from None
    except IsADirectoryError:
        raise error(f"{path}: is a directory, not a {what}", "file") from None
    except Exception as err:  # BadZipFile, OSError, struct and decoding errors of a mangled directory
        raise error(f"{path}: not a {what} (not a readable .npz archive: {err})", "file") from None
    arrays = {}
    with archive:
        for info in archive.infolist():
            name = info.filename[:-4] if info.filename.endswith(".npy") else None
            if name not in names:
                if not strict:
                    continue
                if name is None:
                    raise error(f"{path}: unexpected archive member {info.filename!r}", info.filename)
                raise error(f"{path}: unexpected member {name!r}", name)
            if name in arrays:
                raise error(f"{path}: the member {name!r} is stored twice", name)
            try:
                with archive.open(info) as f:
                    version = npy_format.read_magic(f)
                    if version == (1, 0):
                        shape, _, dtype = npy_format.read_array_header_1_0(f)
                    elif version == (2, 0):
                        shape, _, dtype = npy_format.read_array_header_2_0(f)
                    else:
                        raise ValueError(f"unsupported .npy version {version}")
                    if dtype.hasobject:
                        raise ValueError("it holds Python objects (pickles are never read)")
                    header = f.tell()
                    expected = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
                    if header + expected != info.file_size:
                        raise ValueError(
                            f"its header promises {expected} bytes of data but "
                            f"{info.file_size - header} are stored"
                        )
                with archive.open(info) as f:
                    arrays[name] = npy_format.read_array(f, allow_pickle=False)
            except Exception as err:  # corrupt data: zlib, CRC, header syntax, short reads
                raise error(f"{path}: the member {name!r} is unreadable: {err}", name) from None
    return arrays
