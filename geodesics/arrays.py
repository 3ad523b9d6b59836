"""Small array helpers shared by every package: read-only arrays, ragged index ranges, grouped minima."""

from __future__ import annotations

import numpy as np

__all__ = ["ranges", "readonly", "smallest_per_key"]


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


def smallest_per_key(keys: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Where each distinct key has its smallest value (the first such entry on a tie), by key.

    Parameters
    ----------
    keys : (n,) int ndarray
    values : (n,) float ndarray

    Returns
    -------
    (u,) int64 ndarray
        One index into ``keys`` per distinct key, in increasing key order.
    """
    order = np.lexsort((values, keys))
    sorted_keys = keys[order]
    first = np.empty(order.size, bool)
    first[:1] = True
    np.not_equal(sorted_keys[1:], sorted_keys[:-1], out=first[1:])
    return order[first]
