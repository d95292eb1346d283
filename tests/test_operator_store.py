"""The one operator store per domain: built once under a lock, each entry measured."""

from __future__ import annotations

import threading
import time

import numpy as np

from solvers import Grid
from solvers.domains.operators import OperatorStore, nbytes_of
from solvers.emd import earth_movers_distance


def test_concurrent_callers_share_one_build():
    store = OperatorStore()
    calls = []

    def build():
        calls.append(1)
        time.sleep(0.05)
        return np.zeros(1000)

    results = []
    threads = [threading.Thread(target=lambda: results.append(store.get("x", build)))
               for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(calls) == 1 and store.builds == 1
    assert all(r is results[0] for r in results)
    assert store.sizes() == {"x": 8000} and store.nbytes == 8000


def test_different_keys_do_not_wait_for_each_other():
    store = OperatorStore()
    release = threading.Event()
    slow = threading.Thread(target=lambda: store.get("slow", lambda: release.wait(5)))
    slow.start()
    t0 = time.monotonic()
    store.get("fast", lambda: 1)
    assert time.monotonic() - t0 < 1.0 and "fast" in store
    release.set()
    slow.join()


def test_sizes_count_arrays_sparse_and_self_reported_bytes():
    import scipy.sparse as sp

    class Factor:
        nbytes = 12345

    m = sp.identity(10, format="csr")
    assert nbytes_of(m) == m.data.nbytes + m.indices.nbytes + m.indptr.nbytes
    assert nbytes_of({"a": np.zeros(3), "b": [np.zeros(2), Factor()]}) == 24 + 16 + 12345
    shared = np.zeros(5)
    assert nbytes_of([shared, shared]) == 40  # counted once


def test_heat_kernels_and_emd_factors_live_in_the_store(shared_mesh):
    grid = Grid((16, 16))
    k1 = grid.heat_kernel(0.01)
    assert grid.heat_kernel(0.01) is k1 and len(grid.operators) == 1
    woody = shared_mesh("woody.obj")
    before, store_before = woody.nbytes, woody.operators.nbytes
    m0 = np.zeros(woody.n)
    m0[0] = 1.0
    m1 = np.zeros(woody.n)
    m1[300] = 1.0
    earth_movers_distance(woody, m0, m1, tol=1e-3)  # interior point over all flows
    earth_movers_distance(woody, m0, m1, basis="full", tol=1e-3)  # ADMM over the curl basis
    keys = woody.operators.keys()
    assert "emd" in keys and ("emd", "curl_factor") in keys and ("emd", "stream") in keys
    assert ("emd", "interior_point") in keys
    sizes = woody.operators.sizes()
    # the Poisson and curl factorizations are counted (estimated fill), not zero
    assert sizes["emd"] > 0 and sizes[("emd", "curl_factor")] > 0
    assert sizes[("emd", "interior_point")] > 0  # frames, divergence, normal pattern
    assert woody.operators.nbytes == sum(sizes.values())
    grown = woody.operators.nbytes - store_before
    assert woody.nbytes - before >= grown  # geometry cached on the way may add more
