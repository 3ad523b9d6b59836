"""Batch posing of saved scenes (``contact-edit pose``), with the bpy module or inside Blender.

The scene is opened, its hand posed from its stored contacts (or a pairing file's), and saved to a new
file; the inputs are never written, an existing output only when the caller asks. Output is written
atomically: a complete .blend at the output path, or the previous file (if any) untouched. A file
Blender cannot open is a :class:`BridgeError` naming the file and what is wrong with it, before anything
is written.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import bpy

from geodesics import ContactError, MeshError
from solver import SolverError

from .. import posing, store
from ..bridge import BridgeError
from .outputs import check_outputs


class SceneChoiceError(BridgeError):
    """The scene has no hand or no object chosen to pose against, and the call named none.

    ``missing`` holds ``"hand"``, ``"object"`` or both; ``meshes`` the scene's mesh objects to choose
    from. :meth:`message` words it for another interface's options (the command line's ``--hand NAME``).
    """

    def __init__(self, scene_path, missing: Sequence[str], meshes: Sequence[str]):
        self.scene_path, self.missing, self.meshes = Path(scene_path), tuple(missing), tuple(meshes)
        super().__init__(self.message("hand=NAME", "target=NAME"))

    def message(self, hand_option: str, object_option: str) -> str:
        """The error in the words of an interface whose options name the hand and the object."""
        options = {"hand": hand_option, "object": object_option}
        what = " and no ".join(self.missing)
        them = "them" if len(self.missing) > 1 else "it"
        return (
            f"{self.scene_path}: no {what} chosen in the scene's Contact tab; name {them} with "
            f"{' '.join(options[m] for m in self.missing)} "
            f"(mesh objects: {', '.join(self.meshes) or 'none'})"
        )


class ObjectChoiceError(BridgeError):
    """The object to pose against is the hand itself or its armature, or not a mesh.

    ``given`` says whether the call named it (else the scene's Contact tab chose it); ``meshes`` are the
    scene's other mesh objects. :meth:`message` words it for another interface's options, as
    :class:`SceneChoiceError` does.
    """

    def __init__(self, scene_path, name: str, what: str, given: bool, meshes: Sequence[str]):
        self.scene_path, self.name, self.what = Path(scene_path), name, what
        self.given, self.meshes = given, tuple(meshes)
        super().__init__(self.message("hand=NAME", "target=NAME"))

    def message(self, hand_option: str, object_option: str) -> str:
        """The error in the words of an interface whose options name the hand and the object."""
        option = object_option.split("=")[0].split()[0]  # "--object NAME" -> "--object"
        chosen = (
            f"{option} '{self.name}'"
            if self.given
            else f"the object chosen in the scene's Contact tab, '{self.name}',"
        )
        return (
            f"{self.scene_path}: {chosen} is {self.what}, not a mesh the hand touches; name the object with "
            f"{object_option} (mesh objects: {', '.join(self.meshes) or 'none'})"
        )


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
    quiet: bool = True,
) -> str:
    """Pose the hand of a saved scene and save the result; returns the solve's one-line summary.

    Parameters
    ----------
    scene_path, output : path-like
        The .blend to read and the one to write (never the same, nor the pairing file).
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
    overwrite : bool
        Replace an existing output file (never an input: :func:`.outputs.check_outputs`).
    progress : callable, optional
        Called with (evaluations, max_evaluations, energy) as the solve goes.
    quiet : bool
        Keep Blender's own reports on opening and saving ("Read blend: …", "Info: Saved copy as …"
        naming the temporary file) off standard output.

    Raises
    ------
    BridgeError
        For a scene that is missing, not a .blend file, or damaged (nothing is written then); a missing
        hand or object choice (:class:`SceneChoiceError`); an object that is the hand itself, its
        armature or not a mesh (:class:`ObjectChoiceError`, before anything is read or solved); an
        output Blender cannot write; contacts, a pairing file or a rig that cannot be solved. Every
        message starts with the file it is about (the library's own error is its ``__cause__``).
    """
    scene_path, output = Path(scene_path).resolve(), Path(output).resolve()
    if scene_path.is_dir():
        raise BridgeError(f"{scene_path}: a folder, not a .blend file")
    if not scene_path.is_file():
        raise BridgeError(f"{scene_path}: no such .blend file")
    if output.is_dir():
        raise BridgeError(f"{output}: a folder; name the .blend file to write")
    if not output.parent.is_dir():
        raise BridgeError(f"{output.parent}: no such folder for the output")
    inputs = {scene_path: "the input scene", contacts: "the pairing file (--contacts)"}
    check_outputs([output], inputs, overwrite=overwrite, error=BridgeError, suffix=".blend")
    _open(scene_path, quiet)
    scene = bpy.context.scene
    settings = scene.contact_edit
    if hand:
        settings.hand = _object(hand, scene_path)
    if target:
        settings.target = _object(target, scene_path)
    missing = [what for what, obj in (("hand", settings.hand), ("object", settings.target)) if obj is None]
    if missing:
        raise SceneChoiceError(scene_path, missing, _mesh_names())
    what = posing.of_the_hand(settings.hand, settings.target)
    if what is None and settings.target.type != "MESH":
        what = _a(settings.target.type.lower())
    if what is not None:  # before any contacts are read or anything solved
        others = [name for name in _mesh_names() if name != settings.hand.name]
        raise ObjectChoiceError(scene_path, settings.target.name, what, target is not None, others)
    if contacts is not None:
        with _naming(Path(contacts)):
            store.load_pairing(contacts, settings.hand, settings.target, remap)
    if frame is not None:
        scene.frame_set(frame)

    def report(step) -> bool:
        if progress is not None:
            progress(step.iteration, max_evaluations, step.energy)
        return False

    with _naming(scene_path):
        problem = posing.problem(scene, stage)
        result = problem.ik.solve(problem.theta0, problem.free, report, max_evaluations)
        armature = problem.posed.armature_object()
        animated = armature.animation_data is not None and armature.animation_data.action is not None
        keyed = scene.frame_current if frame is not None or animated else None
        problem, result = posing.settle(scene, problem, result, stage, keyed)
    settings.last_solve = posing.summary(scene, problem, result)
    off = posing.rig_mismatch(scene, problem, result.theta)
    if off:
        settings.last_solve += f"; {off}"
    _save_atomically(output, quiet)
    return settings.last_solve


@contextlib.contextmanager
def _naming(path: Path) -> Iterator[None]:
    """Errors of the block as BridgeErrors whose message starts with ``path``, the file they are about."""
    try:
        yield
    except (BridgeError, ContactError, MeshError, SolverError) as err:
        named = str(err).startswith(str(path))
        if named and isinstance(err, BridgeError):
            raise
        raise BridgeError(str(err) if named else f"{path}: {err}") from err


def _a(noun: str) -> str:
    return f"{'an' if noun[:1] in 'aeiou' else 'a'} {noun}"


def _mesh_names() -> list[str]:
    return sorted(o.name for o in bpy.data.objects if o.type == "MESH")


def _object(name: str, scene_path: Path) -> bpy.types.Object:
    obj = bpy.data.objects.get(name)
    if obj is None:
        meshes = ", ".join(_mesh_names())
        raise BridgeError(f"{scene_path}: there is no object '{name}' (mesh objects: {meshes or 'none'})")
    return obj


def _open(scene_path: Path, quiet: bool) -> None:
    """Open a .blend, or raise BridgeError saying what is wrong with it (Blender raises RuntimeError)."""
    try:
        with quiet_stdout(quiet):
            bpy.ops.wm.open_mainfile(filepath=str(scene_path), load_ui=False)
    except RuntimeError as err:
        raise BridgeError(f"{scene_path}: {_unreadable(scene_path, str(err))}") from err


def _unreadable(path: Path, blender: str) -> str:
    """Why Blender could not open ``path``, from its message (which names the file again)."""
    said = " ".join(blender.split()).removeprefix("Error: ")
    for quoted in (f'"{path}"', f"'{path}'"):
        said = said.replace(f" {quoted}", "").replace(quoted, "")
    try:
        empty = path.stat().st_size == 0
    except OSError:
        empty = False
    if empty:
        return "an empty file, not a .blend file"
    if "File format is not supported" in said:
        return "not a .blend file (Blender does not recognize its contents)"
    if "incomplete header" in said:
        return "a damaged or truncated .blend file, or one saved by a newer Blender (incomplete header)"
    if "Failed to read blend file" in said or "Missing DNA" in said:
        detail = said.rpartition(": ")[2]
        return f"a damaged or truncated .blend file (Blender: {detail})"
    return f"Blender cannot open it ({said})"


def _save_atomically(output: Path, quiet: bool = True) -> None:
    temp = output.with_name(f".{output.stem}.{os.getpid()}.{time.monotonic_ns()}.blend")
    try:
        with quiet_stdout(quiet):
            bpy.ops.wm.save_as_mainfile(filepath=str(temp), check_existing=False, copy=True)
        os.replace(temp, output)
    except RuntimeError as err:
        said = " ".join(str(err).split()).removeprefix("Error: ")
        raise BridgeError(f"{output}: Blender cannot save it ({said})") from err
    finally:
        temp.unlink(missing_ok=True)


@contextlib.contextmanager
def quiet_stdout(enabled: bool = True) -> Iterator[None]:
    """Drop whatever is printed to standard output while the block runs.

    Blender's C code reports straight to the process's standard output ("Read blend: …", "Info: Saved
    copy as …", its own "Error: …" lines), past Python's ``sys.stdout``; so file descriptor 1 is pointed
    at the null device for the block (and ``sys.stdout`` with it), and restored afterwards, on errors
    too. What was printed before the block is flushed out first; what Blender buffered during it is
    flushed into the null device before the descriptor is restored, so none of it appears later.
    """
    if not enabled:
        yield
        return
    _flush_stdout()
    try:
        saved = os.dup(1)
    except OSError:  # no standard output at all: nothing can leak
        saved = None
    with open(os.devnull, "w") as null:
        try:
            if saved is not None:
                os.dup2(null.fileno(), 1)
            with contextlib.redirect_stdout(null):
                yield
        finally:
            _flush_stdout()
            if saved is not None:
                os.dup2(saved, 1)
                os.close(saved)


def _flush_stdout() -> None:
    """Flush Python's standard output and the C library's buffered streams (Blender's printf)."""
    for stream in (sys.stdout, sys.__stdout__):
        with contextlib.suppress(AttributeError, OSError, ValueError):  # None, or closed
            stream.flush()
    libc = _libc()
    if libc is not None:
        libc.fflush(None)


_LIBC: list = []


def _libc():
    if not _LIBC:
        try:
            import ctypes

            libc = ctypes.CDLL(None)
            libc.fflush.argtypes = [ctypes.c_void_p]
        except (OSError, TypeError, AttributeError):  # a platform without a process-wide C library
            libc = None
        _LIBC.append(libc)
    return _LIBC[0]
