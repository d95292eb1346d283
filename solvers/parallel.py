"""Threads for compiled kernels that release the GIL (numba ``nogil``, BLAS)."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor

from solvers.validation import check_int


def thread_count(threads: int | None = None) -> int:
    """``threads`` checked (>= 1), or by default the CPUs this process may use."""
    if threads is None:
        try:
            return max(1, len(os.sched_getaffinity(0)))
        except AttributeError:  # pragma: no cover - not Linux
            return max(1, os.cpu_count() or 1)
    return check_int(threads, "threads", low=1)


def run_blocks(work: Callable[[slice], None], n: int, block: int,
               threads: int | None = None) -> None:
    """``work(rows)`` for consecutive row blocks of ``range(n)``, in threads (each block
    writes its own rows, so the order does not matter)."""
    blocks: Iterable[slice] = [slice(s, min(s + block, n)) for s in range(0, n, block)]
    count = min(thread_count(threads), len(blocks))
    if count <= 1:
        for rows in blocks:
            work(rows)
        return
    with ThreadPoolExecutor(count) as pool:
        for _ in pool.map(work, blocks):
            pass
