"""Array helpers that the mesh code needs many times over.

``np.unique(a, axis=0)`` compares rows through a structured view, which is several times slower than a
sort on one key; scans have hundreds of thousands of edges and positions, and several stages find
unique rows. :func:`unique_rows` gives the same results (rows in lexicographic order, column 0 first).
"""

from __future__ import annotations

import numpy as np


def unique_rows(a: np.ndarray, *, return_inverse: bool = False, return_counts: bool = False):
    """The distinct rows of ``a (N, K)`` in lexicographic order, as ``np.unique(a, axis=0)`` returns them
    (with ``inverse (N,)`` and ``counts`` when asked). Floats compare by value (``-0.0 == 0.0``)."""
    a = np.asarray(a)
    if a.ndim != 2:
        raise ValueError(f"expected a 2-D array of rows, got shape {a.shape}")
    n = len(a)
    if n == 0:
        unique, inverse, counts = a[:0], np.zeros(0, np.intp), np.zeros(0, np.intp)
    elif a.dtype.kind in "iu" and a.shape[1] == 2 and a.min() >= 0 and a.max() < 2**31:
        # two small non-negative integers (edges, index pairs): one int64 key each
        key = (a[:, 0].astype(np.int64) << 32) | a[:, 1].astype(np.int64)
        _, first, inverse, counts = np.unique(key, return_index=True, return_inverse=True, return_counts=True)
        unique = a[first]
    else:
        order = np.lexsort(a.T[::-1])  # the last key is the primary one: column 0
        ordered = a[order]
        starts = np.ones(n, bool)
        starts[1:] = np.any(ordered[1:] != ordered[:-1], axis=1)
        unique = ordered[starts]
        inverse = np.empty(n, np.intp)
        inverse[order] = np.cumsum(starts) - 1
        counts = np.diff(np.append(np.flatnonzero(starts), n))
    out = (unique,)
    if return_inverse:
        out += (inverse.reshape(-1),)
    if return_counts:
        out += (counts,)
    return out if len(out) > 1 else unique


def read_only(array: np.ndarray) -> np.ndarray:
    """``array``, made read-only in place: for results a cache hands to several callers."""
    array.setflags(write=False)
    return array


def uv_areas(triangles: np.ndarray, *, signed: bool = False) -> np.ndarray:
    """The areas ``(F,)`` of 2-D triangles ``(F, 3, 2)`` (UV triangles: in UV units, or texels when their corners
    are in texels); ``signed``: positive counter-clockwise, negative for a mirrored triangle."""
    e1, e2 = triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]
    area = 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    return area if signed else np.abs(area)
