"""Memory bound of a worker process (the per-job bound is checked at submission).

At submission a job's working memory is estimated from its sizes and refused above
``Settings.job_memory_bytes`` (``service.operations.base.check_job_memory``). In the worker,
``limit_worker_memory`` caps the process's address space (``RLIMIT_AS``) at what one job
plus the operator cache may use, so an underestimated job fails with ``MemoryError``
(reported as ``out_of_memory``) instead of swapping the machine. Measured to work with
numba's compiled kernels and cholespy factorizations when BLAS threads are pinned (one
thread reserves little address space; many OpenBLAS threads reserve tens of MB each).
"""

from __future__ import annotations

import logging

log = logging.getLogger("otgeo.worker")

# Address space of a worker before any job: interpreter, numpy/scipy/numba/LLVM, thread
# stacks, allocator slack (virtual, not resident).
WORKER_BASE_BYTES = 2 * 2**30


def worker_memory_limit(settings) -> int:
    """Bytes of address space a worker may use: base + operator cache + one job."""
    return WORKER_BASE_BYTES + int(settings.cache_bytes) + int(settings.job_memory_bytes)


def limit_worker_memory(settings) -> int | None:
    """Set ``RLIMIT_AS`` of this process (never raising an existing lower limit); returns
    the limit set, or None where the platform has no such limit."""
    try:
        import resource
    except ImportError:  # pragma: no cover - not on POSIX
        return None
    limit = worker_memory_limit(settings)
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    if hard != resource.RLIM_INFINITY:
        limit = min(limit, hard)
    if soft != resource.RLIM_INFINITY and soft <= limit:
        return soft
    try:
        resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
    except (ValueError, OSError) as exc:  # pragma: no cover - refused by the system
        log.warning("could not limit the worker's address space: %s", exc)
        return None
    log.info("worker address space limited to %.1f GiB", limit / 2**30)
    return limit
