"""Returning freed heap memory to the operating system (glibc's ``malloc_trim``).

glibc keeps freed blocks in its heaps (one per thread that allocated: the solvers' worker
threads each get one) and raises its mmap threshold after large frees, so a process that
allocated and freed large temporaries keeps them resident.  A long solve that is about to
allocate its working arrays (or a service job that has finished) hands them back first, so
the next peak does not stack on top of memory nobody uses.  Elsewhere (musl, macOS) this is
a no-op.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools


@functools.cache
def _malloc_trim():
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        trim = libc.malloc_trim
    except (OSError, AttributeError):
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return trim


def release_free_heap() -> bool:
    """Give freed heap memory of every glibc arena back to the OS; ``True`` if any was."""
    trim = _malloc_trim()
    return bool(trim(0)) if trim is not None else False
