"""Photos side by side on threads: results in order, BLAS on one thread meanwhile, restored after."""

from __future__ import annotations

import threading

import numpy as np
from threadpoolctl import threadpool_info

from scantex.threads import side_by_side


def blas_threads() -> list[int]:
    return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]


def test_side_by_side_keeps_order_and_holds_blas_to_one_thread():
    np.linalg.svd(np.ones((8, 3)))  # numpy's BLAS loaded
    before = blas_threads()
    seen_threads, seen_blas = set(), []

    def work(i: int) -> int:
        seen_threads.add(threading.get_ident())
        seen_blas.append(blas_threads())
        return i * i

    assert list(side_by_side(work, range(10), threads=2)) == [i * i for i in range(10)]
    assert all(all(n == 1 for n in counts) for counts in seen_blas)
    assert threading.get_ident() not in seen_threads and len(seen_threads) <= 2
    assert blas_threads() == before
    assert list(side_by_side(work, [])) == []


def test_a_runs_cores_bound_the_threads():
    """``EnhanceConfig.threads`` (a tile's share of the machine) bounds the photos side by side."""
    from scantex.threads import cores, using_cores

    seen = set()

    def work(i: int) -> int:
        seen.add(threading.get_ident())
        return i

    with using_cores(1):
        assert cores() == 1
        assert list(side_by_side(work, range(6), threads=2)) == list(range(6))
    assert len(seen) == 1 and cores() >= 1
