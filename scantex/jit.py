"""Loops compiled with numba: the field's compiler for per-point work that numpy would do in dozens of passes.

A kernel is a plain Python function over arrays and numbers, compiled by :func:`compiled` on first use (a few
seconds) and cached on disk by numba beside its module, so later runs load it (a fraction of a second); ``scantex
precompile`` (:mod:`scantex.pipeline.precompile`) compiles them all ahead of a first run. A
compiled kernel releases the interpreter lock: kernels on threads run side by side. Where numba is missing,
:func:`compiled` gives ``None`` and the caller runs its numpy twin (each kernel has one: the tests compare them).
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable

log = logging.getLogger(__name__)


@functools.cache
def compiled(function: Callable) -> Callable | None:
    """``function`` compiled (no interpreter lock, numpy's error model: a division by zero gives inf or NaN, as in
    numpy), or ``None`` where numba is not installed. Compiled once a run; cached on disk where numba can keep a
    cache, compiled in every run (with a warning) where it cannot."""
    try:
        import numba
    except ImportError as error:  # an optional speed-up: each kernel's numpy twin computes the same
        log.info("numba is not installed (%s): %s runs in numpy", error, function.__name__)
        return None
    try:
        kernel, cached = numba.njit(nogil=True, cache=True, error_model="numpy")(function), True
    except RuntimeError as error:  # no folder numba may keep its cache in (a read-only install, no home)
        log.debug("%s cannot be cached: %s", function.__name__, error)
        _uncached()
        kernel, cached = numba.njit(nogil=True, error_model="numpy")(function), False
    _made[function] = kernel, cached
    return kernel


#: ``{function: (kernel, cached)}``: the kernel :func:`compiled` made last for each function in this process, and
#: whether numba keeps it in its cache on disk
_made: dict = {}


def keeps_cache() -> bool:
    """Whether numba keeps every kernel made so far in this process in its cache on disk, for later runs."""
    return all(cached for _, cached in _made.values())


def cache_counts() -> tuple[int, int]:
    """``(loaded, compiled)``: how many versions of this process's kernels (a kernel and the types it was called
    with) numba loaded from its cache, and how many it compiled."""
    kernels = [kernel for kernel, _ in _made.values()]
    return (sum(sum(k.stats.cache_hits.values()) for k in kernels),
            sum(sum(k.stats.cache_misses.values()) for k in kernels))


def compile_seconds() -> tuple[int, float]:
    """``(versions, seconds)``: the kernel versions compiled in this process (not loaded from numba's cache) and
    the time numba spent compiling them (a first run on a machine, or the first after an update)."""
    versions, seconds = 0, 0.0
    for kernel, _ in _made.values():
        for signature in kernel.stats.cache_misses:
            result = kernel.overloads.get(signature)
            timers = (getattr(result, "metadata", None) or {}).get("timers", {})
            versions += 1
            seconds += float(timers.get("compiler_lock", 0.0))
    return versions, seconds


@functools.cache
def _uncached() -> None:
    """Says once a run, not once a kernel, that numba keeps no cache here."""
    log.warning("numba cannot keep its cache here (no writable folder for it; NUMBA_CACHE_DIR names one): the "
                "compiled loops are compiled again in each run, a few seconds each")
