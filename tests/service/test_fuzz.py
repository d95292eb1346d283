"""schemathesis over the app's own OpenAPI spec, in process (ASGI transport, immediate queue):
no request the fuzzer makes, valid or not, gets a 5xx, and no job it submits fails with an
internal error.

Path parameters ``domain_id`` / ``job_id`` are mostly replaced by ids that exist (small
domains of every kind uploaded first, jobs the fuzzer created), so request bodies reach the
operations' validation and, when valid, the solvers. Bounded examples and a fixed seed
(hypothesis ``derandomize``) keep the suite run at ~30 s; run longer outside the suite::

    .venv/bin/python tests/service/test_fuzz.py --examples 150   # per operation and mode
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import tempfile
import time
import warnings
from collections import Counter

import numpy as np
import pytest

schemathesis = pytest.importorskip("schemathesis")

from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis.errors import Unsatisfiable  # noqa: E402
from schemathesis import GenerationMode  # noqa: E402
from schemathesis.checks import not_a_server_error  # noqa: E402

SUITE_EXAMPLES = 12  # per operation and generation mode (positive, negative)
SKIP = {("get", "/v1/jobs/{job_id}/events")}  # streams until the job ends (covered elsewhere)


def _domains(client) -> dict[str, str]:
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=1)
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(40, 3))
    bodies = {
        "mesh": {"kind": "mesh", "vertices": sphere.vertices.tolist(),
                 "faces": sphere.faces.tolist()},
        "grid": {"kind": "grid", "shape": [6, 6]},
        "graph": {"kind": "graph", "n_nodes": 8, "edges": [[i, i + 1] for i in range(7)]},
        "pointcloud": {"kind": "pointcloud", "points": (pts / np.linalg.norm(pts, axis=1)[:, None])
                       .tolist(), "n_neighbors": 8},
    }
    ids = {}
    for kind, body in bodies.items():
        r = client.post("/v1/domains", json=body)
        assert r.status_code in (200, 201), r.text
        ids[kind] = r.json()["id"]
    return ids


def fuzz(data_dir, examples: int, log=None) -> dict:
    """Run every operation of the spec with ``examples`` cases per generation mode.

    Returns counts: cases, statuses, server errors (method, path, status, body excerpt),
    jobs submitted and jobs that failed with ``internal_error``."""
    from fastapi.testclient import TestClient

    from service.app import create_app
    from service.settings import Settings

    app = create_app(Settings(data_dir=data_dir, queue="immediate", job_time_limit=5.0,
                              wait_max=1.0))
    stats = {"cases": 0, "statuses": Counter(), "server_errors": [], "jobs": 0,
             "job_states": Counter(), "internal_job_errors": [], "by_operation": Counter(),
             "job_errors": Counter(),
             "by_status": Counter()}
    with TestClient(app) as client:
        domains = list(_domains(client).values())
        job_ids: list[str] = []
        schema = schemathesis.openapi.from_asgi("/openapi.json", app)
        operations = [r.ok() for r in schema.get_all_operations()]
        for op in operations:
            if (op.method.lower(), op.path) in SKIP:
                continue
            for mode in (GenerationMode.POSITIVE, GenerationMode.NEGATIVE):
                counter = {"i": 0}
                run = _make_run(op, mode, examples, counter, domains, job_ids, stats)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    try:
                        run()
                    except Unsatisfiable:  # no invalid request exists (no parameters)
                        pass
            if log:
                key = f"{op.method.upper()} {op.path}"
                log(f"{key}: {stats['by_operation'][key]} cases")
    return stats


def _make_run(op, mode, examples, counter, domains, job_ids, stats):
    """One hypothesis test: ``examples`` cases of ``op`` in ``mode`` (fixed seed)."""

    @settings(max_examples=examples, derandomize=True, deadline=None,
              database=None, suppress_health_check=list(HealthCheck))
    @given(case=op.as_strategy(generation_mode=mode))
    def run(case):
        counter["i"] += 1
        params = case.path_parameters or {}
        if "domain_id" in params and counter["i"] % 4 and op.method.lower() != "delete":
            params["domain_id"] = domains[counter["i"] % len(domains)]
        if "job_id" in params and job_ids and counter["i"] % 4:
            params["job_id"] = job_ids[counter["i"] % len(job_ids)]
        if mode == GenerationMode.POSITIVE and counter["i"] % 2 == 0:
            _repair(case)
        if case.query and "wait" in case.query:
            case.query["wait"] = 0  # jobs run inside the request anyway
        response = case.call()
        stats["cases"] += 1
        stats["statuses"][response.status_code // 100 * 100] += 1
        stats["by_operation"][f"{op.method.upper()} {op.path}"] += 1
        stats["by_status"][(f"{op.method.upper()} {op.path}", response.status_code)] += 1
        try:
            case.validate_response(response, checks=[not_a_server_error])
        except AssertionError:
            stats["server_errors"].append(
                (op.method.upper(), op.path, response.status_code,
                 response.text[:300], _body_excerpt(case)))
        if response.status_code in (200, 202) and "/v1/domains/" in op.path \
                and op.method.lower() == "post":
            job = response.json()
            if "state" in job:
                stats["jobs"] += 1
                stats["job_states"][job["state"]] += 1
                job_ids.append(job["id"])
                err = job.get("error") or {}
                if err:
                    stats["job_errors"][err.get("code")] += 1
                if err.get("code") not in (None, "no_convergence", "time_limit_exceeded",
                                           "cancelled", "numerical_error"):
                    # accepted at submission, so only numerical failures may happen
                    stats["internal_job_errors"].append(
                        (op.path, err, _body_excerpt(case)))

    return run


BUMP = {"vertex": 0, "radius": 0.6}


def _repair(case) -> None:
    """Give a fuzzed operation body valid distributions (and a short time limit), keeping
    its fuzzed scalars (gamma, tol, substeps, max_iter, k, times, sharpen, ...), so the
    solvers run on them too."""
    body = case.body
    if not isinstance(body, dict):
        return
    for name in ("mu0", "mu1"):
        if name in body:
            body[name] = dict(BUMP, vertex=0 if name == "mu0" else 3)
    if "distributions" in body:
        body["distributions"] = [BUMP, dict(BUMP, vertex=3)]
        if isinstance(body.get("weights"), list):
            body["weights"] = [1.0, 2.0]
    if "fixed" in body and "n_nodes" in body:
        body.update(n_nodes=3, edges=[[0, 1], [1, 2]], edge_weights=None,
                    fixed=[{"node": 0, "distribution": BUMP},
                           {"node": 2, "distribution": dict(BUMP, vertex=3)}])
    if "source" in body:
        body["source"] = 1
    body["time_limit"] = 2.0


def _body_excerpt(case) -> str:
    with contextlib.suppress(Exception):
        return json.dumps(case.body, default=str)[:300]
    return repr(case.body)[:300]


def test_fuzz_no_server_errors(tmp_path):
    start = time.monotonic()
    stats = fuzz(tmp_path, SUITE_EXAMPLES)
    assert stats["cases"] > 100
    assert stats["server_errors"] == [], stats["server_errors"][:5]
    assert stats["internal_job_errors"] == [], stats["internal_job_errors"][:5]
    assert time.monotonic() - start < 120


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--examples", type=int, default=100,
                        help="cases per operation and generation mode")
    args = parser.parse_args(argv)
    start = time.monotonic()
    with open("/proc/loadavg") as fh:
        load_before = fh.read().split()[:3]
    with tempfile.TemporaryDirectory() as d:
        stats = fuzz(d, args.examples, log=lambda m: print(m, flush=True))
    with open("/proc/loadavg") as fh:
        load_after = fh.read().split()[:3]
    print(f"cases {stats['cases']} in {time.monotonic() - start:.0f} s; statuses "
          f"{dict(stats['statuses'])}; jobs {stats['jobs']} {dict(stats['job_states'])} "
          f"errors {dict(stats['job_errors'])}; "
          f"server errors {len(stats['server_errors'])}; internal job errors "
          f"{len(stats['internal_job_errors'])}; load {load_before} -> {load_after}")
    for item in stats["server_errors"][:20] + stats["internal_job_errors"][:20]:
        print("  ", item)
    return 1 if stats["server_errors"] or stats["internal_job_errors"] else 0


if __name__ == "__main__":
    sys.exit(main())
