"""The retargeting paper's authors' own files: contacts, virtual markers and keyframe motion exports.

Their tools (repository ``lakshmipathyarjun6/kinematic-motion-retargeting``, Maya plugins) exchange
three JSON files; each is read and written here as their code does, with surface points as their
``v``/``e``/``f`` strings (:mod:`geodesics.point_strings`, geometry-central's element numbering):

* **Contacts** ``.json`` (``src/contactSequenceIO/contactSequenceIO.cpp``): ``{"meshName": str,
  "data": [{"frame": int, "contacts": [str, …], "omissionIndices": [int, …]}, …]}``. One entry per
  Maya frame that has contacts (frames without are left out, ``omissionIndices`` only when there are
  some); the omitted rows are contacts the distance filter dropped
  (``ContactTransferEditContext::commitParameterizedDistancesFilter``), kept in the file so a hand
  file and its object file stay paired row for row. → :class:`ContactSequence`.
* **Virtual markers** ``.virtualmarkers`` (``src/virtualMarkerIO/virtualMarkerIO.cpp``): ``{"meshName":
  str, "data": [{"name": str, "MarkerPoints": [str, …]}, …]}``, one hand's markers. Two such files,
  the source hand's and the target hand's, pair by name into our
  :class:`~solver.retarget.annotations.MarkerAnnotation` (:func:`pair_markers`).
* **Keyframe motion** ``.kmexp`` (``src/keyframeMotionSequenceIO/keyframeMotionSequenceIO.cpp``, with
  ``USE_QUATS`` as its header defines it, and its ``README.md``): ``framerate``, ``jointNames``,
  ``jointDofs``, ``table`` (scale, quaternion w x y z, translation), and per frame ``object``
  (quaternion, translation) and ``hand`` (the root joint's quaternion and translation, then each
  joint's values). Their exporter treats a joint free about all three axes as a ball joint (its
  rotation as a quaternion, 4 values), writes one Euler angle (radians) per free axis of the others,
  and leaves out joints with none. Lengths are centimetres (Maya's default unit). Joints are listed
  in the order its stack visits them (lines 428-439 and 627-636): depth first, a joint's last child
  first, so a hand's list runs forearm, hand, thumb …, index last. Our writer maps a
  :class:`~solver.Rig` the same way and in that order: the root bone's armature-space rotation and
  head position, a bone with three unlocked rotation DOFs as the quaternion of its local rotation
  (``matrix_basis``), the others' unlocked Euler angles in x, y, z order. Our reader matches joints
  to bones by name, never by position (their plugin has no reader to follow). → :class:`KeyframeMotion`.

Frames: Maya numbers them from the timeline's start, and their tools write Maya's numbers; our frame
``f`` is their ``first_frame + f``. A motion says what its first frame was numbered
(:attr:`Motion.first_frame <solver.retarget.Motion.first_frame>`): 1 by default, as a fresh Maya
timeline starts, but 0 for a GRAB import, whose plugin keys frames 0 … F-1 (:mod:`.grab`). Give the
motion (``ContactSequence.load(…, motion=m)``, :meth:`ContactSequence.of_motion`,
``save_kmexp(…, first_frame=m.first_frame)``) and the numbering follows it.

Every reader validates what it loads and raises :class:`InterchangeError` naming the file, the frame
and the entry; nothing is half loaded. Writers write atomically.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from geodesics import MeshError, SurfacePoints, TriMesh
from geodesics.files import read_json, write_atomically
from geodesics.point_strings import GeometryCentralIndex
from geodesics.schema import Fields

from ..errors import SolverError
from ..rig import Rig
from .annotations import MarkerAnnotation
from .motion import Contacts, Motion, MotionError
from .transfer import keep_rows

#: Metres to the centimetres of the authors' Maya scenes.
CM = 100.0


class InterchangeError(SolverError):
    """A file in the authors' formats cannot be read or written as asked; the message names the file,
    and where it applies the frame and entry."""


# ------------------------------------------------------------------------------ JSON reading


def _read_json(path, what: str) -> Fields:
    return Fields(
        read_json(path, f"{what} file", InterchangeError), str(path), InterchangeError, "a JSON object"
    )


def _check_mesh_name(found: str, expected: str | None, path) -> None:
    if expected is not None and found != expected:
        raise InterchangeError(f"{path} is for mesh {found!r}, not {expected!r}")


def _points(index: GeometryCentralIndex, strings, where: str) -> SurfacePoints:
    try:
        return index.parse(strings, where)
    except MeshError as e:
        raise InterchangeError(str(e)) from None


# ------------------------------------------------------------------------------ contacts


@dataclass(frozen=True, eq=False)
class ContactSequence:
    """One mesh's contacts over a motion, as the authors' contact files hold them.

    Attributes
    ----------
    mesh_name : str
        The Maya shape the contacts are on (``"handShape"``, ``"objectShape"`` in their scenes).
    contacts : Contacts
        Every contact of every frame, omitted ones included, in the file's order.
    omitted : (K,) bool
        Rows the authors' distance filter dropped (``omissionIndices``).
    first_frame : int
        The file's frame number of our frame 0.
    """

    mesh_name: str
    contacts: Contacts
    omitted: np.ndarray
    first_frame: int = 1

    def __post_init__(self):
        omitted = np.array(self.omitted, dtype=bool).reshape(-1)
        if omitted.shape != (len(self.contacts),):
            raise InterchangeError(
                f"omitted needs one flag per contact ({len(self.contacts)}), got {omitted.shape}"
            )
        omitted.setflags(write=False)
        object.__setattr__(self, "omitted", omitted)

    def kept(self) -> Contacts:
        """The contacts without the omitted rows, frames preserved."""
        return keep_rows(self.contacts, ~self.omitted)

    def save(self, path, mesh: TriMesh) -> None:
        """Write the authors' contact file (``mesh`` is the one the contacts are on)."""
        index = GeometryCentralIndex(mesh)
        strings = index.format(SurfacePoints(self.contacts.faces, self.contacts.bary))
        offsets = self.contacts.offsets
        data = []
        for f in np.flatnonzero(self.contacts.count()):
            a, b = int(offsets[f]), int(offsets[f + 1])
            entry = {"frame": int(f) + self.first_frame, "contacts": strings[a:b]}
            dropped = np.flatnonzero(self.omitted[a:b])
            if dropped.size:
                entry["omissionIndices"] = dropped.tolist()
            data.append(entry)
        write_atomically(path, json.dumps({"meshName": self.mesh_name, "data": data}, indent=1))

    @classmethod
    def of_motion(cls, motion: Motion, which: str, mesh_name: str | None = None) -> ContactSequence:
        """The hand's or the object's contacts of a motion (``which``: ``"hand"`` or ``"object"``), to
        save as the authors' file of the motion's scene: frames numbered from ``motion.first_frame``,
        nothing omitted, mesh name ``"handShape"`` or ``"objectShape"`` (their scenes' shapes) unless
        given. Save it with the mesh the contacts are on (``motion.hand_mesh`` or
        ``motion.object_mesh``)."""
        if which not in ("hand", "object"):
            raise InterchangeError(f"which must be 'hand' or 'object', got {which!r}")
        contacts = getattr(motion, f"{which}_contacts")
        if contacts is None:
            raise InterchangeError(f"the motion has no {which} contacts")
        name = f"{which}Shape" if mesh_name is None else mesh_name
        return cls(name, contacts, np.zeros(len(contacts), bool), motion.first_frame)

    @classmethod
    def load(
        cls,
        path,
        mesh: TriMesh,
        n_frames: int | None = None,
        first_frame: int | None = None,
        mesh_name: str | None = None,
        *,
        motion: Motion | None = None,
    ) -> ContactSequence:
        """Read an authors' contact file onto ``mesh``.

        Parameters
        ----------
        path : path-like
        mesh : TriMesh
            The mesh the file was made on, faces in the same order.
        n_frames : int, optional
            The motion's frame count (default: the motion's, or up to the last frame with contacts).
        first_frame : int, optional
            The file's frame number of our frame 0 (default: the motion's ``first_frame``, else 1,
            Maya's default timeline start).
        mesh_name : str, optional
            When given, the file must be for this mesh name.
        motion : Motion, optional
            The motion the file was made for, in the scene it came from: its frame count and its
            ``first_frame`` (0 for a GRAB import: their plugin keys frames from 0, and a contact file
            made in that scene numbers frames as Maya does) place the file's frames on its own, so
            that file frame ``k`` is the motion's frame ``k - motion.first_frame``.

        Raises
        ------
        InterchangeError
            Naming the file, frame and entry: not JSON, missing or mistyped fields, a frame before
            ``first_frame`` or beyond ``n_frames`` or repeated, an unreadable point, an omission index
            out of range; or ``n_frames``/``first_frame`` given that contradict ``motion``.
        """
        if motion is not None:
            for name, given, own in (
                ("n_frames", n_frames, motion.n_frames),
                ("first_frame", first_frame, motion.first_frame),
            ):
                if given is not None and given != own:
                    raise InterchangeError(f"{path}: {name}={given} contradicts the motion's {own}")
            n_frames, first_frame = motion.n_frames, motion.first_frame
        first_frame = 1 if first_frame is None else first_frame
        data = _read_json(path, "contacts")
        name = data.string("meshName")
        _check_mesh_name(name, mesh_name, path)
        index = GeometryCentralIndex(mesh)
        frames, points, omitted = [], [], []
        for entry in data.objects("data"):
            frame = entry.integer("frame")
            f = frame - first_frame
            if f < 0 or (n_frames is not None and f >= n_frames):
                last = "" if n_frames is None else f" to {first_frame + n_frames - 1}"
                entry.fail(f"frame {frame} is outside the motion's frames {first_frame}{last}")
            entry = entry.renamed(f"{path}: frame {frame}")
            p = _points(index, entry.list("contacts"), f"{entry.where}'s contacts")
            flags = np.zeros(len(p), bool)
            if "omissionIndices" in entry:
                flags[entry.indices("omissionIndices", len(p))] = True
            frames.append(f)
            points.append(p)
            omitted.append(flags)
        frames_arr = np.array(frames, np.int64)
        repeated = np.flatnonzero(np.bincount(frames_arr, minlength=1) > 1) if frames else []
        if len(repeated):
            raise InterchangeError(f"{path}: frame {int(repeated[0]) + first_frame} appears more than once")
        F = n_frames if n_frames is not None else (int(frames_arr.max()) + 1 if frames else 0)
        per_frame = [SurfacePoints(np.empty(0, np.int64), np.empty((0, 3)))] * F
        flags_per_frame = [np.zeros(0, bool)] * F
        for f, p, flags in zip(frames, points, omitted, strict=True):
            per_frame[f], flags_per_frame[f] = p, flags
        try:
            contacts = Contacts.from_frames(per_frame)
        except MotionError as e:
            raise InterchangeError(f"{path}: {e}") from None
        flat = np.concatenate(flags_per_frame) if F else np.zeros(0, bool)
        return cls(name, contacts, flat, first_frame)


# ------------------------------------------------------------------------------ virtual markers


def save_markers(path, mesh_name: str, mesh: TriMesh, markers: Mapping[str, SurfacePoints]) -> None:
    """Write one hand's virtual markers (name → points on ``mesh``) as an authors' ``.virtualmarkers``."""
    index = GeometryCentralIndex(mesh)
    data = [{"name": str(name), "MarkerPoints": index.format(points)} for name, points in markers.items()]
    write_atomically(path, json.dumps({"meshName": mesh_name, "data": data}, indent=1))


def load_markers(path, mesh: TriMesh, mesh_name: str | None = None) -> dict[str, SurfacePoints]:
    """Read one hand's virtual markers from an authors' ``.virtualmarkers`` file: name → points.

    Raises
    ------
    InterchangeError
        Naming the file and marker: not JSON, missing or mistyped fields, a repeated or empty marker
        name, a marker without points, an unreadable point, a different ``mesh_name``.
    """
    data = _read_json(path, "virtual markers")
    name = data.string("meshName")
    _check_mesh_name(name, mesh_name, path)
    index = GeometryCentralIndex(mesh)
    markers: dict[str, SurfacePoints] = {}
    for entry in data.objects("data"):
        marker = entry.string("name")
        if not marker or marker in markers:
            entry.fail(f"marker name {marker!r} is empty or repeated")
        where = f"{path}: marker {marker!r}"
        strings = entry.renamed(where).list("MarkerPoints")
        if not strings:
            raise InterchangeError(f"{where} has no points")
        markers[marker] = _points(index, strings, f"{where}'s points")
    return markers


def pair_markers(
    source: Mapping[str, SurfacePoints], target: Mapping[str, SurfacePoints]
) -> tuple[MarkerAnnotation, ...]:
    """Our markers from the source hand's and the target hand's marker sets, paired by name (in the
    source's order). Names on one side only are an error naming them."""
    only = sorted(set(source) ^ set(target))
    if only:
        raise InterchangeError(f"markers {', '.join(map(repr, only))} are on one hand only")
    return tuple(MarkerAnnotation(name, source[name], target[name]) for name in source)


# ------------------------------------------------------------------------------ keyframe motions


def _quaternions(R: np.ndarray) -> np.ndarray:
    """(k, 4) unit quaternions w x y z of rotations (k, 3, 3), w >= 0."""
    q = Rotation.from_matrix(R).as_quat()[:, [3, 0, 1, 2]]
    return np.where(q[:, :1] < 0, -q, q)


def _matrices(q: np.ndarray) -> np.ndarray:
    """(k, 3, 3) rotations of quaternions w x y z (k, 4), normalized."""
    return Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()


def _rigid(q: np.ndarray, t_cm: np.ndarray) -> np.ndarray:
    """(k, 4, 4) rigid transforms (metres) from quaternions and translations in centimetres."""
    T = np.zeros((len(q), 4, 4))
    T[:, :3, :3] = _matrices(q)
    T[:, :3, 3] = t_cm / CM
    T[:, 3, 3] = 1.0
    return T


def _pose_values(T: np.ndarray) -> np.ndarray:
    """(k, 7) quaternion w x y z and translation (cm) of rigid transforms (k, 4, 4) in metres."""
    return np.concatenate([_quaternions(T[:, :3, :3]), T[:, :3, 3] * CM], axis=1)


def _maya_order(rig: Rig) -> list[int]:
    """The rig's bones in the order the authors' exporter visits Maya's joints.

    ``KeyframeMotionSequenceIO::parseKinematicTree`` (``keyframeMotionSequenceIO.cpp`` lines 428-439
    and 627-636) walks the skeleton with a stack: it pops a joint, lists it, then pushes its children
    ``child(0)`` … ``child(n-1)``, so the last child is popped next and its whole subtree is listed
    before the child before it (depth first, siblings last to first). A child's place among its
    siblings is its order in the rig, which is Maya's child order for a skeleton built or imported in
    that order.
    """
    children: list[list[int]] = [[] for _ in range(rig.n_bones)]
    for b in range(1, rig.n_bones):
        children[int(rig.parents[b])].append(b)
    order, stack = [], [0]
    while stack:
        b = stack.pop()
        order.append(b)
        stack.extend(children[b])
    return order


def _joint_layout(rig: Rig) -> tuple[list[int], list[np.ndarray]]:
    """The joints a rig exports (bone ids, in the exporter's stack order, :func:`_maya_order`) and each
    one's free rotation components (0, 1, 2 = x, y, z). A bone with every axis locked is left out, as
    the exporter leaves out welded joints (line 611), but its children are still visited (627-636)."""
    locked = np.asarray(rig.locked, bool)
    bones, components = [], []
    for b in _maya_order(rig):
        free = np.arange(3) if b == 0 else np.flatnonzero(~locked[rig.bone_dofs(b)])
        if free.size:
            bones.append(b)
            components.append(free)
    return bones, components


def _joint_dofs(components: list[np.ndarray]) -> list[int]:
    return [7] + [4 if c.size == 3 else int(c.size) for c in components[1:]]


@dataclass(frozen=True, eq=False)
class KeyframeMotion:
    """An authors' ``.kmexp`` keyframe motion export, in its own units (centimetres, radians).

    Attributes
    ----------
    framerate : int
    joint_names : tuple of str
    joint_dofs : tuple of int
        Values per joint in ``hand``: 7 for the root, 4 for a ball joint, else one per free axis.
    table : (10,) ndarray or None
        Scale x y z, quaternion w x y z, translation (cm); None when the file has no table.
    frames : (F,) int
        Maya frame numbers.
    object : (F, 7) ndarray
        The object's quaternion w x y z and translation (cm).
    hand : (F, sum(joint_dofs)) ndarray
        Each joint's values in ``joint_names`` order, the root's first.
    source : str or None
        The file it was read from (named in errors); None when made by :meth:`from_rig`.

    Joints are listed as the authors' exporter lists them, depth first from a stack with a joint's
    last child first (:func:`_maya_order`); :meth:`from_rig` writes that order too, so our export of a
    rig lists its joints as theirs of the same rig would, and :meth:`theta` matches joints by name.
    """

    framerate: int
    joint_names: tuple[str, ...]
    joint_dofs: tuple[int, ...]
    table: np.ndarray | None
    frames: np.ndarray
    object: np.ndarray
    hand: np.ndarray
    source: str | None = None

    @classmethod
    def from_rig(
        cls,
        rig: Rig,
        theta,
        object_poses,
        fps: float,
        table=None,
        table_size=None,
        first_frame: int = 1,
    ) -> KeyframeMotion:
        """The export of a rig's motion θ (F, d) with the object's poses (F, 4, 4), as the authors'
        exporter writes a Maya scene's (module docstring); ``table`` (4, 4) and ``table_size`` (3,) in
        metres, the box table's pose and full extents."""
        theta = _poses(rig, theta)
        poses = np.asarray(object_poses, np.float64)
        if poses.shape != (len(theta), 4, 4):
            raise InterchangeError(f"object_poses must be ({len(theta)}, 4, 4), got {poses.shape}")
        if float(fps) != round(float(fps)) or fps <= 0:
            raise InterchangeError(f"the format stores a whole frame rate; got {fps}")
        bones, components = _joint_layout(rig)
        F = len(theta)
        root = np.stack([rig.pose_matrices(t)[0] for t in theta])
        columns = [_pose_values(root)]
        for b, c in zip(bones[1:], components[1:], strict=True):
            if c.size == 3:
                columns.append(_quaternions(np.stack([rig.basis(t)[b, :3, :3] for t in theta])))
            else:
                columns.append(theta[:, rig.bone_dofs(b)[c]])
        table_values = None
        if table is not None:
            T = np.asarray(table, np.float64).reshape(1, 4, 4)
            size = np.asarray(table_size, np.float64).reshape(3)
            table_values = np.concatenate([size * CM, _pose_values(T)[0]])
        names = tuple(rig.names[b] for b in bones)
        return cls(
            round(float(fps)), names, tuple(_joint_dofs(components)), table_values,
            np.arange(F) + first_frame, _pose_values(poses), np.concatenate(columns, axis=1),
        )  # fmt: skip

    def theta(self, rig: Rig, default=None) -> np.ndarray:
        """(F, d) the rig's DOFs of every frame: the inverse of :meth:`from_rig`. Values the file does
        not hold (locked axes) come from ``default`` (d,), the rig's rest pose if not given.

        Joints are matched to the rig's bones by name, in whatever order the file lists them: the
        authors' exporter lists them in its stack order (:func:`_maya_order`), not the rig's. Their
        tools have no reader to follow here (the plugin is export only, ``haveReadMethod`` returns
        false, line 249), and a name is what identifies a joint in their schema (``jointNames``,
        "name_of_joint_0_according_to_URDF" in their README), so a position never decides.

        Raises
        ------
        InterchangeError
            Naming the file and the joints: the rig's joints the export lacks, the export's joints
            the rig lacks (or has with every axis locked), and joints whose value counts differ
            (e.g. a ball joint, 4 values, where the rig frees one axis).
        """
        bones, components = _joint_layout(rig)
        names = [rig.names[b] for b in bones]
        where = f"{self.source}: " if self.source else ""
        missing = [n for n in names if n not in self.joint_names]
        extra = [n for n in self.joint_names if n not in names]
        if missing or extra:
            parts = []
            if missing:
                parts.append(f"the rig's joints {', '.join(map(repr, missing))} are not in the export")
            if extra:
                locked = " (every axis locked on the rig)"
                listed = ", ".join(repr(n) + (locked if n in rig.names else "") for n in extra)
                parts.append(f"the export's joints {listed} are not on the rig")
            raise InterchangeError(f"{where}{'; '.join(parts)}")
        expected = dict(zip(names, _joint_dofs(components), strict=True))
        other = [
            f"{n!r} has {d} values in the export, {expected[n]} on the rig"
            for n, d in zip(self.joint_names, self.joint_dofs, strict=True)
            if d != expected[n]
        ]
        if other:
            raise InterchangeError(f"{where}joints carry other DOFs than the rig's: {'; '.join(other)}")
        ends = np.cumsum(self.joint_dofs).tolist()
        column = {n: (e - d, e) for n, d, e in zip(self.joint_names, self.joint_dofs, ends, strict=True)}
        default = rig.rest if default is None else rig.check_theta(default, "default")
        F = len(self.frames)
        basis = np.repeat(rig.basis(default)[None], F, axis=0)
        a, b = column[names[0]]
        root = _rigid(self.hand[:, a : a + 4], self.hand[:, a + 4 : b])
        basis[:, 0] = np.linalg.inv(rig.matrix_local[0]) @ root
        partial = []
        for name, bone, c in zip(names[1:], bones[1:], components[1:], strict=True):
            a, b = column[name]
            values = self.hand[:, a:b]
            if c.size == 3:
                basis[:, bone, :3, :3] = _matrices(values)
            else:
                partial.append((bone, c, values))
        theta = np.empty((F, rig.n_dofs))
        previous = default
        for f in range(F):  # each frame's Euler angles chosen nearest the last's: no 2π jumps
            theta[f] = previous = rig.theta_from_basis(basis[f], previous)
        for b, c, values in partial:
            dofs = rig.bone_dofs(b)
            theta[:, dofs] = default[dofs]
            theta[:, dofs[c]] = values
        return theta

    def object_poses(self) -> np.ndarray:
        """(F, 4, 4) the object's poses in metres."""
        return _rigid(self.object[:, :4], self.object[:, 4:])

    def save(self, path) -> None:
        """Write the ``.kmexp`` file (JSON, as the authors' exporter lays it out)."""
        out = {
            "framerate": self.framerate,
            "jointNames": list(self.joint_names),
            "jointDofs": list(self.joint_dofs),
        }
        if self.table is not None:
            out["table"] = self.table.tolist()
        out["data"] = [
            {"frame": int(f), "object": o, "hand": h}
            for f, o, h in zip(self.frames.tolist(), self.object.tolist(), self.hand.tolist(), strict=True)
        ]
        write_atomically(path, json.dumps(out, indent=1))

    @classmethod
    def load(cls, path) -> KeyframeMotion:
        """Read a ``.kmexp`` file, checking every field's type and length (errors name the frame)."""
        data = _read_json(path, "kmexp")
        where = str(path)
        framerate = data.integer("framerate")
        names = data.strings("jointNames")
        dofs = data.list("jointDofs")
        if len(set(names)) != len(names):
            raise InterchangeError(f"{where}: jointNames must be distinct strings")
        if (
            len(dofs) != len(names)
            or not all(type(d) is int and d > 0 for d in dofs)
            or not dofs
            or dofs[0] != 7
        ):
            raise InterchangeError(
                f"{where}: jointDofs must give a positive count for each of the {len(names)} joints, "
                "7 for the root"
            )
        table = None
        if "table" in data:
            table = data.numbers("table", (10,))
        frames, obj, hand = [], [], []
        for entry in data.objects("data"):
            frames.append(entry.integer("frame"))
            entry = entry.renamed(f"{where}: frame {frames[-1]}")
            obj.append(entry.numbers("object", (7,)))
            hand.append(entry.numbers("hand", (sum(dofs),)))
        if not frames:
            raise InterchangeError(f"{where} has no frames")
        return cls(
            framerate, tuple(names), tuple(dofs), table, np.array(frames, np.int64),
            np.array(obj), np.array(hand), where,
        )  # fmt: skip


def _poses(rig: Rig, theta) -> np.ndarray:
    T = np.asarray(theta, np.float64)
    if T.ndim != 2 or T.shape[1] != rig.n_dofs or not np.all(np.isfinite(T)):
        raise InterchangeError(f"theta must be finite with shape (F, {rig.n_dofs}), got {T.shape}")
    return T


def save_kmexp(
    path, rig: Rig, theta, object_poses, fps: float, table=None, table_size=None, first_frame: int = 1
) -> KeyframeMotion:
    """Write a rig's motion as an authors' ``.kmexp`` (see :meth:`KeyframeMotion.from_rig`); returns it.
    ``first_frame`` is the Maya frame number of frame 0, the motion's own (``Motion.first_frame``) for
    a motion from their scenes: their exporter numbers frames from the timeline's start (line 165)."""
    export = KeyframeMotion.from_rig(rig, theta, object_poses, fps, table, table_size, first_frame)
    export.save(path)
    return export


__all__ = [
    "ContactSequence",
    "InterchangeError",
    "KeyframeMotion",
    "load_markers",
    "pair_markers",
    "save_kmexp",
    "save_markers",
]
