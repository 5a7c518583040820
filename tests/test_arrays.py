import numpy as np
import pytest

from scantex.arrays import unique_rows


@pytest.mark.parametrize("rows", [
    np.random.default_rng(0).integers(0, 30, (5000, 2)),            # edges: the int64-key path
    np.random.default_rng(1).integers(-5, 5, (5000, 3)),            # signed, three columns
    np.round(np.random.default_rng(2).random((5000, 3)), 1),       # floats with repeats
    np.array([[0.0, -0.0], [-0.0, 0.0], [1.0, 2.0]]),               # -0.0 equals 0.0
    np.zeros((0, 2), np.int64),
])
def test_unique_rows_matches_numpy(rows):
    expected = np.unique(rows, axis=0, return_inverse=True, return_counts=True)
    got = unique_rows(rows, return_inverse=True, return_counts=True)
    assert np.array_equal(got[0], expected[0])
    assert np.array_equal(got[1], expected[1].reshape(-1))
    assert np.array_equal(got[2], expected[2])
    assert np.array_equal(unique_rows(rows), expected[0])
