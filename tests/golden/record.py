"""Record the golden outputs of issue 41, or check the tree against them.

    PYTHONPATH=$PWD python tests/golden/record.py           # write golden_outputs.json
    PYTHONPATH=$PWD python tests/golden/record.py --check   # compare, print the report
    PYTHONPATH=$PWD python tests/golden/record.py --check --only distances soft-maps

Runs every case of ``golden_cases.CASES`` through the in-process app (see that module) and
prints each case's time, in a process whose libraries' code paths are pinned
(``golden_cases.pinned_environment``: it re-executes itself with them). Record on a tree
whose outputs are the reference (main before a redesign); tests/golden/test_golden.py runs
the same check in the suite.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from golden_cases import (  # noqa: E402
    CASES,
    GOLDEN_FILE,
    compare,
    pinned_environment,
    run_cases,
)

PINNED = "OTGEO_GOLDEN_PINNED"  # set in the re-executed process


def environment() -> dict:
    import numpy
    import scipy

    return {"python": platform.python_version(), "numpy": numpy.__version__,
            "scipy": scipy.__version__, "machine": platform.machine(),
            "processor": platform.processor() or None}


def main(argv=None) -> int:
    if os.environ.get(PINNED) != "1":  # the pins are read when the libraries load
        env = pinned_environment(os.environ) | {PINNED: "1"}
        os.execve(sys.executable, [sys.executable, __file__, *(argv or sys.argv[1:])], env)
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="compare with the recorded "
                        "file instead of writing it")
    parser.add_argument("--only", nargs="*", default=None, metavar="PREFIX",
                        help="cases whose names start with one of these (with --check)")
    args = parser.parse_args(argv)
    cases = CASES if not args.only else [c for c in CASES
                                         if any(c.name.startswith(p) for p in args.only)]
    if args.only and not args.check:
        parser.error("--only needs --check: the recorded file holds every case")
    start = time.perf_counter()
    records = run_cases(cases, progress=lambda name, s: print(f"{s:7.2f} s  {name}",
                                                              flush=True))
    print(f"{len(records)} cases in {time.perf_counter() - start:.1f} s")
    if args.check:
        golden = json.loads(GOLDEN_FILE.read_text())["cases"]
        golden = {k: v for k, v in golden.items() if k in records}
        result = compare(golden, records)
        print(result.report())
        return 1 if result.mismatches else 0
    GOLDEN_FILE.write_text(json.dumps({"environment": environment(), "cases": records},
                                      indent=1, sort_keys=True) + "\n")
    print(f"wrote {GOLDEN_FILE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
