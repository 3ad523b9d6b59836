"""The stack layout: many bones placed at once, one BLAS product per bone.

Bones whose discrete settings agree are posed together, their rest data being arrays over a stack axis
``g``. Stacked code works on arrays in the *stack layout* ``(g, K, 4, 4)``: the stack axis first, then
the batch (complex-step directions) flattened to one axis ``K``, or ``K = 1`` for what does not vary over
the batch (per-bone constants are ``(g, 1, ...)``, :func:`constant`). Then a product with a per-bone
constant is one BLAS product per bone of all its ``K`` matrices (:func:`matmul`) instead of ``g K`` small
ones, and when the batch is complex-step directions sharing one value (:class:`SharedValues`) so is a
product of two varying matrices. :func:`to_stack` and :func:`from_stack` convert from and to the public
layout ``(..., g, 4, 4)``.
"""

from __future__ import annotations

import math

import numpy as np


def constant(values) -> np.ndarray:
    """Per-bone constants in the stack layout (g, 1, ...), read-only, from one value (a number or an array,
    all of one shape) per bone."""
    out = np.array(values, dtype=np.float64)
    out = out.reshape(len(out), 1, *out.shape[1:])
    out.setflags(write=False)
    return out


def matmul(A, B):
    """``A @ B`` for stack-layout arrays ``(g, K, n, n)`` (``K`` may be 1 on either side), fast.

    numpy multiplies a batch of small matrices one by one; when one side is constant over the batch
    (``K == 1``), the product is instead one matrix product per bone, of the other side's ``K`` rows
    stacked: ``(g, K n, n) @ (g, n, n)`` for a constant right side, through transposes for a constant
    left side; a 2-D side (the same matrix for every bone) makes it one product in all. Any other shapes
    fall back to ``np.matmul``.
    """
    sa, sb = A.shape, B.shape
    if len(sb) == 2:
        if len(sa) == 2:
            return A @ B
        return (A.reshape(-1, sa[-1]) @ B).reshape(*sa[:-1], sb[-1])
    if len(sa) == 2:
        Bt = B.swapaxes(-1, -2)
        out = Bt.reshape(-1, sb[-2]) @ A.T
        return out.reshape(*sb[:-2], sb[-1], sa[0]).swapaxes(-1, -2)
    if len(sa) != 4 or len(sb) != 4 or sa[0] != sb[0]:
        return A @ B
    ka, kb = sa[1], sb[1]
    if kb == 1 and ka > 1:
        g, n, m, p = sa[0], sa[2], sa[3], sb[3]
        return (A.reshape(g, ka * n, m) @ B.reshape(g, m, p)).reshape(g, ka, n, p)
    if ka == 1 and kb > 1:
        g, n, m, p = sa[0], sa[2], sa[3], sb[3]
        Bt = B.swapaxes(-1, -2).reshape(g, kb * p, m)
        out = Bt @ A.reshape(g, n, m).swapaxes(-1, -2)
        return out.reshape(g, kb, p, n).swapaxes(-1, -2)
    if _SHARED[0] and ka > 1 and ka == kb and A.dtype == B.dtype == np.complex128:
        # Complex-step directions sharing their values: (Va + i Ta)(Vb + i Tb) = Va Vb + i (Va Tb + Ta Vb)
        # to far below rounding, i.e. Va B + A Vb - Va Vb: two products with a constant side.
        Va, Vb = A.real[:, :1], B.real[:, :1]
        return matmul(Va, B) + matmul(A, Vb) - Va @ Vb
    return A @ B


#: Whether the complex stack-layout arrays being evaluated are complex-step directions that share their
#: values (set by :class:`SharedValues`).
_SHARED = [False]


def values_shared() -> bool:
    """Whether the complex stack-layout arrays being evaluated share their values (inside a
    ``SharedValues(True)`` block)."""
    return _SHARED[0]


class SharedValues:
    """Context: complex stack-layout arrays (g, K, ...) in the block share their real parts across ``K``
    (complex-step directions of one value), which :func:`matmul` exploits."""

    def __init__(self, on: bool):
        self.on = on

    def __enter__(self):
        self.previous = _SHARED[0]
        _SHARED[0] = self.on

    def __exit__(self, *exc):
        _SHARED[0] = self.previous


def to_stack(A, lead: tuple[int, ...]) -> np.ndarray | None:
    """``A`` (..., g, r, c) or (g, r, c) in the stack layout (g, K, r, c): ``K = prod(lead)`` or 1 when
    ``A`` has no batch dimensions of its own. A view when ``A``'s memory is stack-major already."""
    if A is None:
        return None
    shape = A.shape
    nd = len(shape)
    if nd == 3:
        return A.reshape(shape[0], 1, shape[1], shape[2])
    own = shape[:-3]
    if own != lead:
        if math.prod(own) == 1:
            return A.reshape(shape[-3], 1, shape[-2], shape[-1])
        A = np.broadcast_to(A, (*lead, *shape[-3:]))
    A = A.transpose(nd - 3, *range(nd - 3), nd - 2, nd - 1)
    return A.reshape(shape[-3], -1, shape[-2], shape[-1])


def from_stack(A, lead: tuple[int, ...]) -> np.ndarray:
    """Stack-layout ``A`` (g, K, r, c) back to (*lead, g, r, c) (a view when ``K`` is the batch)."""
    g, k, r, c = A.shape
    size = math.prod(lead)
    if k != size:
        A = np.broadcast_to(A, (g, size, r, c)).copy()
    n = len(lead)
    if n == 0:
        return A.reshape(g, r, c)
    if n == 1:
        return A.swapaxes(0, 1)
    return A.reshape(g, *lead, r, c).transpose(*range(1, n + 1), 0, n + 1, n + 2)


def shared(A) -> bool:
    """Whether a complex stack-layout array (g, K, ...) carries the same value (real part) in every batch
    entry, as complex-step directions do (up to second-order terms far below rounding)."""
    if not np.iscomplexobj(A) or A.shape[1] == 1:
        return False
    real = A.real
    return bool(np.abs(real - real[:, :1]).max() <= 1e-40)


def to_single_stack(*arrays):
    """(lead, arrays (..., 4, 4) of one bone as stack layout (1, K, 4, 4)), their batch shapes ``lead``
    broadcast (None stays None)."""
    present = [np.asarray(a) for a in arrays if a is not None]
    lead = np.broadcast_shapes(*(a.shape[:-2] for a in present)) if present else ()
    return lead, [None if a is None else to_stack(np.asarray(a)[..., None, :, :], lead) for a in arrays]


def from_single_stack(A, lead) -> np.ndarray:
    """(*lead, 4, 4) of a stack of one bone (1, K, 4, 4)."""
    return np.asarray(from_stack(A, lead))[..., 0, :, :]
