"""Per-process LRU cache of built domains, which own their prefactored operators.

A domain object caches its heat kernels per ``(t, substeps, backend)``, so one
entry keyed by the domain id holds every operator built for it: the cache key is
effectively ``(domain id, operator, parameters)``.  The cache is bounded in
bytes; sizes are estimates (arrays + sparse matrices + Cholesky fill), refreshed
after every job since kernels are added as they are used.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable

import numpy as np
import scipy.sparse as sp

# A sparse Cholesky factor of a mesh Laplacian-like matrix has a few times the
# nonzeros of the matrix (nested dissection fill); counted at 12 bytes/nonzero.
FACTOR_FILL = 8.0


def _nbytes(obj, depth: int = 3, seen: set | None = None) -> int:
    """Bytes of the arrays and sparse matrices reachable from ``obj`` (a few levels deep:
    attributes of operator objects, dict/list members), each counted once."""
    seen = set() if seen is None else seen
    if id(obj) in seen:
        return 0
    seen.add(id(obj))
    if isinstance(obj, np.ndarray):
        return int(obj.nbytes)
    if sp.issparse(obj):
        return sum(int(getattr(obj, name).nbytes) for name in ("data", "indices", "indptr",
                                                               "row", "col")
                   if isinstance(getattr(obj, name, None), np.ndarray))
    if depth <= 0 or isinstance(obj, (str, bytes, int, float, bool, type(None))):
        return 0
    if isinstance(obj, dict):
        children = obj.values()
    elif isinstance(obj, (list, tuple)):
        children = obj
    elif hasattr(obj, "__dict__") and not isinstance(obj, type):
        children = vars(obj).values()
    else:
        return 0
    return sum(_nbytes(child, depth - 1, seen) for child in children)


def estimate_bytes(domain) -> int:
    """Rough memory held by a domain and the operators it has built so far: every array
    and sparse matrix reachable from it, plus the Cholesky fill of each factored kernel
    (the factor itself lives in C++ and cannot be measured)."""
    total = _nbytes(domain)
    nnz = 7 * int(domain.n)  # a triangle mesh Laplacian has about 7 nonzeros per row
    for name in ("robust_laplacian", "cotan_laplacian", "laplacian", "_laplacian"):
        lap = domain.__dict__.get(name)
        if lap is not None and sp.issparse(lap):
            nnz = int(lap.nnz)
            break
    for kernel in getattr(domain, "_kernels", {}).values():
        if hasattr(kernel, "factor"):
            total += int(FACTOR_FILL * nnz * 12)
    return total


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
            operators = sum(len(getattr(v, "_kernels", {})) for v in self._items.values())
            return {"hits": self.hits, "misses": self.misses, "evictions": self.evictions,
                    "entries": len(self._items), "operators": operators,
                    "operator_builds": self.operator_builds, "bytes": self.bytes,
                    "max_bytes": self.max_bytes}

