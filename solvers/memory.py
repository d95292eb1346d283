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

# glibc's mallopt parameter for the mmap threshold (malloc.h: M_MMAP_THRESHOLD = -3).
_M_MMAP_THRESHOLD = -3
# Blocks from this size on are mapped on their own (and unmapped when freed).
LARGE_BLOCK = 4 << 20


@functools.cache
def _libc():
    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
    except OSError:
        return None


@functools.cache
def _malloc_trim():
    trim = getattr(_libc(), "malloc_trim", None)
    if trim is None:
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return trim


def release_free_heap() -> bool:
    """Give freed heap memory of every glibc arena back to the OS; ``True`` if any was."""
    trim = _malloc_trim()
    return bool(trim(0)) if trim is not None else False


@functools.cache
def map_large_blocks() -> bool:
    """Have glibc map every block of :data:`LARGE_BLOCK` bytes or more on its own, so that
    freeing it returns it to the OS at once; ``True`` if set.

    By default glibc raises its mmap threshold to the size of the largest block freed (up
    to 32 MiB), after which blocks of that size come from the heap and stay resident when
    freed: a soft map's (samples x target) temporaries of 4-30 MB then stack up across its
    stages.  Process-wide and once per process (it also stops that dynamic adjustment);
    elsewhere (musl, macOS) a no-op.
    """
    mallopt = getattr(_libc(), "mallopt", None)
    if mallopt is None:
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, LARGE_BLOCK))
