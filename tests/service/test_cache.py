"""The operator cache: LRU order, byte bound, hit/miss counters, size estimates."""

from __future__ import annotations

import numpy as np

from service.cache import OperatorCache, estimate_bytes
from solvers.domains import Grid


def test_lru_eviction_by_bytes():
    cache = OperatorCache(max_bytes=250, sizeof=lambda v: v)
    built = []

    def build(value):
        built.append(value)
        return value

    assert cache.get_or_build("a", lambda: build(100)) == 100
    assert cache.get_or_build("b", lambda: build(100)) == 100
    cache.get_or_build("a", lambda: build(-1))  # hit: "a" becomes most recent
    cache.get_or_build("c", lambda: build(100))  # 300 > 250: evict LRU ("b")
    assert "a" in cache and "c" in cache and "b" not in cache
    assert cache.bytes == 200 and cache.stats()["evictions"] == 1
    assert (cache.hits, cache.misses) == (1, 3)
    assert built == [100, 100, 100]
    cache.get_or_build("big", lambda: build(1000))  # larger than the bound: kept alone
    assert len(cache) == 1 and "big" in cache


def test_refresh_grows_entry_size_with_operators(shared_mesh):
    mesh = shared_mesh("woody.obj")
    from solvers.domains import TriangleMesh

    fresh = TriangleMesh(mesh.to_arrays()["vertices"], mesh.faces)
    cache = OperatorCache(max_bytes=10**9)
    cache.get_or_build("m", lambda: fresh)
    before = cache.bytes
    assert before >= fresh.vertices.nbytes + fresh.faces.nbytes
    fresh.heat_kernel(1e-3)  # builds the Laplacian and a factorization
    cache.refresh("m")
    assert cache.bytes > before + fresh.laplacian.nnz * 12
    # d_W^0 one-to-all keeps a dense float32 Green's matrix (4 V^2 bytes) on the mesh
    with_factor = cache.bytes
    from solvers.emd import pointwise_distances

    pointwise_distances(fresh, 0, method="green")
    cache.refresh("m")
    assert cache.bytes >= with_factor + 4 * fresh.n**2


def test_estimate_counts_arrays():
    grid = Grid((10, 10))
    arrays = grid.points.nbytes + np.asarray(grid.areas).nbytes
    assert estimate_bytes(grid) >= arrays
