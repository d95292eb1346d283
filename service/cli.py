"""Command line: ``otgeo serve`` (API + embedded workers), ``otgeo worker``, ``otgeo openapi``.

Nothing numerical is imported at module level: worker processes set their BLAS
thread limits in the environment before numpy is first imported.
"""

from __future__ import annotations

import argparse
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
    import tempfile

    if app is None:
        from service.app import create_app
        from service.settings import Settings

        with tempfile.TemporaryDirectory() as tmp:
            app = create_app(Settings(data_dir=tmp, queue="immediate", api_keys=[]),
                             start_background=False)
            doc = app.openapi()
            app.state.runtime.close()
    else:
        doc = app.openapi()
    return json.dumps(doc, indent=2, sort_keys=True) + "\n"


def cmd_openapi(args) -> None:
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(openapi_document())
    print(f"wrote {out}")


def run_worker(settings) -> None:
    """One worker process: Huey consumer (one job at a time), reaper, statistics."""
    limit_blas_threads(settings.blas_threads)
    from service.runtime import Runtime

    runtime = Runtime(settings, role="worker")
    if settings.queue == "immediate":
        raise SystemExit("OTGEO_QUEUE=immediate runs jobs inside the API; no worker needed")
    wake = None
    if settings.queue == "sqlite":  # block on enqueue datagrams instead of polling the queue
        from service.jobs.wake import WakeSocket

        wake = WakeSocket(settings.data_dir, "worker")
        if wake.sock is not None:
            runtime.huey.storage.wake = wake
            runtime.huey.storage.blocking = True
    consumer = runtime.huey.create_consumer(
        workers=1, worker_type="thread", periodic=False, initial_delay=0.005, backoff=1.5,
        max_delay=settings.worker_poll_interval, check_worker_health=True)
    runtime.start_background(publish=True)
    logging.getLogger("otgeo").info("worker %s ready (queue %s)", runtime.process_id,
                                    settings.queue)
    try:
        consumer.run()
    finally:
        released = runtime.runner.release_current()
        if released:
            runtime.enqueue(released)
            logging.getLogger("otgeo").info("handed job %s back to the queue", released)
        runtime.close()
        if wake is not None:
            wake.close()


def cmd_worker(args) -> None:
    run_worker(_settings(args))


class WorkerPool:
    """Child ``otgeo worker`` processes, restarted if they die, stopped on shutdown."""

    def __init__(self, count: int, env: dict):
        self.count, self.env = count, env
        self.procs: list[subprocess.Popen] = []
        self._stopping = threading.Event()
        self._thread = threading.Thread(target=self._supervise, daemon=True, name="workers")

    def _spawn(self) -> subprocess.Popen:
        return subprocess.Popen([sys.executable, "-m", "service.cli", "worker"], env=self.env,
                                start_new_session=True)

    def start(self) -> None:
        self.procs = [self._spawn() for _ in range(self.count)]
        self._thread.start()

    def _supervise(self) -> None:
        while not self._stopping.wait(1.0):
            for i, proc in enumerate(self.procs):
                if proc.poll() is not None and not self._stopping.is_set():
                    logging.getLogger("otgeo").warning(
                        "worker pid %d exited (%s); starting a new one", proc.pid, proc.returncode)
                    self.procs[i] = self._spawn()

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


def cmd_serve(args) -> None:
    import uvicorn

    settings = _settings(args)
    settings.ensure_dirs()
    env = limit_blas_threads(settings.blas_threads, dict(os.environ))
    env["OTGEO_DATA_DIR"] = str(settings.data_dir.resolve())
    pool = None
    if settings.workers > 0 and settings.queue != "immediate":
        pool = WorkerPool(settings.workers, env)
        pool.start()
        print(f"otgeo: {settings.workers} worker process(es): "
              f"{', '.join(str(p.pid) for p in pool.procs)}", flush=True)
    # uvicorn re-raises SIGINT/SIGTERM after a graceful shutdown, with the handlers that were
    # installed before it started: make those no-ops so the workers are stopped below.
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: None)
    try:
        from service.app import create_app

        uvicorn.run(create_app(settings), host=args.host, port=args.port,
                    log_level=args.log_level)
    finally:
        if pool is not None:
            pool.stop()


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="otgeo", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    serve = sub.add_parser("serve", help="run the API and embedded worker processes")
    serve.add_argument("--host", default="127.0.0.1")
    serve.add_argument("--port", type=int, default=8000)
    serve.add_argument("--workers", type=int, default=None,
                       help="worker processes (default OTGEO_WORKERS, 1)")
    serve.add_argument("--data-dir", default=None)
    serve.add_argument("--log-level", default="info")
    worker = sub.add_parser("worker", help="run a worker only (scaled-out deployments)")
    worker.add_argument("--data-dir", default=None)
    spec = sub.add_parser("openapi", help="write the OpenAPI document")
    spec.add_argument("--output", "-o", default=str(DEFAULT_OPENAPI))
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO,
                        format="%(asctime)s %(process)d %(name)s %(levelname)s %(message)s")
    {"serve": cmd_serve, "worker": cmd_worker, "openapi": cmd_openapi}[args.command](args)


if __name__ == "__main__":
    main()
