"""Giving freed heap memory back to the operating system between the stages of a long run.

glibc serves allocations below its (adaptive, up to 32 MB) mmap threshold from the heap and keeps what is freed
there for reuse, so a stage's temporaries (a CSV parser's chunks, a replay's scratch) stay resident after they
are freed: on a simulated hour at 200 Hz ~70 MB after the load alone. ``malloc_trim`` returns the free pages at
the stage boundaries; elsewhere (another C library, another system) this does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools


@functools.lru_cache(maxsize=1)
def _malloc_trim():
    name = ctypes.util.find_library("c")
    try:
        fn = ctypes.CDLL(name).malloc_trim if name else None
    except (OSError, AttributeError):       # not glibc: nothing to trim
        return None
    if fn is not None:
        fn.argtypes, fn.restype = [ctypes.c_size_t], ctypes.c_int
    return fn


def release_free_heap() -> bool:
    """Return the heap's free pages to the system (glibc's ``malloc_trim(0)``); False where there is none."""
    fn = _malloc_trim()
    return bool(fn(0)) if fn is not None else False
