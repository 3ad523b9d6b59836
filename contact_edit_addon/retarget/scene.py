"""Retargeting in Blender: a scene's hand-object motion onto another hand's armature, keyed as an action.

The source is any deforming hand mesh holding a rigidly moving object (:mod:`.motion`); the target
is a hand mesh deformed by an armature, posed through the controls an animator keys
(:func:`..bridge.posed_hand`: any rig the Solve tool poses, Rigify included). The work comes in three
parts, so that an operator keeps Blender responsive:

1. :func:`prepare` (main thread) reads the target's rig and the annotation, and returns a
   :class:`.motion.SceneReader` for the frames, read a few per timer tick, and the
   :class:`solver.retarget.job.RetargetJob`;
2. :func:`solver.retarget.job.run_job` (plain data: here, or in a child process with
   :class:`solver.retarget.job.ChildRun`) finds and pairs the contacts, carries the motion into the target
   armature's space and runs the retargeting pipeline, its frames solved in worker processes and stored as
   they finish, so that running it again goes on from them;
3. :func:`commit` (main thread) keys the result on the target's controls as one action
   (:func:`.action.write_action`) and packs the metrics plot into the .blend.

:func:`retarget_scene` does all three in turn, for scripts and ``blender --background``.

The pipeline works in the target armature's space: the world-space motion is carried there by the inverse
of the armature's world matrix (a rotation, a translation and a uniform scale, the only scale the solve
accepts). The annotation, which names points on both hands' surfaces, is read from an ``annotation.json``
(in the format ``contact-edit retarget`` writes), or from the curves and markers drawn on the two hands
(:mod:`.annotation`), or, for the procedural hands the add-on makes (*Add › Contact Edit*), built in
(:func:`solver.retarget.annotate.procedural_hand`).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from pathlib import Path

import bpy
import numpy as np

from geodesics import SurfacePoints
from solver import SolverError
from solver.retarget import (
    HandPairAnnotation,
    JobOutcome,
    RetargetJob,
    RetargetOptions,
    procedural_kind,
    run_job,
)

from .. import bridge
from ..bridge import BridgeError, PosedHand
from . import motion as scene_motion
from .action import metrics_image, write_action, write_metrics
from .annotation import hand_pair, has_annotation

#: ``progress(stage, done, total)``: "read" (frames read), then :func:`solver.retarget.job.run_job`'s.
Progress = Callable[[str, int, int], None]


def prepare(
    scene: bpy.types.Scene,
    source: bpy.types.Object,
    obj: bpy.types.Object,
    target: bpy.types.Object,
    frame_start: int,
    frame_end: int,
    *,
    annotation_path: str = "",
    hand_root: str = "",
    options: RetargetOptions | None = None,
    contacts: bool = True,
    folder: str = "",
) -> tuple[scene_motion.SceneReader, RetargetJob, PosedHand]:
    """Check the inputs and read the target's rig: the reader of the frames, the job for
    :func:`solver.retarget.job.run_job`, and the target hand as :func:`commit` keys it.

    Parameters
    ----------
    scene, source, obj, target
        The scene, the source hand's mesh object (any deforming mesh), the object it moves, and the
        target hand's mesh object (deformed by an armature).
    frame_start, frame_end : int
        The frames retargeted, both included.
    annotation_path : str
        An ``annotation.json`` for this source and target hand (Blender's ``//`` prefix allowed); empty:
        the two hands' own annotations (:mod:`.annotation`) when they have them, else the built-in
        annotation, for the procedural hands only.
    hand_root : str
        The target's wrist bone; empty finds it where the bones under the annotated points branch.
    options : RetargetOptions, optional
    contacts : bool
        Find the source's contacts; False retargets from the markers only.
    folder : str
        Where the frames are kept; empty: beside the .blend (``<name>_retarget``), or in Blender's
        temporary folder for an unsaved file.

    Raises
    ------
    BridgeError
        Naming what is wrong: the objects (as :class:`.motion.SceneReader` checks them), a target
        the solve cannot pose, an annotation file that is missing, broken or made for other hands.
    """
    scene_motion.evaluated_depsgraph(scene)  # world matrices as Blender shows them, even just after a script
    reader = scene_motion.SceneReader(scene, source, obj, frame_start, frame_end)
    if target in (source, obj):
        raise BridgeError(f"'{target.name}' cannot be both the target and the source or object", target.name)
    target_mesh = bridge.trimesh(target)
    annotation = None
    if annotation_path:
        path = Path(bpy.path.abspath(annotation_path))
        try:
            annotation = HandPairAnnotation.load(path, reader.hand_rest, target_mesh)
        except SolverError as err:
            text = str(err) if str(path) in str(err) else f"the annotation file {path}: {err}"
            raise BridgeError(f"{text} (retargeting '{source.name}' onto '{target.name}')") from err
    elif has_annotation(source) or has_annotation(target):
        annotation = hand_pair(source, target, reader.hand_rest, target_mesh)
    else:
        for role, name, mesh in (
            ("source", source.name, reader.hand_rest),
            ("target", target.name, target_mesh),
        ):
            if procedural_kind(mesh) is None:
                raise BridgeError(
                    f"the {role} hand '{name}' is not one of the procedural hands (Add > Contact Edit), "
                    "which have an annotation built in: propose and edit an annotation on each hand "
                    "(Retarget > Annotation), or give an annotation file made for these two hands",
                    name,
                )
    points = None
    if annotation is not None:
        points = SurfacePoints.concatenate(
            [c.target_start for c in annotation.curves if not c.dropped]
            + [m.target for m in annotation.markers]
        )
    posed = bridge.posed_hand(target, target_mesh.faces, points, hand_root)
    if posed.rig.locked[:3].all():
        raise BridgeError(
            f"the control '{posed.rig.names[0]}' that moves the wrist of '{target.name}' cannot move (its "
            "location is locked or moves nothing), but retargeting carries the whole hand along the "
            "motion: choose the wrist's IK control (Rigify: the hand's IK control, with IK on)",
            target.name,
        )
    start = np.ascontiguousarray(posed.start)
    job = RetargetJob(
        (source.name, obj.name, target.name),
        tuple(reader.frames),
        posed.skin,
        np.linalg.inv(np.array(posed.armature_object().matrix_world)),
        annotation,
        options or RetargetOptions(),
        contacts,
        _base_folder(folder),
        identity=hashlib.blake2b(start.tobytes() + " ".join(posed.rig.dof_names).encode()).hexdigest(),
    )
    return reader, job, posed


def commit(
    job: RetargetJob,
    posed: PosedHand,
    outcome: JobOutcome,
    action_name: str = "",
    replace_action: bool = True,
):
    """Key the result on the target's controls as one new action (named ``action_name``, or after the two
    hands), with the per-frame metrics as curves of the armature's custom properties in it
    (:func:`.action.write_metrics`), and pack the metrics plot (when matplotlib made one); main
    thread. Returns (action, image or None)."""
    name = action_name or f"{job.names[2]} from {job.names[0]}"
    r = outcome.result
    action = write_action(posed, r.theta, job.frames, name, replace=replace_action)
    mm = outcome.scale * 1e3
    metrics = {"retarget_contacts_mm": r.contact_distance * mm, "retarget_markers_mm": r.marker_distance * mm}
    for key in ("hand_object", "self_intersection"):
        metrics[f"retarget_{key}_percent"] = (
            getattr(r.intersections, key) if r.intersections is not None else np.full(len(r.theta), np.nan)
        )
    write_metrics(posed.armature_object(), action, job.frames, metrics)
    image = None
    if "plot" in outcome.paths:
        image = metrics_image(outcome.paths["plot"], f"{name} metrics")
    return action, image


def retarget_scene(
    scene: bpy.types.Scene,
    source: bpy.types.Object,
    obj: bpy.types.Object,
    target: bpy.types.Object,
    frame_start: int,
    frame_end: int,
    *,
    annotation_path: str = "",
    hand_root: str = "",
    options: RetargetOptions | None = None,
    contacts: bool = True,
    folder: str = "",
    workers: int | None = None,
    action_name: str = "",
    replace_action: bool = True,
    progress: Progress | None = None,
) -> JobOutcome:
    """Retarget the scene's motion of ``source`` holding ``obj`` onto ``target`` and key it as an action on
    the target's armature: :func:`prepare`, the frames read, :func:`solver.retarget.job.run_job` (in this
    process; its frames in ``workers`` worker processes) and :func:`commit`, in turn.

    Parameters are those of the three; ``progress(stage, done, total)`` hears every stage. Returns the
    :class:`~solver.retarget.job.JobOutcome`; its ``summary()`` says how near the contacts came (in the
    scene's units) and what went wrong, if anything.
    """
    report = progress or (lambda _stage, _done, _total: None)
    reader, job, posed = prepare(
        scene, source, obj, target, frame_start, frame_end, annotation_path=annotation_path,
        hand_root=hand_root, options=options, contacts=contacts, folder=folder,
    )  # fmt: skip
    try:
        while reader.read_next():
            report("read", reader.done, reader.n_frames)
    finally:
        reader.restore()
    outcome = run_job(job, reader.motion(), workers=workers, progress=report)
    commit(job, posed, outcome, action_name, replace_action)
    return outcome


def _base_folder(folder: str) -> Path:
    if folder:
        return Path(bpy.path.abspath(folder))
    if bpy.data.filepath:
        blend = Path(bpy.data.filepath)
        return blend.parent / f"{blend.stem}_retarget"
    return Path(bpy.app.tempdir or ".") / "contact_edit_retarget"
