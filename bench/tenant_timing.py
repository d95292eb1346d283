"""Whether a tenant's upload or delete of a content-addressed domain takes a different time
when another tenant holds the same content (a timing side channel between tenants).

Against a running service with two plain keys (``OTGEO_API_KEYS=alpha-key,beta-key``, each
its own tenant), ``ROUNDS`` rounds each of two cases, alternated within a round:

* shared: beta uploads a mesh; alpha uploads it (timed) and deletes it (timed); beta deletes it;
* alone: alpha uploads a mesh nobody holds (timed) and deletes it (timed).

Every round uses new content (an icosphere of 642 vertices, one vertex moved by a round-
dependent amount). Prints per case and request the median, mean and 10-90 % range in ms,
and in how many rounds the shared case was the faster one (about half when nothing leaks).

Start the server outside ``cpu bench`` (a server must not inherit its lock), e.g.
``OTGEO_API_KEYS=alpha-key,beta-key PYTHONPATH=TREE .venv/bin/python -m service.cli serve
--port 18420 --workers 1 --data-dir /tmp/t``, then ``cpu bench .venv/bin/python
bench/tenant_timing.py --url http://127.0.0.1:18420 [more URLs, measured in turn]``.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import httpx
import trimesh

A, B = {"X-API-Key": "alpha-key"}, {"X-API-Key": "beta-key"}
SPHERE = trimesh.creation.icosphere(subdivisions=3)


def mesh_body(tag: int) -> dict:
    vertices = SPHERE.vertices.copy()
    vertices[0] *= 1.0 + 1e-4 * (tag + 1)  # new content, so a new domain id
    return {"kind": "mesh", "vertices": vertices.tolist(), "faces": SPHERE.faces.tolist()}


def timed(call) -> tuple[float, httpx.Response]:
    t = time.perf_counter()
    r = call()
    return time.perf_counter() - t, r


def one_case(c: httpx.Client, body: dict, shared: bool) -> tuple[float, float]:
    """(upload seconds, delete seconds) of alpha's requests."""
    if shared:
        c.post("/v1/domains", json=body, headers=B).raise_for_status()
    up, r = timed(lambda: c.post("/v1/domains", json=body, headers=A))
    r.raise_for_status()
    domain = r.json()["id"]
    down, r = timed(lambda: c.delete(f"/v1/domains/{domain}", headers=A))
    assert r.status_code == 204, r.text
    if shared:
        assert c.delete(f"/v1/domains/{domain}", headers=B).status_code == 204
    return up, down


def summary(xs: list[float]) -> str:
    q = statistics.quantiles(xs, n=10)
    return (f"median {statistics.median(xs) * 1e3:.2f} ms, mean {statistics.mean(xs) * 1e3:.2f}"
            f" ms, 10-90% {q[0] * 1e3:.2f}-{q[-1] * 1e3:.2f} ms")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--url", required=True, nargs="+",
                        help="one or more services (e.g. before and after), measured in turn "
                        "within every round so that they see the same load")
    parser.add_argument("--rounds", type=int, default=40)
    args = parser.parse_args()
    load = Path("/proc/loadavg").read_text().strip()
    times = {(url, case, req): [] for url in args.url for case in ("shared", "alone")
             for req in ("upload", "delete")}
    tag = int(time.time())  # content new to this server run too
    clients = {url: httpx.Client(base_url=url, timeout=60) for url in args.url}
    for c in clients.values():
        for i in range(3):  # warm-up
            one_case(c, mesh_body(tag * 1000 + 900 + i), shared=bool(i % 2))
    for i in range(args.rounds):
        for url, c in clients.items():
            cases = ("shared", "alone") if i % 2 == 0 else ("alone", "shared")
            for k, case in enumerate(cases):
                up, down = one_case(c, mesh_body(tag * 1000 + 2 * i + k), case == "shared")
                times[url, case, "upload"].append(up)
                times[url, case, "delete"].append(down)
    for url in args.url:
        print(url)
        for req in ("upload", "delete"):
            for case in ("shared", "alone"):
                print(f"  {req} ({case}): {summary(times[url, case, req])}")
            faster = sum(s < a for s, a in zip(times[url, "shared", req],
                                               times[url, "alone", req], strict=True))
            diff = statistics.median(times[url, "alone", req]) - \
                statistics.median(times[url, "shared", req])
            print(f"  {req}: shared faster in {faster} of {args.rounds} rounds; median alone "
                  f"- shared {diff * 1e3:+.2f} ms")
    print(f"load before: {load}; after: {Path('/proc/loadavg').read_text().strip()}")


if __name__ == "__main__":
    main()
