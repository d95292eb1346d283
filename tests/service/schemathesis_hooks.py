"""schemathesis hooks of tests/service/test_schemathesis.py (``st run`` loads this file from
``SCHEMATHESIS_HOOKS``; ``OTGEO_FUZZ_MESHES`` lists stored mesh ids, comma-separated).

- Domain ids in bodies: a well-formed id in a mesh field (soft maps, soft-map analyses,
  shape interpolations) becomes a stored mesh's, so those cases reach validation rather
  than 404 (tests/service/fuzz_ids.py).
- ``Idempotency-Key``: a key names one request (the server answers a reuse with another
  body 422, as the IETF draft says); the generator draws few values ("0", "null") and
  repeats them across bodies and routes, which no client does. A well-formed key gets a
  per-request prefix, so each request has its own; a malformed one stays malformed.
- Jobs nobody looks at again: a job a POST left queued or running (202) is cancelled once
  st has its response. st's checks see only responses: a job's later run reaches none of
  them (the pinned ids send every ``/v1/jobs/{job_id}/...`` request to the setup's job), but
  the server's one worker ran them all beside st (most of a run's CPU: the coverage
  phase's boundary values, 20 s of shape interpolations and 9 s of volumetric distances
  of 42 s in a seed-7 run), and ahead of the jobs later requests ``wait`` for. A job that
  finishes within its request's ``wait`` is answered in full (200) and left alone.
- The failed checks (``OTGEO_FUZZ_REPORT``): a report handler writes the failed cases of each
  scenario (their checks, requests and responses) instead of st's full NDJSON report.
"""

from __future__ import annotations

import itertools
import json
import os
import re
import sys
from pathlib import Path

import httpx
import schemathesis

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fuzz_ids import with_mesh_ids  # noqa: E402

from service.schemas import PATH_SEGMENT  # noqa: E402

MESH_IDS = [m for m in os.environ.get("OTGEO_FUZZ_MESHES", "").split(",") if m]
KEY_FORM = re.compile(r"^[\x20-\x7e]{1,255}$")  # the header's pattern
SEGMENT = re.compile(PATH_SEGMENT)
JOB_ID = re.compile(r"^[0-9a-f]{32}$")
UNFINISHED = ("queued", "running")
CANCELS = os.environ.get("OTGEO_FUZZ_CANCELS")  # a file: one line per cancel, its status
REPORT = os.environ.get("OTGEO_FUZZ_REPORT")  # a file: the NDJSON report of failed scenarios
_requests = itertools.count()
_client: httpx.Client | None = None  # the cancels' one connection pool (and SSL context)


def _cancel_client() -> httpx.Client:
    # one client for every cancel: httpx.delete() builds a client per call, its SSL context
    # loading the CA bundle each time (~20 ms CPU; 3-4 CPU-s of st's ~25 in the open run)
    global _client
    if _client is None:
        _client = httpx.Client(timeout=30)
    return _client


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


@schemathesis.hook
def after_call(context, case, response):
    """Cancel the job a POST left unfinished (see the module's docstring), with the request's
    own API key (the run with keys); a later request still finds the job (it stays readable,
    state ``cancelled``). Each cancel's status is appended to ``OTGEO_FUZZ_CANCELS``."""
    if case.method.upper() != "POST" or response.status_code != 202:
        return
    try:
        job = response.json()
    except ValueError:
        return
    if not isinstance(job, dict) or job.get("state") not in UNFINISHED \
            or not JOB_ID.match(str(job.get("id"))):
        return
    url = httpx.URL(response.request.url)
    key = {k: v for k, v in response.request.headers.items() if k.lower() == "x-api-key"}
    r = _cancel_client().delete(f"{url.scheme}://{url.netloc.decode()}/v1/jobs/{job['id']}",
                                headers=key)
    if CANCELS:  # the test reads the statuses: 200, or 409 for a job finished meanwhile
        with open(CANCELS, "a") as fh:
            fh.write(f"{r.status_code}\n")


if REPORT:
    from schemathesis import cli
    from schemathesis.engine import Status, events
    from schemathesis.reporting.ndjson import serialize

    @cli.handler()
    class FailedChecks(cli.EventHandler):
        """The failed checks of the run, one NDJSON line per scenario with some: the
        ``ScenarioFinished`` lines of st's NDJSON report (``--report ndjson``, the same
        serializer), each with only its failed cases' checks and interactions. The test reads
        nothing else; the full report serialized every recorded interaction (~8 MB, ~3 CPU-s
        of st's ~25 in the open run)."""

        def __init__(self, *args, **params):
            self.stream = open(REPORT, "w", encoding="utf-8")  # noqa: SIM115 - shutdown

        def handle_event(self, ctx, event):
            if not isinstance(event, events.ScenarioFinished):
                return
            recorder = event.recorder
            failed = {case_id: checks for case_id, checks in recorder.checks.items()
                      if any(check.status == Status.FAILURE for check in checks)}
            if not failed:
                return
            sanitization = ctx.config.output.sanitization
            kept = {"checks": failed, "interactions": {
                case_id: recorder.interactions[case_id] for case_id in failed
                if case_id in recorder.interactions}}
            line = serialize(kept, sanitization=sanitization if sanitization.enabled else None)
            self.stream.write(json.dumps({"ScenarioFinished": {"recorder": line}}) + "\n")

        def shutdown(self, ctx):
            self.stream.close()
