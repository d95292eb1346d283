"""Tenants: who an API key belongs to, and what that tenant may see.

Every ``X-API-Key`` belongs to a tenant. Keys are known only by their SHA-256
(``OTGEO_TENANT_KEYS`` or the key file ``OTGEO_TENANT_KEY_FILE``); a presented key is
hashed and compared with every stored digest in constant time. Rotating a key is adding the
new key's digest under the same tenant name (and later removing the old one): the tenant, and
so what it sees, stays. A key marked ``admin`` sees every tenant's jobs and domains.

Backwards compatible: each plain key of ``OTGEO_API_KEYS`` is its own tenant (named after its
digest), and with no key configured the service is open: one anonymous tenant that sees
everything (as before tenants existed).
"""

from __future__ import annotations

import hashlib
import hmac
import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from service.errors import ApiError
from service.settings import key_digest

log = logging.getLogger("otgeo.tenants")


@dataclass(frozen=True)
class Tenant:
    """The caller: a tenant name, and whether its key is an admin key (sees everything)."""

    id: str
    admin: bool = False


ANONYMOUS = Tenant("anonymous", admin=True)  # the open service (no key configured)


class QuotaExceeded(ApiError):
    """429: a per-tenant quota (queued jobs, stored bytes); ``retry_after`` in seconds."""

    status_code = 429
    code = "quota_exceeded"

    def __init__(self, message: str, *, field: str | None = None, retry_after: int = 10):
        super().__init__(message, field=field)
        self.retry_after = retry_after
        self.headers = {"Retry-After": str(retry_after)}


def legacy_tenant_name(key: str) -> str:
    """The tenant of a plain ``OTGEO_API_KEYS`` entry: stable for that key, not revealing it."""
    return "key-" + key_digest(key)[:16]


def parse_key_file(text: str) -> list[tuple[str, str, bool]]:
    """``(tenant, sha256, admin)`` per line ``<tenant> <sha256-hex> [admin]``; ``#`` comments."""
    from service.settings import TenantKey

    out = []
    for number, line in enumerate(text.splitlines(), 1):
        fields = line.split("#", 1)[0].split()
        if not fields:
            continue
        if len(fields) not in (2, 3) or (len(fields) == 3 and fields[2] != "admin"):
            raise ValueError(f"key file line {number}: expected '<tenant> <sha256> [admin]'")
        entry = TenantKey(tenant=fields[0], sha256=fields[1].lower(), admin=len(fields) == 3)
        out.append((entry.tenant, entry.sha256, entry.admin))
    return out


class TenantDirectory:
    """Resolves presented keys to tenants. The key file is re-read when it changes (checked
    at most once per ``RELOAD_EVERY`` seconds), so keys rotate without a restart."""

    RELOAD_EVERY = 1.0

    def __init__(self, settings):
        self.settings = settings
        self._fixed: list[tuple[bytes, Tenant]] = []
        for key in settings.api_keys:
            self._fixed.append((bytes.fromhex(key_digest(key)), Tenant(legacy_tenant_name(key))))
        for entry in settings.tenant_keys:
            self._fixed.append((bytes.fromhex(entry.sha256), Tenant(entry.tenant, entry.admin)))
        self._file = settings.tenant_key_file
        self._from_file: list[tuple[bytes, Tenant]] = []
        self._file_stamp: tuple[float, int] | None = None
        self._checked = 0.0
        self._lock = threading.Lock()
        if self._file is not None:
            self._reload(initial=True)

    @property
    def enabled(self) -> bool:
        """Whether keys are required (any key configured, or a key file given)."""
        return bool(self._fixed) or self._file is not None

    def _reload(self, initial: bool = False) -> None:
        path = Path(self._file)
        try:
            stat = path.stat()
            stamp = (stat.st_mtime, stat.st_size)
            if stamp == self._file_stamp:
                return
            entries = parse_key_file(path.read_text())
        except (OSError, ValueError) as exc:
            if initial:
                raise
            log.warning("key file %s unreadable (%s); keeping the keys loaded before", path, exc)
            return
        self._from_file = [(bytes.fromhex(d), Tenant(t, a)) for t, d, a in entries]
        self._file_stamp = stamp

    def _entries(self) -> list[tuple[bytes, Tenant]]:
        if self._file is not None and time.monotonic() - self._checked > self.RELOAD_EVERY:
            with self._lock:
                self._checked = time.monotonic()
                self._reload()
        return self._fixed + self._from_file

    def resolve(self, presented: str | None) -> Tenant | None:
        """The tenant of ``presented`` (ANONYMOUS when no keys are configured), None when the
        key is missing or unknown. Every stored digest is compared (constant time each), so
        the time taken does not tell which entry matched or how far."""
        if not self.enabled:
            return ANONYMOUS
        if presented is None:
            return None
        digest = hashlib.sha256(presented.encode("utf-8", "surrogateescape")).digest()
        found = None
        for stored, tenant in self._entries():
            if hmac.compare_digest(digest, stored) and found is None:
                found = tenant
        return found


QUEUE_RETRY_AFTER = 10  # seconds: queued jobs start within about that (a hint, not a promise)
STORAGE_RETRY_AFTER = 60  # stored bytes free up only when the tenant deletes something


def check_queued_quota(settings, tenant: Tenant, count_queued) -> None:
    """429 when ``tenant`` already has its quota of queued jobs (admins have no quota);
    ``count_queued()`` (a job-table count) is called only when a quota applies."""
    limit = settings.quota(tenant.id).queued_jobs
    if tenant.admin or limit is None:
        return
    queued = count_queued()
    if queued < limit:
        return
    raise QuotaExceeded(f"tenant {tenant.id!r} has {queued} queued jobs, its quota is {limit}; "
                        "retry when some have started", retry_after=QUEUE_RETRY_AFTER)


def check_bytes_quota(settings, tenant: Tenant, stored: int, adding: int) -> None:
    """429 when holding ``adding`` more bytes would pass ``tenant``'s stored-bytes quota."""
    limit = settings.quota(tenant.id).stored_bytes
    if tenant.admin or limit is None or stored + adding <= limit:
        return
    raise QuotaExceeded(f"tenant {tenant.id!r} stores {stored} bytes; {adding} more would "
                        f"exceed its quota of {limit} bytes (delete domains to make room)",
                        retry_after=STORAGE_RETRY_AFTER)
