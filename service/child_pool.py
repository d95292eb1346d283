"""A one-process pool for work kept out of the API process (JSON parsing, domain builds).

Its child exits when the API dies, even by SIGKILL (``PR_SET_PDEATHSIG`` on Linux). That
signal follows the *thread* that started the child, so a pool started by an event loop that
has ended since (an app closed and another started in the same process, as in tests) is
replaced before use.
"""

from __future__ import annotations

import multiprocessing
import threading
from concurrent.futures import ProcessPoolExecutor


def die_with_parent() -> None:
    """Child initializer: exit when the API process dies (Linux), even by SIGKILL."""
    import signal
    import sys

    if sys.platform.startswith("linux"):
        try:
            import ctypes

            ctypes.CDLL(None).prctl(1, signal.SIGKILL, 0, 0, 0)  # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass


class ChildPool:
    """``get(*initargs)`` -> a live single-process executor whose child ran
    ``initializer(*initargs)``; ``discard()`` or ``retire()`` drops it (the next ``get``
    starts another)."""

    def __init__(self, initializer=die_with_parent):
        self.initializer = initializer
        self._pool: ProcessPoolExecutor | None = None
        self._key: tuple | None = None
        self._creator: threading.Thread | None = None
        self._lock = threading.Lock()

    def get(self, *initargs) -> ProcessPoolExecutor:
        with self._lock:
            stale = self._pool is None or self._key != initargs or \
                not self._creator.is_alive()
            if stale:
                if self._pool is not None:
                    self._pool.shutdown(wait=False, cancel_futures=True)
                self._pool = ProcessPoolExecutor(
                    max_workers=1, mp_context=multiprocessing.get_context("spawn"),
                    initializer=self.initializer, initargs=initargs)
                self._key, self._creator = initargs, threading.current_thread()
            return self._pool

    @property
    def active(self) -> bool:
        return self._pool is not None

    def discard(self) -> None:
        """Drop the pool, cancelling the work queued in it."""
        self._drop(cancel=True)

    def retire(self) -> None:
        """Drop the pool once the work queued in it is done (its child then exits)."""
        self._drop(cancel=False)

    def _drop(self, cancel: bool) -> None:
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=cancel)
