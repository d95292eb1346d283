"""All-pairs geodesics as artifacts of a stored domain: computed once, read by every process,
counted in the matrix job's cost only while they are not stored (issue 42)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from shared_meshes import MESHES_DIR, hat_bump, load_shared_mesh

from service.operations.base import COST_PER_SECOND, view_of_info
from service.operations.matrices import (
    DistanceMatrixRequest,
    decide_matrix_job,
    estimate_cost,
    geodesics_cost,
)
from service.store import Store
from solvers.convolutional import distance_matrix
from solvers.domains import TriangleMesh
from solvers.domains.mesh import GEODESICS_ARTIFACT

ROOT = Path(__file__).resolve().parents[2]
CENTRES = (0, 100, 300, 500, 650)
RADIUS = 0.4

# One worker process: loads the stored domain through the store, computes the exact matrix
# and reports how many all-pairs computations and MMP solves it ran (counters wrapped
# around the library's functions), its values, and whether it found the artifact stored.
WORKER = """
import json, sys
import numpy as np
import solvers.geodesics as g
from service.store import Store
from solvers.convolutional import distance_matrix
from solvers.domains.mesh import GEODESICS_ARTIFACT

calls = {"all_pairs": 0, "solves": 0}
all_pairs, one_to_all = g.all_pairs_geodesics, g._one_to_all

def counted_all_pairs(*args, **kwargs):
    calls["all_pairs"] += 1
    return all_pairs(*args, **kwargs)

def counted_one_to_all(*args, **kwargs):
    calls["solves"] += 1
    return one_to_all(*args, **kwargs)

g.all_pairs_geodesics, g._one_to_all = counted_all_pairs, counted_one_to_all
store, domain_id = Store(sys.argv[1]), sys.argv[2]
domain = store.load_domain(domain_id)
before = domain.artifacts.has(GEODESICS_ARTIFACT)
masses = np.load(sys.argv[3])
res = distance_matrix(domain, masses, method="exact", threads=1)
print(json.dumps({"calls": calls, "stored_before": before, "values": res.values.tolist()}))
"""


@pytest.fixture(scope="module")
def woody():
    mesh = load_shared_mesh("woody.obj")
    masses = np.stack([hat_bump(mesh, i, RADIUS) for i in CENTRES], axis=1)
    assert 2 * np.count_nonzero(masses.sum(axis=1)) >= mesh.n  # the stored ones serve
    return mesh, masses


@pytest.fixture(scope="module")
def first_worker(tmp_path_factory, woody) -> tuple[Store, str, Path, dict]:
    """``(store, domain id, masses file, report)`` of a first worker process computing the
    exact matrix on a freshly stored woody: it solves and stores the all-pairs geodesics
    (~5,000 MMP solves), once for the module."""
    _, masses = woody
    root = tmp_path_factory.mktemp("woody-first-worker")
    store = Store(root / "data")
    meta, _ = store.put_domain(TriangleMesh.from_file(MESHES_DIR / "woody.obj"))
    np.save(root / "masses.npy", masses)
    return store, meta["id"], root / "masses.npy", _worker(store.root, meta["id"],
                                                           root / "masses.npy")


@pytest.fixture(scope="module")
def woody_artifact(first_worker) -> np.ndarray:
    """The service's float32 all-pairs geodesics of woody, as the first worker process stored
    them (``stored_ground_distances``); the tests that need them stored write them to their
    own store (``_stored``) instead of solving them again each."""
    store, domain_id, _, _ = first_worker
    return np.array(store.domain_artifacts(domain_id).get(GEODESICS_ARTIFACT))


def _stored(store: Store, domain_id: str, artifact: np.ndarray) -> None:
    store.domain_artifacts(domain_id).put(GEODESICS_ARTIFACT, artifact)


def _worker(store_dir: Path, domain_id: str, masses_file: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", WORKER, str(store_dir), domain_id,
                          str(masses_file)], capture_output=True, text=True, env=env,
                         timeout=600, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_second_worker_process_reads_the_artifact_without_solving(first_worker):
    store, domain_id, masses_file, first = first_worker
    assert not first["stored_before"]
    assert first["calls"]["all_pairs"] == 1
    assert store.domain_artifacts(domain_id).has(GEODESICS_ARTIFACT)
    second = _worker(store.root, domain_id, masses_file)
    assert second["stored_before"]
    assert second["calls"] == {"all_pairs": 0, "solves": 0}
    assert second["values"] == first["values"]
    stored = store.domain_artifacts(domain_id).get(GEODESICS_ARTIFACT)
    assert stored.dtype == np.float32 and isinstance(stored, np.memmap)


def test_float32_artifact_values_within_tolerance_of_float64(tmp_path, woody, woody_artifact):
    mesh, masses = woody
    store = Store(tmp_path)
    meta, _ = store.put_domain(TriangleMesh.from_file(MESHES_DIR / "woody.obj"))
    _stored(store, meta["id"], woody_artifact)
    stored = store.load_domain(meta["id"])
    from_artifact = distance_matrix(stored, masses, method="exact").values
    exact = distance_matrix(mesh, masses, method="exact").values  # float64, library only
    d64 = mesh.operators.peek(("exact_geodesics",))
    d32 = store.domain_artifacts(meta["id"]).get(GEODESICS_ARTIFACT)
    finite = np.isfinite(d64)
    assert np.abs(d32[finite] - d64[finite]).max() <= 1e-6 * d64[finite].max()
    off = ~np.eye(len(CENTRES), dtype=bool)
    rel = np.abs(from_artifact[off] - exact[off]) / np.abs(exact[off])
    assert rel.max() <= 1e-6


def test_matrix_cost_differs_only_by_the_artifact(tmp_path, woody, woody_artifact):
    mesh, masses = woody
    store = Store(tmp_path)
    meta, _ = store.put_domain(TriangleMesh.from_file(MESHES_DIR / "woody.obj"))
    spec = [{"vertex": i, "radius": RADIUS} for i in CENTRES]
    req = DistanceMatrixRequest(distributions=spec, method="exact")

    def decided():
        view = view_of_info(store.domain_info(meta["id"]))
        return estimate_cost(view.n, req, view), decide_matrix_job(view, req), view

    cold_cost, cold_decision, view = decided()
    extra = geodesics_cost(view, req)
    assert extra == pytest.approx(COST_PER_SECOND * TriangleMesh.stored_ground_distance_seconds(
        mesh.n))
    _stored(store, meta["id"], woody_artifact)  # as stored_ground_distances() stores them
    warm_cost, warm_decision, _ = decided()
    assert cold_cost - warm_cost == pytest.approx(extra)
    assert warm_decision == cold_decision
    # the library alone: no artifacts, no such cost, today's per-process store
    assert mesh.artifacts is None and not mesh.has_stored_geodesics()
