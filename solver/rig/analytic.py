"""Exact first derivatives of numpy code by complex-step differentiation.

Evaluating ``f(x + i h e_j)`` with a tiny ``h`` gives ``f(x)`` in the real part and ``h ∂f/∂x_j`` in the
imaginary part, to rounding (there is no subtraction, so no cancellation, and the truncation error is
``O(h²)``, which vanishes in float64 for ``h = STEP``). It is forward-mode differentiation carried by
numpy's complex arithmetic: the same code computes values (on real arrays) and exact derivatives (on
complex arrays, one batch entry per direction), which is how the solver differentiates the long chains
of Blender's constraint and B-Bone math.

The code being differentiated must be analytic in its inputs:

* use ``+ - * / @``, ``sqrt``, ``exp``, ``log``, ``sin``, ``cos``, ``np.linalg.inv``, ``det``;
* take norms with :func:`norm` (``sqrt(Σ v²)``), never ``abs``, ``np.linalg.norm`` or ``conj``;
* angles with :func:`atan2` and :func:`acos` here (numpy's ``arctan2`` refuses complex input);
* branch, compare, clip and pick maxima on ``.real`` only, and never ``np.linalg.svd``.
"""

from __future__ import annotations

import numpy as np

#: The imaginary step: far below float64 resolution of any value, far above its underflow.
STEP = 1e-30


def directions(x: np.ndarray, free: np.ndarray) -> np.ndarray:
    """(k, n) complex: x (n,) with an imaginary step on one free entry per row (k = entries flagged in
    ``free`` (n,); a single unstepped row when there are none)."""
    x = np.asarray(x, dtype=np.float64)
    index = np.flatnonzero(free)
    X = np.repeat(x[None].astype(np.complex128), max(index.size, 1), axis=0)
    X[np.arange(index.size), index] += 1j * STEP
    return X


def value(y: np.ndarray) -> np.ndarray:
    """(...) the value carried by a complex-step result (k, ...): the real part of its first direction."""
    y = np.asarray(y)
    return (y[0].real if np.iscomplexobj(y) else y[0]).copy()


def derivative(y: np.ndarray) -> np.ndarray:
    """(k, ...) the derivative along each direction of a complex-step result (k, ...)."""
    y = np.asarray(y)
    return y.imag / STEP if np.iscomplexobj(y) else np.zeros(y.shape)


def norm(v, axis: int = -1, keepdims: bool = False):
    """Euclidean norm ``sqrt(Σ v²)`` of ``v`` along ``axis``, analytic in complex-step inputs: (..., n) gives
    (...) for the last axis (``keepdims``: (..., 1))."""
    v = np.asarray(v)
    return np.sqrt(np.sum(v * v, axis=axis, keepdims=keepdims))


def atan2(y, x):
    """(...) ``arctan2`` of real or complex-step arrays ``y``, ``x`` (broadcast to (...)), with the derivative
    ``(x dy - y dx) / (x² + y²)``."""
    y, x = np.asarray(y), np.asarray(x)
    angle = np.arctan2(y.real, x.real)
    if not (np.iscomplexobj(y) or np.iscomplexobj(x)):
        return angle
    r2 = x.real**2 + y.real**2
    slope = np.divide(
        x.real * y.imag - y.real * x.imag, r2, out=np.zeros(np.broadcast(x, y).shape), where=r2 > 0
    )
    return angle + 1j * slope


def acos(x):
    """(...) ``arccos`` of ``x`` (...) clamped to [-1, 1] (Blender's ``saacos``); clamped entries have zero
    derivative.

    numpy's complex ``arccos`` loses an imaginary part this small, so the derivative is applied here.
    """
    return _clamped(np.arccos, -1.0, x)


def asin(x):
    """(...) ``arcsin`` of ``x`` (...) clamped to [-1, 1] (Blender's ``saasin``); clamped entries have zero
    derivative."""
    return _clamped(np.arcsin, 1.0, x)


def _clamped(f, sign: float, x):
    x = np.asarray(x)
    angle = f(np.clip(x.real, -1.0, 1.0))
    if not np.iscomplexobj(x):
        return angle
    inside = np.abs(x.real) < 1
    slope = np.divide(sign * x.imag, np.sqrt(1 - x.real**2, where=inside, out=np.ones(x.shape)))
    return angle + 1j * np.where(inside, slope, 0.0)


# Functions numpy evaluates slowly on complex numbers, applied to the real part with the derivative carried
# in the imaginary part (as :func:`atan2` does): exact for complex-step arrays, whose imaginary parts are
# infinitesimal. ``shared``: the array's entries along axis -2 are complex-step directions of one value,
# so the function of the real part is taken once, on the first of them.

_SIGNS = np.array([-1.0, 1.0])[:, None, None, None]


def as_complex(real, imag):
    """real + i imag (numpy's complex multiplication of a real array by 1j is slow)."""
    out = np.empty(np.broadcast_shapes(real.shape, imag.shape), np.complex128)
    out.real = real
    out.imag = imag
    return out


def real_part(x, shared: bool):
    """The real part of x, or when ``shared`` of its first entry along axis -2, the direction axis of
    a complex-step array whose entries there all have the same real part."""
    return x.real[..., :1, :] if shared else x.real


def sqrt(x, shared: bool = False):
    if not np.iscomplexobj(x):
        return np.sqrt(x)
    root = np.sqrt(real_part(x, shared))
    return as_complex(root, x.imag * (0.5 / root))


def rsqrt(x, shared: bool = False):
    """1 / sqrt(x)."""
    if not np.iscomplexobj(x):
        return 1.0 / np.sqrt(x)
    inv = 1.0 / np.sqrt(real_part(x, shared))
    return as_complex(inv, x.imag * (-0.5 * inv * inv * inv))


def exp(x):
    if not np.iscomplexobj(x):
        return np.exp(x)
    e = np.exp(x.real)
    return as_complex(e, e * x.imag)


def log(x):
    if not np.iscomplexobj(x):
        return np.log(x)
    return as_complex(np.log(x.real), x.imag / x.real)


def cos_sin(x, shared: bool = False):
    """(2, ...) cos x and sin x."""
    r = real_part(x, shared)
    cs = np.stack([np.cos(r), np.sin(r)])
    if not np.iscomplexobj(x):
        return cs
    return as_complex(cs, cs[::-1] * x.imag * _SIGNS.reshape(2, *(1,) * x.ndim))
