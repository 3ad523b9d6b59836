"""Per-frame pose estimation of the target hand (Kinematic Motion Retargeting §3.4.1–3.4.2).

Every frame is solved on its own, as §3.4.2 insists (no frame seeds another: errors cannot build up
over a long motion, and a bad frame can be pruned later): first the root alone, then the full pose
seeded by that root. Each solve minimizes Eq. 3,

    λm Γ_M + λc Σ_c (λcd Γ_CD,c + λcn Γ_CN,c) + λt Γ_T + λj Γ_J    subject to θ_L <= θ <= θ_U,

with :class:`solver.ContactIK`: target-hand marker points to the source hand's marker positions at the
frame (single, many-to-one or area markers, :mod:`.annotations`), the transferred target-hand contacts
to the object's contact points posed at the frame with opposed normals, the table box's signed distance
at the hand's vertices, and the prior to the rest pose (or a given pose) — analytic gradients, NLopt.

**Weights** (:class:`RetargetWeights`). The paper sets λm = λc = λcd = λcn = λt = 1 and λj = 50
(Appendix B) in Maya units. Our terms are ContactIK's normalized ones (squared distances in units of
``u`` = the hand's size / 25, about a Maya centimetre on a life-size hand; 1 + n·m for normals; squared
penetration depth over ``u`` for the table; squared radians for the prior), and they map one to one:
``Weights(d = λc λcd, n = λc λcn, m = λm, t = λt, p = λj)``. Only λj's default differs: ours is 10,
Contact Edit's λp (ContactIK's default), not 50. The paper's Γ_J is on Maya DOF values (degrees) and its
distances are not squared, so its 50 has no exact counterpart in radians²; there it biases the
recovered finger joints towards rest more than 10 does while changing nothing else
(:meth:`RetargetWeights.paper` gives the paper's numbers for comparison).

**The root pass** solves the root's six DOFs with every term of Eq. 3, but only over the markers and
contacts on the forearm and palm: with the fingers held at rest, finger markers and contacts would drag
the root towards wherever the resting fingers come closest to them (tens of degrees off on grasp
frames). It starts from the frame's own data: the target hand's rest pose moved rigidly onto those palm
markers (a least-squares rigid fit, Kabsch; all markers when the palm has fewer than three points).

**Tasks.** :class:`FrameTask` holds only one frame's data (plain arrays, surface points, small
dataclasses) and :func:`solve_frame` is a plain function, so frames can run in worker processes or on a
Dask cluster; the target hand travels as a :class:`HandSpec` (kind and scale, rebuilt and cached once
per process) unless a :class:`~solver.SkinnedMesh` is given. :func:`build_tasks` makes all root tasks of
a motion, :func:`full_tasks` the full-pose tasks from the root results, :func:`solve_frames` runs a list
of tasks with any ``map``.

**Frames without contacts** (approach, release) are solved on markers alone: ContactIK needs at least
one contact, so one marker point stands in as a contact with zero distance and normal weights (its
terms are then exactly zero).

**The table** term is left out of a frame whose hand, at the seed pose, is farther than a hand length
from the table (it cannot reach it within one solve, and the box distance at every vertex is a large
part of an evaluation's cost); if the solved pose nevertheless penetrates the table, the frame is
solved again with the term.
"""

from __future__ import annotations

import builtins
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np

from geodesics import SurfacePoints
from geodesics.rigid import rigid_fit

from ..errors import SolverError
from ..hands import hand_from_kind
from ..ik import ContactIK, Markers, Weights
from ..rig import SkinnedMesh
from ..sdf import Box

if TYPE_CHECKING:  # pragma: no cover
    from .annotations import HandPairAnnotation
    from .motion import Contacts, Motion

#: The stages of the initial trajectory estimate (§3.4.2).
STAGES = ("root", "full")
#: Objective evaluations per solve at most.
MAX_EVALUATIONS = 1000
#: NLopt algorithm of the per-frame solves: L-BFGS, which from a root estimate (not from rest, as in
#: Contact Edit's single-pose benchmark) reaches SLSQP's energy in fewer evaluations.
ALGORITHM = "lbfgs"
#: Relative energy change at which a frame's solve stops.
FTOL_REL = 1e-7
#: The norm of the marker and contact distances: plain L2 distances, as Eq. 4-5 (see solver.ik.NORMS).
NORM = "l2"


@dataclass(frozen=True)
class RetargetWeights:
    """The weighting hyperparameters of Eq. 3 and Eq. 5, named as in the paper.

    m: markers λm; c: contacts λc, which multiplies cd (contact distance λcd) and cn (opposed normals
    λcn); t: table λt; j: prior λj. See the module docstring for how they map onto
    :class:`solver.Weights` and why λj defaults to 10 rather than the paper's 50.
    """

    m: float = 1.0
    c: float = 1.0
    cd: float = 1.0
    cn: float = 1.0
    t: float = 1.0
    j: float = 10.0

    def __post_init__(self):
        for name in ("m", "c", "cd", "cn", "t", "j"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value >= 0):
                raise SolverError(f"weight λ{name} must be a finite non-negative number, got {value!r}")
            object.__setattr__(self, name, float(value))

    @classmethod
    def paper(cls) -> RetargetWeights:
        """The values of Appendix B: all 1, λj = 50."""
        return cls(j=50.0)

    def solver_weights(self) -> Weights:
        """The :class:`solver.Weights` of these coefficients (no keyed-pose term)."""
        return Weights(d=self.c * self.cd, n=self.c * self.cn, p=self.j, m=self.m, t=self.t, k=0.0)


@dataclass(frozen=True)
class HandSpec:
    """A procedural target hand by name (:func:`solver.hands.make_hand`'s kinds, or ``"<kind>-left"`` for
    its mirror image: :func:`solver.hands.hand_from_kind`): cheap to send to workers, rebuilt once per
    process."""

    kind: str
    scale: float = 1.0

    def build(self):
        return _built_hand(self.kind, float(self.scale))


@lru_cache(maxsize=8)
def _built_hand(kind: str, scale: float):
    return hand_from_kind(kind, scale)


def as_hand(hand) -> SkinnedMesh:
    """The :class:`~solver.SkinnedMesh` a task's ``hand`` stands for: a :class:`HandSpec` built (once per
    process), a SkinnedMesh as it is."""
    if isinstance(hand, HandSpec):
        return hand.build()
    if isinstance(hand, SkinnedMesh):
        return hand
    raise SolverError(f"a frame's hand must be a HandSpec or a SkinnedMesh, got {type(hand).__name__}")


def table_box(table, table_size) -> Box | None:
    """The :class:`solver.Box` of a motion's table pose (4, 4) and full size (3,), or None."""
    if table is None:
        return None
    T = np.asarray(table, dtype=np.float64)
    return Box(T[:3, 3], 0.5 * np.asarray(table_size, dtype=np.float64), T[:3, :3])


@dataclass(frozen=True, eq=False)
class FrameTask:
    """Everything one frame's solve needs, and nothing of other frames.

    Attributes
    ----------
    frame : int
    stage : str
        ``"root"`` (only the root's six DOFs are free) or ``"full"`` (all DOFs).
    hand : HandSpec or SkinnedMesh
        The target hand.
    seed : (d,) ndarray
        Start pose. In the root stage its root is replaced by the rigid fit to the markers when
        ``align_root`` is set.
    contact_points : SurfacePoints (k)
        Transferred contacts on the target hand (may be empty).
    contact_targets, contact_normals : (k, 3) ndarray
        The paired object contacts posed at this frame and the object's outward normals there.
    marker_points : SurfacePoints (p)
        Marker points on the target hand.
    marker_targets : (p, 3) ndarray
        Where each should be: the source hand's marker positions at this frame.
    table : Box or None
    weights : RetargetWeights
    prior : (d,) ndarray or None
        The pose λj pulls towards (default: the rest pose).
    align_root : bool
    free : (d,) bool ndarray or None
        Overrides the stage's free DOFs (e.g. baselines that keep a given root).
    """

    frame: int
    stage: str
    hand: HandSpec | SkinnedMesh
    seed: np.ndarray
    contact_points: SurfacePoints
    contact_targets: np.ndarray
    contact_normals: np.ndarray
    marker_points: SurfacePoints
    marker_targets: np.ndarray
    table: Box | None = None
    weights: RetargetWeights = field(default_factory=RetargetWeights)
    prior: np.ndarray | None = None
    align_root: bool = True
    free: np.ndarray | None = None
    max_evaluations: int = MAX_EVALUATIONS
    algorithm: str = ALGORITHM
    ftol_rel: float = FTOL_REL
    norm: str = NORM

    def __post_init__(self):
        if self.stage not in STAGES:
            raise SolverError(f"stage must be one of {', '.join(STAGES)}, got {self.stage!r}")
        k, p = len(self.contact_points), len(self.marker_points)
        for what, a, n in (
            ("contact_targets", self.contact_targets, k),
            ("contact_normals", self.contact_normals, k),
            ("marker_targets", self.marker_targets, p),
        ):
            if np.shape(a) != (n, 3):
                raise SolverError(f"frame {self.frame}: {what} must have shape ({n}, 3), got {np.shape(a)}")
        if k == 0 and p == 0:
            raise SolverError(f"frame {self.frame} has neither contacts nor markers to solve for")


@dataclass(frozen=True, eq=False)
class FrameResult:
    """One frame's solve.

    Attributes
    ----------
    frame : int
    stage : str
    theta : (d,) ndarray
    energy : float
    terms : dict
        The weighted terms of the energy (ContactIK's names: distance, normal, marker, table, prior).
    contact_distances : (k,) ndarray
        Distance of each posed target-hand contact from its object contact.
    marker_distances : (p,) ndarray
        Distance of each posed marker point from its target.
    iterations : int
        Objective evaluations (both solves when the table forced a second one).
    seconds : float
        Wall-clock time of the whole task, hand lookup and setup included.
    status : str
        NLopt's outcome (see :class:`solver.SolveResult`).
    """

    frame: int
    stage: str
    theta: np.ndarray
    energy: float
    terms: dict
    contact_distances: np.ndarray
    marker_distances: np.ndarray
    iterations: int
    seconds: float
    status: str

    @property
    def contact_distance(self) -> float:
        """Mean contact distance (NaN without contacts)."""
        return float(self.contact_distances.mean()) if self.contact_distances.size else np.nan

    @property
    def marker_distance(self) -> float:
        """Mean marker distance (NaN without markers)."""
        return float(self.marker_distances.mean()) if self.marker_distances.size else np.nan


# ------------------------------------------------------------------------------------------- solving


def _on_palm(hand: SkinnedMesh, points: SurfacePoints) -> np.ndarray:
    """(k,) whether each point moves with the root or its children (the forearm and palm), judged by
    the posed bone that moves the deform bone weighing most at the point's nearest corner."""
    W = hand.weights.tocsr()
    corners = hand.mesh.faces[points.faces]
    vertex = corners[np.arange(len(corners)), np.argmax(points.bary, 1)]
    bone = hand.rig.deform_owner[np.asarray(W.argmax(axis=1)).reshape(-1)[vertex]]
    return (bone == 0) | (hand.rig.parents[bone] == 0)


def _root_stage(hand: SkinnedMesh, task: FrameTask) -> FrameTask:
    """The root pass's view of a frame: only the markers and contacts on the forearm and palm, which
    the root's six DOFs can meet with the fingers still at rest (finger points would drag the root
    towards wherever the resting fingers come closest to their targets). Falls back to all markers
    when fewer than three lie on the palm."""
    markers = _on_palm(hand, task.marker_points)
    if markers.sum() < 3:
        markers[:] = True
    contacts = _on_palm(hand, task.contact_points)
    return replace(
        task,
        marker_points=task.marker_points[np.flatnonzero(markers)],
        marker_targets=task.marker_targets[markers],
        contact_points=task.contact_points[np.flatnonzero(contacts)],
        contact_targets=task.contact_targets[contacts],
        contact_normals=task.contact_normals[contacts],
    )


def _aligned_seed(hand: SkinnedMesh, task: FrameTask) -> np.ndarray:
    """The seed with its root replaced by the rigid fit of the (palm) marker points onto their targets."""
    rig = hand.rig
    seed = task.seed.copy()
    seed[:6] = rig.rest[:6]
    posed, _ = hand.posed_points(seed, task.marker_points)
    G = rigid_fit(posed, task.marker_targets)
    seed[:6] = rig.root_dofs(G, compatible=task.seed[3:6])
    return seed


def _problem(hand, task: FrameTask, with_table: bool) -> tuple[ContactIK, bool]:
    weights = task.weights.solver_weights()
    markers = Markers(task.marker_points, task.marker_targets) if len(task.marker_points) else None
    dummy = len(task.contact_points) == 0
    if dummy:  # markers only: one marker point stands in as a contact with zero weight
        points = task.marker_points[[0]]
        targets = task.marker_targets[:1]
        normals = np.array([[0.0, 0.0, 1.0]])
        weights = replace(weights, d=0.0, n=0.0)
    else:
        points, targets, normals = task.contact_points, task.contact_targets, task.contact_normals
    problem = ContactIK(
        hand,
        points,
        targets,
        normals,
        weights,
        prior=task.prior,
        markers=markers,
        obstacle=task.table if with_table else None,
        algorithm=task.algorithm,
        norm=task.norm,
    )
    return problem, dummy


def _near_table(hand, table: Box | None, theta) -> bool:
    if table is None:
        return False
    sd, _ = table.evaluate(hand.posed_vertices(theta))
    return bool(sd.min() < hand.size)


def solve_frame(task: FrameTask) -> FrameResult:
    """Solve one frame's pose (Eq. 3): picklable, independent of every other frame."""
    start = time.perf_counter()
    hand = as_hand(task.hand)
    rig = hand.rig
    seed = rig.check_theta(task.seed, "seed")
    task = whole = replace(task, seed=seed)
    if task.stage == "root" and task.free is None and len(task.marker_points):
        task = _root_stage(hand, task)
    if task.stage == "root" and task.align_root and len(task.marker_points) >= 3:
        seed = _aligned_seed(hand, task)
    if task.free is not None:
        free = np.asarray(task.free, dtype=bool)
    else:
        free = rig.dof_bone == 0 if task.stage == "root" else np.ones(rig.n_dofs, bool)
    with_table = _near_table(hand, task.table, seed)
    problem, dummy = _problem(hand, task, with_table)
    result = problem.solve(seed, free, max_evaluations=task.max_evaluations, ftol_rel=task.ftol_rel)
    iterations = result.iterations
    if task.table is not None and not with_table:
        sd, _ = task.table.evaluate(hand.posed_vertices(result.theta))
        if sd.min() < 0:
            problem, dummy = _problem(hand, task, True)
            result = problem.solve(
                result.theta, free, max_evaluations=task.max_evaluations, ftol_rel=task.ftol_rel
            )
            iterations += result.iterations
    theta = result.theta
    marker_distances, contact_distances = (
        np.linalg.norm(hand.posed_points(theta, points)[0] - targets, axis=1) if len(points) else np.empty(0)
        for points, targets in (
            (whole.marker_points, whole.marker_targets),
            (whole.contact_points, whole.contact_targets),
        )
    )
    terms = dict(result.terms)
    if dummy:
        terms.pop("distance", None)
        terms.pop("normal", None)
    return FrameResult(
        task.frame,
        task.stage,
        theta,
        float(result.energy),
        terms,
        contact_distances,
        marker_distances,
        iterations,
        time.perf_counter() - start,
        result.status,
    )


def solve_frames(
    tasks: Sequence[FrameTask],
    progress: Callable[[int, int], None] | None = None,
    map: Callable | None = None,
    solve: Callable[[FrameTask], FrameResult] = solve_frame,
) -> list[FrameResult]:
    """Solve tasks (in any order; results come back in the tasks' order).

    ``map`` is any ``map``-like callable (the builtin by default, ``executor.map`` of a process pool,
    a Dask client's ``map`` followed by gathering); ``progress(done, total)`` is called as results
    arrive. ``solve`` solves one task (a module-level function, e.g. a baseline's).
    """
    mapper = map if map is not None else builtins.map
    results = []
    for result in mapper(solve, tasks):
        results.append(result)
        if progress is not None:
            progress(len(results), len(tasks))
    return results


# ----------------------------------------------------------------------------------- building tasks


def object_contact_geometry(motion: Motion, contacts: Contacts) -> tuple[np.ndarray, np.ndarray]:
    """(K, 3) each: world positions and outward unit normals of every frame's object contacts (K in all)."""
    mesh = motion.object_mesh
    P = np.einsum("kj,kjd->kd", contacts.bary, mesh.vertices[mesh.faces[contacts.faces]])
    N = mesh.face_normals[contacts.faces]
    frame = np.repeat(np.arange(contacts.n_frames), np.diff(contacts.offsets))
    pose = np.asarray(motion.object_poses)[frame]
    return np.einsum("kij,kj->ki", pose[:, :3, :3], P) + pose[:, :3, 3], np.einsum(
        "kij,kj->ki", pose[:, :3, :3], N
    )


def build_tasks(
    motion: Motion,
    hand: HandSpec | SkinnedMesh,
    annotation: HandPairAnnotation,
    weights: RetargetWeights | None = None,
    hand_contacts: Contacts | None = None,
    object_contacts: Contacts | None = None,
    frames: Iterable[int] | None = None,
    use_table: bool = True,
    **options,
) -> list[FrameTask]:
    """The root-stage tasks of every frame (or of ``frames``) of a motion for a target hand.

    Parameters
    ----------
    motion : Motion
        Needs paired ``object_contacts`` and ``hand_contacts`` unless the transferred contacts are given.
    hand : HandSpec or SkinnedMesh
        The target hand (a HandSpec keeps the tasks small).
    annotation : HandPairAnnotation
        The source-target pair's markers (and curves, for the transfer when ``hand_contacts`` is None).
    weights : RetargetWeights, optional
    hand_contacts, object_contacts : Contacts, optional
        Contacts already transferred to the target hand and the object contacts paired with them
        (e.g. :func:`.transfer.transfer_motion`'s). Default: transferred here.
    frames : iterable of int, optional
    use_table : bool
        Include the motion's table (Eq. 6) when it has one.
    **options
        Further :class:`FrameTask` fields (``prior``, ``max_evaluations``, ``algorithm``, ...).
    """
    from .transfer import transfer_motion

    target = as_hand(hand)
    weights = weights or RetargetWeights()
    if hand_contacts is None and motion.hand_contacts is not None:
        moved = transfer_motion(motion, annotation, target.mesh)
        hand_contacts, object_contacts = moved.hand_contacts, moved.object_contacts
    if hand_contacts is not None and object_contacts is None:
        raise SolverError("transferred hand contacts need the object contacts paired with them")
    if hand_contacts is not None and not np.array_equal(hand_contacts.offsets, object_contacts.offsets):
        raise SolverError("hand and object contacts are not paired row for row (their offsets differ)")
    pairs = annotation.marker_pairs() if annotation.markers else None
    F = motion.n_frames
    frame_ids = np.arange(F) if frames is None else np.asarray(list(frames), np.int64)
    if pairs is not None:
        sub = motion if frames is None else motion.select(frame_ids)
        targets = pairs.targets(sub.hand_mesh, sub.hand_vertices)
    if hand_contacts is not None:
        positions, normals = object_contact_geometry(motion, object_contacts)
    table = table_box(motion.table, motion.table_size) if use_table else None
    empty_points = SurfacePoints(np.empty(0, np.int64), np.empty((0, 3)))
    tasks = []
    for i, f in enumerate(frame_ids):
        if hand_contacts is not None:
            a, b = int(hand_contacts.offsets[f]), int(hand_contacts.offsets[f + 1])
            points = hand_contacts.frame(int(f))
            cp, cn = positions[a:b], normals[a:b]
        else:
            points, cp, cn = empty_points, np.empty((0, 3)), np.empty((0, 3))
        tasks.append(
            FrameTask(
                frame=int(f),
                stage="root",
                hand=hand,
                seed=target.rig.rest.copy(),
                contact_points=points,
                contact_targets=cp,
                contact_normals=cn,
                marker_points=pairs.target if pairs is not None else empty_points,
                marker_targets=targets[i] if pairs is not None else np.empty((0, 3)),
                table=table,
                weights=weights,
                **options,
            )
        )
    return tasks


def full_tasks(root_tasks: Sequence[FrameTask], root_results: Sequence[FrameResult]) -> list[FrameTask]:
    """The full-pose tasks: each frame seeded by its own root estimate (joints as in its root seed)."""
    by_frame = {r.frame: r for r in root_results}
    out = []
    for task in root_tasks:
        if task.frame not in by_frame:
            raise SolverError(f"no root result for frame {task.frame}")
        seed = task.seed.copy()
        seed[:6] = by_frame[task.frame].theta[:6]
        out.append(replace(task, stage="full", seed=seed, align_root=False))
    return out


def estimate(
    motion: Motion,
    hand: HandSpec | SkinnedMesh,
    annotation: HandPairAnnotation,
    weights: RetargetWeights | None = None,
    progress: Callable[[str, int, int], None] | None = None,
    map: Callable | None = None,
    **options,
) -> tuple[list[FrameResult], list[FrameResult]]:
    """The initial trajectory estimate (§3.4.2): every frame's root pass, then its full pass.

    Returns the root results and the full results, frame by frame. ``progress(stage, done, total)``;
    ``map`` as for :func:`solve_frames`.
    """
    tasks = build_tasks(motion, hand, annotation, weights, **options)

    def stage_progress(stage):
        return None if progress is None else (lambda done, total: progress(stage, done, total))

    roots = solve_frames(tasks, stage_progress("root"), map)
    fulls = solve_frames(full_tasks(tasks, roots), stage_progress("full"), map)
    return roots, fulls
