"""The job table (SQLAlchemy; SQLite by default, PostgreSQL when scaled out).

The table is what the API reads: state, progress, attempts, heartbeat and the
result location.  Every state change is a conditional UPDATE, so concurrent
workers and reapers never both win: a job is claimed by one worker, and only
the attempt that owns it can heartbeat or finish it.
"""

from __future__ import annotations

import functools
import os
import socket
import time
from dataclasses import dataclass

from sqlalchemy import (
    JSON,
    Boolean,
    Float,
    Integer,
    String,
    and_,
    bindparam,
    create_engine,
    event,
    func,
    insert,
    inspect,
    or_,
    select,
    text,
    update,
)
from sqlalchemy.exc import IntegrityError, OperationalError, ProgrammingError, SQLAlchemyError
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column, sessionmaker

QUEUED, RUNNING, SUCCEEDED, FAILED, CANCELLED = (
    "queued", "running", "succeeded", "failed", "cancelled")
STATES = (QUEUED, RUNNING, SUCCEEDED, FAILED, CANCELLED)
TERMINAL = (SUCCEEDED, FAILED, CANCELLED)


class Base(DeclarativeBase):
    pass


class JobRow(Base):
    __tablename__ = "jobs"

    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    operation: Mapped[str] = mapped_column(String(64))
    domain_id: Mapped[str] = mapped_column(String(64), index=True)
    params: Mapped[dict] = mapped_column(JSON)
    state: Mapped[str] = mapped_column(String(16), index=True)
    iteration: Mapped[int | None] = mapped_column(Integer, nullable=True)
    residual: Mapped[float | None] = mapped_column(Float, nullable=True)
    fraction: Mapped[float | None] = mapped_column(Float, nullable=True)
    stage: Mapped[str | None] = mapped_column(String(160), nullable=True)
    queue: Mapped[str | None] = mapped_column(String(16), nullable=True)
    cost: Mapped[float | None] = mapped_column(Float, nullable=True)
    error: Mapped[dict | None] = mapped_column(JSON, nullable=True)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    max_attempts: Mapped[int] = mapped_column(Integer, default=3)
    cancel_requested: Mapped[bool] = mapped_column(Boolean, default=False)
    time_limit: Mapped[float] = mapped_column(Float)
    worker: Mapped[str | None] = mapped_column(String(128), nullable=True)
    created_at: Mapped[float] = mapped_column(Float)
    enqueued_at: Mapped[float | None] = mapped_column(Float, nullable=True)
    started_at: Mapped[float | None] = mapped_column(Float, nullable=True)
    heartbeat_at: Mapped[float | None] = mapped_column(Float, nullable=True)
    finished_at: Mapped[float | None] = mapped_column(Float, nullable=True)
    duration: Mapped[float | None] = mapped_column(Float, nullable=True)
    result_location: Mapped[str | None] = mapped_column(String(256), nullable=True)
    # a small result without arrays or files, kept in the row (``result_location`` is
    # service.store.IN_ROW): one file write and read less per job
    result: Mapped[dict | None] = mapped_column(JSON, nullable=True)
    # automatic choices taken at submission (Operation.decide), executed by every attempt
    decision: Mapped[dict | None] = mapped_column(JSON, nullable=True)
    # who submitted it (service.tenants); NULL for jobs from before tenants: admin-only
    tenant: Mapped[str | None] = mapped_column(String(64), nullable=True, index=True)
    # a block of a job fanned out over the workers (service.jobs.fanout): the job it is part
    # of; NULL for a job submitted through the API (only those are listed)
    parent: Mapped[str | None] = mapped_column(String(32), nullable=True, index=True)


class WorkerRow(Base):
    """Liveness and cache statistics published by each worker process."""

    __tablename__ = "workers"

    id: Mapped[str] = mapped_column(String(128), primary_key=True)
    started_at: Mapped[float] = mapped_column(Float)
    seen_at: Mapped[float] = mapped_column(Float)
    jobs_done: Mapped[int] = mapped_column(Integer, default=0)
    cache: Mapped[dict] = mapped_column(JSON)


JOBS = JobRow.__table__
# columns added after the first release: created on an existing table at start-up
ADDED_COLUMNS = {"fraction": "FLOAT", "queue": "VARCHAR(16)", "cost": "FLOAT",
                 "decision": "JSON", "tenant": "VARCHAR(64)", "result": "JSON",
                 "stage": "VARCHAR(160)", "parent": "VARCHAR(32)"}
ADDED_INDEXES = {"tenant": "ix_jobs_tenant", "parent": "ix_jobs_parent"}


def queued_job_row(**values) -> JobRow:
    """A new queued job's row with every column set: ``values``, and None for the columns
    a worker fills in later (so the row is complete without reading it back)."""
    return JobRow(**{**{c: None for c in JOBS.c.keys()}, "state": QUEUED, "attempts": 0,
                     "cancel_requested": False, **values})


def worker_identity() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


@dataclass
class Claim:
    attempt: int
    job: JobRow


BUSY_TIMEOUT_MS = 30_000  # how long an SQLite write waits for another writer's lock


class WriteBusy(Exception):
    """A write that was not to wait found the job table locked by another writer."""


def make_engine(url: str):
    if url.startswith("sqlite"):
        engine = create_engine(url, connect_args={"timeout": BUSY_TIMEOUT_MS / 1000,
                                                  "check_same_thread": False})

        @event.listens_for(engine, "connect")
        def _pragmas(dbapi_conn, _record):
            cur = dbapi_conn.cursor()
            cur.execute("PRAGMA journal_mode=WAL")
            cur.execute("PRAGMA synchronous=NORMAL")
            cur.execute(f"PRAGMA busy_timeout={BUSY_TIMEOUT_MS}")
            cur.close()

        return engine
    for plain in ("postgresql://", "postgres://"):
        # SQLAlchemy 2.1 maps a plain postgresql:// URL to psycopg 3; the package ships psycopg2
        if url.startswith(plain):
            url = "postgresql+psycopg2://" + url[len(plain):]
    return create_engine(url, pool_pre_ping=True, pool_size=5, max_overflow=10)


def _bound(name: str):
    """A parameter for column ``name`` (typed as the column: JSON, float, ...)."""
    return bindparam(f"b_{name}", type_=JOBS.c[name].type)


# the per-job statements, built once (building one costs about as much as running it)
# a claimed job's new values (CLAIM and the job-table queue's claim of the oldest job)
_CLAIMED = {"state": RUNNING, "attempts": JOBS.c.attempts + 1, "worker": _bound("worker"),
            "started_at": bindparam("b_now", type_=Float()),
            "heartbeat_at": bindparam("b_now", type_=Float())}
CLAIM = (update(JOBS).where(JOBS.c.id == _bound("id"), JOBS.c.state == QUEUED)
         .values(_CLAIMED).returning(*JOBS.c))
GET = select(JOBS).where(JOBS.c.id == _bound("id"))
_QUEUE = func.coalesce(JOBS.c.queue, "short")


@functools.lru_cache(maxsize=4)
def _claim_next_statement(queues: tuple[str, ...]):
    """``UPDATE`` of the oldest queued job of ``queues`` (in that order) to running for a
    worker, ``RETURNING`` it: the job table as the queue (one statement claims and
    dequeues; the outer ``state = 'queued'`` keeps two workers from both winning)."""
    from sqlalchemy import case

    rank = case({q: i for i, q in enumerate(queues)}, value=_QUEUE)
    # submission order (created_at), not enqueued_at: re-sends and requeues rewrite that,
    # and jobs then ran out of order (first submitted, first started, per queue)
    oldest = (select(JOBS.c.id).where(JOBS.c.state == QUEUED, _QUEUE.in_(queues))
              .order_by(rank, JOBS.c.created_at, JOBS.c.id)
              .limit(1).scalar_subquery())
    return (update(JOBS).where(JOBS.c.id == oldest, JOBS.c.state == QUEUED)
            .values(_CLAIMED).returning(*JOBS.c))


@functools.lru_cache(maxsize=4)
def _any_queued_statement(queues: tuple[str, ...]):
    """A queued job of ``queues``, if any (a read: the idle worker's check before it claims)."""
    return select(JOBS.c.id).where(JOBS.c.state == QUEUED, _QUEUE.in_(queues)).limit(1)


FINISHED = ("state", "error", "result_location", "result", "finished_at", "heartbeat_at",
            "duration")


@functools.lru_cache(maxsize=16)
def _finish_statement(progress: frozenset):
    """``UPDATE`` of a running attempt to its final state, with these progress columns."""
    return (update(JOBS).where(JOBS.c.id == _bound("id"), JOBS.c.state == RUNNING,
                               JOBS.c.attempts == bindparam("b_attempt", type_=Integer()))
            .values({name: _bound(name) for name in (*FINISHED, *sorted(progress))}))


@functools.lru_cache(maxsize=8)
def _insert_statement(table):
    """``INSERT`` of every column of ``table`` (built once per table)."""
    return insert(table)


def _column_values(row, table) -> dict:
    """A mapped row's column values for a Core INSERT (unset values of primary keys and of
    columns with a default left out, so the table's default applies as in the ORM)."""
    values = {}
    for c in table.columns:
        value = getattr(row, c.key)
        if value is not None or not (c.primary_key or c.default is not None):
            values[c.name] = value
    return values


CREATE_ATTEMPTS = 5  # create_all tries when processes start together on a fresh database


def create_tables(metadata, engine) -> None:
    """``metadata.create_all`` that tolerates other processes creating the same tables."""
    for attempt in range(CREATE_ATTEMPTS):
        try:
            metadata.create_all(engine)
            return
        except (OperationalError, IntegrityError, ProgrammingError):
            # another process (API or worker) is creating it at the same moment: SQLite
            # reports a lock, PostgreSQL a duplicate table or a unique violation in its
            # type catalogue; the next create_all sees the finished table
            if attempt == CREATE_ATTEMPTS - 1:
                raise
            time.sleep(0.05 * (attempt + 1))


def require_returning(engine) -> None:
    """Refuse, at start, a job database without ``UPDATE ... RETURNING`` (SQLite before
    3.35): claiming a job (``claim``, and ``claim_next``, the embedded queue) and a
    heartbeat are each one conditional ``UPDATE ... RETURNING``."""
    if not engine.dialect.update_returning:
        linked = getattr(engine.dialect.dbapi, "sqlite_version", None)
        raise RuntimeError(
            f"the job database ({engine.dialect.name}"
            + (f" {linked}" if linked else "") + ") has no UPDATE ... RETURNING, which "
            "claiming a job needs: use SQLite >= 3.35 or PostgreSQL")


class JobRepository:
    def __init__(self, url: str):
        self.engine = make_engine(url)
        require_returning(self.engine)
        create_tables(Base.metadata, self.engine)
        self._add_columns()
        self.Session = sessionmaker(self.engine, expire_on_commit=False)
        # a file on this machine (SQLite, WAL): reads are cheap and never wait for a writer
        self.local = self.engine.dialect.name == "sqlite"

    def _add_columns(self) -> None:
        """ALTER an older job table to the current columns (a no-op on a new one)."""
        present = {c["name"] for c in inspect(self.engine).get_columns("jobs")}
        for name, sql_type in ADDED_COLUMNS.items():
            if name in present:
                continue
            try:
                with self.engine.begin() as conn:
                    conn.execute(text(f"ALTER TABLE jobs ADD COLUMN {name} {sql_type}"))
                    if name in ADDED_INDEXES:  # the index a new table gets from the model
                        conn.execute(text(f"CREATE INDEX IF NOT EXISTS {ADDED_INDEXES[name]} "
                                          f"ON jobs ({name})"))
            except SQLAlchemyError:  # added by another process meanwhile (duplicate column)
                present = {c["name"] for c in inspect(self.engine).get_columns("jobs")}
                if name not in present:
                    raise

    def dispose(self) -> None:
        self.engine.dispose()

    # -- creation / reading ---------------------------------------------
    def create(self, job: JobRow, *also, nowait: bool = False) -> JobRow:
        """Insert the job, and ``also`` (e.g. its idempotency key) in the same transaction.

        Core INSERTs of the rows' column values (the ORM unit of work costs more than the
        statement on this path); ``job`` stays a detached row holding what was written.
        ``nowait`` (SQLite, on the API's event loop): raise :class:`WriteBusy`, writing
        nothing, instead of waiting while another process holds the write lock."""
        nowait = nowait and self.local
        with self.engine.begin() as conn:
            if nowait:
                conn.exec_driver_sql("PRAGMA busy_timeout=0")
            try:
                for row in (job, *also):
                    table = type(row).__table__
                    conn.execute(_insert_statement(table), _column_values(row, table))
            except OperationalError as exc:
                if nowait and "locked" in str(exc.orig):
                    raise WriteBusy(str(exc.orig)) from exc
                raise
            finally:
                if nowait:
                    conn.exec_driver_sql(f"PRAGMA busy_timeout={BUSY_TIMEOUT_MS}")
        return job

    def get(self, job_id: str) -> JobRow | None:
        """The job as a detached row (one Core SELECT: no session bookkeeping)."""
        with self.engine.connect() as conn:
            row = conn.execute(GET, {"b_id": job_id}).mappings().first()
        return None if row is None else JobRow(**row)

    def list(self, limit: int = 100, state: str | None = None, *,
             after: tuple[float, str] | None = None, operation: str | None = None,
             domain_id: str | None = None, tenant: str | None = None) -> list[JobRow]:
        """Newest first (``created_at``, then ``id``, descending); ``after``: the
        ``(created_at, id)`` of the last job of the previous page (cursor paging);
        ``tenant``: only that tenant's jobs (None: every job)."""
        listed = [c for c in JOBS.c if c.name != "result"]  # pages show no results
        q = (select(*listed).where(JOBS.c.parent.is_(None))  # blocks: part of their parent
             .order_by(JOBS.c.created_at.desc(), JOBS.c.id.desc()).limit(limit))
        if tenant is not None:
            q = q.where(JOBS.c.tenant == tenant)
        if state:
            q = q.where(JOBS.c.state == state)
        if operation:
            q = q.where(JOBS.c.operation == operation)
        if domain_id:
            q = q.where(JOBS.c.domain_id == domain_id)
        if after is not None:
            created, last_id = after
            q = q.where(or_(JOBS.c.created_at < created,
                            and_(JOBS.c.created_at == created, JOBS.c.id < last_id)))
        with self.engine.connect() as conn:
            return [JobRow(**row) for row in conn.execute(q).mappings()]

    def queue_position(self, job: JobRow) -> int | None:
        """1 for the next queued job of its queue, 2 after that, ...; None unless queued
        (in submission order, as :meth:`claim_next` takes them)."""
        if job.state != QUEUED:
            return None
        mine = job.queue or "short"
        same = func.coalesce(JOBS.c.queue, "short") == mine
        q = select(func.count()).select_from(JOBS).where(
            JOBS.c.state == QUEUED, same,
            or_(JOBS.c.created_at < job.created_at,
                and_(JOBS.c.created_at == job.created_at, JOBS.c.id < job.id)))
        with self.engine.connect() as conn:
            return int(conn.execute(q).scalar() or 0) + 1

    def _update(self, where, **values) -> int:
        """A conditional UPDATE (Core statement: no ORM bookkeeping); returns the row count."""
        with self.engine.begin() as conn:
            return conn.execute(update(JOBS).where(*where).values(**values)).rowcount

    # -- worker side -----------------------------------------------------
    def claim(self, job_id: str, worker: str) -> Claim | None:
        """Move a queued job to running for this worker; None if someone else has it.

        One conditional ``UPDATE ... RETURNING`` (:func:`require_returning`)."""
        with self.engine.begin() as conn:
            row = conn.execute(CLAIM, {"b_id": job_id, "b_worker": worker,
                                       "b_now": time.time()}).mappings().first()
        return None if row is None else Claim(int(row["attempts"]), JobRow(**row))

    def claim_next(self, queues: tuple[str, ...], worker: str, *,
                   probe: bool = True) -> Claim | None:
        """Claim the first submitted queued job of ``queues`` (earlier queues first) for this
        worker; None when there is none (or another worker took it first).  The embedded queue: the
        job row written at submission is the message, so nothing is handed over twice and a
        requeued job (reaper) is simply queued again.

        With ``probe``, an empty queue is seen by a read first: a worker asks after every
        job, and the ``UPDATE`` would take the write lock even when it matches nothing
        (a worker just woken by an enqueue skips the read: a job is most likely there)."""
        queues = tuple(queues)
        if probe:
            with self.engine.connect() as conn:
                if conn.execute(_any_queued_statement(queues)).first() is None:
                    return None
        with self.engine.begin() as conn:
            row = conn.execute(_claim_next_statement(queues),
                               {"b_worker": worker, "b_now": time.time()}).mappings().first()
        return None if row is None else Claim(int(row["attempts"]), JobRow(**row))

    def heartbeat(self, job_id: str, attempt: int, **progress) -> tuple[bool, bool]:
        """Refresh the heartbeat (and progress); returns (still owned, cancel requested)."""
        where = (JOBS.c.id == job_id, JOBS.c.state == RUNNING, JOBS.c.attempts == attempt)
        values = {"heartbeat_at": time.time(), **progress}
        with self.engine.begin() as conn:
            row = conn.execute(update(JOBS).where(*where).values(**values)
                               .returning(JOBS.c.cancel_requested)).first()
        return (False, True) if row is None else (True, bool(row[0]))

    def finish(self, job_id: str, attempt: int, state: str, *, error: dict | None = None,
               result_location: str | None = None, result: dict | None = None,
               started_at: float | None = None, **progress) -> bool:
        """Final state of a running attempt (and its result location, or its small result
        itself), in one conditional UPDATE; False if the attempt no longer owns the job."""
        now = time.time()
        if started_at is None:
            job = self.get(job_id)
            started_at = job.started_at if job and job.started_at else now
        values = {"b_state": state, "b_error": error, "b_result_location": result_location,
                  "b_result": result,
                  "b_finished_at": now, "b_heartbeat_at": now, "b_duration": now - started_at,
                  **{f"b_{k}": v for k, v in progress.items()}}
        with self.engine.begin() as conn:
            return bool(conn.execute(_finish_statement(frozenset(progress)),
                                     {"b_id": job_id, "b_attempt": attempt, **values}).rowcount)

    def release(self, job_id: str, attempt: int) -> bool:
        """Give a running job back to the queue without counting the attempt."""
        return bool(self._update(
            (JobRow.id == job_id, JobRow.state == RUNNING, JobRow.attempts == attempt),
            state=QUEUED, attempts=attempt - 1, worker=None, enqueued_at=time.time(),
            heartbeat_at=None))

    # -- blocks of a fanned-out job (service.jobs.fanout) ----------------------
    def children(self, parent: str) -> list[JobRow]:
        """The blocks of job ``parent`` (without their results), in id order."""
        listed = [c for c in JOBS.c if c.name != "result"]
        q = select(*listed).where(JOBS.c.parent == parent).order_by(JOBS.c.id)
        with self.engine.connect() as conn:
            return [JobRow(**row) for row in conn.execute(q).mappings()]

    def create_missing(self, jobs: list[JobRow]) -> list[JobRow]:
        """Insert those of ``jobs`` whose id is not in the table yet (one transaction);
        returns the inserted ones (a re-run of the parent finds its earlier blocks)."""
        ids = [j.id for j in jobs]
        with self.engine.begin() as conn:
            present = set(conn.execute(select(JOBS.c.id).where(JOBS.c.id.in_(ids))).scalars())
            new = [j for j in jobs if j.id not in present]
            for job in new:
                conn.execute(_insert_statement(JOBS), _column_values(job, JOBS))
        return new

    # -- API side --------------------------------------------------------
    def request_cancel(self, job_id: str) -> JobRow | None:
        """Cancel a queued job at once; flag a running one (the worker stops it); the same
        for its blocks (a fanned-out job's, service.jobs.fanout)."""
        now = time.time()
        for this in (JobRow.id == job_id, JobRow.parent == job_id):
            self._update((this, JobRow.state == QUEUED), state=CANCELLED,
                         cancel_requested=True, finished_at=now, duration=0.0)
            self._update((this, JobRow.state == RUNNING), cancel_requested=True)
        return self.get(job_id)

    # -- reaper ----------------------------------------------------------
    def stale_running(self, before: float) -> list[JobRow]:
        with self.Session() as s:
            return list(s.scalars(select(JobRow).where(
                JobRow.state == RUNNING, JobRow.heartbeat_at < before)))

    def requeue(self, job: JobRow, before: float) -> bool:
        """Put a stale running job back in the queue (if it is still stale)."""
        return bool(self._update(
            (JobRow.id == job.id, JobRow.state == RUNNING, JobRow.attempts == job.attempts,
             JobRow.heartbeat_at < before),
            state=QUEUED, worker=None, enqueued_at=time.time(), heartbeat_at=None))

    def fail_stale(self, job: JobRow, before: float, error: dict) -> bool:
        now = time.time()
        return bool(self._update(
            (JobRow.id == job.id, JobRow.state == RUNNING, JobRow.attempts == job.attempts,
             JobRow.heartbeat_at < before),
            state=FAILED, error=error, finished_at=now,
            duration=now - (job.started_at or now)))

    def overdue_running(self, now: float, grace: float) -> list[JobRow]:
        """Running jobs past their time limit by more than ``grace`` seconds."""
        with self.Session() as s:
            return list(s.scalars(select(JobRow).where(
                JobRow.state == RUNNING, JobRow.started_at + JobRow.time_limit + grace < now)))

    def fail_overdue(self, job: JobRow, error: dict) -> bool:
        now = time.time()
        return bool(self._update(
            (JOBS.c.id == job.id, JOBS.c.state == RUNNING, JOBS.c.attempts == job.attempts),
            state=FAILED, error=error, cancel_requested=True, finished_at=now,
            duration=now - (job.started_at or now)))

    def stale_queued(self, before: float) -> list[JobRow]:
        with self.Session() as s:
            return list(s.scalars(select(JobRow).where(
                JobRow.state == QUEUED, JobRow.enqueued_at < before)))

    def touch_queued(self, job: JobRow) -> bool:
        return bool(self._update(
            (JobRow.id == job.id, JobRow.state == QUEUED,
             JobRow.enqueued_at == job.enqueued_at), enqueued_at=time.time()))

    # -- metrics ---------------------------------------------------------
    def counts(self, tenant: str | None = None) -> dict[tuple[str, str], int]:
        """(operation, state) -> jobs; ``tenant``: only that tenant's (None: every job)."""
        q = select(JobRow.operation, JobRow.state, func.count())
        if tenant is not None:
            q = q.where(JobRow.tenant == tenant)
        with self.Session() as s:
            rows = s.execute(q.group_by(JobRow.operation, JobRow.state))
            return {(op, st): int(n) for op, st, n in rows}

    def queued_of(self, tenant: str) -> int:
        """Queued jobs of one tenant (its queued-jobs quota)."""
        q = select(func.count()).select_from(JOBS).where(JOBS.c.state == QUEUED,
                                                         JOBS.c.tenant == tenant)
        with self.engine.connect() as conn:
            return int(conn.execute(q).scalar() or 0)

    def queued_by_queue(self, tenant: str | None = None) -> dict[str, int]:
        """Queued jobs per queue (``short`` / ``long``); ``tenant``: only that tenant's."""
        q = func.coalesce(JOBS.c.queue, "short")
        where = [JOBS.c.state == QUEUED] + ([JOBS.c.tenant == tenant] if tenant else [])
        with self.engine.connect() as conn:
            rows = conn.execute(select(q, func.count()).where(*where).group_by(q))
            return {str(name): int(n) for name, n in rows}

    def durations(self, tenant: str | None = None
                  ) -> dict[tuple[str, str], tuple[int, float, float]]:
        """(operation, state) -> (count, sum, max) of run durations of finished jobs;
        ``tenant``: only that tenant's."""
        where = [JobRow.duration.is_not(None), JobRow.state.in_(TERMINAL)]
        if tenant is not None:
            where.append(JobRow.tenant == tenant)
        with self.Session() as s:
            rows = s.execute(
                select(JobRow.operation, JobRow.state, func.count(), func.sum(JobRow.duration),
                       func.max(JobRow.duration))
                .where(*where).group_by(JobRow.operation, JobRow.state))
            return {(op, st): (int(n), float(total or 0.0), float(mx or 0.0))
                    for op, st, n, total, mx in rows}

    def publish_worker(self, worker: str, started_at: float, jobs_done: int,
                       cache: dict) -> None:
        with self.Session.begin() as s:
            row = s.get(WorkerRow, worker)
            if row is None:
                s.add(WorkerRow(id=worker, started_at=started_at, seen_at=time.time(),
                                jobs_done=jobs_done, cache=cache))
            else:
                row.seen_at, row.jobs_done, row.cache = time.time(), jobs_done, cache

    def live_workers(self, since: float) -> list[WorkerRow]:
        with self.Session() as s:
            return list(s.scalars(select(WorkerRow).where(WorkerRow.seen_at >= since)))

    def remove_worker(self, worker: str) -> None:
        with self.Session.begin() as s:
            row = s.get(WorkerRow, worker)
            if row is not None:
                s.delete(row)
