"""One numba decorator for the compiled kernels of every package."""

from __future__ import annotations

import numba


def cached_njit(**options):
    """``numba.njit(cache=True, ...)``; without a writable cache location numba refuses
    to cache (RuntimeError at decoration), so compile per process instead."""

    def wrap(fn):
        try:
            return numba.njit(cache=True, **options)(fn)
        except RuntimeError:  # pragma: no cover - depends on the file system
            return numba.njit(**options)(fn)

    return wrap
