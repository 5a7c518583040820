"""Loops compiled with numba: the field's compiler for per-point work that numpy would do in dozens of passes.

A kernel is a plain Python function over arrays and numbers, compiled by :func:`compiled` on first use (a few
seconds) and cached on disk by numba beside its module, so later runs load it (a fraction of a second). A
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
        return numba.njit(nogil=True, cache=True, error_model="numpy")(function)
    except RuntimeError as error:  # no folder numba may keep its cache in (a read-only install, no home)
        log.debug("%s cannot be cached: %s", function.__name__, error)
        _uncached()
        return numba.njit(nogil=True, error_model="numpy")(function)


@functools.cache
def _uncached() -> None:
    """Says once a run, not once a kernel, that numba keeps no cache here."""
    log.warning("numba cannot keep its cache here (no writable folder for it; NUMBA_CACHE_DIR names one): the "
                "compiled loops are compiled again in each run, a few seconds each")
