"""Warm-up of the operations whose first run compiles numba kernels (``Operation.warm``).

numba compiles a kernel on its first call in a process, or loads it from its on-disk cache
(``cache=True``: ``__pycache__`` beside the source, or ``NUMBA_CACHE_DIR``). A fresh install
has no cache, so the first color transfer spent about a minute compiling while its job sat
at iteration 0. Hence:

- ``python -m service.warm`` (run by ``make install`` and the Docker build) fills the cache;
- every worker warms in a background thread when it starts (``start_background``), which
  compiles once after the kernels' sources changed and otherwise loads the cache;
- a job of such an operation first waits for its warm-up (``ensure``) while its progress
  says so (stage ``WARM_STAGE``), then runs on compiled kernels.
"""

from __future__ import annotations

import logging
import threading
import time

from service.operations import build_registry

log = logging.getLogger("otgeo.warm")

WARM_STAGE = "preparing compiled kernels (the first run of a fresh install compiles them, " \
             "about a minute)"

_locks: dict[str, threading.Lock] = {}
_done: set[str] = set()
_guard = threading.Lock()


def _lock(name: str) -> threading.Lock:
    with _guard:
        return _locks.setdefault(name, threading.Lock())


def is_warm(op) -> bool:
    return op.warm is None or op.name in _done


def ensure(op) -> None:
    """Run ``op.warm()`` once per process; a caller arriving while another thread warms
    waits for it. A failed warm-up is logged, not raised: the job then compiles itself."""
    if is_warm(op):
        return
    with _lock(op.name):
        if op.name in _done:
            return
        start = time.perf_counter()
        try:
            op.warm()
        except Exception:
            log.exception("warm-up of %s failed", op.name)
        else:
            log.info("%s kernels ready in %.1f s", op.name, time.perf_counter() - start)
        _done.add(op.name)


def warm_all(operations) -> None:
    for op in operations.values():
        ensure(op)


def start_background(operations) -> threading.Thread:
    """Warm every operation in a daemon thread (the worker serves jobs meanwhile)."""
    thread = threading.Thread(target=warm_all, args=(operations,), daemon=True,
                              name="warm-up")
    thread.start()
    return thread


def main() -> None:
    """Fill numba's cache with what every operation's warm-up compiles."""
    import os

    logging.basicConfig(level=logging.INFO, format="%(message)s")
    start = time.perf_counter()
    warm_all(build_registry())
    where = os.environ.get("NUMBA_CACHE_DIR") or "__pycache__ beside the sources"
    print(f"compiled kernels ready in {time.perf_counter() - start:.1f} s (cache: {where})")


if __name__ == "__main__":
    main()
