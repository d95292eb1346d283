"""Command line: ``otgeo serve`` (API + embedded workers), ``otgeo worker``, ``otgeo openapi``,
``otgeo routes`` (the route list of the README and docs).

Nothing numerical is imported at module level: worker processes set their BLAS
thread limits in the environment before numpy is first imported.
"""

from __future__ import annotations

import argparse
import functools
import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

BLAS_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
            "BLIS_NUM_THREADS", "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")
DEFAULT_OPENAPI = Path("openapi") / "openapi.json"
# top-level modules of the `service` extra (pyproject.toml), absent from a library-only install
SERVICE_PACKAGES = frozenset({"fastapi", "fastapi_offline", "starlette", "uvicorn", "uvloop",
                              "httptools", "multipart", "python_multipart", "pydantic",
                              "pydantic_settings", "huey", "sqlalchemy", "redis", "psycopg2"})


def limit_blas_threads(threads: int, env: dict | None = None) -> dict:
    env = os.environ if env is None else env
    for name in BLAS_ENV:
        env[name] = str(threads)
    return env


def _settings(args):
    from service.settings import Settings

    overrides = {}
    if getattr(args, "data_dir", None):
        overrides["data_dir"] = args.data_dir
    if getattr(args, "workers", None) is not None:
        overrides["workers"] = args.workers
    return Settings(**overrides)


def openapi_document(app=None) -> str:
    """The OpenAPI document of the app, as the checked-in text (stable across settings)."""
    if app is None:
        return _default_openapi_document()
    return json.dumps(app.openapi(), indent=2, sort_keys=True) + "\n"


@functools.cache
def _default_openapi_document() -> str:
    """The default app's document, built once per process (about 0.6 CPU-s: the test suite
    and the docs build ask for it several times); a function of the code only."""
    import tempfile

    from service.app import create_app
    from service.settings import Settings

    with tempfile.TemporaryDirectory() as tmp:
        app = create_app(Settings(data_dir=tmp, queue="immediate", api_keys=[]),
                         start_background=False)
        try:
            return openapi_document(app)
        finally:
            app.state.runtime.close()


def cmd_openapi(args) -> None:
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(openapi_document())
    print(f"wrote {out}")


def cmd_routes(args) -> None:
    """Print the route list (Markdown), or rewrite its generated block in the given files."""
    import tempfile

    from service.api.routelist import operations_markdown, update_file
    from service.app import create_app
    from service.settings import Settings

    with tempfile.TemporaryDirectory() as tmp:
        app = create_app(Settings(data_dir=tmp, queue="immediate", api_keys=[]),
                         start_background=False)
        try:
            if not args.update:
                print(operations_markdown(app))
            for path in args.update:
                changed = update_file(Path(path), app)
                print(f"{'updated' if changed else 'unchanged'} {path}")
        finally:
            app.state.runtime.close()


PARENT_ENV = "OTGEO_PARENT_PID"  # set by `otgeo serve` for its workers
PR_SET_PDEATHSIG = 1
WATCHDOG_INTERVAL = 0.5  # seconds between parent checks of a worker started by `serve`


def die_with_parent(parent_pid: int, grace: float = 10.0) -> None:
    """Make this worker stop when the ``otgeo serve`` that started it dies, even by SIGKILL.

    Linux: ``prctl(PR_SET_PDEATHSIG, SIGTERM)`` (delivered when the parent exits); everywhere
    a watchdog thread compares ``os.getppid()`` with the parent (a dead parent's children
    are re-parented) and sends SIGTERM itself, then exits hard after ``grace`` seconds if the
    graceful stop hangs. SIGTERM is the worker's graceful stop: its running job goes back to
    the queue."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            if libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0) != 0:
                raise OSError(ctypes.get_errno(), "prctl failed")
        except (OSError, AttributeError) as exc:
            logging.getLogger("otgeo").warning("no parent-death signal (%s); watchdog only", exc)

    def orphaned() -> bool:
        return os.getppid() != parent_pid

    def watchdog() -> None:
        while not orphaned():
            time.sleep(WATCHDOG_INTERVAL)
        logging.getLogger("otgeo").warning("parent %d is gone; stopping this worker",
                                           parent_pid)
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(grace)
        os._exit(1)

    if orphaned():  # the parent died before the signal was armed
        raise SystemExit(f"otgeo worker: parent process {parent_pid} is gone")
    threading.Thread(target=watchdog, daemon=True, name="parent-watchdog").start()


def run_worker(settings, queues=("short", "long")) -> None:
    """One worker process: consumer of the short (and long) queue, one job at a time,
    reaper, statistics."""
    limit_blas_threads(settings.blas_threads)
    parent = os.environ.get(PARENT_ENV)
    if parent and parent.isdigit():
        die_with_parent(int(parent))
    from service.jobs.consumer import Consumer
    from service.limits import limit_worker_memory
    from service.runtime import Runtime

    limit_worker_memory(settings)  # an underestimated job fails as out_of_memory, not by swap
    runtime = Runtime(settings, role="worker")
    if settings.queue == "immediate":
        raise SystemExit("OTGEO_QUEUE=immediate runs jobs inside the API; no worker needed")
    wake = None
    if settings.queue == "sqlite":  # block on enqueue datagrams instead of polling the queue
        from service.jobs.wake import WakeSocket

        wake = WakeSocket(settings.data_dir, "worker")
    consumer = Consumer(runtime, queues, wake)
    runtime.start_background(publish=True)
    logging.getLogger("otgeo").info("worker %s ready (queue %s: %s)", runtime.process_id,
                                    settings.queue, ", ".join(consumer.queues))
    if settings.warm_at_start:
        from service import warm

        warm.start_background(runtime.operations)  # a first job waits for it (runner)
    else:
        logging.getLogger("otgeo").info("no warm-up at start (OTGEO_WARM_AT_START=false): "
                                        "each operation's first job warms its kernels")
    try:
        consumer.run()
    finally:
        released = runtime.runner.release_current()
        if released:
            row = runtime.repo.get(released)
            runtime.enqueue(released, row.queue if row is not None else None)
            logging.getLogger("otgeo").info("handed job %s back to the queue", released)
        runtime.close()
        if wake is not None:
            wake.close()


def cmd_worker(args) -> None:
    queues = tuple(q.strip() for q in args.queues.split(",") if q.strip())
    if not queues or set(queues) - {"short", "long"}:
        raise SystemExit(f"otgeo worker: --queues takes short and/or long, not {args.queues!r}")
    settings = _settings(args)
    fail = storage_problem(settings)
    if fail:
        print(f"otgeo worker: {fail}", file=sys.stderr, flush=True)
        raise SystemExit(2)
    run_worker(settings, queues)
    # A job abandoned by a stop may still be running in the consumer's daemon thread (inside
    # native solver code): skip interpreter finalization, which can abort under it. The job
    # was handed back and the runtime closed above.
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


def worker_queues(count: int, reserved_short: int) -> list[str]:
    """The ``--queues`` of each of ``count`` workers: with two or more, ``reserved_short``
    of them (at least one worker always serves the long queue) take short jobs only."""
    reserved = min(reserved_short, count - 1) if count >= 2 else 0
    return ["short,long"] * (count - reserved) + ["short"] * reserved


class WorkerPool:
    """Child ``otgeo worker`` processes, restarted if they die, stopped on shutdown; they
    die with this process (parent-death signal + watchdog, see ``die_with_parent``)."""

    def __init__(self, count: int, env: dict, reserved_short: int = 1):
        self.count = count
        self.env = {**env, PARENT_ENV: str(os.getpid())}
        self.queues = worker_queues(count, reserved_short)
        self.procs: list[subprocess.Popen] = []
        self._stopping = threading.Event()
        self._thread = threading.Thread(target=self._supervise, daemon=True, name="workers")

    def _spawn(self, queues: str) -> subprocess.Popen:
        return subprocess.Popen([sys.executable, "-m", "service.cli", "worker", "--queues",
                                 queues], env=self.env, start_new_session=True)

    def start(self) -> None:
        self.procs = [self._spawn(q) for q in self.queues]
        self._thread.start()

    def _supervise(self) -> None:
        while not self._stopping.wait(1.0):
            for i, proc in enumerate(self.procs):
                if proc.poll() is not None and not self._stopping.is_set():
                    logging.getLogger("otgeo").warning(
                        "worker pid %d exited (%s); starting a new one", proc.pid, proc.returncode)
                    self.procs[i] = self._spawn(self.queues[i])

    def stop(self, timeout: float = 10.0) -> None:
        self._stopping.set()
        for proc in self.procs:
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)  # Huey: stop now; running job handed back
        deadline = time.monotonic() + timeout
        for proc in self.procs:
            try:
                proc.wait(max(deadline - time.monotonic(), 0.1))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def storage_problem(settings) -> str | None:
    """One line saying why the data directory cannot be used, or None."""
    from service.storage_probe import storage_status

    status = storage_status(settings.data_dir,
                            (settings.data_dir / "domains", settings.data_dir / "results"))
    if status["writable"]:
        return None
    return (f"data directory {settings.data_dir} is not writable ({status['reason']}); "
            "set OTGEO_DATA_DIR or --data-dir to a writable directory")


def cmd_serve(args) -> None:
    import uvicorn

    settings = _settings(args)
    fail = storage_problem(settings)
    if fail:
        print(f"otgeo serve: {fail}", file=sys.stderr, flush=True)
        raise SystemExit(2)
    env = limit_blas_threads(settings.blas_threads, dict(os.environ))
    env["OTGEO_DATA_DIR"] = str(settings.data_dir.resolve())
    pool = None
    if settings.workers > 0 and settings.queue != "immediate":
        pool = WorkerPool(settings.workers, env, settings.reserved_short_workers)
        pool.start()
        print(f"otgeo: {settings.workers} worker process(es): "
              f"{', '.join(str(p.pid) for p in pool.procs)} "
              f"(queues: {'; '.join(pool.queues)})", flush=True)
    # uvicorn re-raises SIGINT/SIGTERM after a graceful shutdown, with the handlers that were
    # installed before it started: make those no-ops so the workers are stopped below.
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: None)
    try:
        from sqlalchemy.exc import SQLAlchemyError

        from service.app import create_app

        try:
            app = create_app(settings)
        except (OSError, SQLAlchemyError) as exc:  # storage or job database unusable
            reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else \
                type(exc).__name__
            print(f"otgeo serve: cannot open the service's storage or job database "
                  f"({reason})", file=sys.stderr, flush=True)
            raise SystemExit(2) from None
        uvicorn.run(app, host=args.host, port=args.port, log_level=args.log_level)
    finally:
        if pool is not None:
            pool.stop()


def cmd_hash_key(args) -> None:
    """Print a key-file line (``<tenant> <sha256> [admin]``) for a key read from stdin (kept
    out of the shell history), or for a new random key (``--new``, shown on stderr once)."""
    import secrets

    from service.settings import TenantKey, key_digest  # not service.tenants: the API's imports

    key = secrets.token_urlsafe(32) if args.new else sys.stdin.readline().rstrip("\r\n")
    if not key:
        raise SystemExit("no key on stdin (or use --new)")
    TenantKey(tenant=args.tenant, sha256=key_digest(key))  # a valid tenant name
    if args.new:
        print(f"new key for {args.tenant}: {key}", file=sys.stderr)
    print(f"{args.tenant} {key_digest(key)}" + (" admin" if args.admin else ""))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="otgeo", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    serve = sub.add_parser("serve", help="run the API and embedded worker processes")
    serve.add_argument("--host", default="127.0.0.1")
    serve.add_argument("--port", type=int, default=8000)
    serve.add_argument("--workers", type=int, default=None,
                       help="worker processes (default OTGEO_WORKERS, else the cores)")
    serve.add_argument("--data-dir", default=None)
    serve.add_argument("--log-level", default="info")
    worker = sub.add_parser("worker", help="run a worker only (scaled-out deployments)")
    worker.add_argument("--data-dir", default=None)
    worker.add_argument("--queues", default="short,long",
                        help="queues served: short,long (default) or short (reserved for "
                        "short jobs)")
    spec = sub.add_parser("openapi", help="write the OpenAPI document")
    spec.add_argument("--output", "-o", default=str(DEFAULT_OPENAPI))
    routes = sub.add_parser("routes", help="print every route (Markdown), or --update the "
                            "generated route list in documentation files")
    routes.add_argument("--update", nargs="*", default=[], metavar="FILE")
    hashed = sub.add_parser("hash-key", help="print the key-file line of an API key (read "
                            "from stdin) for OTGEO_TENANT_KEY_FILE / OTGEO_TENANT_KEYS")
    hashed.add_argument("--tenant", required=True, help="the tenant the key belongs to")
    hashed.add_argument("--admin", action="store_true", help="an admin key (sees everything)")
    hashed.add_argument("--new", action="store_true", help="generate a random key")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO,
                        format="%(asctime)s %(process)d %(name)s %(levelname)s %(message)s")
    command = {"serve": cmd_serve, "worker": cmd_worker, "openapi": cmd_openapi,
               "routes": cmd_routes, "hash-key": cmd_hash_key}[args.command]
    try:
        command(args)
    except ModuleNotFoundError as exc:
        # the library installs alone (`pip install otgeo`); the service is an extra
        if (exc.name or "").split(".")[0] not in SERVICE_PACKAGES:
            raise
        parser.exit(2, f"otgeo {args.command}: the service's packages are not installed "
                       f"(no module {exc.name!r}): pip install 'otgeo[service]'\n")


if __name__ == "__main__":
    main()
