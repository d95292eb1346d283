"""schemathesis hooks of tests/service/test_schemathesis.py (``st run`` loads this file from
``SCHEMATHESIS_HOOKS``; ``OTGEO_FUZZ_MESHES`` lists stored mesh ids, comma-separated).

- Domain ids in bodies: a well-formed id in a mesh field (soft maps, soft-map analyses,
  shape interpolations) becomes a stored mesh's, so those cases reach validation rather
  than 404 (tests/service/fuzz_ids.py).
- ``Idempotency-Key``: a key names one request (the server answers a reuse with another
  body 422, as the IETF draft says); the generator draws few values ("0", "null") and
  repeats them across bodies and routes, which no client does. A well-formed key gets a
  per-request prefix, so each request has its own; a malformed one stays malformed.
"""

from __future__ import annotations

import itertools
import os
import re
import sys
from pathlib import Path

import schemathesis

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fuzz_ids import with_mesh_ids  # noqa: E402

MESH_IDS = [m for m in os.environ.get("OTGEO_FUZZ_MESHES", "").split(",") if m]
KEY_FORM = re.compile(r"^[\x20-\x7e]{1,240}$")  # leaves room for the prefix within 255
_requests = itertools.count()


@schemathesis.hook
def map_case(context, case):
    """Every phase's cases (the coverage phase applies no per-part ``map_*`` hook)."""
    n = next(_requests)
    if MESH_IDS and case.body is not None:
        case.body = with_mesh_ids(case.body, MESH_IDS, n)
    key = (case.headers or {}).get("Idempotency-Key")
    if isinstance(key, str) and KEY_FORM.match(key):
        case.headers = dict(case.headers, **{"Idempotency-Key": f"{n}-{key}"})
    return case
