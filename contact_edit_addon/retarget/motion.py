"""A Blender scene's hand-object motion as a :class:`solver.retarget.Motion`: what retargeting reads.

The source hand is any mesh object whose evaluated (deformed) mesh keeps its topology over the frames:
skinned to an armature, animated by shape keys, read from a mesh cache; whatever the depsgraph
evaluates. Its topology is its own mesh's (:func:`..bridge.trimesh`: the polygons triangulated by
:meth:`geodesics.TriMesh.from_polygons`), so the contacts and annotations made on it in the add-on
apply; each frame's world vertices are the evaluated vertices carried by its world matrix.

The object is rigid: its mesh (:func:`..bridge.trimesh`) moved by its world matrix. A motion's object
poses are rotations and translations only, so a scale in that matrix, which must stay the same over the
frames (uniform or not, mirrored or not), is baked into the object's rest vertices (a mirroring also
reverses its triangles, which keep facing out).

Contacts are found and paired as :mod:`solver.retarget.detection` says, in world space (the scene's units).
"""

from __future__ import annotations

from collections.abc import Callable

import bpy
import numpy as np

from geodesics import MeshError, TriMesh, describe_ids
from solver.retarget import Motion, MotionError, with_contacts

from .. import bridge
from ..bridge import BridgeError

__all__ = ["SceneReader", "evaluated_depsgraph", "motion_from_scene"]

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
        As :func:`solver.retarget.detection.with_contacts` takes them.
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
        hand at some frames only, or meshes whose normals point inwards.
    SolverError
        For a hand that never touches the object (then say ``contacts=False`` for a motion of markers
        only).
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
        depsgraph = evaluated_depsgraph(scene)
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


def evaluated_depsgraph(scene) -> bpy.types.Depsgraph:
    """The scene's evaluated depsgraph (the context's, or its first view layer's), brought up to date: the
    objects' world matrices are then those Blender shows, also right after a script changed a parent's."""
    if scene == bpy.context.scene:
        return bpy.context.evaluated_depsgraph_get()
    depsgraph = scene.view_layers[0].depsgraph
    depsgraph.update()
    return depsgraph


def _evaluated_arrays(evaluated) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`..bridge.mesh_arrays` of an evaluated object's mesh (its modifiers and shape keys applied)."""
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
