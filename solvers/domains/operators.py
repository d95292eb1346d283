"""One explicit store of the prefactored operators a domain owns.

Every expensive object derived from a domain (heat-kernel factorizations, EMD Poisson and
curl factors, the dense Green's matrix, Laplace–Beltrami eigenpairs, descriptors, ...) is
kept in ``domain.operators`` under a key naming what it is, e.g.
``("heat_kernel", t, substeps, backend)``::

    kernel = domain.operators.get(("heat_kernel", t, 1, "auto"), lambda: build(...))

* each entry is built once, under a per-key lock (concurrent jobs on one cached domain
  share one build, and builds of different keys do not wait for each other);
* each entry's size in bytes is measured when it is stored (:func:`nbytes_of`), so the
  service's LRU cache measures a domain as its geometry plus ``operators.nbytes``;
* nothing outside the library reaches into private attributes: callers ask the store.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Hashable

import numpy as np
import scipy.sparse as sp


def nbytes_of(obj, depth: int = 4, seen: set | None = None) -> int:
    """Bytes of the arrays and sparse matrices reachable from ``obj``, each counted once.

    Objects that know their size (an integer ``nbytes`` attribute, as numpy arrays and
    :mod:`solvers.linalg` factorizations have) report it; containers and plain objects are
    walked a few levels deep.
    """
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
    if isinstance(obj, (str, bytes, int, float, bool, type(None), type, OperatorStore)):
        return 0
    if isinstance(getattr(obj, "operators", None), OperatorStore):
        return 0  # a domain referenced by one of its operators is measured on its own
    own = getattr(obj, "nbytes", None)
    if isinstance(own, (int, np.integer)):
        return int(own)
    if depth <= 0:
        return 0
    if isinstance(obj, dict):
        children = obj.values()
    elif isinstance(obj, (list, tuple, set, frozenset)):
        children = obj
    elif hasattr(obj, "__dict__"):
        children = vars(obj).values()
    else:
        return 0
    return sum(nbytes_of(child, depth - 1, seen) for child in children)


class OperatorStore:
    """``key -> operator`` built once under a lock, with each entry's measured bytes."""

    def __init__(self):
        self._items: dict[Hashable, object] = {}
        self._sizes: dict[Hashable, int] = {}
        self._locks: dict[Hashable, threading.Lock] = {}
        self._guard = threading.Lock()
        self.builds = 0  # entries built so far (the service counts factorizations with it)

    def get(self, key: Hashable, build: Callable[[], object]):
        """The entry under ``key``, built by ``build()`` on first use (once, locked)."""
        try:
            return self._items[key]
        except KeyError:
            pass
        with self._guard:
            lock = self._locks.setdefault(key, threading.Lock())
        with lock:
            if key in self._items:  # built by a concurrent caller while we waited
                return self._items[key]
            value = build()
            size = nbytes_of(value)
            with self._guard:
                self._items[key] = value
                self._sizes[key] = size
                self.builds += 1
        return value

    def peek(self, key: Hashable, default=None):
        """The entry if built, else ``default`` (never builds)."""
        return self._items.get(key, default)

    def discard(self, key: Hashable) -> None:
        with self._guard:
            self._items.pop(key, None)
            self._sizes.pop(key, None)

    def clear(self) -> None:
        with self._guard:
            self._items.clear()
            self._sizes.clear()

    def keys(self) -> list:
        with self._guard:
            return list(self._items)

    def sizes(self) -> dict:
        """``{key: bytes}`` of every entry."""
        with self._guard:
            return dict(self._sizes)

    @property
    def nbytes(self) -> int:
        with self._guard:
            return int(sum(self._sizes.values()))

    def __contains__(self, key: Hashable) -> bool:
        return key in self._items

    def __len__(self) -> int:
        return len(self._items)


class ArtifactStore:
    """The persistent backing of a domain's costly, deterministic derived arrays
    (``domain.artifacts``): arrays kept by key beside the stored domain, so that every process
    loading the domain reads them instead of recomputing them.

    The library never needs one: a domain without it (``domain.artifacts is None``, the
    default) computes what it needs and keeps it in its operator store, per process.  The
    service supplies one bound to a stored domain (a folder of content-addressed files);
    any object with these three methods serves.  Keys name what an array is and how it was
    computed (e.g. ``"geodesics-mmp-float32"``); the store binds them to the domain's content.
    """

    def get(self, key: str) -> np.ndarray | None:
        """The stored array ``key`` (read-only, possibly memory-mapped), or None.

        Parameters
        ----------
        key : str
            What the array is.
        """
        raise NotImplementedError

    def put(self, key: str, array: np.ndarray) -> None:
        """Store ``array`` as ``key``, atomically (readers see no array or the whole one).

        Parameters
        ----------
        key : str
            What the array is.
        array : ndarray
            Its value.
        """
        raise NotImplementedError

    def has(self, key: str) -> bool:
        """Whether ``key`` is stored (stored data: the same answer in every process).

        Parameters
        ----------
        key : str
            What the array is.
        """
        raise NotImplementedError
