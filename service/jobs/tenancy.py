"""Tables of the job database that scope content to tenants.

``tenant_holdings``: which tenant holds which content-addressed object (a domain, an uploaded
blob), with its own upload record and the object's stored size. The stored arrays are shared;
a tenant sees (lists, reads, uses) only what it holds, and the object's files go when the last
holding is released.

``idempotency_keys``: a POST's ``Idempotency-Key`` per tenant, with a fingerprint of the
request and the resource it created; written in the same transaction as the job it names, so
a retry after a crash of the API finds it.
"""

from __future__ import annotations

import time

from sqlalchemy import JSON, BigInteger, Float, Index, Integer, String, delete, func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column

from service.jobs.db import create_tables


class TenancyBase(DeclarativeBase):
    pass


class Holding(TenancyBase):
    __tablename__ = "tenant_holdings"
    __table_args__ = (Index("ix_tenant_holdings_object", "kind", "object_id"),)

    tenant: Mapped[str] = mapped_column(String(64), primary_key=True)
    kind: Mapped[str] = mapped_column(String(16), primary_key=True)  # "domain" | "blob"
    object_id: Mapped[str] = mapped_column(String(64), primary_key=True)
    bytes: Mapped[int] = mapped_column(BigInteger, default=0)
    created_at: Mapped[float] = mapped_column(Float)
    source: Mapped[dict | None] = mapped_column(JSON, nullable=True)  # this tenant's upload


class IdempotencyKey(TenancyBase):
    __tablename__ = "idempotency_keys"

    tenant: Mapped[str] = mapped_column(String(64), primary_key=True)
    key: Mapped[str] = mapped_column(String(255), primary_key=True)
    fingerprint: Mapped[str] = mapped_column(String(64))  # route and canonical body
    resource: Mapped[str] = mapped_column(String(16))  # "job" | "domain"
    resource_id: Mapped[str] = mapped_column(String(64))
    status_code: Mapped[int | None] = mapped_column(Integer, nullable=True)
    created_at: Mapped[float] = mapped_column(Float, index=True)


HOLDINGS = Holding.__table__
KEYS = IdempotencyKey.__table__


class TenancyRepository:
    """Holdings and idempotency keys, on the job table's engine (SQLite or PostgreSQL)."""

    def __init__(self, repo):
        self.engine = repo.engine
        self.Session = repo.Session
        create_tables(TenancyBase.metadata, self.engine)

    # -- holdings ----------------------------------------------------------
    def hold(self, tenant: str, kind: str, object_id: str, size: int,
             source: dict | None) -> Holding:
        """Record that ``tenant`` holds the object (the existing holding if it already does)."""
        row = Holding(tenant=tenant, kind=kind, object_id=object_id, bytes=int(size),
                      created_at=time.time(), source=source)
        try:
            with self.Session.begin() as s:
                s.add(row)
            return row
        except IntegrityError:  # held already (a concurrent upload of the same content)
            return self.holding(tenant, kind, object_id)

    def holding(self, tenant: str, kind: str, object_id: str) -> Holding | None:
        with self.engine.connect() as conn:
            row = conn.execute(select(HOLDINGS).where(
                HOLDINGS.c.tenant == tenant, HOLDINGS.c.kind == kind,
                HOLDINGS.c.object_id == object_id)).mappings().first()
        return None if row is None else Holding(**row)

    def holdings(self, tenant: str, kind: str) -> list[Holding]:
        with self.engine.connect() as conn:
            rows = conn.execute(select(HOLDINGS).where(HOLDINGS.c.tenant == tenant,
                                                       HOLDINGS.c.kind == kind)).mappings()
            return [Holding(**row) for row in rows]

    def release(self, tenant: str | None, kind: str, object_id: str) -> int:
        """Drop ``tenant``'s holding of the object (every tenant's: ``tenant=None``)."""
        q = delete(HOLDINGS).where(HOLDINGS.c.kind == kind, HOLDINGS.c.object_id == object_id)
        if tenant is not None:
            q = q.where(HOLDINGS.c.tenant == tenant)
        with self.engine.begin() as conn:
            return conn.execute(q).rowcount

    def holders(self, kind: str, object_id: str) -> int:
        q = select(func.count()).select_from(HOLDINGS).where(
            HOLDINGS.c.kind == kind, HOLDINGS.c.object_id == object_id)
        with self.engine.connect() as conn:
            return int(conn.execute(q).scalar() or 0)

    def stored_bytes(self, tenant: str) -> int:
        """What the tenant holds, each object once (however often it uploaded it)."""
        q = select(func.coalesce(func.sum(HOLDINGS.c.bytes), 0)).where(
            HOLDINGS.c.tenant == tenant)
        with self.engine.connect() as conn:
            return int(conn.execute(q).scalar() or 0)

    # -- idempotency keys ----------------------------------------------------
    def find_key(self, tenant: str, key: str, ttl: float) -> IdempotencyKey | None:
        """The live record of ``key`` (an expired one is deleted and not returned)."""
        with self.engine.connect() as conn:
            row = conn.execute(select(KEYS).where(KEYS.c.tenant == tenant,
                                                  KEYS.c.key == key)).mappings().first()
        if row is None:
            return None
        if row["created_at"] < time.time() - ttl:
            with self.engine.begin() as conn:
                conn.execute(delete(KEYS).where(KEYS.c.tenant == tenant, KEYS.c.key == key,
                                                KEYS.c.created_at == row["created_at"]))
            return None
        return IdempotencyKey(**row)

    def put_key(self, record: IdempotencyKey) -> bool:
        """Store a record; False if the key is recorded already (a concurrent request)."""
        try:
            with self.Session.begin() as s:
                s.add(record)
            return True
        except IntegrityError:
            return False

    PRUNE_EVERY = 600.0  # seconds between prunings of expired keys (per process)
    _pruned_at = float("-inf")

    def prune_keys(self, older_than: float, force: bool = False) -> int:
        """Forget keys recorded more than ``older_than`` seconds ago (at most once per
        ``PRUNE_EVERY`` seconds unless ``force``; expired keys are ignored anyway)."""
        if not force and time.monotonic() - self._pruned_at < self.PRUNE_EVERY:
            return 0
        self._pruned_at = time.monotonic()
        with self.engine.begin() as conn:
            return conn.execute(delete(KEYS).where(
                KEYS.c.created_at < time.time() - older_than)).rowcount
