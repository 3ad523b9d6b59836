"""Blender's blend of a constraint's result by its influence (``interp_m4_m4m4``), and the polar
decomposition it rests on (``mat3_polar_decompose``)."""

from __future__ import annotations

import numpy as np

from .math_matrix import AFTER, NEXT, affine, det3, inverse3, skew
from .math_rotation import interp_qt_qtqt, mat3_normalized_to_quat_fast, quat_to_mat3
from .stack import matmul, values_shared

_EYE3 = np.eye(3)
_EYE3.setflags(write=False)


#: Newton steps of the polar factor converge quadratically; past this many the matrix is singular enough
#: to be left to an SVD.
POLAR_STEPS = 12


def _orthogonal_factor(A: np.ndarray) -> np.ndarray:
    """(..., 3, 3) the orthogonal factor U of real matrices ``A = U P`` (the same as ``W Vᵀ`` of their SVD),
    by Higham's scaled Newton iteration ``U ← (γ U + U⁻ᵀ / γ) / 2`` on closed-form 3×3 inverses: LAPACK on
    thousands of tiny matrices is slower, and threads it."""
    U = A
    for _ in range(POLAR_STEPS):
        inverse_t = inverse3(U).swapaxes(-1, -2)
        gamma = np.sqrt(np.sqrt(np.sum(inverse_t * inverse_t, axis=(-2, -1)) / np.sum(U * U, axis=(-2, -1))))
        nxt = 0.5 * (gamma[..., None, None] * U + inverse_t / gamma[..., None, None])
        done = np.abs(nxt - U).max(initial=0.0) <= 1e-15 * max(np.abs(nxt).max(initial=0.0), 1.0)
        U = nxt
        if done:
            return U
    W, _, Vt = np.linalg.svd(A)
    return W @ Vt


def mat3_polar_decompose(A, shared_batch: bool = False):
    """Right polar decomposition ``A = U P`` of (..., 3, 3) matrices (``mat3_polar_decompose``).

    Blender takes it from an SVD; this iterates to the same factor (:func:`_orthogonal_factor`) from the real
    parts. The derivative carried by a complex
    step is exact: with ``Ω = Uᵀ dU`` (antisymmetric, its vector ``ω``) and ``X = Uᵀ dA``, ``X - Xᵀ = Ω P +
    P Ω``, i.e. ``(tr P - P) ω = vee(X - Xᵀ)``, and ``dP = X - Ω P``. ``U`` is orthogonal with the sign
    of ``det A``.

    Parameters
    ----------
    A : (..., 3, 3) array_like
    shared_batch : bool
        ``A`` is in the stack layout (g, K, 3, 3) and every batch entry has the same real part
        (:func:`~solver.rig.stack.shared`): the SVD is taken once per bone.

    Returns
    -------
    U, P : (..., 3, 3) ndarray
    """
    A = np.asarray(A)
    complex_ = A.dtype == np.complex128
    real = A.real if complex_ else A
    value = real[:, :1] if shared_batch else real
    Ur = _orthogonal_factor(value)
    Urt = Ur.swapaxes(-1, -2)
    Pr = Urt @ value
    if not complex_:
        return Ur, Pr
    X = matmul(Urt, A.imag) if shared_batch else Urt @ A.imag
    x = X[..., AFTER, NEXT] - X[..., NEXT, AFTER]  # vee(X - Xᵀ): (X21 - X12, X02 - X20, X10 - X01)
    trace = Pr[..., 0, 0] + Pr[..., 1, 1] + Pr[..., 2, 2]
    Minv = inverse3(trace[..., None, None] * _EYE3 - Pr)
    if shared_batch:
        g, k = x.shape[:2]
        w = (x.reshape(g, k, 3) @ Minv.reshape(g, 3, 3).swapaxes(-1, -2)).reshape(g, k, 3)
        Omega = skew(w)
        return Ur + 1j * matmul(Ur, Omega), Pr + 1j * (X - matmul(Omega, Pr))
    w = (Minv @ x[..., :, None])[..., 0]
    Omega = skew(w)
    return Ur + 1j * (Ur @ Omega), Pr + 1j * (X - Omega @ Pr)


def _flip_negative(U, P, shared_batch):
    """U and P negated where U is a reflection (``interp_m4_m4m4`` turns those into rotations)."""
    value = U.real[:, :1] if shared_batch else U.real
    negative = det3(value) < 0
    if negative.any():
        U = np.where(negative[..., None, None], -U, U)
        P = np.where(negative[..., None, None], -P, P)
    return U, P


def interp_m4_m4m4(a, b, t, stacked: bool = False) -> np.ndarray:
    """(..., 4, 4) ``interp_m4_m4m4``: Blender's blend of a constraint's result by its influence.

    Locations are interpolated linearly; the 3×3 parts are polar-decomposed (``A = U P``), a negative
    ``U`` flipped together with ``P``, the rotations slerped as quaternions and the stretches ``P``
    interpolated linearly; ``R = U(t) P(t)``.

    Parameters
    ----------
    a, b : (..., 4, 4) array_like
        The matrices at ``t = 0`` and ``t = 1``.
    t : float or (...) array_like
    stacked : bool
        ``a`` and ``b`` are in the stack layout (g, K, 4, 4): when their batch entries share their values
        (complex-step directions, :class:`~solver.rig.stack.SharedValues`), the polar decompositions take
        one SVD per bone.
    """
    a, b = np.asarray(a), np.asarray(b)
    t = np.asarray(t)
    if a.shape != b.shape:
        a, b = np.broadcast_arrays(a, b)
    la = a[..., :3, 3]
    location = la + (b[..., :3, 3] - la) * t[..., None]
    if stacked and a.ndim == 4:
        n = a.shape[0]
        both = np.concatenate([a[..., :3, :3], b[..., :3, :3]], 0)
        share = values_shared() and both.dtype == np.complex128 and both.shape[1] > 1
    else:
        n = 1
        both = np.stack([a[..., :3, :3], b[..., :3, :3]])
        share = False
    U, P = _flip_negative(*mat3_polar_decompose(both, shared_batch=share), share)
    q = mat3_normalized_to_quat_fast(U)
    Pa, Pb = P[:n], P[n:]
    if not stacked or a.ndim != 4:
        Pa, Pb, qa, qb = Pa[0], Pb[0], q[0], q[1]
    else:
        qa, qb = q[:n], q[n:]
    Ut = quat_to_mat3(interp_qt_qtqt(qa, qb, t))
    R = Ut @ (Pa + (Pb - Pa) * t[..., None, None])
    return affine(R, location)
