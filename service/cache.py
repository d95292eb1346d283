"""Per-process LRU cache of built domains, which own their prefactored operators.

A domain keeps every operator built for it in its operator store
(``domain.operators``, :mod:`solvers.domains.operators`), so one entry keyed by the
domain id holds them all: the cache key is effectively ``(domain id, operator,
parameters)``.  The cache is bounded in bytes; an entry's size is the domain's
``nbytes`` (its arrays plus the store's measured entries), refreshed after every job
since operators are added as they are used.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable

from solvers.domains.operators import nbytes_of


def estimate_bytes(domain) -> int:
    """Memory held by a domain: its arrays plus every entry of its operator store (as the
    store measured them; factorizations report their estimated fill)."""
    own = getattr(domain, "nbytes", None)
    return int(own) if isinstance(own, int) else nbytes_of(domain)


class OperatorCache:
    """LRU of ``key -> object`` bounded by ``max_bytes`` (estimated with ``sizeof``)."""

    def __init__(self, max_bytes: int, sizeof: Callable[[object], int] = estimate_bytes):
        self.max_bytes = int(max_bytes)
        self.sizeof = sizeof
        self._items: OrderedDict = OrderedDict()
        self._sizes: dict = {}
        self._lock = threading.RLock()
        self.hits = 0
        self.misses = 0
        self.evictions = 0
        self.operator_builds = 0  # heat kernels (factorizations) built inside cached domains

    def get_or_build(self, key, build: Callable[[], object]):
        with self._lock:
            if key in self._items:
                self._items.move_to_end(key)
                self.hits += 1
                return self._items[key]
            self.misses += 1
        value = build()
        with self._lock:
            if key in self._items:  # built concurrently by another thread
                return self._items[key]
            self._items[key] = value
            self._sizes[key] = self.sizeof(value)
            self._evict()
        return value

    def refresh(self, key) -> None:
        """Re-estimate an entry's size (its operators grew) and evict if needed."""
        with self._lock:
            if key in self._items:
                self._sizes[key] = self.sizeof(self._items[key])
                self._evict(keep=key)

    def discard(self, key) -> None:
        with self._lock:
            self._items.pop(key, None)
            self._sizes.pop(key, None)

    def discard_where(self, predicate: Callable[[object], bool]) -> None:
        with self._lock:
            for key in [k for k in self._items if predicate(k)]:
                self.discard(key)

    def _evict(self, keep=None) -> None:
        """Drop least recently used entries until within budget.

        The newest entry (``keep``, or the most recent) is never dropped: it is in use.
        """
        keep = keep if keep is not None else next(reversed(self._items), None)
        while sum(self._sizes.values()) > self.max_bytes:
            victim = next((k for k in self._items if k != keep), None)
            if victim is None:
                break
            self.discard(victim)
            self.evictions += 1

    @property
    def bytes(self) -> int:
        with self._lock:
            return int(sum(self._sizes.values()))

    def __len__(self) -> int:
        return len(self._items)

    def __contains__(self, key) -> bool:
        return key in self._items

    def stats(self) -> dict:
        with self._lock:
            operators = sum(len(v.operators) for v in self._items.values()
                            if hasattr(v, "operators"))
            return {"hits": self.hits, "misses": self.misses, "evictions": self.evictions,
                    "entries": len(self._items), "operators": operators,
                    "operator_builds": self.operator_builds, "bytes": self.bytes,
                    "max_bytes": self.max_bytes}

