"""Batch posing of saved scenes (``contact-edit pose``), with the bpy module or inside Blender.

The scene is opened, its hand posed from its stored contacts (or a pairing file's), and saved to a new
file; the input is never written unless the caller asks. Output is written atomically: a complete
.blend at the output path, or the previous file (if any) untouched.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path

import bpy

from . import posing, store
from .bridge import BridgeError


def pose_scene(
    scene_path,
    output,
    hand: str | None = None,
    target: str | None = None,
    contacts=None,
    frame: int | None = None,
    stage: str = "ALL",
    overwrite: bool = False,
    remap: bool = False,
    progress: Callable[[int, int, float], None] | None = None,
    max_evaluations: int = 2000,
) -> str:
    """Pose the hand of a saved scene and save the result; returns the solve's one-line summary.

    Parameters
    ----------
    scene_path, output : path-like
        The .blend to read and the one to write (the same only with ``overwrite``).
    hand, target : str, optional
        Object names (default: the hand and object chosen in the scene's Contact tab).
    contacts : path-like, optional
        A pairing file (``store.save_pairing``) to use instead of the contacts stored in the scene.
    remap : bool
        Project a pairing file made for other meshes onto the scene's by position (else it is refused).
    frame : int, optional
        Pose at this frame and key the pose there. Without it the current frame is posed, and keyed
        only if the armature is already animated (otherwise its animation would override the pose).
    stage : str
        ``"ROOT"``, ``"ALL"`` or ``"SELECTED"`` (see :data:`posing.STAGES`).
    progress : callable, optional
        Called with (evaluations, max_evaluations, energy) as the solve goes.
    """
    scene_path, output = Path(scene_path).resolve(), Path(output).resolve()
    if not scene_path.is_file():
        raise BridgeError(f"{scene_path}: no such .blend file")
    if output == scene_path and not overwrite:
        raise BridgeError(f"{output} is the input scene; choose another output or allow overwriting it")
    if not output.parent.is_dir():
        raise BridgeError(f"{output.parent}: no such folder for the output")
    bpy.ops.wm.open_mainfile(filepath=str(scene_path), load_ui=False)
    scene = bpy.context.scene
    settings = scene.contact_edit
    if hand:
        settings.hand = _object(hand, scene_path)
    if target:
        settings.target = _object(target, scene_path)
    if contacts is not None:
        if settings.hand is None or settings.target is None:
            raise BridgeError(f"{scene_path}: name the hand and the object to apply {contacts} to")
        store.load_pairing(contacts, settings.hand, settings.target, remap)
    if frame is not None:
        scene.frame_set(frame)
    problem = posing.problem(scene, stage)

    def report(step) -> bool:
        if progress is not None:
            progress(step.iteration, max_evaluations, step.energy)
        return False

    result = problem.ik.solve(problem.theta0, problem.free, report, max_evaluations)
    armature = problem.posed.armature_object()
    animated = armature.animation_data is not None and armature.animation_data.action is not None
    problem.apply(result.theta, scene.frame_current if frame is not None or animated else None)
    settings.last_solve = posing.summary(scene, problem, result)
    _save_atomically(output)
    return settings.last_solve


def _object(name: str, scene_path: Path) -> bpy.types.Object:
    obj = bpy.data.objects.get(name)
    if obj is None:
        meshes = ", ".join(sorted(o.name for o in bpy.data.objects if o.type == "MESH"))
        raise BridgeError(f"{scene_path}: there is no object '{name}' (mesh objects: {meshes or 'none'})")
    return obj


def _save_atomically(output: Path) -> None:
    temp = output.with_name(f".{output.stem}.{os.getpid()}.{time.monotonic_ns()}.blend")
    try:
        bpy.ops.wm.save_as_mainfile(filepath=str(temp), check_existing=False, copy=True)
        os.replace(temp, output)
    finally:
        temp.unlink(missing_ok=True)
