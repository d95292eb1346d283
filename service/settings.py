"""Service configuration from environment variables (prefix ``OTGEO_``).

Every field can be set as ``OTGEO_<NAME>`` (e.g. ``OTGEO_DATA_DIR=/srv/otgeo``,
``OTGEO_QUEUE=redis``, ``OTGEO_API_KEYS=key1,key2``); see the README table.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, Field, field_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

TENANT_NAME = r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$"


def key_digest(key: str) -> str:
    """The SHA-256 (hex) under which a key is stored (``otgeo hash-key`` prints it; here,
    beside ``TenantKey``, so that the command imports no more than these two)."""
    return hashlib.sha256(key.encode("utf-8")).hexdigest()


class TenantKey(BaseModel):
    """One accepted key, known by its SHA-256 only (``otgeo hash-key`` prints it)."""

    tenant: str = Field(pattern=TENANT_NAME, description="the tenant the key belongs to")
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$", description="hex SHA-256 of the key")
    admin: bool = Field(False, description="an admin key sees every tenant's jobs and domains")


class TenantQuota(BaseModel):
    """Limits of one tenant (``None``: no limit)."""

    queued_jobs: int | None = Field(None, ge=0, description="jobs waiting in the queue")
    stored_bytes: int | None = Field(None, ge=0, description="bytes of the domains and images "
                                     "the tenant holds")


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="OTGEO_", extra="ignore")

    data_dir: Path = Field(Path("data"), description="shared storage: domains, results, "
                           "SQLite queue and job table")
    queue: Literal["sqlite", "redis", "immediate"] = Field(
        "sqlite", description="job queue: Huey on SQLite (embedded), on Redis (scaled out), or "
        "'immediate' (run jobs inside the request; tests only)")
    queue_name: str = "otgeo"
    redis_url: str = "redis://127.0.0.1:6379/0"
    database_url: str | None = Field(
        None, description="SQLAlchemy URL of the job table; default sqlite in data_dir "
        "(use postgresql://... when scaled out)")
    max_upload_bytes: int = Field(200 * 2**20, gt=0, description="largest request body of "
                                  "an upload: a domain (JSON or mesh file) or a color "
                                  "transfer's images (413 beyond)")
    max_json_body_bytes: int = Field(
        16 * 2**20, gt=0, description="largest JSON body of an operation (413 beyond, counted "
        "as the body arrives): its parse and validation in the API process take many times "
        "its size (bench/results/operation_body_latency.md); send large distributions as "
        "sparse or bump distributions")
    body_read_timeout: float = Field(
        15.0, gt=0, description="seconds the server waits for the next part of a request "
        "body before answering 408 and closing the connection")
    max_vertices: int = Field(2_000_000, gt=0, description="largest domain (points) accepted")
    cache_bytes: int = Field(2 * 2**30, ge=0, description="per-process operator cache bound")
    job_memory_bytes: int = Field(4 * 2**30, gt=0, description="largest working memory a job "
                                  "may need, estimated at submission from its sizes (points, "
                                  "distributions, basis size); larger jobs get 413")
    job_time_limit: float = Field(600.0, gt=0, description="seconds; checked between iterations")
    max_attempts: int = Field(3, ge=1, description="runs of a job whose worker died, at most")
    heartbeat_interval: float = Field(2.0, gt=0, description="seconds between heartbeats")
    stale_after: float = Field(30.0, gt=0, description="heartbeat age after which a running "
                               "job's worker counts as dead")
    requeue_queued_after: float = Field(
        300.0, gt=0, description="Redis: re-enqueue a job still queued after this many "
        "seconds (a last resort: lost messages are re-sent within broker_check_interval); "
        "duplicates are harmless. The embedded SQLite queue is the job table: nothing to "
        "re-send")
    reaper_interval: float = Field(5.0, gt=0, description="seconds between reaper passes: "
                                   "jobs of dead workers, and the sweep of domains released "
                                   "by their last holder")
    broker_check_interval: float = Field(
        1.0, gt=0, description="seconds between comparisons of the broker with the job "
        "table: queued jobs whose messages were lost (a Redis restart) are re-sent at once")
    api_keys: Annotated[list[str], NoDecode] = Field(
        default_factory=list, description="comma-separated accepted X-API-Key values; "
        "empty = no authentication. Each key is its own tenant (see OTGEO_TENANT_KEYS for "
        "named tenants, hashed keys and admin keys)")
    tenant_keys: list[TenantKey] = Field(
        default_factory=list, description="JSON list of keys by their SHA-256, each with its "
        "tenant: ``[{\"tenant\": \"acme\", \"sha256\": \"<hex>\", \"admin\": false}]``. "
        "Several keys may name one tenant (key rotation keeps the tenant); an ``admin`` key "
        "sees every tenant's jobs and domains")
    tenant_key_file: Path | None = Field(
        None, description="file of keys, one per line ``<tenant> <sha256-hex> [admin]`` "
        "(``#`` comments); re-read when it changes, so keys rotate without a restart")
    quota_queued_jobs: int | None = Field(
        None, ge=0, description="per-tenant limit of queued jobs (429 with Retry-After "
        "beyond); none = no limit")
    quota_stored_bytes: int | None = Field(
        None, ge=0, description="per-tenant limit of stored bytes: the domains and images the "
        "tenant holds, each counted once however often uploaded (429 beyond); none = no limit")
    tenant_quotas: dict[str, TenantQuota] = Field(
        default_factory=dict, description="JSON object of per-tenant quotas overriding the two "
        "above: ``{\"acme\": {\"queued_jobs\": 100, \"stored_bytes\": 10000000000}}``")
    idempotency_key_ttl: float = Field(
        86400.0, ge=86400.0, description="seconds an Idempotency-Key is remembered (at least a "
        "day); a POST repeating a key within this time returns the first job or domain")
    workers: int = Field(default_factory=lambda: cpu_count(), ge=0,
                         description="worker processes started by `otgeo serve` (default: "
                         "the cores this process may run on)")
    warm_at_start: bool = Field(
        True, description="each worker loads (or, on a fresh install, compiles) the "
        "operations' numba kernels in a background thread when it starts, so that a first "
        "colour transfer need not wait for them; off, a job warms what it needs on its "
        "first run")
    reserved_short_workers: int = Field(
        1, ge=0, description="of `otgeo serve`'s workers, how many serve only the short-job "
        "queue (when there are at least two workers)")
    long_job_cost: float = Field(
        5e7, gt=0, description="estimated cost (domain size x iterations x distributions; "
        "about 5e7 units per second of work, see service.operations.base.COST_PER_SECOND) "
        "from which a job goes to the long-job queue")
    metrics_open: bool = Field(False, description="serve /metrics without an API key even "
                               "when OTGEO_API_KEYS is set")
    min_free_bytes: int = Field(64 * 2**20, ge=0, description="free space in data_dir below "
                                "which /healthz reports degraded storage")
    blas_threads: int = Field(1, ge=1, description="BLAS/OpenMP threads per worker process")
    worker_poll_interval: float = Field(0.01, gt=0, description="longest idle poll delay of "
                                        "a worker on the SQLite queue (seconds) when it has "
                                        "no wake-up socket (service.jobs.wake)")
    wait_max: float = Field(60.0, ge=0, description="largest accepted ?wait= (seconds)")
    result_json_bytes: int = Field(
        2**20, ge=0, description="size budget of a job's JSON result (GET /v1/jobs/{id}/"
        "result): arrays are inlined, smallest first, while the body stays within it; every "
        "array is also a .npy file (GET /v1/jobs/{id}/arrays/{name}.npy)")
    color_max_pixels: int = Field(40_000_000, gt=0, description="largest image (pixels) a "
                                  "color transfer accepts (413 beyond)")
    color_max_job_pixels: int = Field(100_000_000, gt=0, description="largest total of "
                                      "pixels over a color transfer's images (413 beyond)")

    guide_dir: Path | None = Field(None, description="built documentation served at "
                                   "/guide/ (default: the checkout's docs/_build/html, "
                                   "when built by `make docs`)")

    @field_validator("api_keys", mode="before")
    @classmethod
    def _split_keys(cls, value):
        if isinstance(value, str):
            return [k.strip() for k in value.split(",") if k.strip()]
        return value

    def quota(self, tenant: str) -> TenantQuota:
        """The quotas of ``tenant``: what its entry of ``tenant_quotas`` sets, the defaults
        (``quota_queued_jobs``, ``quota_stored_bytes``) for the rest."""
        own = self.tenant_quotas.get(tenant)
        values = {"queued_jobs": self.quota_queued_jobs, "stored_bytes": self.quota_stored_bytes}
        if own is not None:
            values.update({name: getattr(own, name) for name in own.model_fields_set})
        return TenantQuota(**values)

    @property
    def job_database_url(self) -> str:
        return self.database_url or f"sqlite:///{(self.data_dir / 'jobs.sqlite3').resolve()}"

    def ensure_dirs(self) -> None:
        self.data_dir.mkdir(parents=True, exist_ok=True)


def cpu_count() -> int:
    """Cores this process may run on (its affinity mask, else os.cpu_count())."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except (AttributeError, OSError):
        return max(os.cpu_count() or 1, 1)
