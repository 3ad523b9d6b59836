"""Contact IK: the armature pose that makes a skinned hand meet an object at paired contact points.

The objective is Eq. 2 of Contact Edit (Lakshmipathy et al. 2023) with the optional terms of Eq. 3 of
the retargeting paper (Lakshmipathy et al. 2025)::

    E(θ) = λd Σ_i |p_i(θ) - t_i|² / u²          contact distance (hand point i to its target)
         + λn Σ_i (1 + n_i(θ) · m_i)            opposing normals (0 when the hand normal is -m_i)
         + λp Σ_{j not root} (θ_j - θ̄_j)²       prior to the rest (or a given) pose, root excluded
         + λm Σ_q |q(θ) - s_q|² / u²            virtual markers
         + λt Σ_v max(0, -sdf(x_v(θ)) / u)²     table or ground penetration of the hand's vertices
         + λo Σ_v max(0, -sdf_o(x_v(θ)) / u)²   penetration of the hand's vertices into the object
         + λk Σ_j ((θ_j - θ^key_j) / s_j)²      prior to a previous keyed pose (s_j = u for locations)

subject to the rig's bounds ``lower <= θ <= upper``. Sums run over points, as in the papers (denser
contact patches weigh more; Table 2 of Contact Edit). Angles are in radians.

**Keeping out of the object** (λo, with ``keep_out``) is not in either paper's objective; it is the
table term's form applied to the object itself. Eq. 2 pulls every contact point onto its target, and a
rigid skin cannot flatten: a round fingertip pad pressed onto a mug patch of the same geodesic shape
sinks its centre and its tip into the mug by millimetres to bring its rim down. With the object's
signed distance in the objective the pad rests on the surface instead, its rim a little off. λo is
large (:data:`KEEP_OUT_WEIGHT`): a vertex a millimetre inside costs what thirty contacts a centimetre
off do, so a few hundred contacts cannot pull a fingertip into the object. Only skin within
:data:`KEEP_OUT_BAND` of the surface is seen, which keeps the term cheap; skin that contacts pull right
through a thin wall (into a mug's hollow) is not pushed back, so measure the result (the add-on's solve
reports the deepest vertex). The term sees vertices: between them a face can cut a sharp edge of the
object a little deeper than any vertex is.

**Squared or plain distances.** Contact Edit's Eq. 2 squares the contact distances; the retargeting
paper's Eq. 4-5 sum plain L2 distances (Γ_MD, Γ_CD). ``norm="l2"`` gives the latter for the contact and
marker terms, smoothed at zero as ``sqrt(|d|²/u² + δ²) - δ`` (δ = :data:`L2_SMOOTHING`) so the gradient
stays continuous. Plain distances are robust: a few contacts that cannot be met (a hand of another size
touching the same object points) no longer pull the many that can away from zero.

**Normalization.** ``u`` is the manipulator's length unit: its rest bounding-box diagonal divided by
:data:`UNITS_PER_SIZE`. The papers tuned λd = 1, λn = 1, λp = 10 in Maya centimetres on hands about
25 cm across their bounding box, so ``u`` is that centimetre carried to any scale: a hand and its targets
scaled by 100 give the same energy and, since root locations are optimized in units of ``u``, the same
iterates and the same joint angles.

**Why the root is out of the prior and λp is high** (Contact Edit §4.4): rigs with 3-DOF ball joints
everywhere contort to chase contacts; a strong prior on the joints keeps the pose near rest, and
leaving the root out lets the whole hand travel to the object freely.

**The optimizer.** Every term is a sum of squares (the opposing normals too: ``1 + n·m = |n + m|² / 2``
for unit normals), so by default the energy is minimized as one (:meth:`ContactIK.residuals`) by a
trust-region method on its Gauss-Newton model (:mod:`solver.least_squares`), which needs tens of
evaluations where NLopt's quasi-Newton methods need hundreds, and which a stiff term (the keep-out)
cannot throw far. NLopt's SLSQP (the papers used NLopt), L-BFGS, MMA (the retargeting paper's choice) and
CCSA remain available by name (:data:`ALGORITHMS`; ``contact-edit bench solver`` compares them), with
the analytic gradient (reverse mode through the skinning, :class:`solver.rig.skinning.VertexSkin`) or
the papers' finite differences.

**Where a solve starts** (:mod:`solver.start`). A local solve from the hand's pose cannot reach a grasp
that needs the wrist to travel and turn (Contact Edit §7 and §9). :meth:`ContactIK.solve` therefore
starts, by default, from the grasp the contacts imply when the hand is far from them, and from the
hand's pose when it is near them already (a small edit of a solved layout gives a nearby pose).
``start="local"`` is Contact Edit's solve, from the given pose.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import nlopt
import numpy as np
from scipy import sparse

from geodesics import SurfacePoints

from .errors import SolverError, describe_ids
from .least_squares import minimize_squares
from .rig import SkinnedMesh
from .sdf import NarrowBand
from .start import grasp_start

#: The length unit is the rest bounding-box diagonal divided by this (1 cm on a 25 cm hand).
UNITS_PER_SIZE = 25.0
#: NLopt's local gradient-based algorithms the solver accepts, by name.
ALGORITHMS = {
    "slsqp": nlopt.LD_SLSQP,
    "lbfgs": nlopt.LD_LBFGS,
    "mma": nlopt.LD_MMA,
    "ccsaq": nlopt.LD_CCSAQ,
}
#: The default algorithm: the energy as a sum of squares, minimized by scipy's trust-region reflective
#: method (:mod:`solver.least_squares`); it needs the squared norm and the analytic derivatives.
TRUST_REGION = "trust-region"
#: Where :meth:`ContactIK.solve` starts: ``"local"`` from the given pose, ``"global"`` from the grasp the
#: contacts imply (:func:`solver.start.grasp_start`), ``"auto"`` the first when every patch but one is
#: within :data:`EDIT_REACH` of its targets at the given pose (an edit of a solved layout: one patch
#: moved or turned; the solve then stays near that pose, see :meth:`ContactIK.solve`), else the second.
STARTS = ("auto", "local", "global")
#: A patch still meets its targets, for ``start="auto"``, when its contacts' median distance to them is
#: within this many units u (1 cm on a life-size hand): a solve leaves a pad whose targets it cannot all
#: meet (a patch draped over a box's edge) several millimetres from them, touching, and an edit of such
#: a layout is still an edit (with 5 mm, the alien hand's box held 7-8 mm off its patches was solved
#: afresh after a 25° turn of one pad, and came back turned 67°).
EDIT_REACH = 1.0
#: A patch touches when its contacts' median distance to their targets is at most this, in units u (2 mm
#: on a life-size hand); :attr:`SolveResult.unreached` names the patches that do not.
TOUCH_DISTANCE = 0.2
#: Pressing (:meth:`ContactIK._pressed`) goes on for the patches farther than this from their targets, in
#: units u (1.5 mm on a life-size hand): a patch that barely touches by :data:`TOUCH_DISTANCE` is
#: pressed on until it sits on them.
PRESS_DISTANCE = 0.15
#: Pressing is not kept when it pushes the skin deeper into the table or the object than this many
#: units u, or than it was before pressing if that was deeper: under 1 mm on hands up to 31 cm across
#: (0.95 mm on the procedural human hand, whose bounding box is 29.6 cm across).
PRESS_DEPTH = 0.08
#: While a patch is short of touching, the contacts weigh this many times more in the next round of
#: pressing (:meth:`ContactIK._pressed`), of at most :data:`PRESS_ROUNDS`.
PRESS_FACTOR = 10.0
PRESS_ROUNDS = 3
#: Evaluations of each round of pressing: it starts near its end.
PRESS_EVALUATIONS = 50
#: A round of pressing stops when an evaluation improves its energy by less than this fraction (or the
#: solve's own, if looser): it is to bring the patches on, and the last hundredths of a millimetre took
#: tens of evaluations (the Rigify hand's rounds: 510 evaluations over 12 layouts, 396 with this).
PRESS_FTOL = 1e-4
#: Evaluations of each solve that looks for the patch out of reach (:meth:`ContactIK._out_of_reach`),
#: pressing included: it starts from the solved pose, and must not take longer than the solve.
EXPLAIN_EVALUATIONS = 2 * PRESS_EVALUATIONS
#: What NLopt raises when it stops short of convergence (roundoff, or its generic failure). Its 2.9
#: wheels, which the extension bundles, raise the generic failure as their own ``nlopt.runtime_error``
#: (not a RuntimeError; nor can it be pickled, so a worker process could not even report it).
STOPPED_SHORT = (
    nlopt.RoundoffLimited,
    RuntimeError,
    *([nlopt.runtime_error] if hasattr(nlopt, "runtime_error") else []),
)
#: Default stopping rule: relative change of the energy, and a cap on objective evaluations.
FTOL_REL = 1e-9
#: The trust region's: its Gauss-Newton steps settle in few evaluations, and a tighter rule only buys
#: tiny steps on the keep-out's stiff walls.
TRUST_REGION_FTOL = 1e-6
#: How the objective's gradient is computed.
GRADIENTS = ("analytic", "finite-difference", "central-difference")
MAX_EVALUATIONS = 2000
#: How the contact and marker terms weigh a distance d: d²/u² (Contact Edit Eq. 2) or d/u (Eq. 4-5 of
#: the retargeting paper).
NORMS = ("squared", "l2")
#: Smoothing δ of the L2 norm at zero, in units of u (0.5 mm on a life-size hand).
L2_SMOOTHING = 0.05
#: The default λo (:attr:`Weights.o`), used whenever a hand is kept out of an object (``keep_out``):
#: 1 mm (0.1 u) inside weighs 3000 · 0.01 = 30, as thirty contacts 1 cm off do (λd = 1).
KEEP_OUT_WEIGHT = 3000.0
#: The keep-out term sees skin within this many units u of the object's surface (5 mm on a life-size
#: hand): deeper inside than that, a vertex is not pushed out (see :meth:`solver.MeshSDF.evaluate`).
KEEP_OUT_BAND = 0.5


@dataclass(frozen=True)
class Weights:
    """The λ of each term (non-negative; zero switches a term off).

    d: contact distance, n: opposing normals, p: prior to the rest or given pose (root excluded),
    m: virtual markers, t: table or ground penetration, k: prior to a previous keyed pose,
    o: penetration into the object (with ``ContactIK(keep_out=...)``).
    """

    d: float = 1.0
    n: float = 1.0
    p: float = 10.0
    m: float = 1.0
    t: float = 1.0
    k: float = 10.0
    o: float = KEEP_OUT_WEIGHT

    def __post_init__(self):
        for name in ("d", "n", "p", "m", "t", "k", "o"):
            value = getattr(self, name)
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise SolverError(f"weight λ{name} must be a number, got {value!r}") from None
            if not (np.isfinite(value) and value >= 0):
                raise SolverError(f"weight λ{name} must be finite and non-negative, got {value!r}")
            object.__setattr__(self, name, value)


@dataclass(frozen=True)
class Markers:
    """Virtual markers: points on the hand (k) and where each should be (k, 3)."""

    points: SurfacePoints
    targets: np.ndarray


@dataclass(frozen=True)
class Progress:
    """What a progress callback receives after each objective evaluation."""

    iteration: int
    energy: float
    terms: dict[str, float]
    theta: np.ndarray


@dataclass(frozen=True)
class SolveResult:
    """The outcome of :meth:`ContactIK.solve`.

    Attributes
    ----------
    theta : (d,) ndarray
        The best pose found (never NaN).
    energy : float
        Its energy; ``terms`` splits it by term (weighted).
    iterations : int
        Objective evaluations.
    seconds : float
        Wall-clock time of the solve.
    distances : (k,) ndarray
        Per contact, the distance from the posed hand point to its target (scene units).
    start_energy : float
        The energy of the (clipped) start pose.
    status : str
        ``"converged"``, ``"max evaluations"``, ``"cancelled"``, ``"stopped"`` (NLopt gave up, e.g.
        on round-off; the best pose is still returned), ``"no free DOFs"`` (nothing was allowed to move)
        or ``"unchanged"`` (the optimizer found nothing better than the start, to ``ftol_rel``: a solve
        that moved nothing never reports convergence).
    gaps : dict
        Per contact patch (``ContactIK(patches=...)``, else one patch ``"contacts"``), the median
        distance of its contacts from their targets (scene units).
    unreached : tuple of str
        The patches whose gap is above :data:`TOUCH_DISTANCE`: those the pose does not bring onto the
        object.
    out_of_reach : tuple of str
        Why: the patch the hand cannot reach together with the others (solved without it, every other
        patch touches), or when there is no one such patch, all the unreached ones.
    start : str
        Where the solve started: ``"local"`` (the given pose) or ``"global"`` (the grasp the contacts
        imply).
    """

    theta: np.ndarray
    energy: float
    terms: dict[str, float]
    iterations: int
    seconds: float
    distances: np.ndarray
    status: str
    start_energy: float = field(default=np.nan)
    gaps: dict[str, float] = field(default_factory=dict)
    unreached: tuple[str, ...] = ()
    out_of_reach: tuple[str, ...] = ()
    start: str = "local"


def _array(value, shape_tail, what: str) -> np.ndarray:
    a = np.array(value, dtype=np.float64)
    if a.ndim != 1 + len(shape_tail) or a.shape[1:] != shape_tail:
        raise SolverError(f"{what} must have shape (k, {', '.join(map(str, shape_tail))}), got {a.shape}")
    return a


def _targets(k: int, target_points, target_normals) -> tuple[np.ndarray, np.ndarray]:
    """The k contacts' target points (k, 3) and unit normals (k, 3), checked."""
    if k == 0:
        raise SolverError("there are no contacts: hand_points is empty")
    T = _array(target_points, (3,), "target_points")
    N = _array(target_normals, (3,), "target_normals")
    if len(T) != k or len(N) != k:
        raise SolverError(
            f"got {k} hand points but {len(T)} target points and {len(N)} target normals; they pair up "
            "one to one"
        )
    for what, a in (("target points", T), ("target normals", N)):
        bad = np.flatnonzero(~np.all(np.isfinite(a), axis=1))
        if bad.size:
            raise SolverError(f"{what} of contacts {describe_ids(bad)} are NaN or infinite", contacts=bad)
    length = np.linalg.norm(N, axis=1)
    bad = np.flatnonzero(length == 0)
    if bad.size:
        raise SolverError(f"target normals of contacts {describe_ids(bad)} are zero", contacts=bad)
    return T, N / length[:, None]


def _method(algorithm: str | None, gradient: str, norm: str) -> tuple[str, str, str]:
    """(algorithm, gradient, norm), checked; the algorithm by default :data:`TRUST_REGION` where it
    applies (the squared norm, analytic derivatives), else ``"slsqp"``."""
    if gradient not in GRADIENTS:
        raise SolverError(f"gradient must be one of {', '.join(GRADIENTS)}, got {gradient!r}")
    if norm not in NORMS:
        raise SolverError(f"norm must be one of {', '.join(NORMS)}, got {norm!r}")
    squares = norm == "squared" and gradient == "analytic"
    if algorithm is None:
        algorithm = TRUST_REGION if squares else "slsqp"
    if algorithm == TRUST_REGION and not squares:
        raise SolverError(
            f"the {TRUST_REGION} algorithm needs norm='squared' and the analytic gradient; use one of "
            f"{', '.join(ALGORITHMS)}"
        )
    if algorithm != TRUST_REGION and algorithm not in ALGORITHMS:
        raise SolverError(
            f"unknown algorithm {algorithm!r}; use {TRUST_REGION} or one of {', '.join(ALGORITHMS)}"
        )
    return algorithm, gradient, norm


def _patches(patches, k: int) -> tuple[tuple[str, ...], np.ndarray]:
    """(names, patch index (k,) per contact) of ``patches``, a sequence of (name, count), or one patch."""
    if patches is None:
        return ("contacts",), np.zeros(k, np.int64)
    try:
        names = tuple(str(name) for name, _ in patches)
        counts = np.array([int(count) for _, count in patches], dtype=np.int64)
    except (TypeError, ValueError):
        raise SolverError("patches must be (name, count) pairs, one per patch, in contact order") from None
    if counts.sum() != k or np.any(counts <= 0) or len(set(names)) != len(names):
        raise SolverError(
            f"patches must name each patch once and count its contacts (at least one each), {k} in all; "
            f"got {len(names)} patches holding {int(counts.sum())} contacts"
        )
    return names, np.repeat(np.arange(len(names)), counts)


def _contact_weights(values, k: int) -> np.ndarray:
    """(k,) the contacts' weight factors, checked (default ones)."""
    if values is None:
        return np.ones(k)
    c = np.array(values, dtype=np.float64).reshape(-1)
    if c.size != k:
        raise SolverError(f"contact_weights must give one factor per contact ({k}), got {c.size}")
    bad = np.flatnonzero(~(np.isfinite(c) & (c >= 0)))
    if bad.size:
        raise SolverError(f"contact_weights of contacts {describe_ids(bad)} are not finite and non-negative")
    return c


def movable_vertices(skin: SkinnedMesh) -> np.ndarray:
    """Indices of the skin's vertices that a solve can move: those weighted to a deformer whose skinning
    matrix changes with some unlocked DOF. The others (a one-mesh character's chest, which keeps Blender's
    pose) add only a constant to a keep-out term, so it leaves them out."""
    rig = skin.rig
    step = np.where(rig.locked, 0.0, np.where(rig.is_rotation, 0.3, 0.1 * skin.size))
    before = rig.kinematics(rig.rest, derivatives=False).skinning
    after = rig.kinematics(rig.rest + step, derivatives=False).skinning
    moved = np.flatnonzero(np.abs(after - before).max(axis=(1, 2)) > 0)
    weights = sparse.csc_matrix(skin.deformer_weights)[:, moved].tocsr()
    weights.eliminate_zeros()
    return np.flatnonzero(np.diff(weights.indptr) > 0)


def free_dofs(rig, free=None) -> np.ndarray:
    """(k,) indices of the DOFs a solve may change: those flagged in ``free`` ((d,) bool; default all)
    that the rig does not lock. Raises SolverError for a mask of another length."""
    mask = np.ones(rig.n_dofs, bool) if free is None else np.array(free, dtype=bool).reshape(-1)
    if mask.size != rig.n_dofs:
        raise SolverError(f"free needs {rig.n_dofs} flags (one per DOF), got {mask.size}")
    return np.flatnonzero(mask & ~rig.locked)


class ContactIK:
    """The contact IK problem for one hand and one set of paired contacts.

    Parameters
    ----------
    hand : SkinnedMesh
        The manipulator (e.g. from :func:`solver.hands.make_hand`).
    hand_points : SurfacePoints
        k contact points on ``hand.mesh`` (intrinsic: face and barycentric coordinates at rest).
    target_points : (k, 3) array_like
        Where each hand point should be, on the object.
    target_normals : (k, 3) array_like
        The object's outward normals there (normalized here).
    weights : Weights
    prior : (d,) array_like, optional
        The pose the prior pulls towards (default: the rest pose).
    markers : Markers, optional
    obstacle : HalfSpace or Box, optional
        A table or the ground: anything with ``evaluate(points) -> (sdf, gradient)``.
    keep_out : MeshSDF, optional
        The object itself (closed, in the hand's space): its inside costs λo, within
        :data:`KEEP_OUT_BAND` of its surface (see the module docstring). Anything with
        ``evaluate(points, band=np.inf)`` works here too.
    keyed : (d,) array_like, optional
        A previous keyed pose for the λk prior.
    unit : float, optional
        The length unit ``u`` (default: ``hand.size / UNITS_PER_SIZE``).
    algorithm : str, optional
        :data:`TRUST_REGION` (the default with the squared norm and analytic derivatives) or one of NLopt's
        :data:`ALGORITHMS` (the default otherwise: ``"slsqp"``).
    patches : sequence of (str, int), optional
        The contacts' patches, in order: names and how many consecutive contacts each holds (default:
        one patch ``"contacts"``). A global start weighs each patch alike, the solve presses a patch
        left short of touching, and the result names the patches it does not bring onto the object.
    contact_weights : (k,) array_like, optional
        Per contact, a non-negative factor on its λd and λn (default 1): some contacts matter more.
    gradient : str
        ``"analytic"``, or for comparison with the papers (which used finite differences)
        ``"finite-difference"`` (forward: one energy evaluation per free DOF) or ``"central-difference"``
        (two per free DOF).
    norm : str
        ``"squared"`` (Contact Edit) or ``"l2"`` (the retargeting paper): see :data:`NORMS`.

    Raises
    ------
    SolverError
        For empty, NaN or mismatched contacts, zero target normals, bad weights, poses of the wrong
        size, or an unknown algorithm; the message names the offending contacts or DOFs.
    """

    def __init__(
        self,
        hand: SkinnedMesh,
        hand_points: SurfacePoints,
        target_points,
        target_normals,
        weights: Weights | None = None,
        *,
        prior=None,
        markers: Markers | None = None,
        obstacle=None,
        keep_out=None,
        keyed=None,
        unit: float | None = None,
        algorithm: str | None = None,
        gradient: str = "analytic",
        norm: str = "squared",
        patches=None,
        contact_weights=None,
    ):
        if not isinstance(hand, SkinnedMesh):
            raise SolverError(
                f"hand must be a SkinnedMesh (e.g. hands.make_hand()), got {type(hand).__name__}"
            )
        self.hand = hand
        rig = hand.rig
        if not isinstance(hand_points, SurfacePoints):
            raise SolverError(
                f"hand_points must be geodesics.SurfacePoints, got {type(hand_points).__name__}"
            )
        self.hand_points = hand_points
        self.target_points, self.target_normals = _targets(len(hand_points), target_points, target_normals)
        self.weights = weights if weights is not None else Weights()
        if not isinstance(self.weights, Weights):
            raise SolverError(f"weights must be a solver.Weights, got {type(self.weights).__name__}")
        self.prior = rig.rest if prior is None else rig.check_theta(prior, "prior")
        self.keyed = None if keyed is None else rig.check_theta(keyed, "keyed")
        self.algorithm, self.gradient, self.norm = _method(algorithm, gradient, norm)
        self.patch_names, self.patch_of = _patches(patches, len(hand_points))
        self.contact_weights = _contact_weights(contact_weights, len(hand_points))
        self.unit = hand.size / UNITS_PER_SIZE if unit is None else float(unit)
        if not (np.isfinite(self.unit) and self.unit > 0):
            raise SolverError(f"unit must be a positive length, got {unit!r}")
        sets = [hand_points]
        self.markers = markers
        if markers is not None:
            targets = _array(markers.targets, (3,), "marker targets")
            if len(targets) != len(markers.points) or not np.all(np.isfinite(targets)):
                raise SolverError(
                    f"got {len(markers.points)} marker points but {len(targets)} targets (they must pair "
                    "up and be finite)"
                )
            self._marker_targets = targets
            sets.append(markers.points)
        for name, solid in (("obstacle", obstacle), ("keep_out", keep_out)):
            if solid is not None and not callable(getattr(solid, "evaluate", None)):
                raise SolverError(
                    f"{name} must have evaluate(points) -> (sdf, gradient), e.g. solver.sdf.Box or MeshSDF"
                )
        self.obstacle, self.keep_out = obstacle, keep_out
        self._solids = []  # what the hand's vertices stay out of: (term, weight, signed distance)
        self._exact = []  # the same, exact at any depth (pressing's check), each followed as the skin moves
        if obstacle is not None:  # its exact distance, queried only where the skin may have come inside
            table = NarrowBand(obstacle, np.inf).evaluate  # exact at any depth: the penalty and the check
            self._solids.append(("table", self.weights.t, table))
            self._exact.append(table)
        if keep_out is not None:
            inside = NarrowBand(keep_out, KEEP_OUT_BAND * self.unit).evaluate
            self._solids.append(("penetration", self.weights.o, inside))
            self._exact.append(NarrowBand(keep_out, np.inf).evaluate)
        extra = movable_vertices(hand) if self._solids else None
        self._skin = hand.point_skin(sets, extra)
        # Internal variables: locations in units of u, angles in radians.
        self._scale = np.where(rig.is_rotation, 1.0, self.unit)
        self._prior_mask = rig.dof_bone != 0

    # ------------------------------------------------------------------ objective

    def energy(self, theta) -> tuple[float, dict[str, float]]:
        """Energy at θ (d,) and its terms (dict of floats, summing to the energy)."""
        energy, terms, _ = self._evaluate(theta, False, None)
        return energy, terms

    def energy_and_gradient(self, theta, dofs=None) -> tuple[float, dict[str, float], np.ndarray]:
        """Energy at θ (d,), its terms (dict) and dE/dθ (d,): exact for the DOFs ``dofs`` (default all);
        a rig may leave the others' derivatives out (zero)."""
        return self._evaluate(theta, True, dofs)

    def _evaluate(self, theta, with_gradient: bool, dofs) -> tuple[float, dict, np.ndarray | None]:
        """:meth:`energy_and_gradient`, or only the energy and terms (gradient None)."""
        rig = self.hand.rig
        t = rig.check_theta(theta)
        w = self.weights
        kin = rig.kinematics(t, with_gradient, dofs)
        skin = self._skin
        V = skin.vertices.positions(kin)
        terms: dict[str, float] = {}
        adjoint = np.zeros_like(V)  # dE/dV of the posed vertices
        grad = np.zeros(rig.n_dofs)
        contacts = skin.sets[0]
        p, n, aux = contacts.geometry(V)
        c = self.contact_weights
        value, d_diff = self._distance_term(p - self.target_points, c)
        terms["distance"] = w.d * value
        terms["normal"] = w.n * float(c @ (1.0 + np.einsum("ki,ki->k", n, self.target_normals)))
        if with_gradient:
            adjoint += contacts.adjoint(n, aux, w.d * d_diff, w.n * c[:, None] * self.target_normals)
        if self.markers is not None:
            markers = skin.sets[1]
            q, qn, qaux = markers.geometry(V)
            value, d_diff = self._distance_term(q - self._marker_targets)
            terms["marker"] = w.m * value
            if with_gradient:
                adjoint += markers.adjoint(qn, qaux, w.m * d_diff, None)
        for name, weight, evaluate in self._solids:
            rows = skin.extra_rows
            sd, sd_grad = evaluate(V[rows])
            depth = np.maximum(-sd, 0.0) / self.unit
            terms[name] = weight * float(np.sum(depth**2))
            if with_gradient:
                adjoint[rows] += (-2 * weight / self.unit * depth)[:, None] * sd_grad  # distinct vertices
        dp = np.where(self._prior_mask, t - self.prior, 0.0)
        terms["prior"] = w.p * float(np.sum(dp**2))
        grad += 2 * w.p * dp
        if self.keyed is not None:
            dk = (t - self.keyed) / self._scale
            terms["keyed"] = w.k * float(np.sum(dk**2))
            grad += 2 * w.k * dk / self._scale
        energy = float(sum(terms.values()))
        if not with_gradient:
            return energy, terms, None
        grad += skin.vertices.vjp(kin, adjoint)
        return energy, terms, grad

    def _distance_term(self, diff: np.ndarray, factors=None) -> tuple[float, np.ndarray]:
        """The sum over rows of ``diff`` (k, 3) in the chosen norm, each row times its factor (k,)
        (default 1), and its gradient (k, 3)."""
        u2 = self.unit**2
        c = np.ones(len(diff)) if factors is None else factors
        if self.norm == "squared":
            return float(c @ np.einsum("ki,ki->k", diff, diff)) / u2, (2.0 / u2 * c)[:, None] * diff
        r = np.sqrt(np.einsum("ki,ki->k", diff, diff) / u2 + L2_SMOOTHING**2)
        return float(c @ (r - L2_SMOOTHING)), diff * (c / (u2 * r))[:, None]

    def residuals(self, theta, dofs=None, solids: bool = True) -> tuple[np.ndarray, np.ndarray, float, dict]:
        """The energy as a sum of squares (norm ``"squared"``): residuals r (m,), their Jacobian (m, n)
        with respect to the DOFs ``dofs`` (n,) (default all), the energy ``Σ r²`` and its terms.

        The rows are the contacts' offsets ``√λd (p - t) / u``, the normals' ``√(λn / 2) (n + m)``, the
        markers', the priors' and, with ``solids``, a row per vertex inside the table or the object
        (``√λ depth / u``; a vertex outside adds nothing, so it has no row). Without ``solids`` the energy
        and terms leave those out.
        """
        if self.norm != "squared":
            raise SolverError("residuals need the squared norm (norm='squared')")
        rig = self.hand.rig
        t = rig.check_theta(theta)
        index = np.arange(rig.n_dofs) if dofs is None else np.asarray(dofs, dtype=np.int64)
        w, u, skin = self.weights, self.unit, self._skin
        kin = rig.kinematics(t, True, index)
        V = skin.vertices.positions(kin)
        rows_r, rows_J, terms = [], [], {}

        def points(point_set, targets, normals, w_p, w_n, c):
            p, n, aux = point_set.geometry(V)
            dp, dn = point_set.jacobian(n, aux, skin.vertices.jacobian(kin, point_set.rows)[:, :, index])
            s = np.sqrt(c)[:, None]
            rows_r.append((np.sqrt(w_p) / u * s * (p - targets)).ravel())
            rows_J.append(np.sqrt(w_p) / u * (s[:, :, None] * dp).reshape(-1, index.size))
            if normals is not None:
                rows_r.append((np.sqrt(w_n / 2) * s * (n + normals)).ravel())
                rows_J.append(np.sqrt(w_n / 2) * (s[:, :, None] * dn).reshape(-1, index.size))
            return p, n

        c = self.contact_weights
        p, n = points(skin.sets[0], self.target_points, self.target_normals, w.d, w.n, c)
        terms["distance"] = w.d * float(c @ np.sum((p - self.target_points) ** 2, axis=1)) / u**2
        terms["normal"] = w.n * float(c @ (1.0 + np.einsum("ki,ki->k", n, self.target_normals)))
        if self.markers is not None:
            ones = np.ones(len(self._marker_targets))
            q, _ = points(skin.sets[1], self._marker_targets, None, w.m, 0.0, ones)
            terms["marker"] = w.m * float(np.sum((q - self._marker_targets) ** 2)) / u**2
        for name, weight, evaluate in self._solids if solids else ():
            rows = skin.extra_rows
            sd, gradient = evaluate(V[rows])
            inside = np.flatnonzero(~(sd >= 0))  # a NaN distance too: the energy must say so
            depth = -sd[inside] / u
            terms[name] = weight * float(np.sum(depth**2))
            J = np.zeros((0, index.size))
            if inside.size:
                Jv = skin.vertices.jacobian(kin, rows[inside])[:, :, index]
                J = -np.sqrt(weight) / u * np.einsum("vi,vid->vd", gradient[inside], Jv)
            rows_r.append(np.sqrt(weight) * depth)
            rows_J.append(J)
        dp = np.where(self._prior_mask, t - self.prior, 0.0)
        terms["prior"] = w.p * float(np.sum(dp**2))
        rows_r.append(np.sqrt(w.p) * dp)
        rows_J.append(np.sqrt(w.p) * np.eye(rig.n_dofs)[:, index] * self._prior_mask[:, None])
        if self.keyed is not None:
            dk = (t - self.keyed) / self._scale
            terms["keyed"] = w.k * float(np.sum(dk**2))
            rows_r.append(np.sqrt(w.k) * dk)
            rows_J.append(np.sqrt(w.k) * np.eye(rig.n_dofs)[:, index] / self._scale[:, None])
        return np.concatenate(rows_r), np.concatenate(rows_J), float(sum(terms.values())), terms

    def gaps(self, theta) -> dict[str, float]:
        """Per contact patch, the median distance of its contacts from their targets at θ (d,): how far
        the patch as a whole is from touching (one contact touching does not make a pad touch)."""
        d = self.distances(theta)
        return {name: float(np.median(d[self.patch_of == i])) for i, name in enumerate(self.patch_names)}

    def distances(self, theta) -> np.ndarray:
        """(k,) distance of each posed hand point from its target at θ (d,)."""
        p, _ = self.hand.posed_points(theta, self.hand_points)
        return np.linalg.norm(p - self.target_points, axis=1)

    # ------------------------------------------------------------------ solve

    def solve(
        self,
        theta0=None,
        free=None,
        progress: Callable[[Progress], bool | None] | None = None,
        max_evaluations: int = MAX_EVALUATIONS,
        ftol_rel: float | None = None,
        start: str = "auto",
        press: bool | None = None,
    ) -> SolveResult:
        """Minimize the energy from θ0 over the free DOFs.

        Parameters
        ----------
        theta0 : (d,) array_like, optional
            Start pose (default: the rest pose), clipped into the bounds.
        free : (d,) array_like of bool, optional
            DOFs to solve (default: all); the others keep their θ0 value. Locked DOFs are never free.
            Staged solves: the root only first (``free = rig.dof_bone == 0``), then unlock more.
        progress : callable, optional
            Called with a :class:`Progress` after each evaluation (the best pose so far, by the whole
            energy; while pressing, by the pressed energy); returning True cancels the solve, which then
            returns the best pose found so far.
        max_evaluations : int
            For the whole solve, its start included.
        ftol_rel : float, optional
            Stop when an evaluation improves the energy by less than this fraction (default
            :data:`TRUST_REGION_FTOL` for the trust region, :data:`FTOL_REL` for NLopt's algorithms).
        start : str
            One of :data:`STARTS`: from θ0 (``"local"``), from the grasp the contacts imply
            (``"global"``, :mod:`solver.start`; with the :data:`TRUST_REGION` algorithm and a free root),
            or the second when the hand is far from its contacts (``"auto"``). An ``"auto"`` start from a
            given θ0 near its contacts (an edit's re-solve) also stays near θ0, unless the problem has a
            keyed pose of its own: the λk term pulls towards θ0. A solved pose pressed onto its patches
            is not a minimum of the plain energy, and a re-solve from it without that term relaxed away:
            a 25° turn of one pad turned the alien hand on a box by up to 70°, 12° at most with it.
        press : bool, optional
            Press the patches the solve leaves short of touching onto their targets (:meth:`_pressed`;
            default: with the :data:`TRUST_REGION` algorithm). Off, the solve minimizes the energy of
            the given weights alone (Contact Edit's Eq. 2 with ``start="local"`` and its weights).

        Returns
        -------
        SolveResult
            Its energy and terms are those of the given weights, pressed or not (with the λk term
            towards θ0 of an ``"auto"`` start that stayed near it).
        """
        clock = time.perf_counter()
        if ftol_rel is None:
            ftol_rel = TRUST_REGION_FTOL if self.algorithm == TRUST_REGION else FTOL_REL
        if press is None:
            press = self.algorithm == TRUST_REGION
        if start == "auto" and theta0 is not None and self.keyed is None:
            rig = self.hand.rig
            theta = rig.clip(rig.check_theta(theta0, "theta0"))
            if self._start_mode(start, theta, free_dofs(rig, free)) == "local":
                near = self._subset(
                    np.ones(len(self.contact_weights), bool), self.contact_weights, keyed=theta
                )
                return near.solve(theta, free, progress, max_evaluations, ftol_rel, "local", press)
        result = self._solve_pressed(theta0, free, progress, max_evaluations, ftol_rel, start, press)
        if len(result.unreached) > 1 and result.status != "cancelled":
            why = self._out_of_reach(result, free, max_evaluations, ftol_rel, press)
            result = replace(result, out_of_reach=why)
        return replace(result, seconds=time.perf_counter() - clock)

    def _solve_pressed(self, theta0, free, progress, max_evaluations, ftol_rel, start, press) -> SolveResult:
        """:meth:`_solve`, then with ``press`` :meth:`_pressed`."""
        result = self._solve(theta0, free, progress, max_evaluations, ftol_rel, start)
        return self._pressed(result, free, progress, max_evaluations, ftol_rel) if press else result

    def _pressed(self, result: SolveResult, free, progress, max_evaluations, ftol_rel) -> SolveResult:
        """``result`` with the patches it leaves short of touching pressed onto their targets.

        With a strong prior (Contact Edit's λp) and patches placed by eye, a patch's best compromise may hover
        a few millimetres off the object: a curled finger's prior outweighs its last few millimetres. A person
        asked for the patch to touch, so while a patch lies farther than :data:`PRESS_DISTANCE` from its
        targets every contact's weight grows by :data:`PRESS_FACTOR` (the prior and the solids weigh that much
        less) and the solve goes on from the best pose so far, :data:`PRESS_ROUNDS` times at most, each of at
        most :data:`PRESS_EVALUATIONS` (to :data:`PRESS_FTOL`). A round's pose is kept only if it leaves fewer
        patches unreached, or as many nearer touching in all (:meth:`_standing`), without pushing the skin in
        (:data:`PRESS_DEPTH`). A round that pushes the skin in is tried again with the weights grown by the
        factor's square root: a pad whose targets wrap over an edge of the object can come down only as far
        as its fingertip may sink. A round that is not kept does not end pressing: the next presses harder
        (the alien hand's pad on a box's edge went from 2.54 to 2.61 mm at ten times, then to 2.35 mm at a
        hundred). Every patch is pressed, not only the short ones: a patch left as it was weighs less than
        those pressed, and slipped off in their round (the Rigify hand's palm on a cylinder, from 1.3 to 3.7
        mm); and a patch out of reach drags the others no more than it did in the solve."""
        factors, allowed, count = self.contact_weights, None, result.iterations
        for _ in range(PRESS_ROUNDS):
            if (
                not self._short(result)
                or count >= max_evaluations
                or result.status in ("cancelled", "no free DOFs")
            ):
                break
            if allowed is None:
                allowed = max(self._depth(result.theta), PRESS_DEPTH * self.unit)
            for factor in (PRESS_FACTOR, np.sqrt(PRESS_FACTOR)):
                more, count = self._press_round(
                    result, factors * factor, free, progress, count, max_evaluations, ftol_rel
                )
                if (
                    self._depth(more.theta) <= allowed
                    or count >= max_evaluations
                    or more.status == "cancelled"
                ):
                    break
            factors = factors * factor
            if self._standing(more) < self._standing(result) and self._depth(more.theta) <= allowed:
                energy, terms = self.energy(more.theta)
                status = more.status if more.status in ("cancelled", "stopped") else result.status
                result = replace(
                    more, energy=energy, terms=terms, status=status,
                    start_energy=result.start_energy, start=result.start,
                )  # fmt: skip
            elif more.status == "cancelled":
                result = replace(result, status="cancelled")
        return replace(result, iterations=count)

    def _press_round(self, result, factors, free, progress, count, max_evaluations, ftol_rel):
        """A round of :meth:`_pressed` from ``result``'s pose, each contact weighted by ``factors`` (k,),
        after ``count`` evaluations of the solve: the pressed result, and the evaluations counted with it."""
        budget = min(int(max_evaluations) - count, PRESS_EVALUATIONS)
        told = None if progress is None else _counting_on(progress, count)
        more = self._subset(np.ones(len(factors), bool), factors)._solve(
            result.theta, free, told, budget, max(ftol_rel, PRESS_FTOL), "local"
        )
        return more, count + more.iterations

    def _depth(self, theta) -> float:
        """How deep the skin the solve moves lies inside the table or the object at θ (d,) (0 outside;
        exact, where the keep-out term's narrow band sees no deeper than its band; the object queried
        again only where the skin may have come inside since the last call)."""
        if not self._exact:
            return 0.0
        V = self._skin.vertices.positions(self.hand.rig.kinematics(theta, derivatives=False))
        return max(0.0, -min(float(evaluate(V[self._skin.extra_rows])[0].min()) for evaluate in self._exact))

    def _short(self, result: SolveResult) -> bool:
        """Whether pressing goes on from ``result``: a patch lies farther than :data:`PRESS_DISTANCE`."""
        return any(gap > PRESS_DISTANCE * self.unit for gap in result.gaps.values())

    def _standing(self, result: SolveResult) -> tuple[int, float]:
        """How far a result is from every patch touching, to compare two (lower is nearer): how many
        patches are unreached, then the sum of their gaps beyond :data:`PRESS_DISTANCE`."""
        short = sum(max(gap - PRESS_DISTANCE * self.unit, 0.0) for gap in result.gaps.values())
        return len(result.unreached), float(short)

    def _solve(self, theta0, free, progress, max_evaluations, ftol_rel, start) -> SolveResult:
        """:meth:`solve`, the unreached patches left unexplained."""
        rig = self.hand.rig
        clock = time.perf_counter()
        theta = rig.clip(rig.rest if theta0 is None else rig.check_theta(theta0, "theta0"))
        index = free_dofs(rig, free)
        if start not in STARTS:
            raise SolverError(f"start must be one of {', '.join(STARTS)}, got {start!r}")
        start_energy, start_terms = self.energy(theta)
        tally = _Tally(progress, theta, start_energy, start_terms)
        mode = self._start_mode(start, theta, index)

        def judge(t):
            energy, terms = self.energy(t)
            if tally.offer(t, energy, terms):
                raise _Cancelled
            return energy

        try:
            if mode == "global":
                theta = grasp_start(
                    self, theta, index,
                    lambda t, dofs, count: self._descend(t, dofs, count, ftol_rel, tally, solids=False),
                    judge,
                )  # fmt: skip
            budget = max(int(max_evaluations) - tally.count, 1)
            status = self._descend(theta, index, budget, ftol_rel, tally, status=True)
        except _Cancelled:
            status = "cancelled"
        if status == "converged" and start_energy - tally.energy <= ftol_rel * max(abs(start_energy), 1.0):
            status = "unchanged"  # nothing better than where it started (to the stopping tolerance)
        gaps = self.gaps(tally.theta)
        unreached = tuple(name for name, gap in gaps.items() if gap > TOUCH_DISTANCE * self.unit)
        return SolveResult(
            theta=tally.theta,
            energy=tally.energy,
            terms=tally.terms,
            iterations=tally.count,
            seconds=time.perf_counter() - clock,
            distances=self.distances(tally.theta),
            status=status if index.size else "no free DOFs",
            start_energy=float(start_energy),
            gaps=gaps,
            unreached=unreached,
            out_of_reach=unreached,
            start=mode,
        )

    def _out_of_reach(self, result: SolveResult, free, max_evaluations, ftol_rel, press) -> tuple[str, ...]:
        """The patch that keeps the others from touching (see :attr:`SolveResult.out_of_reach`): each
        unreached patch in turn, farthest first, left out of a local solve from the result's pose (of at
        most :data:`EXPLAIN_EVALUATIONS`); the first whose absence lets every other patch touch, else all
        the unreached."""
        budget = min(int(max_evaluations), EXPLAIN_EVALUATIONS)
        for name in sorted(result.unreached, key=result.gaps.get, reverse=True):
            others = self._subset(self.patch_of != self.patch_names.index(name), self.contact_weights)
            alone = others._solve_pressed(result.theta, free, None, budget, ftol_rel, "local", press)
            if not alone.unreached:
                return (name,)
        return result.unreached

    def _subset(self, keep: np.ndarray, factors: np.ndarray, keyed=None) -> ContactIK:
        """This problem with only the contacts ``keep`` (k,) bool, weighted by ``factors`` (k,) (and with
        ``keyed`` (d,) as its keyed pose, if given)."""
        kept = np.unique(self.patch_of[keep])
        return ContactIK(
            self.hand, self.hand_points[np.flatnonzero(keep)], self.target_points[keep],
            self.target_normals[keep], self.weights, prior=self.prior, markers=self.markers,
            obstacle=self.obstacle, keep_out=self.keep_out, keyed=self.keyed if keyed is None else keyed,
            unit=self.unit, algorithm=self.algorithm, gradient=self.gradient, norm=self.norm,
            patches=[(self.patch_names[i], int(np.sum(self.patch_of[keep] == i))) for i in kept],
            contact_weights=factors[keep],
        )  # fmt: skip

    def _start_mode(self, start: str, theta: np.ndarray, index: np.ndarray) -> str:
        """``"local"`` or ``"global"``: where :meth:`solve` starts (see :data:`STARTS`)."""
        rig = self.hand.rig
        can = self.algorithm == TRUST_REGION and np.any(rig.dof_bone[index] == 0)
        if start == "global" and not can:
            raise SolverError(
                f"a global start needs the {TRUST_REGION} algorithm and the hand's root free to move"
            )
        if start != "auto":
            return start
        return "global" if can and self.far(theta) else "local"

    def far(self, theta) -> bool:
        """Whether the hand at θ (d,) stands far from its contacts, so that a solve from there must move
        it: more than one patch (the only one, if there is one) farther than :data:`EDIT_REACH` from its
        targets, where a patch moved or turned by an edit is one."""
        gaps = np.array(list(self.gaps(theta).values()))
        return int(np.sum(gaps > EDIT_REACH * self.unit)) > min(1, gaps.size - 1)

    def _descend(self, theta, index, max_evaluations, ftol_rel, tally, solids=True, status=False):
        """A local solve of the DOFs ``index`` from θ with the configured algorithm, every evaluation
        told to ``tally`` (which keeps the best pose by the whole energy); with ``solids`` False (the
        trust region only) the table and object terms are left out, and the evaluations only counted.
        Returns the solved θ, or with ``status`` the outcome (:class:`SolveResult`)."""
        rig = self.hand.rig
        if self.algorithm != TRUST_REGION:
            final, _, _, _, outcome = minimize(
                self.energy, functools.partial(self.energy_and_gradient, dofs=index), theta, index,
                self._scale[index], rig, self.algorithm, max_evaluations, ftol_rel, gradient=self.gradient,
                progress=lambda step: tally.offer(step.theta, step.energy, step.terms),
            )  # fmt: skip
            if tally.cancelled:
                raise _Cancelled
            return outcome if status else final
        index = index[rig.lower[index] < rig.upper[index]]  # a DOF its limits pin is not free
        if not index.size:
            return "converged" if status else theta

        def full(x):
            t = theta.copy()
            t[index] = x
            return t

        def told(x, energy, terms):
            return tally.offer(full(x), energy, terms) if solids else tally.poll()

        x, _, _, _, outcome = minimize_squares(
            lambda x: self.residuals(full(x), index, solids), theta[index], rig.lower[index],
            rig.upper[index], self._scale[index], max_evaluations, ftol_rel, told,
        )  # fmt: skip
        if outcome == "cancelled":
            raise _Cancelled
        return outcome if status else full(x)


def _counting_on(progress: Callable[[Progress], bool | None], done: int) -> Callable[[Progress], bool | None]:
    """``progress`` told of a later stage's evaluations, counted on from the ``done`` before it."""
    return lambda step: progress(replace(step, iteration=step.iteration + done))


class _Cancelled(Exception):
    """The progress callback asked to stop."""


class _Tally:
    """A solve's evaluations across its stages: their count, the best pose by the whole energy (the
    start's, until one is better), and the progress reports (each with the best pose so far)."""

    def __init__(self, progress, theta: np.ndarray, energy: float, terms: dict):
        self.progress = progress
        self.theta, self.energy, self.terms = theta.copy(), float(energy), dict(terms)
        self.count = 0
        self.cancelled = False

    def offer(self, theta: np.ndarray, energy: float, terms: dict) -> bool:
        """An evaluation of the whole energy at θ; whether to cancel."""
        if energy < self.energy:
            self.theta, self.energy, self.terms = theta.copy(), float(energy), dict(terms)
        return self.poll()

    def poll(self) -> bool:
        """One more evaluation (of whatever objective); reports the best pose so far; whether to cancel."""
        self.count += 1
        if self.progress is not None and self.progress(
            Progress(self.count, self.energy, dict(self.terms), self.theta.copy())
        ):
            self.cancelled = True
        return self.cancelled


def minimize(
    energy: Callable[[np.ndarray], tuple[float, dict]],
    energy_and_gradient: Callable[[np.ndarray], tuple[float, dict, np.ndarray]],
    theta: np.ndarray,
    index: np.ndarray,
    scale: np.ndarray,
    rig,
    algorithm: str,
    max_evaluations: int = MAX_EVALUATIONS,
    ftol_rel: float = FTOL_REL,
    *,
    gradient: str = "analytic",
    progress: Callable[[Progress], bool | None] | None = None,
    start: tuple[float, dict] | None = None,
) -> tuple[np.ndarray, float, dict, int, str]:
    """Minimize ``energy(θ) -> (E, terms)`` over the DOFs ``index`` (n,) of θ (d,) with NLopt;
    gradient-based algorithms take ``energy_and_gradient(θ) -> (E, terms, dE/dθ (d,))``.

    The free DOFs are optimized as ``θ[index] / scale`` (``scale`` (n,), so locations and angles are of one
    size) within the rig's bounds; the others keep θ's values. Returns the best pose seen (d,) (never
    NaN), its energy and terms, the number of evaluations and the outcome (see :class:`SolveResult`).
    ``start`` is θ's energy and terms when the caller has them already.
    """
    start_energy, start_terms = start if start is not None else energy(theta)
    best = {"energy": start_energy, "theta": theta.copy(), "terms": start_terms}
    count = [0]
    cancelled = [False]

    def full(x):
        t = theta.copy()
        t[index] = x * scale
        return t

    def value(x):
        return energy(full(x))[0]

    def objective(x, grad):
        t = full(x)
        if grad.size:
            if gradient == "analytic":
                e, terms, g = energy_and_gradient(t)
                grad[:] = g[index] * scale
            else:
                e, terms = energy(t)
                grad[:] = _finite_differences(value, x, e, central=gradient == "central-difference")
        else:
            e, terms = energy(t)
        count[0] += 1
        if not np.isfinite(e):
            raise nlopt.ForcedStop
        if e < best["energy"]:
            best.update(energy=e, theta=t, terms=terms)
        if progress is not None and progress(Progress(count[0], e, dict(terms), t.copy())):
            cancelled[0] = True
            raise nlopt.ForcedStop
        return e

    status = "converged" if index.size else "no free DOFs"
    if index.size:
        opt = nlopt.opt(ALGORITHMS[algorithm], index.size)
        opt.set_lower_bounds(rig.lower[index] / scale)
        opt.set_upper_bounds(rig.upper[index] / scale)
        opt.set_min_objective(objective)
        opt.set_ftol_rel(ftol_rel)
        opt.set_maxeval(int(max_evaluations))
        try:
            opt.optimize(theta[index] / scale)
            if opt.last_optimize_result() == nlopt.MAXEVAL_REACHED:
                status = "max evaluations"
        except nlopt.ForcedStop:
            status = "cancelled" if cancelled[0] else "stopped"
        except STOPPED_SHORT:
            status = "stopped"
    if status == "converged" and start_energy - best["energy"] <= ftol_rel * max(abs(start_energy), 1.0):
        status = "unchanged"  # nothing better than where it started (to the stopping tolerance)
    return best["theta"], float(best["energy"]), dict(best["terms"]), count[0], status


def _finite_differences(
    f: Callable[[np.ndarray], float], x: np.ndarray, fx: float, central: bool
) -> np.ndarray:
    """Forward (steps sqrt(eps)) or central (steps eps^(1/3)) differences of f at x; steps scale with
    max(1, |x|)."""
    eps = np.finfo(np.float64).eps
    h = (eps ** (1 / 3) if central else np.sqrt(eps)) * np.maximum(1.0, np.abs(x))
    g = np.empty_like(x)
    for j in range(x.size):
        step = x.copy()
        step[j] += h[j]
        ahead = f(step)
        if central:
            step[j] = x[j] - h[j]
            g[j] = (ahead - f(step)) / (2 * h[j])
        else:
            g[j] = (ahead - fx) / h[j]
    return g
