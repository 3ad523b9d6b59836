"""A retarget of a motion read from an application's scene, as plain data that runs here or in a child
process: what an application with its own event loop (Blender) starts, watches and stops without waiting
on it.

:func:`run_job` finds the motion's contacts (:mod:`.detection`), carries it into the target hand's space
(:func:`in_space`), builds the procedural hands' annotation where none is given, runs the pipeline
(:func:`.pipeline.retarget`) with its frames kept in a folder of this run (:func:`run_folder`, so that a
run stopped part way goes on from them) and writes the pipeline's outputs there
(:func:`.pipeline.save_result`).

:class:`ChildRun` runs it in a child process started by Python's spawn method: the parent only reads
progress messages from a queue, so nothing the retarget computes competes with the parent's own thread
for Python's global interpreter lock (a worker thread in Blender's process held its event loop back).
The child's own frames go to worker processes as usual.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import json
import multiprocessing
import os
import queue as queues
import sys
import threading
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from geodesics import TriMesh

from ..errors import SolverError
from ..rig import SkinnedMesh
from .annotate import default_annotation, procedural_hand
from .annotations import HandPairAnnotation
from .detection import with_contacts
from .motion import Motion
from .pipeline import Retarget, RetargetOptions, retarget, save_result

#: How much lower the child's scheduling priority is than its parent's (POSIX niceness).
CHILD_NICENESS = 10
#: ``progress(stage, done, total)``: "contacts" (frames searched, then paired), then the pipeline's stages.
Progress = Callable[[str, int, int], None]


class Stopped(SolverError):
    """The run was asked to stop (its frames solved so far are kept in its folder)."""


@dataclass(frozen=True)
class RetargetJob:
    """Everything a retarget of a scene's motion needs besides the motion, all plain data.

    Attributes
    ----------
    names : (str, str, str)
        The source hand's, the object's and the target hand's names, for messages and file names.
    frames : tuple of int
        The scene frame of each motion frame.
    hand : SkinnedMesh
        The target hand, in its own space.
    to_hand_space : (4, 4)
        The motion's space to the target hand's: a rotation, a translation and a uniform scale.
    annotation : HandPairAnnotation or None
        None: both hands are procedural ones (:func:`.annotate.procedural_hand`), whose annotation is
        built once the motion is known.
    options : RetargetOptions
    contacts : bool
        Find the motion's contacts (else it is retargeted from its markers only).
    folder : Path
        Below it, a folder per run (:func:`run_folder`).
    identity : str
        What else makes the target's solves differ (e.g. the pose its controls were read at).
    """

    names: tuple[str, str, str]
    frames: tuple[int, ...]
    hand: SkinnedMesh
    to_hand_space: np.ndarray
    annotation: HandPairAnnotation | None
    options: RetargetOptions
    contacts: bool
    folder: Path
    identity: str = ""


@dataclass(frozen=True, eq=False)
class JobOutcome:
    """A finished run: the result, its folder and files, and the scale back to the motion's units."""

    result: Retarget
    folder: Path
    paths: dict
    scale: float

    def summary(self) -> str:
        """One line: frames, contact distances (in the motion's units, as mm) and the warnings."""
        r, mm = self.result, self.scale * 1e3
        contact = r.contact_distance[np.isfinite(r.contact_distance)]
        estimate = r.estimate_contact_distance[np.isfinite(r.estimate_contact_distance)]
        text = f"Retargeted {len(r.theta)} frames"
        if contact.size:
            text += (
                f"; contacts {np.median(contact) * mm:.2f} mm from the object (median; the frames' own "
                f"solves {np.median(estimate) * mm:.2f} mm)"
            )
        if r.warnings:
            text += "; " + " ".join(r.warnings)
        return text


def run_job(
    job: RetargetJob, motion: Motion, *, workers: int | None = None, progress: Progress | None = None
) -> JobOutcome:
    """Run the job on ``motion`` (the scene's, in its space, without contacts); see the module docstring.
    ``workers`` as :func:`.pipeline.retarget` takes them.

    Raises
    ------
    SolverError
        For a hand that never touches the object, an annotation that does not fit the hands, failed
        solves, or :class:`Stopped` from ``progress``.
    """
    report = progress or (lambda _stage, _done, _total: None)
    if job.contacts:
        motion = with_contacts(
            motion, job.names[:2], job.frames, progress=lambda d, t: report("contacts", d, t)
        )
    moved, scale = in_space(motion, job.to_hand_space)
    annotation = job.annotation
    if annotation is None:
        source, target = procedural_hand(moved.hand_mesh), procedural_hand(job.hand.mesh)
        if source is None or target is None:
            raise SolverError(
                f"'{job.names[0] if source is None else job.names[2]}' is not a procedural hand: give an "
                "annotation made for these two hands"
            )
        annotation = default_annotation(source, target)
    folder = run_folder(job, moved, annotation)
    with main_script_hidden():
        result = retarget(
            moved, job.hand, annotation, job.options, folder=folder / "frames", workers=workers,
            progress=report,
        )  # fmt: skip
    title = f"{job.names[0]} onto {job.names[2]}, frames {job.frames[0]}-{job.frames[-1]}"
    plot = importlib.util.find_spec("matplotlib") is not None
    paths = save_result(result, folder, annotation, plot=plot, title=title)
    return JobOutcome(result, folder, paths, scale)


def in_space(motion: Motion, M: np.ndarray) -> tuple[Motion, float]:
    """The motion carried by ``M`` (4, 4): a rotation, a translation and a uniform scale s; the object's
    poses stay rigid, its rest mesh and the hand's are scaled by s. Returns the motion and 1 / s, which
    turns its lengths back into the original units."""
    A = np.asarray(M, dtype=np.float64)
    s = float(np.cbrt(np.linalg.det(A[:3, :3])))
    poses = motion.object_poses.copy()
    poses[:, :3, :3] = (A[:3, :3] / s) @ motion.object_poses[:, :3, :3]
    poses[:, :3, 3] = motion.object_poses[:, :3, 3] @ A[:3, :3].T + A[:3, 3]
    moved = replace(
        motion,
        object_mesh=TriMesh(motion.object_mesh.vertices * s, motion.object_mesh.faces),
        object_poses=poses,
        hand_mesh=TriMesh(motion.hand_mesh.vertices * s, motion.hand_mesh.faces),
        hand_vertices=motion.hand_vertices @ A[:3, :3].T + A[:3, 3],
    )
    return moved, 1.0 / s


def run_folder(job: RetargetJob, motion: Motion, annotation: HandPairAnnotation) -> Path:
    """The folder of one run below ``job.folder``: named after the target hand and a digest of everything
    the frames' solves depend on (the motion, the target's rest mesh, ``job.identity``, the annotation,
    the options), so that the same inputs go on where a run stopped and other inputs start afresh."""
    digest = hashlib.blake2b(digest_size=8)
    for array in (*motion.to_arrays().values(), job.hand.mesh.vertices):
        array = np.ascontiguousarray(array)
        digest.update(str(array.shape).encode() + array.tobytes())
    described = {"identity": job.identity, "annotation": annotation.to_dict(), "options": asdict(job.options)}
    digest.update(json.dumps(described, sort_keys=True, default=str).encode())
    name = "".join(c if c.isalnum() or c in "-_." else "_" for c in job.names[2])
    return Path(job.folder) / f"{name}-{digest.hexdigest()}"


@contextlib.contextmanager
def main_script_hidden():
    """Child processes started by spawn first run the parent's main script again, unless it has no file.
    In Blender that is the script Blender was started with (``--python``), which imports bpy, which a
    child (a plain Python) lacks; a user's script may not guard its work with ``__main__``. The children
    need nothing of it, so while they start, it has no file."""
    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    if path is None:
        yield
        return
    del main.__file__
    try:
        yield
    finally:
        main.__file__ = path


class ChildRun:
    """:func:`run_job` in a child process: :meth:`poll` reads its progress, :meth:`stop` asks it to stop
    (it stops at the next frame, keeping the frames solved), :meth:`outcome` returns what it made.

    Parameters are :func:`run_job`'s.
    """

    def __init__(self, job: RetargetJob, motion: Motion, workers: int | None = None):
        context = multiprocessing.get_context("spawn")
        self._messages = context.Queue()
        self._stop = context.Event()
        self._process = context.Process(
            target=_child,
            args=(job, motion, workers, self._messages, self._stop),
            name="contact-edit retarget",
        )
        self.progress: tuple[str, int, int] = ("contacts", 0, 2 * len(job.frames))
        self._last: tuple | None = None  # the child's last message
        self._end: tuple | None = None  # the same once the child has exited, or why it ended
        # Starting waits until the child, a new Python, has imported what the job needs and read it
        # (a second or more): a thread waits for that, so that the caller's own thread goes on.
        self._starting = threading.Thread(target=self._start, name="contact-edit retarget start", daemon=True)
        self._starting.start()

    def _start(self) -> None:
        try:
            with main_script_hidden():
                self._process.start()
        except Exception as err:  # read by poll
            self._end = ("error", f"the retarget's process could not start: {type(err).__name__}: {err}")

    @property
    def done(self) -> bool:
        """Whether the child has ended (after :meth:`poll` read its last message and saw it exit)."""
        return self._end is not None

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def poll(self) -> tuple[str, int, int]:
        """Read the child's messages so far (never waits); the latest progress ``(stage, done, total)``."""
        while self._last is None and not self._starting.is_alive():
            try:
                message = self._messages.get_nowait()
            except queues.Empty:
                if not self._process.is_alive() and self._messages.empty():
                    code = self._process.exitcode
                    self._end = ("error", f"the retarget's process ended unexpectedly (exit code {code})")
                break
            if message[0] == "progress":
                self.progress = message[1:]
            else:
                self._last = message
        # Done once the child has exited too (its interpreter takes a tenth of a second to shut down),
        # so that outcome() does not wait for it.
        if self._end is None and self._last is not None and not self._process.is_alive():
            self._end = self._last
        return self.progress

    def stop(self, wait: float | None = None) -> None:
        """Ask the child to stop; with ``wait`` (seconds), wait that long for it, then end it outright."""
        self._stop.set()
        if wait is not None:
            self._starting.join()
        if wait is not None and self._process.pid is not None:
            self._process.join(wait)
            if self._process.is_alive():
                self._process.terminate()
                self._process.join()

    def outcome(self) -> JobOutcome:
        """What the child made, once :attr:`done`; raises :class:`Stopped` or a SolverError with the
        child's message."""
        if self._end is None:
            raise SolverError("the retarget is still running")
        if self._process.pid is not None:
            self._process.join()
        kind, value = self._end
        if kind == "done":
            return value
        if kind == "stopped":
            raise Stopped(value)
        raise SolverError(value)


def _child(job, motion, workers, messages, stop) -> None:
    """The child process: run the job, sending progress and then ("done", outcome), ("stopped", message)
    or ("error", message). It stops when asked to, or when its parent is gone."""
    parent = os.getppid()
    _yield_to_parent()

    def progress(stage, done, total):
        if stop.is_set() or os.getppid() != parent:
            raise Stopped("stopped; the frames solved so far are kept")
        messages.put(("progress", stage, done, total))

    try:
        messages.put(("done", run_job(job, motion, workers=workers, progress=progress)))
    except Stopped as err:
        messages.put(("stopped", str(err)))
    except Exception as err:  # sent as words: the parent reports it
        messages.put(("error", f"{err}" if isinstance(err, SolverError) else f"{type(err).__name__}: {err}"))


def _yield_to_parent() -> None:
    """Lower this process's priority, and so its worker processes' (they inherit it), below the parent's:
    with as many busy processes as cores, the parent (Blender drawing its window) would otherwise get a
    share of a core and stall."""
    if hasattr(os, "nice"):
        os.nice(CHILD_NICENESS)
    elif sys.platform == "win32":
        import ctypes

        kernel32 = ctypes.windll.kernel32
        kernel32.SetPriorityClass(kernel32.GetCurrentProcess(), 0x4000)  # BELOW_NORMAL_PRIORITY_CLASS
