"""Golden outputs (issue 41): every service operation, on every domain kind, with every
method its request offers, gives the decision and the values recorded in
golden_outputs.json (by ``python tests/golden/record.py``) — decisions and strings
identical, numbers within 1e-12 relative. A redesign that must keep the behaviour keeps this
test passing; the report (``-s``, or ``record.py --check``) says which leaves are not
bit-identical.

One test runs every case in one app (about 30 s on the shared 2-core machine): as one test
it stays in one process under pytest-xdist, on its own temporary data directory."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from golden_cases import CASES, GOLDEN_FILE, compare, pinned_environment

RECORD = Path(__file__).with_name("record.py")
ROOT = Path(__file__).resolve().parents[2]


def test_golden_outputs_are_unchanged():
    """``record.py --check`` in a new process (whose libraries' code paths it pins)."""
    golden = json.loads(GOLDEN_FILE.read_text())["cases"]
    assert sorted(golden) == sorted(c.name for c in CASES), "re-record: the cases changed"
    env = os.environ | {"PYTHONPATH": os.pathsep.join(filter(None, (
        str(ROOT), os.environ.get("PYTHONPATH"))))}
    run = subprocess.run([sys.executable, str(RECORD), "--check"], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=1200)
    print(run.stdout)
    assert run.returncode == 0 and " recorded leaves; 0 mismatches" in run.stdout, \
        run.stdout[-6000:] + run.stderr[-3000:]


def test_pinned_environment_pins_the_code_paths():
    """In a process started with ``pinned_environment``: one BLAS thread, and OpenBLAS on
    its Haswell kernels whatever this processor is."""
    probe = ("import json, numpy, scipy.linalg, threadpoolctl\n"
             "print(json.dumps([(i['internal_api'], i.get('architecture'), i['num_threads'])\n"
             "      for i in threadpoolctl.threadpool_info() if i['user_api'] == 'blas']))")
    out = subprocess.run([sys.executable, "-c", probe], env=pinned_environment(os.environ),
                         capture_output=True, text=True, check=True, timeout=120)
    blas = json.loads(out.stdout)
    assert blas and all(n == 1 for _, _, n in blas), blas
    assert all(arch == "Haswell" for api, arch, _ in blas if api == "openblas"), blas


def test_comparison_catches_changes():
    """The comparison itself: a value off by 1e-10 relative, a changed decision and a
    changed array fail; a change in the last bit passes and is reported."""
    golden = json.loads(GOLDEN_FILE.read_text())["cases"]
    name = "distances-mesh-w2-exact"
    case = json.loads(json.dumps(golden[name]))
    case["values"]["value"] *= 1 + 1e-15
    result = compare({name: golden[name]}, {name: case})
    assert result.mismatches == [] and len(result.not_bitwise) == 1
    case["values"]["value"] *= 1 + 1e-10
    case["decision"]["method"] = "convolutional"
    arrays = json.loads(json.dumps(golden["pointwise-distances-mesh"]))
    key = next(iter(arrays["arrays"]))
    arrays["arrays"][key]["sha256"] = "0" * 16
    arrays["arrays"][key]["norm"] *= 1 + 1e-9
    result = compare({name: golden[name], "pointwise-distances-mesh":
                      golden["pointwise-distances-mesh"]},
                     {name: case, "pointwise-distances-mesh": arrays})
    assert len(result.mismatches) == 3, result.report()
