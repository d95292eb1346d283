"""Failure counts of schemathesis (``st run``, every check) against a live ``otgeo serve``, per
seed, with and without an API key: how many schema-valid requests the server rejects (ST202)
and how many created resources it cannot find (ST302), and which allow-list entries they fall
under (tests/service/test_schemathesis.py sets the server and its data up).

    .venv/bin/python bench/schemathesis_failures.py --seeds 7 11 99 --port 18510

Prints one line per run and a table per failure code, entry and operation; ``--out`` writes
the table as JSON too.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:1] = [str(ROOT), str(ROOT / "tests" / "service")]  # not bench/: bench/service.py
from test_schemathesis import ALLOWED, EXAMPLES, KEY, run_schemathesis  # noqa: E402


def entry_of(failure: dict) -> str:
    """The name of the allow-list entry a failure falls under, or ``unexplained``."""
    for allowed in ALLOWED:
        if allowed.matches(failure):
            return allowed.name
    return "unexplained"


def measure(seed: int, key: str | None, examples: int, port: int | None) -> dict:
    start = time.monotonic()
    load = Path("/proc/loadavg").read_text().split()[0]
    with tempfile.TemporaryDirectory() as d:
        found, _ = run_schemathesis(Path(d), examples, seed, key, port)
    return {"seed": seed, "key": key is not None, "examples": examples,
            "seconds": round(time.monotonic() - start), "load": load,
            "codes": dict(Counter(f["code"] for f in found)),
            "by_entry": dict(Counter(f"{f['code']} {entry_of(f)}" for f in found)),
            "by_operation": dict(Counter(f"{f['code']} {f['operation']} {f['status']}"
                                         for f in found)),
            "unexplained": [f for f in found if entry_of(f) == "unexplained"][:10],
            "failures": found,
            "samples": {f"{f['code']} {f['operation']}": f["error_message"][:160]
                        for f in found}}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[7, 11, 99])
    parser.add_argument("--examples", type=int, default=EXAMPLES)
    parser.add_argument("--port", type=int, help="the server's port (default: a free one)")
    parser.add_argument("--keys", choices=["both", "open", "key"], default="both")
    parser.add_argument("--out", type=Path, help="write the runs as JSON here")
    args = parser.parse_args(argv)
    keys = {"both": [None, KEY], "open": [None], "key": [KEY]}[args.keys]
    runs = []
    for seed in args.seeds:
        for key in keys:
            run = measure(seed, key, args.examples, args.port)
            runs.append(run)
            print(f"seed {seed:>3} {'key ' if key else 'open'}: {run['codes']} "
                  f"({len(run['unexplained'])} unexplained) in {run['seconds']} s, "
                  f"load {run['load']}", flush=True)
    for run in runs:
        print(f"\nseed {run['seed']} key={run['key']}")
        for name, count in sorted(run["by_entry"].items()):
            print(f"  {count:>4}  {name}")
        for name, count in sorted(run["by_operation"].items()):
            print(f"  {count:>4}  {name}")
        for item in run["unexplained"]:
            print("  unexplained:", json.dumps(item)[:400])
    if args.out:
        args.out.write_text(json.dumps(runs, indent=1) + "\n")
    return 1 if any(run["unexplained"] for run in runs) else 0


if __name__ == "__main__":
    sys.exit(main())
