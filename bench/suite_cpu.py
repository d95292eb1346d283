"""Where the test suite's CPU goes, per test and per file (bench/results/test_suite.md).

A pytest plugin that appends, for every test, the CPU-seconds of the process running it
(an xdist worker) and of its children reaped meanwhile (servers, ``st``, subprocesses: a
module-scoped server is counted at the teardown of the module's last test), its wall time
and its worker, one JSON line each to ``SUITE_CPU_OUT``; and a summary of such a file::

    SUITE_CPU_OUT=/tmp/cpu.jsonl PYTHONPATH=$PWD .venv/bin/python -m pytest -q \\
        -n auto --dist loadfile --no-loadscope-reorder -p no:cacheprovider -p bench.suite_cpu
    .venv/bin/python bench/suite_cpu.py /tmp/cpu.jsonl 30   # files, then the 30 costliest

(Not ``PYTHONPATH=...:bench``: ``bench/docker.py`` would then shadow the ``docker`` package
that ``docker-compose`` imports, and the Docker tests fail at the stack's start.)

Children whose parent died first (orphans) are not counted: for those, run one file inside
its own cgroup (cpuacct) instead.
"""

from __future__ import annotations

import collections
import json
import os
import resource
import sys
import time

import pytest


def _cpu() -> tuple[float, float]:
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime, kids.ru_utime + kids.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    own, kids = _cpu()
    start = time.monotonic()
    yield
    own2, kids2 = _cpu()
    row = {"id": item.nodeid, "worker": os.environ.get("PYTEST_XDIST_WORKER", "-"),
           "self": own2 - own, "children": kids2 - kids, "wall": time.monotonic() - start,
           "start": start}
    with open(os.environ.get("SUITE_CPU_OUT", "suite_cpu.jsonl"), "a") as fh:
        fh.write(json.dumps(row) + "\n")


def summary(path: str, top: int = 30) -> str:
    rows = [json.loads(line) for line in open(path)]
    files: dict[str, list] = collections.defaultdict(lambda: [0.0, 0.0, 0.0, 0, set()])
    workers: dict[str, float] = collections.Counter()
    for r in rows:
        f = files[r["id"].split("::")[0]]
        f[0] += r["self"]
        f[1] += r["children"]
        f[2] += r["wall"]
        f[3] += 1
        f[4].add(r["worker"])
        workers[r["worker"]] += r["self"] + r["children"]
    out = ["CPU-s   self    children  wall  tests  worker  file"]
    for name, (own, kids, wall, n, ws) in sorted(files.items(), key=lambda x: -x[1][0] - x[1][1]):
        out.append(f"{own + kids:7.1f} {own:7.1f} {kids:7.1f} {wall:7.1f} {n:5d} "
                   f"{','.join(sorted(ws))} {name}")
    out.append(f"total {sum(workers.values()):.1f} CPU-s in {len(rows)} tests; per worker "
               + ", ".join(f"{w} {c:.1f}" for w, c in sorted(workers.items())))
    for r in sorted(rows, key=lambda r: -r["self"] - r["children"])[:top]:
        out.append(f"{r['self'] + r['children']:7.1f} {r['wall']:7.1f} {r['id']}")
    return "\n".join(out)


if __name__ == "__main__":
    print(summary(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 30))
