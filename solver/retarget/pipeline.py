"""The whole retarget of a motion onto another hand (Kinematic Motion Retargeting §3, Fig. 2).

Stages, each with its own progress (``progress(stage, done, total)``, stages in :data:`STAGES`):

1. ``transfer`` — the motion's hand contacts move to the target hand through the annotated contact
   atlas, all frames in one call (§3.3.2, :func:`.transfer.transfer_motion`).
2. ``root`` and ``full`` — every frame solved on its own (§3.4.2): the root alone, then the full pose
   seeded by it (:mod:`.frames`).
3. ``refine`` — acceleration violations replaced by interpolation and re-solved (§3.4.3,
   :func:`.refine.refine_trajectory`), until none is left, rounds stop helping, or the paper's cap; one
   progress bar over all its rounds, its total an estimate (:func:`.refine.remaining_work`).
4. ``spline`` — a cubic B-spline per DOF with a fixed number of control points (§3.4.4,
   :func:`.spline.fit_bspline`), evaluated at every frame: the result. The count is the paper's, about
   :data:`CONTROL_PER_SECOND` per second, where that fits: when the fitted curves put the contacts
   (markers, without contacts) more than :data:`FIT_BAR` times as far from their targets as the
   per-frame estimate does, in median, the count grows by half until they fit or it reaches the frame
   count. A short, fast motion needs more than its length gives (a whole manipulation in 60 frames:
   six control points cannot follow its grasp). A result that still misses is returned with a warning
   saying why (:attr:`Retarget.warnings`), never silently.
5. ``baselines`` (when asked for) — the §4.6 baselines on the same inputs, each given our root pass as
   its root and the same per-frame solves, refinement and spline (:mod:`.baselines`); all three methods'
   final curves measured alike into Table 1.
6. ``metrics`` — per-frame mean marker and contact distances and intersection volumes (§4.2).

Every per-frame solve (root, full, the baselines', the refinements' re-solves) and every frame's
intersection measure is a task run by :func:`.executor.run_frames`: in worker processes on this machine,
or on a Dask cluster given its scheduler's address, with each frame's result written to a folder as it
finishes.
Running the same retarget into the same folder again resumes: solved frames are read back, not solved
again (the refinement's re-solves are deterministic, so they are found again too).
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field, fields, replace
from functools import cached_property
from pathlib import Path
from typing import NamedTuple

import numpy as np

from geodesics.files import write_atomically

from ..errors import SolverError, check_count
from ..rig import Rig, SkinnedMesh
from .annotations import HandPairAnnotation
from .baselines import Table, keypoint_tasks, keyvector_tasks, reseeded, solve_task
from .executor import FrameStore, check_workers, run_frames
from .frames import (
    HandSpec,
    RetargetWeights,
    build_tasks,
    full_tasks,
    object_contact_geometry,
)
from .interchange import save_kmexp
from .metrics import IntersectionMeter, Intersections, mean_distances
from .motion import Motion
from .refine import E_ACC, MAX_ITERATIONS, MIN_PROGRESS, RefineLog, refine_trajectory, remaining_work
from .spline import DEGREE, SplineFit, fit_bspline
from .transfer import TransferredContacts, transfer_motion

#: The stages a retarget reports progress for, in order.
STAGES = ("transfer", "root", "full", "refine", "spline", "baselines", "metrics")
#: The §4.6 baselines ``RetargetOptions.baselines`` runs, by their Table 1 names, and how their tasks are
#: made from ours (:mod:`.baselines`).
BASELINES = {"Keypoint": keypoint_tasks, "Keyvector": keyvector_tasks}
#: Default spline control points per second of motion (the paper's Table 4: 60-120 points for 6-13 s
#: motions at 120 fps, 9-12 per second).
CONTROL_PER_SECOND = 10.0
#: The final curves may leave the contacts (or markers) this many times as far from their targets as the
#: per-frame estimate does, in median, before the spline gets more control points (or, at the most, a
#: warning).
FIT_BAR = 1.5
#: Each try at fitting grows the control point count by this factor.
CONTROL_GROWTH = 1.5

Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class RetargetOptions:
    """How a retarget runs. The defaults are the paper's method.

    Attributes
    ----------
    weights : RetargetWeights
        λ of Eq. 3 (``weights.c = 0`` is the no-contact ablation of §4.7).
    root_pass : bool
        Solve each frame's root first (§3.4.2); False is the §4.7 ablation: the full pose is solved from
        the rest pose directly.
    refine : bool
        Run the refinement (§3.4.3).
    e_acc : float
        Acceleration threshold of the refinement, rad/s² (translations in hand lengths/s²).
    max_refine_iterations : int
    min_refine_progress : float
        The refinement ends when rounds stop removing this fraction of the excess acceleration
        (:func:`.refine.refine_trajectory`; 0: only the cap ends it, as in the paper).
    n_control : int or None
        Spline control points per DOF (default: :data:`CONTROL_PER_SECOND` per second, at least 4, more
        where that does not fit; see the module docstring). A given count is used as it is.
    use_table : bool
        Keep the hand out of the motion's table (Eq. 6).
    intersections : bool
        Measure intersection volumes.
    baselines : bool
        Also run the §4.6 baselines (:data:`BASELINES`) and compare the three methods (Table 1).
    """

    weights: RetargetWeights = field(default_factory=RetargetWeights)
    root_pass: bool = True
    refine: bool = True
    e_acc: float = E_ACC
    max_refine_iterations: int = MAX_ITERATIONS
    min_refine_progress: float = MIN_PROGRESS
    n_control: int | None = None
    use_table: bool = True
    intersections: bool = True
    baselines: bool = False

    def __post_init__(self):
        # Checked here, not when the spline stage comes to it after every frame's solves.
        if self.n_control is not None:
            note = " (a cubic spline's degree + 1) or None for the default"
            check_count(self.n_control, "n_control", DEGREE + 1, note)


@dataclass(frozen=True, eq=False)
class Retarget:
    """A retargeted motion and everything measured on the way.

    Attributes
    ----------
    motion : Motion
        The target hand's motion: its vertices posed by the final DOF curves, the same object poses and
        table, the transferred contacts (paired row for row with the object's), ``source_theta`` = the
        final DOF curves. It can be retargeted again (e.g. back to the source hand, §4.5).
    theta : (F, d)
        The final DOF curves (the spline evaluated at every frame).
    estimate, refined : (F, d)
        The per-frame estimate (§3.4.2) and the refined samples (§3.4.3).
    valid : (F, d) bool
        Samples the refinement kept (the spline ignores the others).
    spline : SplineFit
    refine_log : RefineLog or None
    marker_distance, contact_distance : (F,)
        Per-frame mean distances of the final motion in metres (NaN: no markers or contacts that frame).
    estimate_contact_distance : (F,)
        The same for the per-frame estimate.
    intersections : Intersections or None
    transferred : TransferredContacts
    baselines : dict[str, ndarray]
        The final DOF curves (F, d) of each baseline that ran, by its Table 1 name.
    table : baselines.Table or None
        Table 1 (with ``baselines``): marker and contact distances of every method's final curves.
    seconds : dict
        Wall-clock seconds of each stage.
    iterations : dict
        Objective evaluations of the root, full and refine solves.
    estimate_marker_distance : (F,)
        The per-frame estimate's mean marker distances.
    default_control : int
        The paper's control point count for this motion (``len(spline.control)`` may be more).
    warnings : tuple of str
        What is wrong with the result, in words (e.g. contacts the final curves leave much farther off
        than the frames reached, and why).
    """

    motion: Motion
    theta: np.ndarray
    estimate: np.ndarray
    refined: np.ndarray
    valid: np.ndarray
    spline: SplineFit
    refine_log: RefineLog | None
    marker_distance: np.ndarray
    contact_distance: np.ndarray
    estimate_contact_distance: np.ndarray
    intersections: Intersections | None
    transferred: TransferredContacts
    baselines: dict
    table: Table | None
    seconds: dict
    iterations: dict
    estimate_marker_distance: np.ndarray = field(default_factory=lambda: np.empty(0))
    default_control: int = 0
    warnings: tuple[str, ...] = ()

    def summary(self) -> dict:
        """Figures of the result (JSON-serializable): distances in millimetres, seconds per stage."""
        contact = np.isfinite(self.contact_distance)

        def mm(a):
            return float(np.nanmedian(a) * 1e3) if np.isfinite(a).any() else None

        out = {
            "frames": len(self.theta),
            "contact_frames": int(contact.sum()),
            "median_contact_distance_mm": mm(self.contact_distance),
            "median_marker_distance_mm": mm(self.marker_distance),
            "median_estimate_contact_distance_mm": mm(self.estimate_contact_distance),
            "median_estimate_marker_distance_mm": mm(self.estimate_marker_distance),
            "spline_control_points": len(self.spline.control),
            "spline_default_control_points": self.default_control,
            "refinement": refinement_outcome(self.refine_log),
            "refine_rounds": 0 if self.refine_log is None else self.refine_log.iterations,
            "masked_samples": int((~self.valid).sum()),
            "seconds": {k: round(v, 3) for k, v in self.seconds.items()},
            "iterations": dict(self.iterations),
        }
        if self.intersections is not None:
            for name in ("hand_object", "self_intersection", "table"):
                out[f"max_{name}_percent"] = float(np.max(getattr(self.intersections, name)))
        if self.table is not None:
            out["table1"] = self.table.to_dict()
        out["warnings"] = list(self.warnings)
        return out


def refinement_outcome(log: RefineLog | None) -> str:
    """How the refinement ended, in words (the summary's ``refinement``)."""
    if log is None:
        return "skipped"
    if log.converged:
        return f"converged in {log.iterations} rounds"
    if log.cancelled:
        return f"cancelled after {log.iterations} rounds"
    why = "rounds stopped helping" if log.stalled else "reached the cap"
    return f"{why} after {log.iterations} rounds, {log.violations[-1]} samples still beyond the threshold"


def _solve(hand, task) -> dict:
    """One frame's solve (ours or a baseline's) for :func:`.executor.run_frames`: the target hand travels
    once per worker."""
    r = solve_task(replace(task, hand=hand))
    return {
        "theta": r.theta,
        "energy": r.energy,
        "iterations": r.iterations,
        "seconds": r.seconds,
        "contact_distance": r.contact_distance,
        "marker_distance": r.marker_distance,
    }


def _measure(meter: IntersectionMeter, task) -> dict:
    """One frame's intersection volumes for :func:`.executor.run_frames`: the meter travels once per
    worker; ``task`` is the frame's posed hand vertices and object pose."""
    vertices, pose = task
    r = meter.frame(vertices, pose)
    return {f.name: getattr(r, f.name) for f in fields(Intersections)}


def _digest(*arrays) -> str:
    h = hashlib.blake2b(digest_size=10)
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str(a.shape).encode() + a.tobytes())
    return h.hexdigest()


def _motion_digest(motion: Motion) -> str:
    return _digest(*(motion.to_arrays().values()))


def retarget(
    motion: Motion,
    hand: HandSpec | SkinnedMesh,
    annotation: HandPairAnnotation,
    options: RetargetOptions | None = None,
    *,
    folder=None,
    workers: int | None = None,
    scheduler: str | None = None,
    contacts: TransferredContacts | None = None,
    progress: Progress | None = None,
) -> Retarget:
    """Retarget a motion onto another hand (§3): transfer, per-frame solves, refinement, spline, metrics.

    Parameters
    ----------
    motion : Motion
        The source motion, with paired ``hand_contacts`` and ``object_contacts`` (pair them first with
        :func:`.pairing.pair_motion` when only one side is known), or none for markers only.
    hand : HandSpec or SkinnedMesh
        The target hand (a HandSpec is rebuilt in each worker; a SkinnedMesh is sent to each once).
    annotation : HandPairAnnotation
        For this source and target hand (checked against both meshes).
    options : RetargetOptions, optional
    folder : path-like, optional
        Where per-frame results go as they finish (``folder/root``, ``folder/full``,
        ``folder/refine-NN``, ``folder/metrics-<digest of the final curves>``); an interrupted retarget
        into the same folder resumes. Default: a temporary folder, removed afterwards.
    workers : int, optional
        Worker processes, at least 1 (default: one per CPU; 1 solves in this process).
    scheduler : str, optional
        A Dask distributed scheduler's address to send the frames to instead.
    contacts : TransferredContacts, optional
        Target-hand contacts to use instead of transferring the motion's (e.g. the original contacts in
        a cyclic retarget, §4.5).
    progress : callable, optional
        ``progress(stage, done, total)``.

    Raises
    ------
    SolverError
        For mismatched inputs, a folder holding another run's results, or failed solves.
    """
    options = options or RetargetOptions()
    check_workers(workers)
    target = hand.build() if isinstance(hand, HandSpec) else hand
    if not isinstance(target, SkinnedMesh):
        raise SolverError(f"hand must be a HandSpec or a SkinnedMesh, got {type(hand).__name__}")
    annotation.check(motion.hand_mesh, target.mesh)
    with contextlib.ExitStack() as temporary:
        if folder is None:
            folder = temporary.enter_context(tempfile.TemporaryDirectory(prefix="retarget-"))
        return _retarget(motion, hand, target, annotation, options, Path(folder), workers=workers,
                         scheduler=scheduler, contacts=contacts, progress=progress)  # fmt: skip
    return _retarget(motion, hand, target, annotation, options, Path(folder), workers=workers,
                     scheduler=scheduler, contacts=contacts, progress=progress)  # fmt: skip


def _retarget(motion, hand, target, annotation, options, folder, *, workers, scheduler, contacts, progress):
    """:func:`retarget`'s stages in order (``target``: ``hand`` built), each timed into the result."""
    seconds, iterations = {}, {}
    report = progress or _silent
    with _timed(seconds, "transfer"):
        contacts = _transferred(motion, annotation, target, contacts, report)
    run = _Run(motion, hand, target, annotation, contacts, options, folder, workers, scheduler, report)
    built = build_tasks(
        motion,
        hand,
        annotation,
        options.weights,
        hand_contacts=None if contacts is None else contacts.hand_contacts,
        object_contacts=None if contacts is None else contacts.object_contacts,
        use_table=options.use_table,
    )
    tasks = [replace(t, hand=None) for t in built]  # the hand goes to each worker once, not per frame

    with _timed(seconds, "root"):
        roots, full_stage, iterations["root"] = run.roots(tasks)
    with _timed(seconds, "full"):
        fulls = run.solve("full", "full", {t.frame: t for t in full_stage})
        estimate = _thetas(fulls, range(run.frames))
        estimate_contact, estimate_marker = (
            np.array([fulls[f][key] for f in range(run.frames)], dtype=np.float64)
            for key in ("contact_distance", "marker_distance")
        )
        iterations["full"] = _evaluations(fulls)
    with _timed(seconds, "refine"):
        refined, valid, log, iterations["refine"] = run.refine(
            "refine", "refine", estimate, {t.frame: t for t in full_stage}
        )
    with _timed(seconds, "spline"):
        fitted = run.spline(refined, valid, log, (estimate_contact, estimate_marker))

    baselines, table = {}, None
    if options.baselines:
        with _timed(seconds, "baselines"):
            given = _thetas(roots, range(run.frames)) if options.root_pass else estimate
            baselines, evaluations = run.baselines(built, given, len(fitted.spline.control))
            iterations |= evaluations
    with _timed(seconds, "metrics"):
        vertices = np.stack([target.posed_vertices(t) for t in fitted.theta])
        if options.baselines:
            rows = {m: run.distances(c) for m, c in baselines.items()}
            table = Table.from_distances({**rows, "Ours": (fitted.contact, fitted.marker)})
        intersections = run.intersections(fitted.theta, vertices) if options.intersections else None
        report("metrics", 1, 1)

    result_motion = replace(
        motion,
        hand_mesh=target.mesh,
        hand_vertices=vertices,
        hand_contacts=None if contacts is None else contacts.hand_contacts,
        object_contacts=None if contacts is None else contacts.object_contacts,
        source_kind=hand.kind if isinstance(hand, HandSpec) else None,
        source_scale=float(hand.scale) if isinstance(hand, HandSpec) else 1.0,
        source_theta=fitted.theta,
    )
    return Retarget(
        result_motion, fitted.theta, estimate, refined, fitted.valid, fitted.spline, log, fitted.marker,
        fitted.contact, estimate_contact, intersections, contacts, baselines, table, seconds, iterations,
        estimate_marker, run.default_control, fitted.warnings,
    )  # fmt: skip


def _silent(_stage: str, _done: int, _total: int) -> None:
    """The progress callback when none is given."""


@contextlib.contextmanager
def _timed(seconds: dict, stage: str) -> Iterator[None]:
    """Add the wall-clock seconds of the block to ``seconds[stage]``."""
    clock = time.perf_counter()
    try:
        yield
    finally:
        seconds[stage] = time.perf_counter() - clock


def _transferred(motion, annotation, target, contacts, report) -> TransferredContacts | None:
    """Stage 1: the given target-hand contacts, else the motion's transferred (None without contacts)."""
    if contacts is None and motion.hand_contacts is not None:
        contacts = transfer_motion(
            motion, annotation, target.mesh, progress=lambda d, t: report("transfer", d, t)
        )
    report("transfer", 1, 1)
    if contacts is not None and contacts.hand_contacts.n_frames != motion.n_frames:
        raise SolverError(
            f"the contacts have {contacts.hand_contacts.n_frames} frames, the motion {motion.n_frames}"
        )
    return contacts


def _thetas(results: dict[int, dict], frames) -> np.ndarray:
    """(len(frames), d) the solved DOF vectors of ``frames``."""
    return np.stack([results[int(f)]["theta"] for f in frames])


def _evaluations(results: dict[int, dict]) -> int:
    """Objective evaluations of a stage's solves, summed."""
    return int(sum(r["iterations"] for r in results.values()))


@dataclass(frozen=True, eq=False)
class _Run:
    """One retarget's inputs and its folder: what the stages after the transfer share.

    ``hand`` is as the caller gave it (a HandSpec is rebuilt in each worker), ``target`` the hand built;
    ``report`` is ``progress(stage, done, total)``.
    """

    motion: Motion
    hand: HandSpec | SkinnedMesh
    target: SkinnedMesh
    annotation: HandPairAnnotation
    contacts: TransferredContacts | None
    options: RetargetOptions
    folder: Path
    workers: int | None
    scheduler: str | None
    report: Progress

    @property
    def frames(self) -> int:
        return self.motion.n_frames

    @cached_property
    def identity(self) -> dict:
        """What changes the per-frame solves (not the spline or the metrics, which are recomputed): a
        folder holding frames of another identity is refused (:class:`.executor.FrameStore`)."""
        hand, target, contacts, options = self.hand, self.target, self.contacts, self.options
        return {
            "motion": _motion_digest(self.motion),
            "hand": hand.__dict__
            if isinstance(hand, HandSpec)
            else _digest(target.mesh.vertices, target.mesh.faces),
            "annotation": hashlib.blake2b(
                json.dumps(self.annotation.to_dict(), sort_keys=True).encode()
            ).hexdigest(),
            "contacts": None
            if contacts is None
            else _digest(contacts.hand_contacts.faces, contacts.hand_contacts.bary),
            "weights": asdict(options.weights),
            "root_pass": options.root_pass,
            "use_table": options.use_table,
        }

    @cached_property
    def default_control(self) -> int:
        """The paper's spline control point count for this motion: :data:`CONTROL_PER_SECOND` per second,
        at least 4, at most one per frame."""
        F = self.frames
        return min(F, max(4, round(CONTROL_PER_SECOND * (F - 1) / self.motion.fps) + 1))

    def solve(self, stage: str, label: str, tasks: dict, refining: bool = False, shift=(0, 0.0)) -> dict:
        """A stage's frames solved into ``folder/<stage>``, by frame. ``label`` is the progress bar;
        ``shift``: frames this bar counted before, and expects after."""
        extra = (
            {
                "e_acc": self.options.e_acc,
                "max_refine_iterations": self.options.max_refine_iterations,
                "min_refine_progress": self.options.min_refine_progress,
            }
            if refining
            else {}
        )
        store = FrameStore(self.folder / stage, self.identity | extra | {"stage": stage})
        before, after = shift
        return run_frames(
            _solve, self.hand if isinstance(self.hand, HandSpec) else self.target, tasks, store,
            workers=self.workers, scheduler=self.scheduler,
            progress=lambda d, t: self.report(label, before + d, round(before + t + after)),
        )  # fmt: skip

    def roots(self, tasks: list) -> tuple[dict, list, int]:
        """Stage 2a: the root pass (§3.4.2) when asked for: (root results by frame, the full solves'
        tasks seeded by them, objective evaluations)."""
        if not self.options.root_pass:
            self.report("root", 1, 1)
            return {}, [replace(t, stage="full", align_root=False) for t in tasks], 0
        roots = self.solve("root", "root", {t.frame: t for t in tasks})
        seeds = [_AsResult(f, r["theta"]) for f, r in roots.items()]
        return roots, full_tasks(tasks, seeds), _evaluations(roots)

    def refine(self, name: str, label: str, estimate: np.ndarray, by_frame: dict):
        """§3.4.3 on a per-frame estimate (F, d), re-solving ``by_frame``'s tasks into
        ``folder/<name>-NN``: (refined, valid, log, objective evaluations)."""
        options = self.options
        if not (options.refine and self.frames >= 3):
            return estimate.copy(), np.isfinite(estimate), None, 0
        sizes, count = [], [0]  # frames of each re-solve; objective evaluations

        def resolve(frames, seeds):
            sizes.append(len(frames))
            redo = {int(f): reseeded(by_frame[int(f)], s) for f, s in zip(frames, seeds, strict=True)}
            later = remaining_work(sizes, options.max_refine_iterations + 1 - len(sizes))
            shift = (sum(sizes[:-1]), later)
            results = self.solve(f"{name}-{len(sizes):02d}", label, redo, refining=True, shift=shift)
            count[0] += _evaluations(results)
            return _thetas(results, frames)

        r = refine_trajectory(
            estimate, self.motion.fps, self.target.rig.is_rotation, resolve, length=self.target.length,
            e_acc=options.e_acc, max_iterations=options.max_refine_iterations,
            min_progress=options.min_refine_progress,
        )  # fmt: skip
        done = sum(sizes) or 1
        self.report(label, done, done)
        return r.theta, r.valid, r.log, count[0]

    def fit(self, refined: np.ndarray, valid: np.ndarray, n: int) -> tuple[SplineFit, np.ndarray]:
        """§3.4.4: the spline of ``n`` control points (at most one per frame), and its curves (F, d)
        brought into the rig's bounds (unwrapped angles past the limits wrap back, not clip)."""
        spline = fit_bspline(refined, min(n, self.frames), valid=valid, fps=self.motion.fps)
        return spline, self.target.rig.clip(spline.values)

    def spline(self, refined: np.ndarray, valid: np.ndarray, log: RefineLog | None, estimate) -> _Fitted:
        """Stage 4: the first fit, of the paper's count and more (:func:`_control_counts`), whose curves
        leave the contacts (or markers) within :data:`FIT_BAR` of the per-frame ``estimate``'s
        (contact, marker) distances; else the best, with warnings saying why."""
        counts = [self.options.n_control] if self.options.n_control is not None else _control_counts(
            self.default_control, self.frames
        )  # fmt: skip
        # Leaving out what refinement could not smooth (§3.4.3) first; if no count fits that way, all
        # samples (a motion faster than the threshold has too few left to bridge the gaps).
        masks = [valid] + ([np.isfinite(refined)] if not valid.all() else [])
        tries = [(mask, n) for mask in masks for n in counts]
        fits = []  # (ratio to the estimate, spline, curves, contact and marker distances) of each try
        for mask, n in tries:
            spline, theta = self.fit(refined, mask, n)
            distances = self.distances(theta)
            fits.append((_fit_ratio(distances, estimate), spline, theta, distances))
            self.report("spline", len(fits), len(tries))
            if fits[-1][0] <= FIT_BAR:
                break
        best = min(range(len(fits)), key=lambda i: fits[i][0])
        ratio, spline, theta, (contact, marker) = fits[best]
        warnings = []
        if best >= len(counts):
            valid = tries[best][0]  # the fit saw every sample
            warnings.append(_unmasked_warning(len(spline.control), log))
        if ratio > FIT_BAR:
            warnings.append(_misfit_warning(ratio, len(spline.control), (contact, marker), valid, log))
        self.report("spline", len(tries), len(tries))
        return _Fitted(spline, theta, valid, contact, marker, tuple(warnings))

    def baselines(self, built: list, given: np.ndarray, n_control: int) -> tuple[dict, dict]:
        """Stage 5, §4.6: each baseline is given ``given`` (F, d) as its "ground-truth" root (our root
        pass, or the full estimate's root without one), solves every frame on its own and is refined and
        fitted like ours, with our control point count. (Final curves by method, objective evaluations
        by method.)"""
        curves, evaluations = {}, {}
        for method, make in BASELINES.items():
            name = method.lower()
            by_frame = {t.frame: replace(t, hand=None) for t in make(built, self.annotation, given)}
            solved = self.solve(name, "baselines", by_frame)
            refined, valid, _, resolved = self.refine(
                f"{name}-refine", "baselines", _thetas(solved, range(self.frames)), by_frame
            )
            evaluations[name] = _evaluations(solved) + resolved
            curves[method] = self.fit(refined, valid, n_control)[1]
        self.report("baselines", 1, 1)
        return curves, evaluations

    def intersections(self, theta: np.ndarray, vertices: np.ndarray) -> Intersections:
        """Stage 6: the intersection volumes of the hand posed by the curves θ (F, d) as ``vertices``
        (F, V, 3), frames measured in parallel like the solves. The folder is named by the curves, so a
        rerun with other curves (e.g. another control point count) measures them anew."""
        motion, F = self.motion, self.frames
        meter = IntersectionMeter(self.target.mesh, motion.object_mesh, motion.table, motion.table_size)
        poses = motion.object_poses
        store = FrameStore(self.folder / f"metrics-{_digest(theta)}", self.identity | {"stage": "metrics"})
        measured = run_frames(
            _measure, meter, {f: (vertices[f], None if poses is None else poses[f]) for f in range(F)},
            store, workers=self.workers, scheduler=self.scheduler,
            progress=lambda d, t: self.report("metrics", d, t),
        )  # fmt: skip
        columns = (np.array([measured[f][k.name] for f in range(F)]) for k in fields(Intersections))
        return Intersections(*(c.astype(np.float64) for c in columns))

    def distances(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-frame mean contact and marker distances (F,) of the target hand posed by θ (F, d), in the
        order of :func:`.baselines.frame_distances` (NaN: none that frame)."""
        motion, target, F = self.motion, self.target, self.frames
        marker = np.full(F, np.nan)
        if self.annotation.markers:
            pairs = self.annotation.marker_pairs()
            goal = pairs.targets(motion.hand_mesh, motion.hand_vertices)
            posed = np.stack([target.posed_points(t, pairs.target)[0] for t in theta])
            p = len(pairs.target)
            marker = mean_distances(posed.reshape(-1, 3), goal.reshape(-1, 3), np.arange(F + 1) * p)
        contact = np.full(F, np.nan)
        if self.contacts is not None:
            hand_c, obj_c = self.contacts.hand_contacts, self.contacts.object_contacts
            offsets = np.asarray(hand_c.offsets)
            P = np.concatenate([target.posed_points(theta[f], hand_c.frame(f))[0] for f in range(F)])
            contact = mean_distances(P, object_contact_geometry(motion, obj_c)[0], offsets)
        return contact, marker


class _Fitted(NamedTuple):
    """The spline stage's outcome: the fit, its curves (F, d), the samples it saw (F, d), the contact and
    marker distances (F,) of its curves, and what is wrong with it in words."""

    spline: SplineFit
    theta: np.ndarray
    valid: np.ndarray
    contact: np.ndarray
    marker: np.ndarray
    warnings: tuple[str, ...]


def _control_counts(first: int, frames: int) -> list[int]:
    """The spline control point counts to try: the paper's, then half as many more each time, up to one
    per frame."""
    counts = [min(first, frames)]
    while counts[-1] < frames:
        counts.append(min(frames, int(np.ceil(counts[-1] * CONTROL_GROWTH))))
    return counts


def _fit_ratio(final, estimate) -> float:
    """How many times as far from their targets the final curves leave the contacts as the per-frame
    estimate does, in median (the markers when there are no contacts; 1 when there is neither)."""
    for got, reached in zip(final, estimate, strict=True):
        if np.isfinite(got).any() and np.isfinite(reached).any():
            return float(np.nanmedian(got) / max(np.nanmedian(reached), 1e-12))
    return 1.0


def _unmasked_warning(n: int, log: RefineLog | None) -> str:
    """What fitting every sample, the unsmoothed ones too, means, in words."""
    return (
        f"refinement ({refinement_outcome(log)}) left too many samples to bridge, so the spline of {n} "
        "control points follows every frame's solve and keeps their jitter; a motion this fast needs "
        "more frames per second"
    )


def _misfit_warning(ratio: float, n: int, final, valid: np.ndarray, log: RefineLog | None) -> str:
    """Why the final curves leave the contacts far off, in words."""
    what, got = ("contacts", final[0]) if np.isfinite(final[0]).any() else ("markers", final[1])
    text = (
        f"the final curves leave the {what} {ratio:.1f} times as far from their targets as the per-frame "
        f"solves did (median {np.nanmedian(got) * 1e3:.1f} mm), even with {n} spline control points"
    )
    masked = int((~valid).sum())
    if masked:
        text += (
            f": the frames' solves disagree from frame to frame, and refinement "
            f"({refinement_outcome(log)}) left {100 * masked / valid.size:.0f}% of the samples out of the "
            "fit, so the spline bridges them"
        )
    return text + (
        "; a motion this fast needs more frames per second (or set the count: RetargetOptions.n_control, "
        "contact-edit retarget --control)"
    )


@dataclass(frozen=True)
class _AsResult:
    """The two fields of a root result that :func:`.frames.full_tasks` reads."""

    frame: int
    theta: np.ndarray


#: The files :func:`save_result` writes into its folder, by the key of the paths it returns (those it
#: writes only in some cases included: a command checks them all before the work).
RESULT_FILES = {
    "motion": "motion.npz",
    "kmexp": "motion.kmexp",
    "curves": "curves.npz",
    "summary": "summary.json",
    "table1": "table1.txt",
    "annotation": "annotation.json",
    "plot": "metrics.png",
}


def save_result(
    result: Retarget,
    folder,
    annotation: HandPairAnnotation | None = None,
    plot: bool = True,
    rig: Rig | None = None,
    title: str | None = None,
):
    """Write a retarget's outputs into ``folder`` (each file atomically) and return their paths.

    ``motion.npz`` (the target hand's motion, :class:`.motion.Motion` format), ``motion.kmexp`` (the
    same for the authors' tools, :mod:`.interchange`; when the target hand's ``rig`` is given and the
    frame rate is a whole number, as that format stores it; frames numbered from the motion's
    ``first_frame``, as the scene it came from numbers them: 0 for a GRAB import), ``curves.npz``
    (the final, estimated and refined DOF curves, the valid mask, the spline's knots and control
    points, the per-frame distances and intersection volumes, each baseline's final curves as
    ``<name>_theta``),
    ``summary.json`` (:meth:`Retarget.summary`), ``table1.txt`` (the baseline comparison, when the
    baselines ran), ``annotation.json`` (the hand pair's annotation, when given) and ``metrics.png`` (the
    §4.2 plots, under ``title``: :func:`.metrics.plot_metrics`'s default when None).
    """
    from .metrics import plot_metrics

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = {key: folder / RESULT_FILES[key] for key in ("motion", "curves", "summary")}
    result.motion.save(paths["motion"])
    if rig is not None and float(result.motion.fps).is_integer():
        paths["kmexp"] = folder / RESULT_FILES["kmexp"]
        m = result.motion
        save_kmexp(
            paths["kmexp"], rig, result.theta, m.object_poses, m.fps, m.table, m.table_size, m.first_frame
        )
    curves = {
        "theta": result.theta,
        "estimate": result.estimate,
        "refined": result.refined,
        "valid": result.valid,
        "knots": result.spline.knots,
        "control": result.spline.control,
        "marker_distance": result.marker_distance,
        "contact_distance": result.contact_distance,
        "estimate_contact_distance": result.estimate_contact_distance,
    }
    if result.intersections is not None:
        for name in ("hand_object", "self_intersection", "table"):
            curves[f"{name}_percent"] = getattr(result.intersections, name)
    for method, theta in result.baselines.items():
        curves[f"{method.lower()}_theta"] = theta
    buffer = io.BytesIO()
    np.savez(buffer, **curves)
    write_atomically(paths["curves"], buffer.getvalue())
    write_atomically(paths["summary"], json.dumps(result.summary(), indent=2))
    if result.table is not None:
        paths["table1"] = folder / RESULT_FILES["table1"]
        note = (
            "Refinement (§3.4.3) was skipped: every method's spline is fitted to its per-frame solves.\n"
            if result.refine_log is None
            else f"Our refinement {refinement_outcome(result.refine_log)}.\n"
        )
        control = f"Splines of {len(result.spline.control)} control points per DOF for every method.\n"
        write_atomically(paths["table1"], result.table.text() + "\n\n" + note + control)
    if annotation is not None:
        paths["annotation"] = folder / RESULT_FILES["annotation"]
        annotation.save(paths["annotation"])
    if plot:
        counts = None if result.transferred is None else result.transferred.hand_contacts.count()
        paths["plot"] = plot_metrics(
            folder / RESULT_FILES["plot"], result.motion.fps, marker_distance=result.marker_distance,
            contact_distance=result.contact_distance, contact_count=counts,
            intersections=result.intersections, title=title,
        )  # fmt: skip
    return paths
