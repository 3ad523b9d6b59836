"""A Blender scene's hand-object motion as a :class:`solver.retarget.Motion`: what retargeting reads.

The source hand is any mesh object whose evaluated (deformed) mesh keeps its topology over the frames:
skinned to an armature, animated by shape keys, read from a mesh cache; whatever the depsgraph
evaluates. Its topology is its own mesh's (:func:`.bridge.trimesh`: the polygons triangulated by
:meth:`geodesics.TriMesh.from_polygons`), so the contacts and annotations made on it in the add-on
apply; each frame's world vertices are the evaluated vertices carried by its world matrix.

The object is rigid: its mesh (:func:`.bridge.trimesh`) moved by its world matrix. A motion's object
poses are rotations and translations only, so a scale in that matrix, which must stay the same over the
frames (uniform or not, mirrored or not), is baked into the object's rest vertices (a mirroring also
reverses its triangles, which keep facing out).

Contacts are found where the datasets the retargeting paper reads mark them, on the object where the
skin touches it (GRAB's contact map, whose hand side the paper finds by ray casting): area-uniform
samples of the object's surface (seeded; :data:`SPACING_FRACTION` of the hand's size apart on average)
that lie within ``contact_distance`` of the posed hand surface, or inside the hand (no deeper than the
pairing cutoff ε, when the hand mesh is closed and has an inside), are the frame's object contacts;
each is then paired with the hand by ray casting along the object's normal
(:func:`solver.retarget.pair_motion`, §3.2), which discards the few whose ray misses the hand or meets
it farther than ε.

The hand's size is the square root of its surface area in world space at the first frame (0.245 m for
the procedural human hand with its forearm), so the defaults follow the scene's scale.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import bpy
import numpy as np

from geodesics import MeshError, SurfacePoints, TriMesh
from geodesics.closest import ClosestPoints
from geodesics.errors import describe_ids
from solver.retarget.motion import Contacts, Motion, MotionError
from solver.retarget.pairing import pair_motion
from solver.sdf import MeshSDF

from . import bridge
from .bridge import BridgeError

__all__ = [
    "CONTACT_FRACTION",
    "CUTOFF_FACTOR",
    "SPACING_FRACTION",
    "SceneReader",
    "detect_contacts",
    "hand_size",
    "motion_from_scene",
    "with_contacts",
]

#: Default contact distance, as a fraction of the hand's size: 2.45 mm for the life-size human hand,
#: about the synthetic motions' 2 mm (``solver.retarget.synthetic.CONTACT_TOLERANCE``).
CONTACT_FRACTION = 0.01
#: Mean spacing of the object's surface samples, as a fraction of the hand's size: 1.5 mm for the human
#: hand, about 45 samples per cm² (43,000 on a mug 12 cm across), some 500 contacts where it holds the mug
#: with the fingertips and palm. Sparser contacts let the retargeting's markers outweigh them: with 2.45 mm
#: (a third as many) a human hand 1.25 times as large ends 4.8 mm from the mug instead of 3.0 mm.
SPACING_FRACTION = 0.006
#: Default pairing cutoff ε, in contact distances: 9.8 mm for the human hand, about the paper's 1 cm
#: (``solver.retarget.pairing.DEFAULT_CUTOFF``). Contacts deeper inside the hand than ε are not sought:
#: their rays would meet the skin farther than ε, and the pairing would discard them.
CUTOFF_FACTOR = 4.0
#: The object's scale may vary by this much (relative) over the frames: Blender's float32 matrices.
SCALE_TOLERANCE = 1e-5
#: A world matrix whose scale is within this of 1 (float32 rounding of a rotation) is not scaled.
UNSCALED = 1e-6
#: The object's evaluated mesh may differ from its own mesh by this much (relative to its size).
SHAPE_TOLERANCE = 1e-5

Progress = Callable[[int, int], None]


def motion_from_scene(
    scene: bpy.types.Scene,
    hand_obj: bpy.types.Object,
    object_obj: bpy.types.Object,
    frame_start: int,
    frame_end: int,
    *,
    contacts: bool = True,
    contact_distance: float | None = None,
    cutoff: float | None = None,
    spacing: float | None = None,
    seed: int = 0,
    progress: Progress | None = None,
) -> Motion:
    """Read the hand's and the object's animation over frames ``frame_start..frame_end`` (inclusive).

    Parameters
    ----------
    scene : bpy.types.Scene
        The scene both objects are in; its frame rate (``render.fps / render.fps_base``) is the
        motion's. Its current frame is restored afterwards.
    hand_obj : bpy.types.Object
        The source hand's mesh object (the skinned mesh, not its armature).
    object_obj : bpy.types.Object
        The manipulated object's mesh object, moved rigidly by its world matrix.
    frame_start, frame_end : int
        The frames read, both included.
    contacts : bool
        Detect and pair the dense contacts (see the module docstring). Without them the motion has
        none, and retargets from markers only.
    contact_distance, cutoff, spacing, seed
        As :func:`with_contacts` takes them.
    progress : callable, optional
        ``progress(done, total)`` after each frame read and, with contacts, after each frame searched
        for contacts and after each frame paired (``total`` is the frame count, three times it with
        contacts).

    Returns
    -------
    Motion
        World space, the scene's units; the hand's rest mesh with the scale of its world matrix at
        ``frame_start``; ``source_scale`` 1 and no ``source_kind``: the hand is not a procedural one.

    Raises
    ------
    BridgeError
        Naming the object and the frame: not a mesh, no faces, an empty frame range, a hand whose
        modifiers change its topology, an object that is deformed or whose scale changes, a mirrored
        hand at some frames only, meshes whose normals point inwards, or a hand that never touches
        the object (then say ``contacts=False`` for a motion of markers only).
    """
    reader = SceneReader(scene, hand_obj, object_obj, frame_start, frame_end)
    total = reader.n_frames * (3 if contacts else 1)
    try:
        while reader.read_next():
            if progress is not None:
                progress(reader.done, total)
    finally:
        reader.restore()
    motion = reader.motion()
    if not contacts:
        return motion
    step = reader.n_frames
    return with_contacts(
        motion,
        reader.names,
        reader.frames,
        contact_distance=contact_distance,
        cutoff=cutoff,
        spacing=spacing,
        seed=seed,
        progress=None if progress is None else lambda done, _: progress(step + done, total),
    )


class SceneReader:
    """Reads a hand-object motion from a scene one frame at a time, so that an operator can read a few
    frames per timer tick and keep Blender responsive (:func:`motion_from_scene` reads them all).

    Each :meth:`read_next` sets the scene's frame; :meth:`restore` puts back the frame the scene was on
    (call it when done or stopped); :meth:`motion` makes the motion once every frame is read. The
    objects are checked when the reader is made; each frame as it is read.
    """

    def __init__(self, scene, hand_obj, object_obj, frame_start, frame_end):
        self.frames = _frame_range(frame_start, frame_end)
        _check_objects(scene, hand_obj, object_obj)
        self.scene, self.hand_obj, self.object_obj = scene, hand_obj, object_obj
        #: The hand's and the object's names, for messages made where Blender data is not at hand.
        self.names = (hand_obj.name, object_obj.name)
        self.hand_rest = bridge.trimesh(hand_obj)
        self.object_rest = bridge.trimesh(object_obj)
        _, self._hand_corners, self._hand_sizes = bridge.mesh_arrays(hand_obj.data)
        self._object_local, _, _ = bridge.mesh_arrays(object_obj.data)
        size = max(float(np.ptp(self._object_local, axis=0).max()), 1e-30)
        self._tolerance = SHAPE_TOLERANCE * size
        F = len(self.frames)
        self.hand_matrices, self.object_matrices = np.empty((F, 4, 4)), np.empty((F, 4, 4))
        self.hand_vertices = np.empty((F, len(hand_obj.data.vertices), 3))
        self.done = 0
        self._current = scene.frame_current, scene.frame_subframe

    @property
    def n_frames(self) -> int:
        return len(self.frames)

    def read_next(self) -> bool:
        """Read the next frame; False (reading nothing) once every frame is read."""
        if self.done == self.n_frames:
            return False
        f, frame = self.done, self.frames[self.done]
        scene, hand_obj, object_obj = self.scene, self.hand_obj, self.object_obj
        scene.frame_set(frame)
        depsgraph = _depsgraph(scene)
        evaluated = hand_obj.evaluated_get(depsgraph)
        V, corners, sizes = _evaluated_arrays(evaluated)
        if not (np.array_equal(sizes, self._hand_sizes) and np.array_equal(corners, self._hand_corners)):
            raise BridgeError(_topology_message(hand_obj, frame, len(V), len(sizes)), hand_obj.name)
        M = np.array(evaluated.matrix_world)
        self.hand_matrices[f] = M
        self.hand_vertices[f] = V @ M[:3, :3].T + M[:3, 3]
        evaluated = object_obj.evaluated_get(depsgraph)
        W, _, _ = _evaluated_arrays(evaluated)
        local = self._object_local
        if W.shape != local.shape or np.abs(W - local).max() > self._tolerance:
            moved = "" if W.shape != local.shape else f" (by up to {np.abs(W - local).max():.3g})"
            raise BridgeError(
                f"'{object_obj.name}' is not rigid at frame {frame}: its modifiers or shape keys change "
                f"its shape{moved}; the object must be moved by its transform only (apply or remove "
                "them)",
                object_obj.name,
            )
        self.object_matrices[f] = np.array(evaluated.matrix_world)
        self.done += 1
        return True

    def restore(self) -> None:
        """Put the scene back on the frame it was on when the reader was made."""
        frame, subframe = self._current
        self.scene.frame_set(frame, subframe=subframe)

    def motion(self) -> Motion:
        """The motion of the frames read (all of them), without contacts; checks what needs every frame
        (a changing scale, a mirroring at some frames only, inward normals)."""
        if self.done != self.n_frames:
            raise BridgeError(f"only {self.done} of the {self.n_frames} frames are read")
        hand_obj, object_obj, frames = self.hand_obj, self.object_obj, self.frames
        hand_mesh = _hand_mesh(hand_obj, self.hand_rest, self.hand_matrices, frames)
        object_mesh, object_poses = _rigid_object(object_obj, self.object_rest, self.object_matrices, frames)
        _check_outwards(hand_obj, hand_mesh)
        _check_outwards(object_obj, object_mesh)
        try:
            return Motion(
                fps=self.scene.render.fps / self.scene.render.fps_base,
                object_mesh=object_mesh,
                object_poses=object_poses,
                hand_mesh=hand_mesh,
                hand_vertices=self.hand_vertices,
            )
        except MotionError as err:
            raise BridgeError(
                f"'{hand_obj.name}' and '{object_obj.name}' do not make a motion: {err}"
            ) from None


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
    """The motion with its dense contacts found and paired (see the module docstring). Plain data only:
    it may run off Blender's main thread.

    Parameters
    ----------
    motion : Motion
        Without contacts (:meth:`SceneReader.motion`).
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
    BridgeError
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
        raise BridgeError(
            f"'{hand_name}' never comes within {distance * 1e3:.3g} mm of '{object_name}' in frames "
            f"{frames[0]}-{frames[-1]}, so there are no contacts to retarget; give a larger contact "
            "distance, another frame range, or read the motion without contacts (markers only)",
            hand_name,
        )
    motion = replace(motion, object_contacts=found)
    pairing = pair_motion(
        motion,
        "object",
        cutoff=epsilon,
        progress=None if progress is None else lambda done, _: progress(F + done, 2 * F),
    )
    if len(pairing.object_contacts) == 0:
        counts = ", ".join(f"{n} {name}" for name, n in pairing.counts().items() if n)
        raise BridgeError(
            f"none of the {len(found)} points of '{object_name}' near '{hand_name}' pair with the "
            f"hand along the object's normals ({counts}; cutoff {epsilon * 1e3:.3g} mm): do the normals "
            "of both meshes point outwards?",
            object_name,
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
    hand_name: str = "the hand",
    progress: Progress | None = None,
) -> Contacts:
    """Object contacts of every frame: the object's surface samples within ``contact_distance`` of the
    posed hand, or inside it no deeper than ``cutoff`` (closed hands only; sought in the frames where
    some sample is found more than half ``contact_distance`` inside the skin, i.e. where the surfaces
    cross that deep, since looking deeper costs four times as much).

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
            raise BridgeError(f"{hand_name} is not a valid mesh at frame {frame}: {err}") from None
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


# ------------------------------------------------------------------------------------------ checks


def _frame_range(frame_start, frame_end) -> list[int]:
    for name, value in (("frame_start", frame_start), ("frame_end", frame_end)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise BridgeError(f"{name} must be a whole frame number, got {value!r}")
    if frame_end < frame_start:
        raise BridgeError(
            f"the frame range {frame_start}-{frame_end} is empty: it ends before it starts; give "
            "frame_start <= frame_end"
        )
    return list(range(int(frame_start), int(frame_end) + 1))


def _check_objects(scene, hand_obj, object_obj) -> None:
    for role, obj in (("hand", hand_obj), ("object", object_obj)):
        if not isinstance(obj, bpy.types.Object):
            raise BridgeError(f"the {role} must be a Blender object, got {type(obj).__name__}")
        if obj.type != "MESH":
            hint = " (choose the mesh it deforms)" if obj.type == "ARMATURE" else ""
            kind = obj.type.title().replace("_", " ")
            raise BridgeError(
                f"the {role} '{obj.name}' is not a mesh object (its type is {kind}){hint}", obj.name
            )
        if scene.objects.get(obj.name) != obj:
            raise BridgeError(f"the {role} '{obj.name}' is not in the scene '{scene.name}'", obj.name)
    if hand_obj == object_obj:
        raise BridgeError(f"'{hand_obj.name}' cannot be both the hand and the object", hand_obj.name)


def _positive(name: str, value, default: float) -> float:
    if value is None:
        return float(default)
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise BridgeError(f"{name} must be a number, got {type(value).__name__}")
    if not (math.isfinite(value) and value > 0):
        raise BridgeError(f"{name} must be finite and positive, got {value!r}")
    return float(value)


def _check_outwards(obj, mesh: TriMesh) -> None:
    """Raise if a closed mesh encloses a negative volume: its normals point inwards."""
    if np.any(mesh.twin < 0):
        return
    T = mesh.vertices[mesh.faces] - mesh.vertices.mean(0)
    volume = np.einsum("ij,ij->i", T[:, 0], np.cross(T[:, 1], T[:, 2])).sum() / 6.0
    if volume < 0:
        raise BridgeError(
            f"the normals of '{obj.name}' point inwards; recalculate them outside "
            "(Mesh > Normals > Recalculate Outside)",
            obj.name,
        )


# ------------------------------------------------------------------------------------------ reading


def _topology_message(obj, frame: int, n_vertices: int, n_faces: int) -> str:
    own = len(obj.data.vertices), len(obj.data.polygons)
    if (n_vertices, n_faces) == own:
        what = f"connects its {own[0]} vertices and {own[1]} faces otherwise than its own mesh"
    else:
        what = f"has {n_vertices} vertices and {n_faces} faces where its own mesh has {own[0]} and {own[1]}"
    return (
        f"at frame {frame} the evaluated mesh of '{obj.name}' {what}: its modifiers change its topology (as "
        "Subdivision Surface, Build or Remesh do), so its vertices cannot be followed; disable or apply them"
    )


def _depsgraph(scene) -> bpy.types.Depsgraph:
    """The evaluated depsgraph of the scene: the context's, or the scene's first view layer's."""
    if scene == bpy.context.scene:
        return bpy.context.evaluated_depsgraph_get()
    return scene.view_layers[0].depsgraph


def _evaluated_arrays(evaluated) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`.bridge.mesh_arrays` of an evaluated object's mesh (its modifiers and shape keys applied)."""
    mesh = evaluated.to_mesh()
    try:
        return bridge.mesh_arrays(mesh)
    finally:
        evaluated.to_mesh_clear()


# ------------------------------------------------------------------------------------------ scale


def _polar(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotations R (F, 3, 3) with det +1 and symmetric S (F, 3, 3) with ``A = R S`` (A: (F, 3, 3)); S is
    the scale (negative definite for a mirroring matrix, det A < 0)."""
    U, sigma, Vt = np.linalg.svd(A)
    R = U @ Vt
    S = np.einsum("fji,fj,fjk->fik", Vt, sigma, Vt)
    mirrored = np.linalg.det(A) < 0
    R[mirrored] *= -1.0
    S[mirrored] *= -1.0
    return R, S


def _scaled(mesh: TriMesh, S: np.ndarray) -> TriMesh:
    """``mesh`` with its vertices scaled by ``S`` (3, 3); a mirroring also reverses its triangles. A scale
    within :data:`UNSCALED` of none (a rotation's float32 rounding) leaves the mesh as it is."""
    if np.abs(S - np.eye(3)).max() <= UNSCALED:
        return mesh
    faces = mesh.faces if np.linalg.det(S) > 0 else mesh.faces[:, ::-1]
    return TriMesh(mesh.vertices @ S.T, faces)


def _rigid_object(obj, rest: TriMesh, matrices: np.ndarray, frames) -> tuple[TriMesh, np.ndarray]:
    """The object's rest mesh with its constant scale baked in, and its rigid poses (F, 4, 4)."""
    R, S = _polar(matrices[:, :3, :3])
    change = np.abs(S - S[0]).max(axis=(1, 2)) / max(float(np.abs(S[0]).max()), 1e-300)
    bad = np.flatnonzero(change > SCALE_TOLERANCE)
    if bad.size:
        scale = np.linalg.norm(matrices[:, :3, :3], axis=1)  # Blender's scale: column lengths
        raise BridgeError(
            f"the scale of '{obj.name}' changes over the frames: {_vector(scale[0])} at frame {frames[0]}, "
            f"{_vector(scale[bad[0]])} at frame {frames[bad[0]]} (frames "
            f"{describe_ids(np.asarray(frames)[bad])}); a rigid object keeps one scale: animate its "
            "location and rotation only",
            obj.name,
        )
    poses = np.zeros_like(matrices)
    poses[:, :3, :3] = R
    poses[:, :3, 3] = matrices[:, :3, 3]
    poses[:, 3, 3] = 1.0
    try:
        return _scaled(rest, S[0]), poses
    except MeshError as err:
        raise BridgeError(
            f"'{obj.name}' scaled by its transform is not a valid mesh: {err}", obj.name
        ) from None


def _hand_mesh(obj, rest: TriMesh, matrices: np.ndarray, frames) -> TriMesh:
    """The hand's rest mesh with the scale of its world matrix at the first frame (mirrored hands: their
    triangles reversed, so they face out in world space; the mirroring must then hold at every frame)."""
    det = np.linalg.det(matrices[:, :3, :3])
    flipped = np.flatnonzero(np.sign(det) != np.sign(det[0]))
    if flipped.size:
        raise BridgeError(
            f"'{obj.name}' is mirrored (a negative scale) at frames "
            f"{describe_ids(np.asarray(frames)[flipped])} but not at frame {frames[0]}, which turns its skin "
            "inside out there",
            obj.name,
        )
    _, S = _polar(matrices[:1, :3, :3])
    try:
        return _scaled(rest, S[0])
    except MeshError as err:
        raise BridgeError(
            f"'{obj.name}' scaled by its transform is not a valid mesh: {err}", obj.name
        ) from None


def _vector(v: np.ndarray) -> str:
    return "(" + ", ".join(f"{x:.4g}" for x in v) + ")"
