"""``Idempotency-Key`` on POST: a retried submission returns the first job (or domain).

The key is scoped to the tenant and remembered ``OTGEO_IDEMPOTENCY_KEY_TTL`` seconds (at
least a day) in the job database, with a fingerprint of the request (route and canonical
body). The same key with the same request returns what the first request created; with a
different request it gets 422 naming the header. A job's key is written in the same
transaction as the job, so a client whose connection broke (or whose API process died) before
it saw the job's id finds it by retrying.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass

from service.errors import InvalidInput
from service.jobs.tenancy import IdempotencyKey, TenancyRepository

HEADER = "Idempotency-Key"
KEY_PATTERN = r"^[\x20-\x7e]{1,255}$"  # printable ASCII (a UUID, a request id, ...)
DESCRIPTION = ("any string of 1-255 printable ASCII characters (e.g. a UUID): a POST repeating "
               "a key within a day returns what the first one created (the same job or "
               "domain) instead of creating another; the same key with a different request "
               "gets 422. Keys are per tenant")
REPLAYED = "Idempotent-Replayed"  # response header: "true" when the key was seen before


def fingerprint(route: str, payload) -> str:
    """SHA-256 of the route and the request's canonical JSON (sorted keys, no spacing)."""
    canonical = json.dumps(payload, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(f"{route}\n{canonical}".encode()).hexdigest()


@dataclass
class Idempotency:
    """One request's key: find what it created before, or record what it creates now."""

    repo: TenancyRepository
    tenant: str
    key: str
    fingerprint: str
    ttl: float

    def previous(self) -> IdempotencyKey | None:
        """The record of an earlier request with this key; 422 if that request differed."""
        found = self.repo.find_key(self.tenant, self.key, self.ttl)
        if found is not None and found.fingerprint != self.fingerprint:
            raise InvalidInput(f"{HEADER} {self.key!r} was used for a different request "
                               "(another route or body); use a new key for a new request",
                               field=HEADER, code="idempotency_key_reused")
        return found

    def record(self, resource: str, resource_id: str,
               status_code: int | None = None) -> IdempotencyKey:
        return IdempotencyKey(tenant=self.tenant, key=self.key, fingerprint=self.fingerprint,
                              resource=resource, resource_id=resource_id,
                              status_code=status_code, created_at=time.time())


def for_request(rt, tenant: str, key: str | None, route: str, payload) -> Idempotency | None:
    """The request's Idempotency (None without a key). ``route`` names what is created
    (e.g. ``POST /v1/domains/{id}/distances``), ``payload`` the request's canonical content."""
    if key is None:
        return None
    return Idempotency(rt.tenancy, tenant, key, fingerprint(route, payload),
                       rt.settings.idempotency_key_ttl)
