"""Giving memory that numpy has freed back to the system.

A freed array goes back to the C library's allocator, which keeps it for the next allocation. On glibc,
once a large block that it mapped on its own has been freed, blocks up to that size (32 MB at most) are
carved from the heap instead, and the heap does not shrink while anything lives above the freed space: a
room's hundreds of photo views of a few MB each, freed while other arrays are made, stayed in the process's
resident memory (1 GB of 3.5 at the peak of 438 views). :func:`trim` asks glibc (``malloc_trim``) to give
the free pages back; elsewhere (another C library, another system) it does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools


@functools.cache
def _malloc_trim():
    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim
    except (OSError, AttributeError):  # no C library by that name, or one without malloc_trim
        return None


def trim() -> None:
    """Give the allocator's free memory back to the system, where the C library can (glibc); a few ms."""
    malloc_trim = _malloc_trim()
    if malloc_trim is not None:
        malloc_trim(0)
