"""schemathesis over the app's own OpenAPI spec, in process (ASGI transport, immediate queue):
no valid request the fuzzer makes gets a 5xx, no job it submits fails with an internal
error (each runs inside its request, half of them with their distributions repaired so the
solvers run on the fuzzed scalars), and every operation is reached (some case gets past its
id lookups).

Invalid requests (schemathesis' negative mode) are tests/service/test_schemathesis.py's: the
live server gets every parameter's invalid values (its coverage phase) and negative fuzzed
cases with either seed (7 without keys, 11 with), with real ids too (stored domains of
every kind, meshes in the bodies, a finished job), checked for no 5xx and for rejection.
Here they were checked for no 5xx only, and took some 40% of this file's CPU; ``--negative``
runs them, by hand.

Three cases in four get ids that exist (tests/service/fuzz_ids.py): small domains of every
kind and two meshes (also in the bodies of soft maps, soft-map analyses and shape
interpolations), a finished job with files and 2-D arrays (``/files``, ``/arrays``, ``/rows``
with a row inside), the jobs the fuzzer created, a spare domain for DELETE; so request bodies
reach the operations' validation and, when valid, the solvers. Bounded examples and two fixed
seeds keep the suite run short; run longer outside the suite (it prints the status codes of
every operation, as in bench/results/schemathesis_failures.md)::

    .venv/bin/python tests/service/test_fuzz.py --examples 150 --seed 11  # per operation, mode
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
from dataclasses import dataclass, field
from pathlib import Path

import pytest

schemathesis = pytest.importorskip("schemathesis")

import hypothesis  # noqa: E402
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis.errors import Unsatisfiable  # noqa: E402
from schemathesis import GenerationMode  # noqa: E402
from schemathesis.checks import not_a_server_error  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fuzz_ids import QUICK_BRDF, domain_bodies, with_mesh_ids  # noqa: E402

SUITE_EXAMPLES = 8  # valid cases per operation and seed
SUITE_SEEDS = (7, 11)
SKIP = {("get", "/v1/jobs/{job_id}/events")}  # streams until the job ends (covered elsewhere)


def _domains(client) -> dict[str, str]:
    """Upload a small domain of every kind (two meshes); their ids by name."""
    ids = {}
    for name, body in domain_bodies().items():
        r = client.post("/v1/domains", json=body)
        assert r.status_code in (200, 201), r.text
        ids[name] = r.json()["id"]
    return ids


@dataclass
class Data:
    """What the fuzzed requests' ids point at: stored domains, two meshes (bodies of the
    global operations), finished jobs, and one finished job with files and a 2-D array."""

    domains: list[str]
    meshes: list[str]
    job_ids: list[str]
    files_job: str = ""
    files: list[str] = field(default_factory=list)
    arrays: dict[str, int] = field(default_factory=dict)  # 2-D array name -> rows
    sizes: dict[str, int] = field(default_factory=dict)  # mesh id -> vertices
    spare: str = ""  # a domain DELETE may remove


def _data(client) -> Data:

    ids = _domains(client)
    data = Data(domains=[v for k, v in ids.items() if k != "box"],
                meshes=[ids["mesh"], ids["box"]], job_ids=[])
    data.sizes = {m: client.get(f"/v1/domains/{m}").json()["n"] for m in data.meshes}
    spare = client.post("/v1/domains", json={"kind": "grid", "shape": [3, 3]})
    data.spare = spare.json()["id"]
    r = client.post("/v1/brdf-interpolations", json=QUICK_BRDF)
    assert r.status_code in (200, 201) and r.json()["state"] == "succeeded", r.text
    data.files_job = r.json()["id"]
    result = client.get(f"/v1/jobs/{data.files_job}/result").json()
    data.files = sorted(result["files"])
    data.arrays = {name: f["shape"][0] for name, f in result["array_files"].items()
                   if len(f["shape"]) == 2}
    data.job_ids.append(data.files_job)
    return data


def _real_ids(case, op, i: int, data: Data) -> None:
    """Point three cases in four at stored data (the fourth keeps its generated ids: 404s):
    path ids, a file or array of the finished job, a row within the array, and the mesh
    ids in global operations' bodies (``source_id``, ``shapes``, ...)."""
    if i % 4 == 0:
        return
    params = case.path_parameters or {}
    if "domain_id" in params:
        params["domain_id"] = data.spare if op.method.lower() == "delete" \
            else data.domains[i % len(data.domains)]
    if "job_id" in params:
        params["job_id"] = data.job_ids[i % len(data.job_ids)]
    if "name" in params:
        params["job_id"] = data.files_job
        names = sorted(data.arrays) if "/arrays/" in op.path else data.files
        params["name"] = names[i % len(names)]
        if "row" in params and i % 2:
            params["row"] = i % data.arrays[params["name"]]
    case.body = with_mesh_ids(case.body, data.meshes, i)


def fuzz(data_dir, examples: int, seed: int = 0, log=None, negative: bool = False) -> dict:
    """Run every operation of the spec with ``examples`` valid cases (``negative``: and as
    many invalid ones where schemathesis makes some), drawn from ``seed`` (the same cases on
    every run).

    Returns counts: cases, statuses, server errors (method, path, status, body excerpt),
    jobs submitted and jobs that failed with ``internal_error``."""
    from fastapi.testclient import TestClient

    from service.app import create_app
    from service.settings import Settings

    # job_time_limit: the live fuzz server's (test_schemathesis) and the repaired bodies' 2 s
    # (was 5: jobs past 2 s ended by the limit anyway, later)
    app = create_app(Settings(data_dir=data_dir, queue="immediate", job_time_limit=2.0,
                              wait_max=1.0))
    stats = {"cases": 0, "statuses": Counter(), "server_errors": [], "jobs": 0,
             "job_states": Counter(), "internal_job_errors": [], "by_operation": Counter(),
             "job_errors": Counter(),
             "by_status": Counter(), "operations": set(), "reached": Counter()}
    with TestClient(app) as client:
        data = _data(client)
        schema = schemathesis.openapi.from_asgi("/openapi.json", app)
        operations = [r.ok() for r in schema.get_all_operations()]
        for op in operations:
            if (op.method.lower(), op.path) in SKIP:
                continue
            stats["operations"].add(f"{op.method.upper()} {op.path}")
            modes = [GenerationMode.POSITIVE]
            if negative and _negative_exists(op):
                modes.append(GenerationMode.NEGATIVE)
            for mode in modes:
                counter = {"i": 0}
                run = _make_run(op, mode, examples, seed, counter, data, stats)
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


def _negative_exists(op) -> bool:
    """False where schemathesis makes no invalid request: no body and only path parameters,
    each a string (a string breaking a path parameter's pattern is no URL segment; no
    parameters at all, /healthz). There hypothesis gave up only after some 460 draws and
    raised Unsatisfiable (~1 CPU-s per operation, 10 operations, each seed)."""
    params = [p.definition for p in op.iter_parameters()]
    only_path_strings = all(p.get("in") == "path" and p.get("schema", {}).get("type") == "string"
                            for p in params)
    return len(op.body) > 0 or not only_path_strings


def _make_run(op, mode, examples, seed, counter, data, stats):
    """One hypothesis test: ``examples`` cases of ``op`` in ``mode`` (fixed seed)."""

    @hypothesis.seed(seed)
    @settings(max_examples=examples, derandomize=False, deadline=None,
              database=None, suppress_health_check=list(HealthCheck))
    @given(case=op.as_strategy(generation_mode=mode))
    def run(case):
        counter["i"] += 1
        _real_ids(case, op, counter["i"], data)
        if mode == GenerationMode.POSITIVE and counter["i"] % 2 == 0:
            _repair(case, data)
        if case.query and "wait" in case.query:
            case.query["wait"] = 0  # jobs run inside the request anyway
        response = case.call()
        stats["cases"] += 1
        stats["statuses"][response.status_code // 100 * 100] += 1
        stats["by_operation"][f"{op.method.upper()} {op.path}"] += 1
        stats["by_status"][(f"{op.method.upper()} {op.path}", response.status_code)] += 1
        if mode == GenerationMode.POSITIVE and response.status_code != 404:
            stats["reached"][f"{op.method.upper()} {op.path}"] += 1  # past the id lookups
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
                data.job_ids.append(job["id"])
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


def _repair(case, data: Data) -> None:
    """Give a fuzzed operation body valid distributions, landmarks and point maps (and a
    short time limit), keeping its fuzzed scalars (gamma, tol, substeps, max_iter, times,
    sharpen, ...), so the solvers run on them too."""
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
    if "landmarks" in body:  # soft maps: vertices of both meshes, few eigenpairs
        body.update(landmarks=[{"source": 0, "target": 0}, {"source": 5, "target": 5}], k=10)
    n_target = data.sizes.get(body.get("target_id"))
    for point_map in body.get("maps") or []:  # soft-map analyses: one vertex per vertex
        n_source = data.sizes.get(point_map.get("source_id")) if isinstance(point_map, dict) \
            else None
        if n_source and n_target:
            point_map["correspondence"] = [j % n_target for j in range(n_source)]
            body["descriptor_k"] = 10
    body["time_limit"] = 2.0


def _body_excerpt(case) -> str:
    with contextlib.suppress(Exception):
        return json.dumps(case.body, default=str)[:300]
    return repr(case.body)[:300]


@pytest.mark.parametrize("seed", SUITE_SEEDS)
def test_fuzz_no_server_errors(tmp_path, seed):
    stats = fuzz(tmp_path, SUITE_EXAMPLES, seed)
    assert stats["cases"] > 100
    assert stats["server_errors"] == [], stats["server_errors"][:5]
    assert stats["internal_job_errors"] == [], stats["internal_job_errors"][:5]
    assert stats["operations"] - set(stats["reached"]) == set(), stats["reached"]


def test_mesh_ids_replace_only_well_formed_ids():
    body = {"source_id": "0" * 32, "target_id": "bad", "maps": [{"source_id": "1" * 16}],
            "shapes": ["2" * 20, 5], "samples": 3}
    mesh = "a" * 32
    assert with_mesh_ids(body, [mesh]) == {
        "source_id": mesh, "target_id": "bad", "maps": [{"source_id": mesh}],
        "shapes": [mesh, 5], "samples": 3}


def status_table(stats: dict) -> str:
    """The status codes of every operation's cases, one line per operation."""
    table: dict[str, Counter] = {}
    for (operation, status), count in stats["by_status"].items():
        table.setdefault(operation, Counter())[status] = count
    return "\n".join(f"{op:<60} " + " ".join(f"{s}:{n}" for s, n in sorted(c.items()))
                     for op, c in sorted(table.items()))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=SUITE_SEEDS[0])
    parser.add_argument("--examples", type=int, default=100,
                        help="cases per operation and generation mode")
    parser.add_argument("--negative", action="store_true", help="invalid cases too")
    args = parser.parse_args(argv)
    start = time.monotonic()
    with open("/proc/loadavg") as fh:
        load_before = fh.read().split()[:3]
    with tempfile.TemporaryDirectory() as d:
        stats = fuzz(d, args.examples, args.seed, log=lambda m: print(m, flush=True),
                     negative=args.negative)
    with open("/proc/loadavg") as fh:
        load_after = fh.read().split()[:3]
    print(f"cases {stats['cases']} in {time.monotonic() - start:.0f} s; statuses "
          f"{dict(stats['statuses'])}; jobs {stats['jobs']} {dict(stats['job_states'])} "
          f"errors {dict(stats['job_errors'])}; "
          f"server errors {len(stats['server_errors'])}; internal job errors "
          f"{len(stats['internal_job_errors'])}; load {load_before} -> {load_after}")
    for item in stats["server_errors"][:20] + stats["internal_job_errors"][:20]:
        print("  ", item)
    print(status_table(stats))
    return 1 if stats["server_errors"] or stats["internal_job_errors"] else 0


if __name__ == "__main__":
    sys.exit(main())
