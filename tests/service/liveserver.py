"""Run ``otgeo serve`` / ``otgeo worker`` as real subprocesses (for live-server tests and
bench/service.py): free ports, environment, health waits, logs, and clean shutdown."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[2]


def otgeo_command() -> list[str]:
    """The installed console script if present, else the same entry point via ``-m``."""
    exe = Path(sys.executable).parent / "otgeo"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "service.cli"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Process:
    """A child process in its own session (so its own children die with it), logging to a file."""

    def __init__(self, name: str, args: list[str], env: dict[str, str], log_dir: Path):
        self.name = name
        self.log_path = Path(log_dir) / f"{name}.log"
        self._log = open(self.log_path, "ab")  # noqa: SIM115 - closed in stop()
        full_env = {k: v for k, v in os.environ.items() if not k.startswith("OTGEO_")}
        if "PYTEST_CURRENT_TEST" in os.environ:
            # Under pytest, workers skip the start-up warm-up (about 2.5 CPU-s each; a job
            # warms what it needs on its first run): tests/service/test_warm.py asks for it.
            # Benchmarks keep the default, as `otgeo serve` runs.
            full_env["OTGEO_WARM_AT_START"] = "false"
        full_env.update(env)
        full_env.setdefault("PYTHONUNBUFFERED", "1")
        self.popen = subprocess.Popen(args, env=full_env, cwd=ROOT, stdout=self._log,
                                      stderr=subprocess.STDOUT, start_new_session=True)

    @property
    def pid(self) -> int:
        return self.popen.pid

    def alive(self) -> bool:
        return self.popen.poll() is None

    def kill(self, sig: int = signal.SIGKILL) -> None:
        """Signal this process only (not its children): what a crash of it looks like."""
        if self.alive():
            os.kill(self.pid, sig)
            if sig == signal.SIGKILL:
                self.popen.wait(timeout=10)

    def terminate(self) -> None:
        """SIGTERM the whole session (graceful shutdown), without waiting."""
        if self.alive():
            try:
                os.killpg(self.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass

    def stop(self, timeout: float = 10.0) -> None:
        """SIGTERM the whole session, then SIGKILL what is left."""
        self.terminate()
        try:
            self.popen.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            pass
        try:
            os.killpg(self.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        if self.popen.poll() is None:
            self.popen.wait(timeout=5)
        if not self._log.closed:
            self._log.close()

    def log(self, tail: int = 4000) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text(errors="replace")[-tail:]


class API(Process):
    def __init__(self, env: dict[str, str], log_dir: Path, name: str = "api",
                 port: int | None = None):
        self._start = (env, log_dir, name)
        self._fixed_port = port is not None
        self.port = port or free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        log = Path(log_dir) / f"{name}.log"
        self._log_start = log.stat().st_size if log.exists() else 0
        super().__init__(name, otgeo_command() + ["serve", "--host", "127.0.0.1",
                                                  "--port", str(self.port)], env, log_dir)

    def _lost_its_port(self) -> bool:
        """Another process (a parallel test worker) bound the free port first."""
        if self._fixed_port:
            return False
        if not self._log.closed:
            self._log.flush()
        with open(self.log_path, "rb") as fh:
            fh.seek(self._log_start)
            return b"address already in use" in fh.read()

    def wait_healthy(self, timeout: float = 30.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if not self.alive() and self._lost_its_port():
                self.stop()
                API.__init__(self, *self._start)  # again, on another free port
            if not self.alive():
                raise RuntimeError(f"{self.name} exited:\n{self.log()}")
            try:
                if httpx.get(self.url + "/healthz", timeout=1.0).status_code == 200:
                    return
            except httpx.HTTPError:
                pass
            time.sleep(0.1)
        raise TimeoutError(f"{self.name} not healthy after {timeout} s:\n{self.log()}")


class Worker(Process):
    def __init__(self, env: dict[str, str], log_dir: Path, name: str = "worker"):
        super().__init__(name, otgeo_command() + ["worker"], env, log_dir)

    def ready(self) -> bool:
        """The worker logged that its consumer is up (``worker <id> ready``)."""
        return " ready (queue " in self.log(10**7)


def stop_all(processes, timeout: float = 10.0) -> None:
    """Stop several processes in parallel: SIGTERM all, then wait for / kill each."""
    for p in processes:
        p.terminate()
    for p in processes:
        p.stop(timeout)


def wait_for(predicate, timeout: float, interval: float = 0.05, what: str = "condition"):
    """Poll ``predicate()`` until it returns a truthy value; return it."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(interval)
