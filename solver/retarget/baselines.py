"""The contact-free baselines of §4.6 (Kinematic Motion Retargeting) and the comparison of Table 1.

§4.6 compares the method against two retargeting objectives from tele-operation, each "augmented with
information about the known full source trajectory": both get the **ground-truth root** (here: the root
the caller passes, e.g. our own root pass, :func:`.frames.estimate`'s root results, since a retarget to
another hand has no ground truth for its root), **independent per-frame solves** (§3.4.2: every frame
starts from its own root and the rest pose of the fingers, no frame seeds another) and the **same
retroactive smoothing** (§3.4.3: :func:`resolver` turns a baseline's task list into the ``resolve``
callback of :func:`.refine.refine_trajectory`, keeping the given root).

**Fingertip keypoint tracking** (Qin et al. 2022; "equivalent to Equation (3) with λc = 0"):
:func:`keypoint_tasks` keeps only the fingertip markers of the annotation (``<finger>_tip``, see
:func:`.annotate.hand_markers`: the target's fingertip markers track the source's fingertip markers)
and solves Eq. 3 without the contact terms (table and prior stay) through :func:`.frames.solve_frame`,
the root fixed (``FrameTask.free``). The contacts are left out of those tasks rather than weighted by
zero: their terms would be exactly zero and only cost evaluations.

**Relative keyvectors** (DexPilot, Handa et al. 2019, Eq. 1-3): with keypoints at the palm and at the
fingertips, keyvectors ``r_i`` run from the palm to every fingertip and between every pair of
fingertips, and the pose minimizes

    C(θ) = 1/2 Σ_i s(d_i) |r_i(θ) - f(d_i) r̂_i|² / L² + γ Σ_{j not root} (θ_j - θ̄_j)²

over the rig's bounds, where ``d_i`` and ``r̂_i`` are the length and direction of the source hand's
keyvector at the frame. DexPilot's switching rule: a vector between a primary finger and the thumb with
``d_i <= ε`` is in S1 (a pinch: ``f = η1``, a tiny distance, ``s = 200``); a vector between two primary
fingers that both pinch the thumb, itself no longer than ε, is in S2 (``f = η2``, keeping the two apart,
``s = 400``); every other vector keeps its scaled length ``f = η d_i`` with ``s = 1``. Constants
(:class:`KeyvectorParams`): ε = 3 cm, η1 = 0.1 mm, η2 = 3 cm, s = 200/400, γ = 2.5·10⁻³ as in DexPilot
(ε and the η's as in the authors' reference implementation, ``dex_retargeting.DexPilotOptimizer``);
DexPilot's hysteresis (a pinch ends only beyond 5 cm) needs the previous frame and is left out, since
frames are independent. DexPilot's β = 1.6 was the Allegro-to-human size ratio; here the scaling is
``η = target hand length / source hand length``. Lengths are in metres at life size: ``L`` is the
source hand's scale (1 at life size) and ε, η1, η2 scale with it, so the cost is DexPilot's at life size
and the same at any scale. DexPilot regularizes the Allegro angles to zero (its open hand); ours pull
towards the rest pose (the open hand) and leave the root out (it is fixed). The palm keypoint is the
mean of the wrist and knuckle markers (on the back of the hand); each keypoint is the mean of its
markers' points on the target and of the source positions they track, so on the same hand at the same
pose the keyvectors agree exactly. The gradient is analytic (reverse mode through
:class:`solver.skinning.PointSkin`), the solver NLopt's L-BFGS as the per-frame solves of
:mod:`.frames`.

**Tasks.** Both task lists are derived from the root-stage tasks of our method (:func:`.frames.build_tasks`)
so the baselines see exactly the same inputs: the same frames, marker targets and table. Keypoint tasks
are :class:`.frames.FrameTask`; keyvector tasks are :class:`KeyvectorTask`, solved by the module-level
:func:`solve_keyvector_frame`; :func:`solve_task` takes either, so all run through the same executor
(any ``map``: a process pool, Dask) as our frames.

**Table 1** (:func:`comparison_table`): for each method, the median and mean ± standard deviation over
frames of the per-frame average contact distance and marker distance, in centimetres. Both are measured
the same way for every method, from its poses (:func:`frame_distances`): the transferred target-hand
contacts posed with the method's pose against their object contacts (the baselines do not optimize
them), and the annotation's full marker set (or a named subset) against the source markers. The
contact column uses frames with contacts only.

**In a retarget.** ``RetargetOptions(baselines=True)`` (``contact-edit retarget --baselines``) runs both
beside our method through the same executor and compares the three methods' final curves
(:mod:`.pipeline`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from geodesics import SurfacePoints

from ..errors import SolverError
from ..ik import ALGORITHMS, free_dofs, minimize
from .frames import (
    ALGORITHM,
    FTOL_REL,
    MAX_EVALUATIONS,
    FrameResult,
    FrameTask,
    HandSpec,
    as_hand,
    solve_frame,
    solve_frames,
)

__all__ = [
    "KEYVECTOR_CLASSES",
    "KeyvectorIK",
    "KeyvectorParams",
    "KeyvectorTask",
    "Keyvectors",
    "MethodSummary",
    "Table",
    "comparison_table",
    "dexpilot_targets",
    "fingertip_names",
    "frame_distances",
    "keypoint_tasks",
    "keyvector_layout",
    "keyvector_problem",
    "keyvector_tasks",
    "reseeded",
    "resolver",
    "solve_keyvector_frame",
    "solve_task",
    "solve_tasks",
]

#: Keyvector classes: 0 a palm or open vector (s = 1, f = η d), 1 S1 (thumb pinch), 2 S2 (two pinching
#: primary fingers).
KEYVECTOR_CLASSES = ("open", "S1", "S2")
#: The palm keypoint's markers (their mean): on the back of the hand at the wrist and at the knuckles.
PALM_MARKERS = ("wrist_radial", "wrist_ulnar", "knuckle_radial", "knuckle_ulnar")
#: The thumb's fingertip marker (the other fingertips are DexPilot's primary fingers).
THUMB_TIP = "thumb_tip"
#: Method names of the comparison, in the paper's row order.
METHODS = ("Keypoint", "Keyvector", "Ours")


# ------------------------------------------------------------------------------------------- common


def fingertip_names(annotation) -> tuple[str, ...]:
    """The annotation's fingertip markers (``<finger>_tip``), in its order."""
    names = tuple(m.name for m in annotation.markers if m.name.endswith("_tip"))
    if not names:
        raise SolverError("the annotation has no fingertip markers (named '<finger>_tip')")
    return names


def _marker_rows(annotation, names) -> tuple[np.ndarray, np.ndarray]:
    """Rows of the annotation's full marker point list (as in ``FrameTask.marker_points`` of
    :func:`.frames.build_tasks`) that belong to the named markers, and each row's index into ``names``."""
    pairs = annotation.marker_pairs()
    index = {n: i for i, n in enumerate(pairs.names)}
    missing = [n for n in names if n not in index]
    if missing:
        raise SolverError(f"the annotation has no markers named {', '.join(missing)}")
    which = np.full(len(pairs.names), -1)
    for i, n in enumerate(names):
        which[index[n]] = i
    owner = which[pairs.marker]
    rows = np.flatnonzero(owner >= 0)
    return rows, owner[rows]


def _check_tasks(tasks: Sequence[FrameTask], annotation) -> int:
    """The marker point count every task must have (the annotation's full set)."""
    if not tasks:
        raise SolverError("no tasks: give the root-stage tasks of frames.build_tasks")
    p = len(annotation.marker_pairs().target)
    for t in tasks:
        if not isinstance(t, FrameTask):
            raise SolverError(f"expected frames.FrameTask, got {type(t).__name__}")
        if len(t.marker_points) != p:
            raise SolverError(
                f"frame {t.frame}'s task has {len(t.marker_points)} marker points but the annotation's "
                f"markers have {p}: build the tasks with this annotation (frames.build_tasks)"
            )
    return p


def _roots(roots, tasks: Sequence) -> np.ndarray:
    """(n, 6) the given root DOFs of each task's frame, from FrameResults (any order) or an array whose
    rows follow the tasks."""
    if isinstance(roots, np.ndarray) or (len(roots) and not isinstance(roots[0], FrameResult)):
        R = np.asarray(roots, dtype=np.float64)
        if R.ndim != 2 or R.shape[0] != len(tasks) or R.shape[1] < 6:
            raise SolverError(
                f"roots must have shape ({len(tasks)}, 6 or more), one row per task; got {R.shape}"
            )
        R = R[:, :6]
    else:
        by_frame = {r.frame: r for r in roots}
        missing = [t.frame for t in tasks if t.frame not in by_frame]
        if missing:
            raise SolverError(f"no root for frames {missing[:10]}")
        R = np.stack([np.asarray(by_frame[t.frame].theta[:6], dtype=np.float64) for t in tasks])
    if not np.all(np.isfinite(R)):
        raise SolverError("the given roots are not finite")
    return R


def _joint_mask(rig) -> np.ndarray:
    """(d,) the DOFs a baseline solves: every one but the root's (fixed to the given root)."""
    return rig.dof_bone != 0


# ------------------------------------------------------------------------------ keypoint tracking


def keypoint_tasks(
    tasks: Sequence[FrameTask],
    annotation,
    roots,
    names: Sequence[str] | None = None,
) -> list[FrameTask]:
    """Fingertip keypoint tracking (Qin et al. 2022: Eq. 3 with λc = 0) for the frames of our tasks.

    Parameters
    ----------
    tasks : sequence of FrameTask
        Our method's root-stage tasks (:func:`.frames.build_tasks` with ``annotation``): the same frames,
        marker targets, table and weights.
    annotation : HandPairAnnotation
    roots : sequence of FrameResult, or (n, >= 6) array_like
        The given ("ground-truth") root of each frame: e.g. our root pass. Rows follow ``tasks``.
    names : sequence of str, optional
        The tracked markers (default: the fingertips, :func:`fingertip_names`).

    Returns
    -------
    list of FrameTask
        Full-stage tasks with only the tracked markers, no contacts, λc = 0, the root fixed to the given
        one (``free``), the fingers seeded at their rest pose. Solve them with :func:`.frames.solve_frame`
        (or :func:`solve_task`).
    """
    _check_tasks(tasks, annotation)
    names = fingertip_names(annotation) if names is None else tuple(names)
    rows, _ = _marker_rows(annotation, names)
    R = _roots(roots, tasks)
    empty = SurfacePoints(np.empty(0, np.int64), np.empty((0, 3)))
    out = []
    for task, root in zip(tasks, R, strict=True):
        rig = as_hand(task.hand).rig
        seed = rig.rest.copy()
        seed[:6] = root
        out.append(
            replace(
                task,
                stage="full",
                seed=seed,
                contact_points=empty,
                contact_targets=np.empty((0, 3)),
                contact_normals=np.empty((0, 3)),
                marker_points=task.marker_points[rows],
                marker_targets=np.asarray(task.marker_targets)[rows],
                weights=replace(task.weights, c=0.0),
                align_root=False,
                free=_joint_mask(rig),
            )
        )
    return out


# ---------------------------------------------------------------------------- relative keyvectors


@dataclass(frozen=True)
class KeyvectorParams:
    """DexPilot's constants (Handa et al. 2019, Eq. 2-3), lengths in metres at life size.

    Attributes
    ----------
    scaling : float or None
        η (DexPilot's β): multiplies the source keyvector lengths. None: target hand length / source
        hand length (the procedural hands' lengths).
    pinch : float
        ε, the switching distance below which a thumb-finger vector is a pinch (S1).
    eta1 : float
        η1, the distance a pinching S1 pair is pulled to.
    eta2 : float
        η2, the distance two primary fingers that both pinch the thumb (S2) are held apart.
    weight_s1, weight_s2 : float
        s(d) of S1 and S2 vectors (every other vector weighs 1).
    gamma : float
        γ, the regularization towards the rest pose (radians²).
    """

    scaling: float | None = None
    pinch: float = 0.03
    eta1: float = 1e-4
    eta2: float = 0.03
    weight_s1: float = 200.0
    weight_s2: float = 400.0
    gamma: float = 2.5e-3

    def __post_init__(self):
        for name in ("pinch", "eta1", "eta2", "weight_s1", "weight_s2", "gamma"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v >= 0):
                raise SolverError(
                    f"keyvector parameter {name} must be a finite non-negative number, got {v!r}"
                )
            object.__setattr__(self, name, float(v))
        if self.scaling is not None:
            if not (
                isinstance(self.scaling, (int, float)) and np.isfinite(self.scaling) and self.scaling > 0
            ):
                raise SolverError(f"keyvector scaling η must be a positive number, got {self.scaling!r}")
            object.__setattr__(self, "scaling", float(self.scaling))


@dataclass(frozen=True)
class Keyvectors:
    """The keyvector layout of a hand pair: which keypoints each vector joins, and its class.

    Attributes
    ----------
    names : tuple of str
        Keypoint names: ``"palm"`` then the fingertip markers.
    origin, tip : (m,) int
        Each vector runs from keypoint ``origin`` to keypoint ``tip``.
    candidate : (m,) int
        1 for thumb-finger pairs (S1 candidates), 2 for pairs of primary fingers (S2 candidates), 0 for
        the palm vectors (never projected) and, on a hand without a thumb, every pair.
    palm : (m,) bool
        The palm-to-fingertip vectors.
    """

    names: tuple[str, ...]
    origin: np.ndarray
    tip: np.ndarray
    candidate: np.ndarray
    palm: np.ndarray


def keyvector_layout(tips: Sequence[str]) -> Keyvectors:
    """Palm-to-fingertip vectors and every fingertip pair (thumb pairs point from the finger to the thumb,
    as DexPilot's S1)."""
    tips = tuple(tips)
    names = ("palm", *tips)
    origin, tip, candidate, palm = [], [], [], []
    thumb = tips.index(THUMB_TIP) + 1 if THUMB_TIP in tips else None
    k = len(names)
    for a in range(1, k):
        for b in range(a + 1, k):
            if thumb is not None and b == thumb:
                origin.append(a), tip.append(b), candidate.append(1)
            elif thumb is not None and a == thumb:
                origin.append(b), tip.append(a), candidate.append(1)
            else:
                origin.append(a), tip.append(b), candidate.append(2 if thumb is not None else 0)
            palm.append(False)
    for a in range(1, k):
        origin.append(0), tip.append(a), candidate.append(0), palm.append(True)
    return Keyvectors(
        names,
        np.array(origin, np.int64),
        np.array(tip, np.int64),
        np.array(candidate, np.int64),
        np.array(palm),
    )


def dexpilot_targets(
    source: np.ndarray, layout: Keyvectors, params: KeyvectorParams, scaling: float, length: float = 1.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """DexPilot's reference vectors ``f(d_i) r̂_i`` and weights ``s(d_i)`` for source keyvectors.

    Parameters
    ----------
    source : (m, 3) ndarray
        The source hand's keyvectors at a frame (``layout`` order).
    layout : Keyvectors
    params : KeyvectorParams
    scaling : float
        η.
    length : float
        Scale of ε, η1 and η2 (the source hand's scale: 1 at life size).

    Returns
    -------
    reference : (m, 3) ndarray
    weights : (m,) ndarray
    classes : (m,) int
        0 open, 1 S1, 2 S2 (:data:`KEYVECTOR_CLASSES`).
    """
    S = np.asarray(source, dtype=np.float64)
    d = np.linalg.norm(S, axis=1)
    direction = S / np.where(d > 0, d, 1.0)[:, None]
    eps = params.pinch * length
    classes = np.zeros(len(S), np.int64)
    s1 = (layout.candidate == 1) & (d <= eps)
    classes[s1] = 1
    # S2: both primary fingers pinch the thumb, and the two are within ε of each other.
    pinching = set()
    for i in np.flatnonzero(s1):
        pinching.add(int(layout.origin[i]))
    both = np.array(
        [int(o) in pinching and int(t) in pinching for o, t in zip(layout.origin, layout.tip, strict=True)],
        bool,
    )
    s2 = (layout.candidate == 2) & both & (d <= eps)
    classes[s2] = 2
    f = np.where(
        classes == 1, params.eta1 * length, np.where(classes == 2, params.eta2 * length, scaling * d)
    )
    s = np.where(classes == 1, params.weight_s1, np.where(classes == 2, params.weight_s2, 1.0))
    return direction * f[:, None], s, classes


@dataclass(frozen=True, eq=False)
class KeyvectorTask:
    """One frame of the DexPilot baseline: plain arrays, picklable.

    Attributes
    ----------
    frame : int
    hand : HandSpec or SkinnedMesh
        The target hand.
    seed : (d,) ndarray
        Start pose; its fixed DOFs (not ``free``) keep their values (the given root).
    points : SurfacePoints (p)
        The keypoint markers' points on the target hand.
    matrix : (m, p) ndarray
        Keyvector i at a pose is ``matrix[i] @ posed points``.
    reference : (m, 3) ndarray
        DexPilot's ``f(d_i) r̂_i``.
    weights : (m,) ndarray
        ``s(d_i)``.
    classes : (m,) int
    source : (m, 3) ndarray
        The source keyvectors (for reports).
    gamma : float
    length : float
        L, the length scale of the residuals (the source hand's scale).
    free : (d,) bool ndarray
    prior : (d,) ndarray or None
        The pose γ pulls towards (default: rest).
    """

    frame: int
    hand: HandSpec | object
    seed: np.ndarray
    points: SurfacePoints
    matrix: np.ndarray
    reference: np.ndarray
    weights: np.ndarray
    classes: np.ndarray
    source: np.ndarray
    gamma: float
    length: float
    free: np.ndarray
    prior: np.ndarray | None = None
    max_evaluations: int = MAX_EVALUATIONS
    algorithm: str = ALGORITHM
    ftol_rel: float = FTOL_REL

    def __post_init__(self):
        m, p = np.shape(self.matrix)
        if p != len(self.points):
            raise SolverError(f"frame {self.frame}: matrix has {p} columns for {len(self.points)} points")
        for what, a, shape in (
            ("reference", self.reference, (m, 3)),
            ("weights", self.weights, (m,)),
            ("source", self.source, (m, 3)),
        ):
            if np.shape(a) != shape:
                raise SolverError(f"frame {self.frame}: {what} must have shape {shape}, got {np.shape(a)}")
        if not np.all(np.isfinite(self.reference)):
            raise SolverError(f"frame {self.frame}: the source keyvectors are not finite")


class KeyvectorIK:
    """DexPilot's keyvector cost on a skinned hand, with its analytic gradient, and its NLopt solve.

    Parameters
    ----------
    hand : SkinnedMesh
    points : SurfacePoints (p)
    matrix : (m, p) array_like
    reference : (m, 3) array_like
    weights : (m,) array_like
    gamma : float
    length : float
        L: residuals are divided by it (the source hand's scale).
    prior : (d,) array_like, optional
        The pose γ pulls towards (default: rest); the root is left out.
    algorithm : str
        One of :data:`solver.ik.ALGORITHMS`.
    """

    def __init__(
        self, hand, points, matrix, reference, weights, gamma, length=1.0, prior=None, algorithm=ALGORITHM
    ):
        if algorithm not in ALGORITHMS:
            raise SolverError(f"unknown algorithm {algorithm!r}; use one of {', '.join(ALGORITHMS)}")
        self.hand = hand
        rig = hand.rig
        self.matrix = np.asarray(matrix, dtype=np.float64)
        self.reference = np.asarray(reference, dtype=np.float64)
        self.weights = np.asarray(weights, dtype=np.float64)
        self.gamma = float(gamma)
        self.length = float(length)
        if not (np.isfinite(self.length) and self.length > 0):
            raise SolverError(f"length must be positive, got {length!r}")
        self.prior = rig.rest if prior is None else rig.check_theta(prior, "prior")
        self.algorithm = algorithm
        self._skin = hand.point_skin([points])
        self._mask = rig.dof_bone != 0

    def vectors(self, theta) -> np.ndarray:
        """(m, 3) the target hand's keyvectors at pose θ (d,)."""
        kin = self.hand.rig.kinematics(self.hand.rig.check_theta(theta), derivatives=False)
        p, _, _ = self._skin.sets[0].geometry(self._skin.vertices.positions(kin))
        return self.matrix @ p

    def energy(self, theta) -> tuple[float, dict[str, float]]:
        """Cost at θ (d,) and its terms (dict: keyvector, regularization)."""
        energy, terms, _ = self._evaluate(theta, False)
        return energy, terms

    def energy_and_gradient(self, theta) -> tuple[float, dict[str, float], np.ndarray]:
        """Cost at θ (d,), its terms (dict: keyvector, regularization) and its gradient (d,)."""
        return self._evaluate(theta, True)

    def _evaluate(self, theta, with_gradient: bool) -> tuple[float, dict[str, float], np.ndarray | None]:
        """:meth:`energy_and_gradient`, or only the cost and terms (gradient None)."""
        rig = self.hand.rig
        t = rig.check_theta(theta)
        kin = rig.kinematics(t, derivatives=with_gradient)
        skin = self._skin
        V = skin.vertices.positions(kin)
        points = skin.sets[0]
        p, n, aux = points.geometry(V)
        E = (self.matrix @ p - self.reference) / self.length
        ws = self.weights[:, None] * E
        dp = np.where(self._mask, t - self.prior, 0.0)
        terms = {
            "keyvector": 0.5 * float(np.sum(ws * E)),
            "regularization": self.gamma * float(np.sum(dp**2)),
        }
        energy = terms["keyvector"] + terms["regularization"]
        if not with_gradient:
            return energy, terms, None
        grad_p = self.matrix.T @ ws / self.length
        grad = skin.vertices.vjp(kin, points.adjoint(n, aux, grad_p, None)) + 2 * self.gamma * dp
        return energy, terms, grad

    def solve(self, theta0, free, max_evaluations: int = MAX_EVALUATIONS, ftol_rel: float = FTOL_REL):
        """Minimize over the DOFs ``free`` ((d,) bool, or None for all; within the rig's bounds) from θ0
        (d,), brought into the bounds (:meth:`solver.Rig.clip`); the others keep θ0's values.

        Returns the best pose (d,), its energy, terms, the evaluation count and NLopt's outcome.
        """
        rig = self.hand.rig
        theta = rig.clip(rig.check_theta(theta0, "theta0"))
        index = free_dofs(rig, free)
        scale = np.where(rig.is_rotation, 1.0, self.length)[index]
        return minimize(
            self.energy,
            self.energy_and_gradient,
            theta,
            index,
            scale,
            rig,
            self.algorithm,
            max_evaluations,
            ftol_rel,
        )


def _source_length(annotation, params: KeyvectorParams, target) -> tuple[float, float]:
    """(η, L): the scaling and the source hand's scale."""
    L = float(annotation.source.scale)
    if params.scaling is not None:
        return params.scaling, L
    if annotation.source.kind is None or getattr(target, "length", None) is None:
        raise SolverError(
            "the keyvector scaling η needs the source and target hand lengths: give "
            "KeyvectorParams(scaling=...) for hands that are not procedural"
        )
    source = HandSpec(annotation.source.kind, float(annotation.source.scale)).build()
    return float(target.length) / float(source.length), L


def keyvector_tasks(
    tasks: Sequence[FrameTask],
    annotation,
    roots,
    params: KeyvectorParams | None = None,
    palm: Sequence[str] = PALM_MARKERS,
    tips: Sequence[str] | None = None,
) -> list[KeyvectorTask]:
    """DexPilot's relative keyvectors for the frames of our tasks.

    Parameters
    ----------
    tasks : sequence of FrameTask
        Our method's root-stage tasks (:func:`.frames.build_tasks` with ``annotation``).
    annotation : HandPairAnnotation
    roots : sequence of FrameResult, or (n, >= 6) array_like
        The given root of each frame (rows follow ``tasks``).
    params : KeyvectorParams, optional
    palm : sequence of str
        Markers whose mean is the palm keypoint.
    tips : sequence of str, optional
        The fingertip markers (default :func:`fingertip_names`); ``thumb_tip`` among them makes the
        others primary fingers.
    """
    params = params or KeyvectorParams()
    _check_tasks(tasks, annotation)
    tips = fingertip_names(annotation) if tips is None else tuple(tips)
    palm = tuple(palm)
    layout = keyvector_layout(tips)
    groups = [palm] + [(t,) for t in tips]
    flat = tuple(dict.fromkeys(n for g in groups for n in g))
    rows, owner = _marker_rows(annotation, flat)
    # Keypoint k = mean over its markers of the mean of each marker's points.
    counts = np.bincount(owner, minlength=len(flat)).astype(np.float64)
    A = np.zeros((len(groups), rows.size))
    for k, group in enumerate(groups):
        for name in group:
            i = flat.index(name)
            A[k, owner == i] += 1.0 / (counts[i] * len(group))
    D = np.zeros((len(layout.origin), len(groups)))
    D[np.arange(len(D)), layout.tip] += 1.0
    D[np.arange(len(D)), layout.origin] -= 1.0
    M = D @ A
    R = _roots(roots, tasks)
    out = []
    for task, root in zip(tasks, R, strict=True):
        hand = as_hand(task.hand)
        scaling, L = _source_length(annotation, params, hand)
        source = M @ np.asarray(task.marker_targets)[rows]
        reference, weights, classes = dexpilot_targets(source, layout, params, scaling, L)
        seed = hand.rig.rest.copy()
        seed[:6] = root
        out.append(
            KeyvectorTask(
                frame=task.frame,
                hand=task.hand,
                seed=seed,
                points=task.marker_points[rows],
                matrix=M,
                reference=reference,
                weights=weights,
                classes=classes,
                source=source,
                gamma=params.gamma,
                length=L,
                free=_joint_mask(hand.rig),
                prior=task.prior,
                max_evaluations=task.max_evaluations,
                algorithm=task.algorithm,
                ftol_rel=task.ftol_rel,
            )
        )
    return out


def keyvector_problem(task: KeyvectorTask) -> KeyvectorIK:
    """The :class:`KeyvectorIK` of a task."""
    return KeyvectorIK(
        as_hand(task.hand),
        task.points,
        task.matrix,
        task.reference,
        task.weights,
        task.gamma,
        task.length,
        prior=task.prior,
        algorithm=task.algorithm,
    )


def solve_keyvector_frame(task: KeyvectorTask) -> FrameResult:
    """Solve one frame of the DexPilot baseline: picklable, independent of every other frame.

    The result's ``marker_distances`` are the distances of the posed target keyvectors from their
    references ``f(d_i) r̂_i`` (m,); ``contact_distances`` is empty (the table measures contacts).
    """
    start = time.perf_counter()
    problem = keyvector_problem(task)
    theta, energy, terms, iterations, status = problem.solve(
        task.seed, task.free, task.max_evaluations, task.ftol_rel
    )
    residual = np.linalg.norm(problem.vectors(theta) - task.reference, axis=1)
    return FrameResult(
        task.frame,
        "full",
        theta,
        energy,
        terms,
        np.empty(0),
        residual,
        iterations,
        time.perf_counter() - start,
        status,
    )


# --------------------------------------------------------------------------------- running tasks


def solve_task(task: FrameTask | KeyvectorTask) -> FrameResult:
    """Solve one task of either baseline (or of our method): the function to send to workers."""
    if isinstance(task, KeyvectorTask):
        return solve_keyvector_frame(task)
    if isinstance(task, FrameTask):
        return solve_frame(task)
    raise SolverError(f"cannot solve a {type(task).__name__}: expected a FrameTask or a KeyvectorTask")


def solve_tasks(
    tasks: Sequence[FrameTask | KeyvectorTask],
    progress: Callable[[int, int], None] | None = None,
    map: Callable | None = None,
) -> list[FrameResult]:
    """Solve tasks with any ``map`` (default: the builtin), results in the tasks' order;
    ``progress(done, total)`` as they arrive."""
    return solve_frames(tasks, progress, map, solve=solve_task)


def reseeded(task: FrameTask | KeyvectorTask, seed) -> FrameTask | KeyvectorTask:
    """The task solved again from ``seed`` (d,) (a refinement's interpolated pose), except its fixed DOFs
    (the baselines' given root), which keep the task's own values."""
    seed = np.asarray(seed, np.float64)
    free = np.ones(len(seed), bool) if task.free is None else np.asarray(task.free, bool)
    new_seed = np.where(free, seed, task.seed)
    if isinstance(task, FrameTask):
        return replace(task, seed=new_seed, align_root=False)
    return replace(task, seed=new_seed)


def resolver(
    tasks: Sequence[FrameTask | KeyvectorTask], map: Callable | None = None
) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """The ``resolve(frames (k,), seeds (k, d)) -> θ (k, d)`` callback of :func:`.refine.refine_trajectory`
    for a task list (rows of the trajectory follow ``tasks``): the given frames are solved again from the
    given seeds (:func:`reseeded`)."""
    tasks = list(tasks)

    def resolve(frames: np.ndarray, seeds: np.ndarray) -> np.ndarray:
        again = [
            reseeded(tasks[int(i)], seed)
            for i, seed in zip(np.asarray(frames, np.int64), np.asarray(seeds, np.float64), strict=True)
        ]
        return np.stack([r.theta for r in solve_tasks(again, map=map)])

    return resolve


# --------------------------------------------------------------------------------------- Table 1


def frame_distances(
    tasks: Sequence[FrameTask], thetas, annotation=None, markers: Sequence[str] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame average contact and marker distance (metres) of poses, measured as our method's.

    Parameters
    ----------
    tasks : sequence of FrameTask
        Our method's tasks (:func:`.frames.build_tasks`): the transferred contacts and their object
        contacts, the marker points and their source positions.
    thetas : (n, d) array_like
        One pose per task.
    annotation : HandPairAnnotation, optional
        Needed with ``markers``.
    markers : sequence of str, optional
        Measure only these markers (default: all of the tasks' markers).

    Returns
    -------
    contact : (n,) ndarray
        Mean distance of the posed contacts from their object contacts (NaN for a frame without any).
    marker : (n,) ndarray
        Mean distance of the posed marker points from their targets.
    """
    T = np.asarray(thetas, dtype=np.float64)
    if T.ndim != 2 or len(T) != len(tasks):
        raise SolverError(f"thetas must have one row per task ({len(tasks)}), got shape {T.shape}")
    rows = None
    if markers is not None:
        if annotation is None:
            raise SolverError("measuring named markers needs the annotation")
        rows, _ = _marker_rows(annotation, tuple(markers))
    contact = np.full(len(tasks), np.nan)
    marker = np.full(len(tasks), np.nan)
    for i, (task, theta) in enumerate(zip(tasks, T, strict=True)):
        hand = as_hand(task.hand)
        if len(task.contact_points):
            p, _ = hand.posed_points(theta, task.contact_points)
            contact[i] = np.linalg.norm(p - task.contact_targets, axis=1).mean()
        points, targets = task.marker_points, np.asarray(task.marker_targets)
        if rows is not None:
            points, targets = points[rows], targets[rows]
        if len(points):
            q, _ = hand.posed_points(theta, points)
            marker[i] = np.linalg.norm(q - targets, axis=1).mean()
    return contact, marker


@dataclass(frozen=True)
class MethodSummary:
    """One row of Table 1: a method's per-frame average distances, summarized over frames (cm).

    Attributes
    ----------
    method : str
    marker_median, marker_mean, marker_std : float
    contact_median, contact_mean, contact_std : float
        Over frames with contacts.
    frames, contact_frames : int
    marker, contact : (n,) ndarray
        The per-frame values (cm; contact NaN without contacts).
    """

    method: str
    marker_median: float
    marker_mean: float
    marker_std: float
    contact_median: float
    contact_mean: float
    contact_std: float
    frames: int
    contact_frames: int
    marker: np.ndarray = field(repr=False, compare=False)
    contact: np.ndarray = field(repr=False, compare=False)


def _summary(method: str, contact_m: np.ndarray, marker_m: np.ndarray) -> MethodSummary:
    c = 100.0 * contact_m
    m = 100.0 * marker_m
    ok = np.isfinite(c)
    cs = c[ok]

    def stats(x):
        return (float(np.median(x)), float(np.mean(x)), float(np.std(x))) if x.size else (np.nan,) * 3

    return MethodSummary(method, *stats(m[np.isfinite(m)]), *stats(cs), len(m), int(ok.sum()), m, c)


@dataclass(frozen=True)
class Table:
    """Table 1 of the paper: marker and contact distance statistics per method (cm)."""

    rows: tuple[MethodSummary, ...]
    title: str = "Baseline distance metric comparisons (cm)"

    @classmethod
    def from_distances(cls, distances: Mapping[str, tuple[np.ndarray, np.ndarray]]) -> Table:
        """The table of methods' per-frame average distances: ``{method: (contact, marker)}``, each (n,)
        in metres (contact NaN for frames without contacts), as :func:`frame_distances` measures them.
        Rows follow the mapping's order."""
        if not distances:
            raise SolverError("no methods to compare")
        return cls(
            tuple(
                _summary(method, np.asarray(contact, np.float64), np.asarray(marker, np.float64))
                for method, (contact, marker) in distances.items()
            )
        )

    def to_dict(self) -> dict:
        """The statistics as plain numbers for JSON: ``{method: {"marker_median_cm": ..., "frames": ...}}``
        (None where a statistic has no frames, e.g. contacts in a motion without any)."""
        keys = ("marker_median", "marker_mean", "marker_std", "contact_median", "contact_mean", "contact_std")

        def number(x):
            return float(x) if np.isfinite(x) else None

        return {
            r.method: {**{f"{k}_cm": number(getattr(r, k)) for k in keys}, "frames": r.frames,
                       "contact_frames": r.contact_frames}
            for r in self.rows
        }  # fmt: skip

    def row(self, method: str) -> MethodSummary:
        for r in self.rows:
            if r.method == method:
                return r
        raise KeyError(f"no method {method!r} in the table (it has {', '.join(r.method for r in self.rows)})")

    def text(self) -> str:
        """The table as plain text, in the paper's layout (median, mean ± std; marker then contact)."""
        width = max([10, *(len(r.method) for r in self.rows)]) + 2

        def cell(med, mean, std):
            return f"{med:7.3f}  {mean:7.3f} ± {std:6.3f}"

        lines = [
            self.title,
            " " * width + f"{'Marker':^25}    {'Contact':^25}",
            " " * width + f"{'Med.':>7}  {'μ ± σ':^16}    {'Med.':>7}  {'μ ± σ':^16}",  # noqa: RUF001
        ]
        for r in self.rows:
            lines.append(
                f"{r.method:<{width}}"
                + cell(r.marker_median, r.marker_mean, r.marker_std)
                + "    "
                + cell(r.contact_median, r.contact_mean, r.contact_std)
            )
        n = self.rows[0].frames if self.rows else 0
        k = self.rows[0].contact_frames if self.rows else 0
        lines.append(f"({n} frames; contact statistics over the {k} with contacts)")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.text()


def comparison_table(
    results: Mapping[str, Sequence[FrameResult]],
    tasks: Sequence[FrameTask],
    annotation=None,
    markers: Sequence[str] | None = None,
) -> Table:
    """Table 1 for several methods' per-frame results on the same frames.

    Parameters
    ----------
    results : mapping of method name -> sequence of FrameResult
        E.g. ``{"Keypoint": ..., "Keyvector": ..., "Ours": fulls}``; each must hold every task's frame
        (any order). Rows follow the mapping's order.
    tasks : sequence of FrameTask
        Our method's tasks for these frames: what is measured (:func:`frame_distances`).
    annotation, markers
        Measure only the named markers (default: the full marker set).
    """
    if not results:
        raise SolverError("no methods to compare")
    distances = {}
    for method, res in results.items():
        by_frame = {r.frame: r for r in res}
        missing = [t.frame for t in tasks if t.frame not in by_frame]
        if missing:
            raise SolverError(f"method {method!r} has no result for frames {missing[:10]}")
        thetas = np.stack([by_frame[t.frame].theta for t in tasks])
        distances[method] = frame_distances(tasks, thetas, annotation, markers)
    return Table.from_distances(distances)
