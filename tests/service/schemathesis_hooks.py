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

from service.schemas import PATH_SEGMENT  # noqa: E402

MESH_IDS = [m for m in os.environ.get("OTGEO_FUZZ_MESHES", "").split(",") if m]
KEY_FORM = re.compile(r"^[\x20-\x7e]{1,255}$")  # the header's pattern
SEGMENT = re.compile(PATH_SEGMENT)
_requests = itertools.count()


@schemathesis.hook
def filter_case(context, case):
    """Drop a case whose path parameter is no URL segment (an empty value, seen from a
    stateful link): its request goes to another path (DELETE /v1/domains: 405)."""
    return all(isinstance(v, str) and SEGMENT.match(v) or not isinstance(v, str)
               for v in (case.path_parameters or {}).values())


@schemathesis.hook
def map_case(context, case):
    """Every phase's cases (the coverage phase applies no per-part ``map_*`` hook); a case
    is changed only where an id or a key is replaced."""
    n = next(_requests)
    if MESH_IDS and isinstance(case.body, dict):
        body = with_mesh_ids(case.body, MESH_IDS, n)
        if body != case.body:
            case.body = body
    key = (case.headers or {}).get("Idempotency-Key")
    if isinstance(key, str) and KEY_FORM.match(key):  # a prefix per request, within 255
        # in place: a new dict would count the CLI's X-API-Key as the hook's own, which
        # schemathesis then keeps in the request missing_required_header sends without it
        case.headers["Idempotency-Key"] = f"{n}-{key}"[:255]
    return case
