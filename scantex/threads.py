"""Photos (or views) side by side on threads: one a core, with the BLAS library held to one thread meanwhile.

Per-photo work (a pose fit, an alignment check) is many small numpy, Embree and solver steps; the heavy
ones release the interpreter lock, so photos on threads use every core. The solver's small factorisations
are BLAS calls, and OpenBLAS runs each on all cores by default: its threads then spin waiting for work and
take the cores the other photos need (the bolster's 12 pose fits: 3.2 s on one core plus 2.3 s of
spinning; 1.9 s two at a time with BLAS on one thread, about 2.9 s without that limit).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextvars import ContextVar
from typing import TypeVar

#: photos handled at once at most (each holds its photo and working images)
MAX_THREADS = 8

T = TypeVar("T")
R = TypeVar("R")

_CORES: ContextVar[int | None] = ContextVar("scantex_cores", default=None)


def cores() -> int:
    """The cores scantex's own threads may use: what :func:`using_cores` set (a run's ``threads`` setting,
    a tile's share of the machine), else every core."""
    return _CORES.get() or os.cpu_count() or 1


@contextlib.contextmanager
def using_cores(n: int | None) -> Iterator[None]:
    """Within it, :func:`cores` is ``n`` (``None`` or 0: every core)."""
    token = _CORES.set(n or None)
    try:
        yield
    finally:
        _CORES.reset(token)


def one_blas_thread():
    """A context in which the BLAS library runs each call on the calling thread alone (restored after)."""
    from threadpoolctl import threadpool_limits

    return threadpool_limits(1, user_api="blas")


def side_by_side(work: Callable[[T], R], items: Iterable[T], threads: int | None = None) -> Iterator[R]:
    """``work`` of each of ``items`` on threads (``threads``: how many at most; ``None``: one a core, up to
    :data:`MAX_THREADS`; never more than :func:`cores`), BLAS on one thread meanwhile; the results in
    ``items``' order, each as soon as it and those before it are done. ``work`` must allow calls from
    several threads at once."""
    items = list(items)
    workers = max(1, min(threads or MAX_THREADS, cores(), MAX_THREADS, len(items)))
    with ThreadPoolExecutor(workers) as pool, one_blas_thread():
        yield from pool.map(work, items)
