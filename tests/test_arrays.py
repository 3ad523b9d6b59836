"""The shared array helpers (geodesics.arrays): ragged ranges, read-only arrays, grouped minima."""

import numpy as np
import pytest

from geodesics.arrays import ranges, readonly, smallest_per_key


def test_ranges_concatenate_aranges_with_their_owners():
    owner, index = ranges([5, 0, 9, 2], [3, 0, 1, 2])
    np.testing.assert_array_equal(owner, [0, 0, 0, 2, 3, 3])
    np.testing.assert_array_equal(index, [5, 6, 7, 9, 2, 3])
    assert owner.dtype == index.dtype == np.int64


def test_ranges_match_a_python_loop():
    rng = np.random.default_rng(0)
    starts, counts = rng.integers(0, 100, 50), rng.integers(0, 6, 50)
    owner, index = ranges(starts, counts)
    np.testing.assert_array_equal(
        index, np.concatenate([np.arange(s, s + c) for s, c in zip(starts, counts, strict=True)])
    )
    np.testing.assert_array_equal(owner, np.repeat(np.arange(50), counts))


@pytest.mark.parametrize(("starts", "counts"), [([], []), ([4, 7], [0, 0])])
def test_empty_ranges(starts, counts):
    owner, index = ranges(np.array(starts, np.int64), np.array(counts, np.int64))
    assert owner.shape == index.shape == (0,)
    assert owner.dtype == index.dtype == np.int64


def test_readonly_flags_the_same_array():
    a = np.arange(4.0)
    assert readonly(a) is a
    with pytest.raises(ValueError, match="read-only"):
        a[0] = 1.0
    b = readonly([1, 2, 3])
    assert isinstance(b, np.ndarray) and not b.flags.writeable


def test_smallest_per_key_matches_a_python_loop_and_breaks_ties_by_position():
    rng = np.random.default_rng(1)
    keys = rng.integers(0, 30, 400)
    values = rng.integers(0, 5, 400).astype(float)  # many ties
    got = smallest_per_key(keys, values)
    expected = [min(np.flatnonzero(keys == k), key=lambda i: (values[i], i)) for k in np.unique(keys)]
    np.testing.assert_array_equal(got, expected)


def test_smallest_per_key_of_nothing_is_empty():
    assert smallest_per_key(np.empty(0, np.int64), np.empty(0)).shape == (0,)
