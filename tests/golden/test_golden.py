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

from golden_cases import CASES, GOLDEN_FILE, compare, run_cases


def test_golden_outputs_are_unchanged():
    golden = json.loads(GOLDEN_FILE.read_text())["cases"]
    assert sorted(golden) == sorted(c.name for c in CASES), "re-record: the cases changed"
    result = compare(golden, run_cases())
    print(result.report())
    assert result.mismatches == [], result.report()


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
