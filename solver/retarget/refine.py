"""Trajectory refinement (§3.4.3 of Kinematic Motion Retargeting): filter, find acceleration violations,
interpolate and re-solve, until the trajectory is temporally consistent.

Input is the per-frame trajectory θ (F, d) of *independent* per-frame solves (§3.4.2) and a re-solve
callback ``resolve(frames, seeds) -> θ`` that solves Eq. 3 again for the given frames from the given
start poses (the caller decides how: in worker processes, on a Dask cluster). The steps, as the paper:

1. **Filters, then one re-solve** ("we found it beneficial to re-solve for the estimates after applying
   low-pass and peak removal filters"): a Hampel filter removes peaks (a sample farther than
   ``hampel_sigmas`` robust standard deviations, ``1.4826 · MAD``, and more than ``tolerance`` from the
   median of its ``2 · hampel_half_width + 1`` frame window is replaced by that median), then a
   zero-phase Butterworth low-pass (``scipy.signal.butter`` + ``sosfiltfilt``, ``filter_order`` poles,
   ``cutoff`` Hz; run forwards and backwards, so nothing lags) smooths what is left. Frames whose
   filtered pose differs from the solve by more than ``tolerance`` in some DOF are re-solved, seeded by
   their whole filtered pose; the others already sit at a solution within the tolerance of their
   filtered seed, so re-solving them would only repeat their solve (this is where we save most of the
   paper's re-solve work).
2. **Iterate** up to ``max_iterations`` times: compute every DOF's acceleration by central second
   differences (the first and last frame take their neighbour's), flag each (frame, DOF) whose
   magnitude exceeds ``e_acc``, remove all flagged samples of each DOF in a single pass, replace them by
   linear interpolation between the DOF's nearest unflagged left and right neighbours (constant beyond
   the ends), and re-solve every frame with a flagged DOF, seeded by the interpolated values (its
   unflagged DOFs keep their values). Stop when nothing is flagged.
3. **Stop when re-solving stops helping** (not in the paper, which only caps the rounds at 20): a
   round's worth is how much it lowers the *excess* acceleration, the sum over flagged samples of how
   far they exceed ``e_acc`` (a non-finite sample counts as ``e_acc``). When :data:`PATIENCE` rounds in
   a row fail to bring it below ``1 - min_progress`` of the lowest yet, the rest are accelerations
   that interpolating and re-solving cannot remove: a motion faster than the threshold (a whole
   grasp-and-lift in half a second), or a solver that falls back into the same local minimum. The
   paper's cap then costs 20 full re-solves for nothing; a spike that shrinks with every round keeps
   the rounds going.
4. What is still flagged at the end is **reported and masked**: ``valid`` is False there, and the
   spline fit (:func:`solver.retarget.spline.fit_bspline`) ignores those samples, as the paper's fit does.

**One threshold for all DOFs** ("in support of standardization"). Rotation DOFs are compared in rad/s².
A translation DOF's acceleration (m/s²) is divided by ``length``, a characteristic length of the hand
(pass ``hand.length``): a translation by one hand length then counts like a turn of one radian, so the
one threshold means the same at every scene scale. (The paper pairs 500 °/s² with 500 cm/s², i.e. one
degree with one centimetre, at life size; that is ``length = 0.573 m``, three hand lengths.)

**The threshold's value.** The paper sets 500 °/s² (:data:`PAPER_E_ACC`) and calls it high. At 120 fps
ordinary grasping exceeds it many times over (a 1 rad finger curl in 0.3 s peaks near 67 rad/s² =
3,800 °/s²), so in physical units it would flag, re-solve and finally mask every grasp. The default
:data:`E_ACC` (20,000 °/s², 349 rad/s²) sits between genuine hand motion and what refinement is for:
a single-frame solver flip of 1° at 120 fps has a second difference of 2° = 28,800 °/s².

**Angle wrap.** Euler angles that the solves return on different 2π branches are unwrapped along time
(``numpy.unwrap``) before anything else, so a rotation passing ±π is one smooth curve, not a spike. Seeds
go to ``resolve`` on the branch of that frame's latest solve (so they stay within the rig's bounds);
what it returns is brought back to the branch nearest its seed. The refined trajectory is returned
unwrapped (continuous; the poses are identical, and the spline fit needs continuity).

Non-finite input samples (failed solves) count as violations from the start; a re-solve returning
non-finite values keeps its seed there and is retried in the next iteration.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import signal

from ..errors import SolverError, describe_ids

#: The paper's threshold (Appendix B), 500 °/s², in rad/s²; see the module docstring.
PAPER_E_ACC = float(np.radians(500.0))
#: The default acceleration threshold, rad/s² (translations: per ``length``).
E_ACC = float(np.radians(20_000.0))
#: The paper's iteration cap.
MAX_ITERATIONS = 20
#: A round must lower the excess acceleration below (1 - MIN_PROGRESS) of the lowest so far to count as
#: progress; PATIENCE rounds in a row without progress end the refinement.
MIN_PROGRESS = 0.1
PATIENCE = 2
#: Low-pass cutoff (Hz) and Butterworth order.
CUTOFF = 10.0
FILTER_ORDER = 2
#: Hampel window half width (frames) and threshold (robust standard deviations).
HAMPEL_HALF_WIDTH = 3
HAMPEL_SIGMAS = 3.0
#: Filters changing a DOF by less than this (rad, or hand lengths) leave its frame alone.
TOLERANCE = float(np.radians(1.0))
#: MAD to standard deviation of a normal distribution.
MAD_TO_SIGMA = 1.4826

TWO_PI = 2.0 * np.pi

Resolve = Callable[[np.ndarray, np.ndarray], np.ndarray]

__all__ = [
    "CUTOFF",
    "E_ACC",
    "MAX_ITERATIONS",
    "MIN_PROGRESS",
    "PAPER_E_ACC",
    "PATIENCE",
    "TOLERANCE",
    "RefineLog",
    "Refinement",
    "acceleration",
    "hampel",
    "interpolate_gaps",
    "lowpass",
    "refine_trajectory",
    "remaining_work",
]


@dataclass(frozen=True, eq=False)
class RefineLog:
    """What the refinement did.

    Attributes
    ----------
    nonfinite : int
        Non-finite (frame, DOF) samples in the input.
    peaks : int
        Samples the peak filter replaced.
    prefilter_frames : (k,) int
        Frames re-solved from their filtered poses.
    violations : tuple of int
        Violating (frame, DOF) samples found by each detection pass: one before each iteration and a
        last one after it, so ``len(violations) == iterations + 1`` (0 at the end: converged).
    resolved_frames : tuple of (k,) int arrays
        Frames re-solved in each iteration.
    excess : tuple of float
        The excess acceleration found by each detection pass (see the module docstring).
    unresolved : (u, 2) int
        (frame, DOF) pairs still violating at the end; masked in ``Refinement.valid``.
    converged, stalled, cancelled : bool
        No violation is left; :data:`PATIENCE` rounds in a row made no progress; the progress callback
        asked to stop.
    """

    nonfinite: int
    peaks: int
    prefilter_frames: np.ndarray
    violations: tuple[int, ...]
    excess: tuple[float, ...]
    resolved_frames: tuple[np.ndarray, ...]
    unresolved: np.ndarray
    converged: bool
    stalled: bool
    cancelled: bool

    @property
    def iterations(self) -> int:
        return len(self.resolved_frames)

    @property
    def resolves(self) -> int:
        """Frame solves requested in all (prefilter and iterations)."""
        return int(self.prefilter_frames.size + sum(f.size for f in self.resolved_frames))


@dataclass(frozen=True, eq=False)
class Refinement:
    """The refined trajectory θ (F, d) (rotations unwrapped), its ``valid`` mask (F, d) and the log."""

    theta: np.ndarray
    valid: np.ndarray
    log: RefineLog


# ------------------------------------------------------------------------------------ building blocks


def acceleration(theta, fps: float) -> np.ndarray:
    """(F, d) second time derivative of ``theta`` (F, d) by central differences; frames 0 and F-1 repeat
    their neighbour's.

    Zero when F < 3.
    """
    X = np.asarray(theta, dtype=np.float64)
    A = np.zeros_like(X)
    if len(X) >= 3:
        A[1:-1] = (X[2:] - 2.0 * X[1:-1] + X[:-2]) * (fps * fps)
        A[0], A[-1] = A[1], A[-2]
    return A


def interpolate_gaps(values, keep) -> np.ndarray:
    """Replace every (frame, DOF) not kept by linear interpolation between the DOF's nearest kept frames.

    Parameters
    ----------
    values : (F, d)
    keep : (F, d) bool

    Returns
    -------
    (F, d)
        Kept entries unchanged; others interpolated, constant beyond the first or last kept frame. A DOF
        with no kept frame is returned unchanged.
    """
    X = np.asarray(values, dtype=np.float64)
    K = np.asarray(keep, dtype=bool)
    F = len(X)
    idx = np.arange(F)[:, None]
    left = np.maximum.accumulate(np.where(K, idx, -1), axis=0)
    right = np.minimum.accumulate(np.where(K, idx, F)[::-1], axis=0)[::-1]
    has_left, has_right = left >= 0, right < F
    lo = np.clip(left, 0, F - 1)
    hi = np.clip(right, 0, F - 1)
    cols = np.arange(X.shape[1])[None, :]
    xl, xr = X[lo, cols], X[hi, cols]
    span = np.maximum(right - left, 1)
    w = np.where(has_left & has_right, (idx - left) / span, 0.0)
    inner = xl + w * (xr - xl)
    out = np.where(has_left, np.where(has_right, inner, xl), np.where(has_right, xr, X))
    return np.where(K, X, out)


def _odd_pad(X: np.ndarray, k: int) -> np.ndarray:
    """Point-reflect k frames about each end (linear trends continue; what filtfilt calls 'odd')."""
    k = min(k, len(X) - 1)
    if k <= 0:
        return X
    head = 2 * X[:1] - X[k:0:-1]
    tail = 2 * X[-1:] - X[-2 : -k - 2 : -1]
    return np.concatenate([head, X, tail])


def hampel(values, half_width: int = HAMPEL_HALF_WIDTH, sigmas: float = HAMPEL_SIGMAS, floor=0.0):
    """Peak removal: the Hampel filter on every DOF (column) at once.

    A sample farther from its window's median than both ``sigmas · 1.4826 · MAD`` and ``floor`` is
    replaced by that median. Windows are ``2 · half_width + 1`` frames, point-reflected at the ends.

    Parameters
    ----------
    values : (F, d)
    half_width : int
    sigmas : float
    floor : float or (d,)
        Smallest deviation that counts as a peak (per DOF), so that numerically flat stretches (MAD 0)
        keep their noise.

    Returns
    -------
    filtered : (F, d)
    replaced : (F, d) bool
    """
    X = np.asarray(values, dtype=np.float64)
    F = len(X)
    h = min(int(half_width), F - 1)
    if h < 1:
        return X.copy(), np.zeros(X.shape, bool)
    windows = np.lib.stride_tricks.sliding_window_view(_odd_pad(X, h), 2 * h + 1, axis=0)  # (F, d, w)
    med = np.median(windows, axis=2)
    mad = np.median(np.abs(windows - med[..., None]), axis=2)
    dev = np.abs(X - med)
    replaced = (dev > sigmas * MAD_TO_SIGMA * mad) & (dev > np.asarray(floor, dtype=np.float64))
    return np.where(replaced, med, X), replaced


def lowpass(values, fps: float, cutoff: float = CUTOFF, order: int = FILTER_ORDER) -> np.ndarray:
    """(F, d) zero-phase Butterworth low-pass of ``values`` (F, d) along time (axis 0), every DOF alike.

    ``order`` poles at ``cutoff`` Hz, run forwards and backwards (``scipy.signal.sosfiltfilt``, odd
    padding of four cutoff periods, shortened for short clips, so linear motion passes unchanged); a
    cutoff at or above 0.45 · fps is lowered to it.
    """
    X = np.asarray(values, dtype=np.float64)
    if len(X) < 2:
        return X.copy()
    wn = min(float(cutoff), 0.45 * float(fps))
    sos = signal.butter(int(order), wn, btype="low", fs=float(fps), output="sos")
    # Pad by about four periods of the cutoff, so that the start-up transient dies out in the padding.
    padlen = min(max(3 * (2 * len(sos) + 1), int(np.ceil(4 * fps / wn))), len(X) - 1)
    return signal.sosfiltfilt(sos, X, axis=0, padlen=padlen)


def _ffill(X: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Carry each DOF's last finite value forward (and its first one backward)."""
    F = len(X)
    idx = np.arange(F)[:, None]
    last = np.maximum.accumulate(np.where(ok, idx, -1), axis=0)
    first = np.argmax(ok, axis=0)[None, :]
    src = np.where(last >= 0, last, first)
    return X[src, np.arange(X.shape[1])[None, :]]


def remaining_work(sizes, rounds_left: int) -> float:
    """An estimate of the frame solves the rounds after this one will need, for a progress bar over the
    whole refinement: ``sizes`` are the frames of the re-solves so far (this one last). Rounds are taken
    to shrink as the last two did; rounds that hardly shrink end within :data:`PATIENCE` more."""
    if not sizes or rounds_left <= 0:
        return 0.0
    last = float(sizes[-1])
    ratio = last / sizes[-2] if len(sizes) > 1 and sizes[-2] else 0.5
    if ratio >= 1.0 - MIN_PROGRESS:
        return last * min(rounds_left, PATIENCE)
    return last * float(np.sum(ratio ** np.arange(1, rounds_left + 1)))


# ------------------------------------------------------------------------------------ the refinement


def refine_trajectory(
    theta,
    fps: float,
    is_rotation,
    resolve: Resolve,
    *,
    length: float,
    e_acc: float = E_ACC,
    max_iterations: int = MAX_ITERATIONS,
    min_progress: float = MIN_PROGRESS,
    prefilter: bool = True,
    cutoff: float = CUTOFF,
    filter_order: int = FILTER_ORDER,
    hampel_half_width: int = HAMPEL_HALF_WIDTH,
    hampel_sigmas: float = HAMPEL_SIGMAS,
    tolerance: float = TOLERANCE,
    progress: Callable[[int, int], bool | None] | None = None,
) -> Refinement:
    """Refine a per-frame trajectory for temporal consistency (§3.4.3).

    Parameters
    ----------
    theta : (F, d) array_like
        Independent per-frame solves; NaN rows (failed solves) are allowed.
    fps : float
        Frame rate.
    is_rotation : (d,) array_like of bool
        Which DOFs are angles (``Rig.is_rotation``); the others are translations.
    resolve : callable
        ``resolve(frames (k,) int, seeds (k, d)) -> (k, d)``: solves the given frames again from the given
        start poses. Called once after filtering and once per iteration, each time with all the frames
        of that step, ascending, so the caller can run them in parallel.
    length : float
        Characteristic length of the hand (``hand.length``): translation accelerations are divided by it.
    e_acc : float
        Acceleration threshold, rad/s² (translations: hand lengths/s²).
    max_iterations : int
        Cap on interpolate-and-re-solve rounds (the paper: 20).
    min_progress : float
        The fraction of the excess acceleration a round must remove to count as progress; 0 never
        stops early (the paper's rule: only the cap).
    prefilter : bool
        Run the filters and their re-solve first.
    cutoff, filter_order, hampel_half_width, hampel_sigmas
        The filters (see :func:`lowpass` and :func:`hampel`).
    tolerance : float
        Filters changing no DOF of a frame by more than this (rad, or hand lengths) leave it unsolved;
        also the smallest deviation the peak filter acts on.
    progress : callable, optional
        ``progress(done, total)`` after the filter step (1) and after each iteration (``total`` is
        ``max_iterations + 1``); returning True stops early: what is still violating is masked.

    Returns
    -------
    Refinement

    Raises
    ------
    SolverError
        For malformed input, a DOF with no finite sample, or a ``resolve`` answer of the wrong shape.
    """
    X = np.array(theta, dtype=np.float64)
    rot = _checked_rotations(X, is_rotation)
    fps, length, e_acc = _positive(fps=fps, length=length, e_acc=e_acc)
    max_iterations, min_progress = _checked_rounds(max_iterations, min_progress)
    scale = np.where(rot, 1.0, 1.0 / length)  # DOF units -> threshold units
    path = _Trajectory(X, rot, resolve)

    peaks, prefilter_frames = 0, np.empty(0, np.int64)
    if prefilter and len(X) >= 3:
        peaks, prefilter_frames = _prefilter(
            path, scale, fps, tolerance, cutoff, filter_order, hampel_half_width, hampel_sigmas
        )
    cancelled = progress is not None and bool(progress(1, max_iterations + 1))
    rounds = _resolve_violations(path, fps, scale, e_acc, max_iterations, min_progress, progress, cancelled)

    violating = rounds.violating
    log = RefineLog(
        nonfinite=int((~np.isfinite(X)).sum()),
        peaks=peaks,
        prefilter_frames=prefilter_frames,
        violations=tuple(rounds.counts),
        excess=tuple(rounds.excess),
        resolved_frames=tuple(rounds.frames),
        unresolved=np.argwhere(violating),
        converged=not violating.any(),
        stalled=bool(violating.any()) and rounds.idle >= PATIENCE,
        cancelled=rounds.cancelled,
    )
    return Refinement(path.U, ~violating, log)


def _prefilter(
    path: _Trajectory,
    scale: np.ndarray,
    fps: float,
    tolerance: float,
    cutoff: float,
    filter_order: int,
    hampel_half_width: int,
    hampel_sigmas: float,
) -> tuple[int, np.ndarray]:
    """Step 1: the peak filter and the low-pass, then one re-solve of the frames they changed by more than
    ``tolerance`` (or that no solve made finite), seeded by their filtered poses. Returns how many samples
    the peak filter replaced and the frames re-solved."""
    H, replaced = hampel(path.U * scale, hampel_half_width, hampel_sigmas, floor=tolerance)
    peaks = int(replaced.sum())
    L = lowpass(H, fps, cutoff, filter_order)
    changed = (np.abs(L - path.U * scale) > tolerance) | path.bad
    prefilter_frames = np.flatnonzero(changed.any(1))
    if prefilter_frames.size:
        path.solve(prefilter_frames, L[prefilter_frames] / scale)
    return peaks, prefilter_frames


@dataclass
class _Rounds:
    """How steps 2-3 went: the samples still violating (F, d) at the end, the violations and excess found
    by each detection pass, the frames of each round, the rounds without progress at the end, and whether
    the caller asked to stop."""

    violating: np.ndarray
    counts: list[int]
    excess: list[float]
    frames: list[np.ndarray]
    idle: int
    cancelled: bool


def _resolve_violations(
    path: _Trajectory,
    fps: float,
    scale: np.ndarray,
    e_acc: float,
    max_iterations: int,
    min_progress: float,
    progress: Callable[[int, int], bool | None] | None,
    cancelled: bool,
) -> _Rounds:
    """Steps 2-3: find the violating samples, interpolate them and re-solve their frames, round after
    round, until none is left, the caller stops it (``cancelled`` already, or ``progress`` says so), the
    rounds reach ``max_iterations`` or :data:`PATIENCE` rounds in a row make no progress."""
    total = max_iterations + 1
    counts: list[int] = []
    excess: list[float] = []
    rounds: list[np.ndarray] = []
    lowest, idle = np.inf, 0
    while True:
        violating, mass = path.violations(fps, scale, e_acc)
        counts.append(int(violating.sum()))
        excess.append(mass)
        if mass <= (1.0 - min_progress) * lowest or not rounds:
            lowest, idle = min(lowest, mass), 0
        else:
            idle += 1
        if not violating.any() or cancelled or len(rounds) >= max_iterations or idle >= PATIENCE:
            break
        seeds = np.where(violating, interpolate_gaps(path.U, ~violating), path.U)
        frames = np.flatnonzero(violating.any(1))
        path.solve(frames, seeds[frames])
        rounds.append(frames)
        if progress is not None and progress(len(rounds) + 1, total):
            cancelled = True
    return _Rounds(violating, counts, excess, rounds, idle, cancelled)


def _checked_rounds(max_iterations, min_progress) -> tuple[int, float]:
    """``max_iterations`` as a non-negative int and ``min_progress`` as a float in [0, 1)."""
    max_iterations = int(max_iterations)
    if max_iterations < 0:
        raise SolverError(f"max_iterations must be non-negative, got {max_iterations}")
    min_progress = float(min_progress)
    if not 0 <= min_progress < 1:
        raise SolverError(f"min_progress must be in [0, 1), got {min_progress!r}")
    return max_iterations, min_progress


def _checked_rotations(X: np.ndarray, is_rotation) -> np.ndarray:
    """(d,) bool: ``is_rotation`` checked against the trajectory X (F, d), which is checked too."""
    if X.ndim != 2:
        raise SolverError(f"theta must have shape (F, d), got {X.shape}")
    F, d = X.shape
    if F == 0:
        raise SolverError("theta has no frames")
    rot = np.asarray(is_rotation, dtype=bool).reshape(-1)
    if rot.size != d:
        raise SolverError(f"is_rotation needs {d} flags (one per DOF), got {rot.size}")
    empty = np.flatnonzero(~np.isfinite(X).any(0))
    if empty.size:
        raise SolverError(f"DOFs {describe_ids(empty)} have no finite value in any frame", dofs=empty)
    return rot


def _positive(**values) -> tuple[float, ...]:
    """The values as floats, each checked to be positive and finite (the error names it)."""
    out = tuple(float(v) for v in values.values())
    for name, v in zip(values, out, strict=True):
        if not (np.isfinite(v) and v > 0):
            raise SolverError(f"{name} must be a positive finite number, got {v!r}")
    return out


class _Trajectory:
    """The trajectory under refinement, and its re-solves.

    ``U`` (F, d) is the working copy with rotations unwrapped along time (gaps interpolated);
    ``branch`` (F, d) each frame's latest solve on the solver's own 2π branch (seeds go to ``resolve``
    on it, so they stay within the rig's bounds); ``bad`` (F, d) the samples no solve made finite.
    """

    def __init__(self, X: np.ndarray, rot: np.ndarray, resolve: Resolve):
        finite = np.isfinite(X)
        U = _ffill(X, finite)
        U[:, rot] = np.unwrap(U[:, rot], axis=0)
        self.U = interpolate_gaps(U, finite)
        self.branch = np.where(finite, X, np.mod(self.U + np.pi, TWO_PI) - np.pi)
        self.bad = ~finite
        self.rot = rot
        self.resolve = resolve

    def solve(self, frames: np.ndarray, seeds_u: np.ndarray) -> None:
        """Re-solve ``frames`` (k,) from unwrapped seeds (k, d); each answer is brought back to the branch
        nearest its seed, and a non-finite one keeps its seed (and stays bad)."""
        rot = self.rot
        seeds = seeds_u.copy()
        seeds[:, rot] -= TWO_PI * np.round((seeds_u[:, rot] - self.branch[frames][:, rot]) / TWO_PI)
        out = np.asarray(self.resolve(frames.copy(), seeds), dtype=np.float64)
        if out.shape != seeds.shape:
            raise SolverError(
                f"resolve returned shape {out.shape} for {len(frames)} frames of {seeds.shape[1]} DOFs"
            )
        ok = np.isfinite(out)
        out = np.where(ok, out, seeds)
        self.branch[frames] = out
        unwrapped = out.copy()
        unwrapped[:, rot] += TWO_PI * np.round((seeds_u[:, rot] - out[:, rot]) / TWO_PI)
        self.U[frames] = unwrapped
        self.bad[frames] = ~ok

    def violations(self, fps: float, scale: np.ndarray, e_acc: float) -> tuple[np.ndarray, float]:
        """The violating samples (F, d) bool and their excess acceleration (see the module docstring)."""
        over = np.abs(acceleration(self.U, fps) * scale) - e_acc
        violating = (over > 0) | self.bad
        return violating, float(np.sum(np.where(self.bad, e_acc, np.maximum(over, 0.0))))
