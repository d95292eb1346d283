"""Working memory of jobs vs the service's submission estimate (service.operations.base.
estimate_job_bytes): tracemalloc peak of numpy allocations during the solve, after the
domain's operators (heat kernel factorization: cached, counted by the operator cache) are
built. Memory does not depend on load; the load is printed anyway.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -P bench/job_memory.py   # -P: bench/service.py
    would shadow the service package
"""

from __future__ import annotations

import os
import tracemalloc

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from service.operations.base import DomainView, estimate_job_bytes  # noqa: E402
from service.operations.transport import BarycenterRequest, PropagationRequest  # noqa: E402
from solvers.convolutional import barycenter, wasserstein_propagation  # noqa: E402
from solvers.domains import Grid, load_mesh  # noqa: E402

MESHES = "/work/shared/meshes"


def view(domain) -> DomainView:
    return DomainView(kind=domain.kind, n=domain.n, areas=domain.areas,
                      component_labels=domain.component_labels,
                      n_faces=getattr(domain, "n_faces", None))


def peak(fn, *args, **kwargs) -> int:
    tracemalloc.start()
    fn(*args, **kwargs)
    out = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return out


def main() -> None:
    with open("/proc/loadavg") as fh:
        print("load before", fh.read().split()[:3])
    rng = np.random.default_rng(0)
    rows = []
    for name, domain in (("grid 200x200", Grid([200, 200])),
                         ("stanford-bunny", load_mesh(f"{MESHES}/stanford-bunny.obj"))):
        h = max(domain.spacing) if domain.kind == "grid" else domain.mean_edge_length
        gamma = (2 * h) ** 2
        domain.heat_kernel(gamma / 4)
        for k in (4, 16):
            M = np.zeros((domain.n, k))
            for j in range(k):
                M[rng.integers(0, domain.n, 20), j] = 1.0
            used = peak(barycenter, domain, M, gamma=gamma, max_iter=100)
            req = BarycenterRequest(distributions=[[0.0]] * k)
            rows.append((name, f"barycenter k={k}", used, estimate_job_bytes(view(domain), req)))
        nodes = 6
        edges = [[i, i + 1] for i in range(nodes - 1)]
        fixed = {0: M[:, 0] / M[:, 0].sum(), nodes - 1: M[:, 1] / M[:, 1].sum()}
        used = peak(wasserstein_propagation, domain, nodes, edges, fixed, gamma=gamma,
                    max_iter=50)
        req = PropagationRequest(n_nodes=nodes, edges=edges, fixed=[
            {"node": 0, "distribution": [0.0]}, {"node": nodes - 1, "distribution": [0.0]}])
        rows.append((name, f"propagation {nodes} nodes", used,
                     estimate_job_bytes(view(domain), req)))
    print(f"{'domain':16} {'job':24} {'measured MB':>12} {'estimate MB':>12} {'ratio':>6}")
    for name, job, used, est in rows:
        print(f"{name:16} {job:24} {used / 2**20:12.1f} {est / 2**20:12.1f} "
              f"{est / used:6.2f}")
    with open("/proc/loadavg") as fh:
        print("load after", fh.read().split()[:3])


if __name__ == "__main__":
    main()
