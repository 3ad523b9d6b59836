"""Minimizing an energy written as a sum of squares, ``E(θ) = Σ r_i(θ)²``, within box bounds: scipy's
trust-region reflective method (``scipy.optimize.least_squares``, ``method="trf"``).

Contact IK's energy is a sum of squares in every term (contact distances, the opposing normals'
``1 + n·m = |n + m|² / 2``, the priors, the penetration depths), and with the residuals' Jacobian a
Gauss-Newton model of it is nearly exact near a solution: a trust-region method on that model takes
tens of evaluations where a quasi-Newton method, which learns the curvature one gradient at a time,
takes hundreds; and a stiff term (the skin kept out of the object) cannot throw it far, since every step
stays within the region where the model holds.

Each evaluation hands the method a compressed system of n + 1 rows for n variables, from ``JᵀJ`` and
``Jᵀr`` (:func:`compressed`): its cost, gradient and Gauss-Newton model ``|r + J δ|²`` are those of the
full system of thousands of rows (contacts, normals, a penetration row per vertex of the skin), and the
method's own linear algebra stays (n + 1) × n.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.optimize import least_squares

#: Residuals (m,), their Jacobian (m, n) with respect to the free DOFs, the energy and its terms.
Residuals = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, float, dict]]


class _Stop(Exception):
    """Raised inside the method to end it early, with the outcome (:func:`minimize_squares`)."""

    def __init__(self, status: str):
        super().__init__(status)
        self.status = status


def compressed(r: np.ndarray, J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The system (r (n + 1,), J (n + 1, n)) with the cost ``|r|²``, the gradient ``Jᵀr`` and the
    Gauss-Newton model of ``r`` (m,), ``J`` (m, n): with ``JᵀJ = V Λ Vᵀ``, the rows ``Λ^½ Vᵀ`` and
    residuals ``Λ^-½ Vᵀ Jᵀr`` (the part of r in J's column space), plus one row of the rest of ``|r|²``
    (orthogonal to every step's change ``J δ``, so its Jacobian row is zero)."""
    n = J.shape[1]
    eigenvalues, V = np.linalg.eigh(J.T @ J)
    keep = eigenvalues > eigenvalues.max(initial=0.0) * (n * np.finfo(float).eps)
    root = np.sqrt(eigenvalues[keep])
    head = (V[:, keep].T @ (J.T @ r)) / root
    rest = np.sqrt(max(float(r @ r) - float(head @ head), 0.0))
    out_r = np.zeros(n + 1)
    out_J = np.zeros((n + 1, n))
    out_r[: head.size], out_r[n] = head, rest
    out_J[: head.size] = root[:, None] * V[:, keep].T
    return out_r, out_J


def minimize_squares(
    residuals: Residuals,
    x0: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    scale: np.ndarray,
    max_evaluations: int,
    ftol_rel: float,
    on_evaluation: Callable[[np.ndarray, float, dict], bool] | None = None,
) -> tuple[np.ndarray, float, dict, int, str]:
    """Minimize ``Σ r(x)²`` over ``lower <= x <= upper`` from ``x0`` (n,) with the trust-region reflective
    method.

    Parameters
    ----------
    residuals : callable
        ``x -> (r (m,), J (m, n), energy, terms)``; ``energy`` is ``Σ r²`` as the caller computes it.
    x0, lower, upper, scale : (n,) ndarray
        Start, bounds (``lower < upper``; infinite for none) and the variables' characteristic sizes.
    max_evaluations : int
    ftol_rel : float
        Stop when a step changes the energy by less than this fraction of it.
    on_evaluation : callable, optional
        ``(x, energy, terms) -> cancel`` after each evaluation; True stops the method.

    Returns
    -------
    x : (n,) ndarray
        The best point evaluated.
    energy : float
    terms : dict
    evaluations : int
    status : str
        ``"converged"``, ``"max evaluations"``, ``"cancelled"``, or ``"stopped"`` (the energy or the
        Jacobian was not finite; the best point before is returned).
    """
    best = {"energy": np.inf, "x": x0.copy(), "terms": {}}
    count = [0]
    cache: dict = {}

    def system(x):
        key = x.tobytes()
        if key not in cache:
            cache.clear()
            r, J, energy, terms = residuals(x)
            count[0] += 1
            if not (np.isfinite(energy) and np.all(np.isfinite(J))):
                raise _Stop("stopped")
            if energy < best["energy"]:
                best.update(energy=energy, x=x.copy(), terms=terms)
            if on_evaluation is not None and on_evaluation(x, energy, terms):
                raise _Stop("cancelled")
            cache[key] = compressed(r, J)
        return cache[key]

    status = "converged"
    x_start = np.clip(x0, lower, upper)
    try:
        result = least_squares(
            lambda x: system(x)[0], x_start, jac=lambda x: system(x)[1], bounds=(lower, upper),
            x_scale=scale, method="trf", ftol=ftol_rel, xtol=1e-12, gtol=1e-12, max_nfev=int(max_evaluations),
        )  # fmt: skip
        if result.status == 0:
            status = "max evaluations"
    except _Stop as stop:
        status = stop.status
    return best["x"], float(best["energy"]), dict(best["terms"]), count[0], status
