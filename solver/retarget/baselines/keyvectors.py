"""Relative keyvectors (DexPilot, Handa et al. 2019, Eq. 1-3), the second baseline of §4.6 (Kinematic
Motion Retargeting).

With keypoints at the palm and at the fingertips, keyvectors ``r_i`` run from the palm to every fingertip
and between every pair of fingertips, and the pose minimizes

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
:class:`solver.rig.skinning.PointSkin`), the solver NLopt's L-BFGS as the per-frame solves of
:mod:`.frames`.

Keyvector tasks (:class:`KeyvectorTask`) are derived from our method's root-stage tasks, as the keypoint
tasks are, and solved by the module-level :func:`solve_keyvector_frame`.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from geodesics import SurfacePoints

from ...errors import SolverError
from ...ik import ALGORITHMS, free_dofs, minimize
from ..frames import ALGORITHM, FTOL_REL, MAX_EVALUATIONS, FrameResult, FrameTask, HandSpec, as_hand
from .inputs import check_tasks, fingertip_names, given_roots, joint_mask, marker_rows

#: Keyvector classes: 0 a palm or open vector (s = 1, f = η d), 1 S1 (thumb pinch), 2 S2 (two pinching
#: primary fingers).
KEYVECTOR_CLASSES = ("open", "S1", "S2")
#: The palm keypoint's markers (their mean): on the back of the hand at the wrist and at the knuckles.
PALM_MARKERS = ("wrist_radial", "wrist_ulnar", "knuckle_radial", "knuckle_ulnar")
#: The thumb's fingertip marker (the other fingertips are DexPilot's primary fingers).
THUMB_TIP = "thumb_tip"


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
    check_tasks(tasks, annotation)
    tips = fingertip_names(annotation) if tips is None else tuple(tips)
    palm = tuple(palm)
    layout = keyvector_layout(tips)
    groups = [palm] + [(t,) for t in tips]
    flat = tuple(dict.fromkeys(n for g in groups for n in g))
    rows, owner = marker_rows(annotation, flat)
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
    R = given_roots(roots, tasks)
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
                free=joint_mask(hand.rig),
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
