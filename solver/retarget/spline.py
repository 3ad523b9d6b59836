"""Cubic B-spline fit of DOF curves (§3.4.4 of Kinematic Motion Retargeting): C² by construction.

Every DOF's refined samples θ_j(t_k), one per frame at ``t_k = k / fps``, are fitted by one cubic
B-spline with a fixed number ``n`` of control points, by least squares, as Eberly does (*Least Squares
Fitting of Data with B-Spline Curves*, Geometric Tools, 2005):

* **Knots**: clamped ("open uniform"): four-fold knots at the first and last sample time and ``n - 4``
  uniformly spaced interior knots, so the curve starts and ends at its first and last control value.
* **Parameterization**: the sample times themselves. Eberly fits a parametric curve and spaces the
  samples' parameters uniformly (or by chord length); a DOF curve is a graph over time whose samples
  are uniform in time, so both choices give exactly ``t_k``.
* **Values and locations in time of the control points** (the paper's "solve simultaneously for both
  values and locations in time"): fitting the 2D curve ``(t, θ_j(t))`` reproduces its linear time
  coordinate exactly, which puts control point ``i`` at the Greville abscissa
  ``ξ_i = (τ_{i+1} + τ_{i+2} + τ_{i+3}) / 3`` (``SplineFit.times``); only the values need solving.
* **Least squares**: the normal equations ``(Aᵀ W_j A) c_j = Aᵀ W_j θ_j`` with the (F, n) basis matrix
  ``A`` (scipy's ``BSpline.design_matrix``, four nonzeros a row) and the per-DOF sample weights ``W_j``
  (1 for a valid sample, 0 for one the refinement masked). ``A`` is built once for all DOFs; the Gram
  matrices of all DOFs come out of one sparse product, and DOFs that share a mask share one banded
  Cholesky solve with many right-hand sides.
* **Regularization** only where data is missing: when masked samples leave control points with (almost)
  no data (support below :data:`WEAK_SUPPORT` of the median), a small penalty
  ``smoothing · mean(diag Aᵀ W A) · ‖D² c‖²`` on the second differences of the control values around
  them keeps the system definite and bridges the gap with the smoothest spline; if the data are still
  too few for their control points somewhere (Schoenberg–Whitney fails), the penalty covers all of
  them. A fit whose control points all see data is plain least squares: a cubic comes back exactly.

Why not ``scipy.interpolate.make_lsq_spline`` (the tests' oracle, which this matches where both apply):
it takes one weight vector for all columns and has no penalty, so it would need one call per distinct
DOF mask, and where masking leaves a control point without data its system is singular (scipy 1.17
returns NaN control values): exactly the gaps the refinement's masks make, which this fit bridges.

Evaluation: :class:`SplineFit` is vectorized over DOFs (``fit(t)`` gives (len(t), d)); ``fit.values``
holds the fit at every sample frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.interpolate import BSpline
from scipy.linalg import solveh_banded
from scipy.sparse import csr_array

from ..errors import SolverError, describe_ids

#: Cubic splines: C² everywhere.
DEGREE = 3
#: Relative weight of the curvature penalty where it applies.
SMOOTHING = 1e-6
#: Control points whose data support (diagonal of the Gram matrix) is below this fraction of the
#: median control point's are regularized.
WEAK_SUPPORT = 1e-3

__all__ = ["DEGREE", "SMOOTHING", "WEAK_SUPPORT", "SplineFit", "clamped_knots", "fit_bspline", "greville"]


def clamped_knots(start: float, end: float, n_control: int, degree: int = DEGREE) -> np.ndarray:
    """(n_control + degree + 1,) clamped open uniform knots on [start, end]."""
    interior = np.linspace(start, end, n_control - degree + 1)
    return np.concatenate([np.full(degree, start), interior, np.full(degree, end)])


def greville(knots: np.ndarray, degree: int = DEGREE) -> np.ndarray:
    """(n,) Greville abscissae of ``knots`` (n + degree + 1,): where in time each of the n control points
    sits (the mean of ``degree`` knots)."""
    n = len(knots) - degree - 1
    return np.lib.stride_tricks.sliding_window_view(knots[1:-1], degree)[:n].mean(1)


@dataclass(frozen=True, eq=False)
class SplineFit:
    """Cubic B-splines of d DOFs over one knot vector.

    Attributes
    ----------
    knots : (n + 4,)
        Clamped open uniform knots, in seconds.
    control : (n, d)
        Control values of each DOF (column).
    times : (n,)
        Each control point's location in time (Greville abscissae).
    values : (F, d)
        The fit evaluated at every sample frame.
    residual : (d,)
        Root-mean-square difference between the fit and the valid samples of each DOF.
    """

    knots: np.ndarray
    control: np.ndarray
    times: np.ndarray
    values: np.ndarray
    residual: np.ndarray

    @cached_property
    def bspline(self) -> BSpline:
        """The fit as one vector-valued :class:`scipy.interpolate.BSpline` (values along axis 1)."""
        return BSpline(self.knots, self.control, DEGREE, extrapolate=False)

    def __call__(self, t, nu: int = 0) -> np.ndarray:
        """(k, d) values (or ``nu``-th time derivatives) at times t (k,); NaN outside the knot range."""
        T = np.asarray(t, dtype=np.float64).reshape(-1)
        spline = self.bspline if nu == 0 else self.bspline.derivative(nu)
        return spline(T)


def fit_bspline(samples, n_control: int, *, valid=None, fps: float = 1.0, smoothing: float = SMOOTHING):
    """Least-squares cubic B-spline fit of every DOF curve at once.

    Parameters
    ----------
    samples : (F, d) array_like
        One row per frame (the refined DOF vectors); entries that ``valid`` masks may be anything,
        NaN included.
    n_control : int
        Control points per DOF, at least 4 and at most F.
    valid : (F, d) array_like of bool, optional
        Samples to fit (default: every finite one).
    fps : float
        Frame rate; frame k is at time ``k / fps``.
    smoothing : float
        Relative weight of the curvature penalty where data is missing (see the module docstring).

    Returns
    -------
    SplineFit

    Raises
    ------
    SolverError
        For malformed input, a control-point count out of range, or DOFs with fewer than two valid
        samples (naming them).
    """
    X, ok, fps, n = _checked_samples(samples, valid, fps, n_control)
    F, d = X.shape
    W = ok.astype(np.float64)
    Y = np.where(ok, X, 0.0)

    t = np.arange(F) / fps
    knots = clamped_knots(t[0], t[-1], n)
    A = BSpline.design_matrix(t, knots, DEGREE)  # (F, n) CSR, exactly DEGREE + 1 entries a row
    u = DEGREE
    products = _gram_products(A, F, n)
    # DOFs with equal masks share a Gram matrix: group them by their masks' bytes.
    packed = np.ascontiguousarray(np.packbits(ok, axis=0).T)  # (d, ceil(F / 8))
    keys = packed.view(np.dtype((np.void, packed.shape[1]))).ravel()
    _, first, group = np.unique(keys, return_index=True, return_inverse=True)
    group = np.asarray(group).reshape(-1)
    gram = (products.T @ W[:, first]).T.reshape(len(first), u + 1, n)
    rhs = A.T @ (W * Y)  # (n, d)

    control = np.empty((n, d))
    for g in range(len(first)):
        members = np.flatnonzero(group == g)
        control[:, members] = _solve_banded(gram[g], rhs[:, members], n, u, smoothing)
    values = A @ control
    err = np.where(ok, values - Y, 0.0)
    residual = np.sqrt((err**2).sum(0) / W.sum(0))
    return SplineFit(knots, control, greville(knots), values, residual)


def _checked_samples(samples, valid, fps, n_control) -> tuple[np.ndarray, np.ndarray, float, int]:
    """The samples (F, d), which of them to fit (F, d) bool, the frame rate and the control point count,
    checked as :func:`fit_bspline` says."""
    X = np.asarray(samples, dtype=np.float64)
    if X.ndim == 1:
        X = X[:, None]
    if X.ndim != 2:
        raise SolverError(f"samples must have shape (F, d), got {X.shape}")
    F = len(X)
    fps = float(fps)
    if not (np.isfinite(fps) and fps > 0):
        raise SolverError(f"fps must be a positive finite number, got {fps!r}")
    n = int(n_control)
    if not (DEGREE + 1 <= n <= F):
        raise SolverError(f"n_control must be between {DEGREE + 1} and the number of frames ({F}), got {n}")
    ok = np.isfinite(X)
    if valid is not None:
        V = np.asarray(valid, dtype=bool)
        if V.ndim == 1:
            V = V[:, None]
        if V.shape != X.shape:
            raise SolverError(f"valid must have the samples' shape {X.shape}, got {V.shape}")
        ok &= V
    few = np.flatnonzero(ok.sum(0) < 2)
    if few.size:
        raise SolverError(
            f"DOFs {describe_ids(few)} have fewer than two valid samples; a spline needs at least two",
            dofs=few,
        )
    return X, ok, fps, n


def _gram_products(A: csr_array, F: int, n: int) -> csr_array:
    """(F, (u + 1) n) per sample, the products of its basis values laid out in the upper banded storage of
    an (n, n) Gram matrix (u = :data:`DEGREE`): times the (F, k) sample weights of k masks, the product
    gives k Gram matrices ``Aᵀ W A`` at once."""
    cols = A.indices.reshape(F, DEGREE + 1)
    vals = A.data.reshape(F, DEGREE + 1)
    # Upper banded storage of every Gram matrix: ab[u + i - j, j] = G[i, j] for j - u <= i <= j.
    u = DEGREE
    a, b = np.triu_indices(DEGREE + 1)
    flat = (u + cols[:, a] - cols[:, b]) * n + cols[:, b]  # (F, pairs)
    return csr_array(
        (
            (vals[:, a] * vals[:, b]).ravel(),
            flat.ravel(),
            np.arange(0, F * len(a) + 1, len(a)),
        ),
        shape=(F, (u + 1) * n),
    )


def _solve_banded(ab: np.ndarray, rhs: np.ndarray, n: int, u: int, smoothing: float) -> np.ndarray:
    """The control values (n, k) of k DOFs sharing the Gram matrix ``ab`` (upper banded storage), for
    their right-hand sides (n, k): the curvature penalty on the control points with (almost) no data, or
    on all of them when the data are too few somewhere (see the module docstring)."""
    weight = smoothing * ab[u].mean()
    weak = ab[u] < WEAK_SUPPORT * np.median(ab[u])
    rows = weak[:-2] | weak[1:-1] | weak[2:] if n >= 3 else np.zeros(0, bool)
    try:
        return solveh_banded(ab + weight * _curvature_band(n, u, rows), rhs, check_finite=False)
    except np.linalg.LinAlgError:  # too few samples somewhere for its control points: regularize all
        return solveh_banded(
            ab + weight * _curvature_band(n, u, np.ones(n - 2, bool)), rhs, check_finite=False
        )


def _curvature_band(n: int, u: int, rows: np.ndarray) -> np.ndarray:
    """``D²ᵀ S D²`` in upper banded storage (u >= 2): D² the (n-2, n) second-difference matrix, S selects
    its ``rows`` ((n-2,) bool)."""
    band = np.zeros((u + 1, n))
    k = np.flatnonzero(rows)
    coefficients = (1.0, -2.0, 1.0)
    for r in range(3):
        for s in range(r, 3):
            # Row k of D² touches columns k, k+1, k+2: entry (k + r, k + s) gains c_r c_s.
            band[u - (s - r), k + s] += coefficients[r] * coefficients[s]
    return band
