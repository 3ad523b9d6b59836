"""Small array helpers shared by every package: read-only arrays and ragged index ranges."""

from __future__ import annotations

import numpy as np

__all__ = ["ranges", "readonly"]


def readonly(a) -> np.ndarray:
    """``a`` as an array (no copy when it is one already), flagged read-only and returned.

    Parameters
    ----------
    a : (...) array_like
        Any shape.

    Returns
    -------
    (...) ndarray
        Of ``a``'s shape; the same array object when ``a`` is an ndarray.
    """
    a = np.asarray(a)
    a.setflags(write=False)
    return a


def ranges(starts, counts) -> tuple[np.ndarray, np.ndarray]:
    """The concatenated index ranges ``starts[i] : starts[i] + counts[i]``, in order.

    Parameters
    ----------
    starts, counts : (r,) array_like of int
        First index and length of each range (lengths ``>= 0``).

    Returns
    -------
    owner : (n,) int64 ndarray
        The range each entry comes from (``n = counts.sum()``).
    index : (n,) int64 ndarray
        The indices themselves: ``arange(starts[i], starts[i] + counts[i])`` for each i, concatenated.
    """
    starts = np.asarray(starts, dtype=np.int64).reshape(-1)
    counts = np.asarray(counts, dtype=np.int64).reshape(-1)
    owner = np.repeat(np.arange(counts.size), counts)
    index = np.arange(owner.size) + (starts - (np.cumsum(counts) - counts))[owner]
    return owner, index
