"""Wake-up datagrams between the processes of one machine (API <-> workers).

Replaces tight polling on the latency path: the API tells the local workers "a job was
enqueued" (their SQLite-queue dequeue blocks on the socket instead of polling), and a worker
tells the local API processes "job <id> finished" (a waiting ``?wait`` request reads the job
table at once instead of polling a marker).  Each process binds a Linux abstract-namespace
datagram socket (no path-length limit, gone when the process dies) and registers it as an
empty file ``<data_dir>/wake/<role>@<host>@<pid>``; senders list that directory.  Only an
optimization: a lost datagram (other host, other network namespace, non-Linux system) costs
the polling interval the callers keep as a fallback.
"""

from __future__ import annotations

import functools
import hashlib
import logging
import os
import select
import socket
from collections import OrderedDict
from pathlib import Path

log = logging.getLogger("otgeo.wake")

ROLES = ("api", "worker")


@functools.lru_cache(maxsize=16)
def _tag(directory: Path) -> bytes:
    """The data directory's part of the socket addresses (its real path resolved once per
    process: resolving costs a syscall per path component, on every datagram otherwise)."""
    return hashlib.sha1(str(directory.resolve()).encode()).hexdigest()[:16].encode()


def _address(directory: Path, name: str) -> bytes:
    return b"\0otgeo-" + _tag(directory) + b"/" + name.encode()


class WakeSocket:
    """This process's receiving end (``role`` is 'api' or 'worker')."""

    def __init__(self, data_dir: Path, role: str):
        assert role in ROLES
        self.directory = Path(data_dir) / "wake"
        self.name = f"{role}@{socket.gethostname()}@{os.getpid()}"
        self.sock: socket.socket | None = None
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
            sock.bind(_address(self.directory, self.name))
            sock.setblocking(False)
            (self.directory / self.name).touch()
            self.sock = sock
        except OSError as exc:  # no abstract namespace (not Linux): callers keep polling
            log.info("wake-up socket unavailable (%s); polling only", exc)

    def fileno(self) -> int:
        return self.sock.fileno()

    def drain(self) -> list[str]:
        """Messages received so far (non-blocking)."""
        out = []
        while self.sock is not None:
            try:
                out.append(self.sock.recv(256).decode(errors="replace"))
            except (BlockingIOError, InterruptedError):
                break
        return out

    def wait(self, timeout: float) -> list[str]:
        """Block up to ``timeout`` seconds for at least one message; returns all pending."""
        if self.sock is None:
            return []
        ready, _, _ = select.select([self.sock], [], [], timeout)
        return self.drain() if ready else []

    def close(self) -> None:
        if self.sock is not None:
            try:
                (self.directory / self.name).unlink()
            except OSError:
                pass
            self.sock.close()
            self.sock = None


class WakeSender:
    """Sends a message to every registered process of a role on this machine."""

    def __init__(self, data_dir: Path):
        self.directory = Path(data_dir) / "wake"
        self.host = socket.gethostname()
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.setblocking(False)

    def notify(self, role: str, message: str) -> int:
        """Returns how many processes were reached."""
        try:
            names = os.listdir(self.directory)
        except OSError:
            return 0
        prefix, sent = f"{role}@{self.host}@", 0
        for name in names:
            if not name.startswith(prefix):
                continue
            try:
                self.sock.sendto(message.encode(), _address(self.directory, name))
                sent += 1
            except (ConnectionRefusedError, FileNotFoundError):
                try:  # its process is gone
                    (self.directory / name).unlink()
                except OSError:
                    pass
            except OSError:  # buffer full (the receiver is awake anyway) or no support
                pass
        return sent

    def close(self) -> None:
        self.sock.close()


class JobWaiters:
    """API side: asyncio events of the requests waiting for jobs, set by "done" datagrams
    read on the event loop (``attach`` inside the running loop, ``detach`` on shutdown)."""

    RECENT_DONE = 1024  # "done" job ids remembered for requests that register late

    def __init__(self, data_dir: Path):
        self.socket = WakeSocket(data_dir, "api")
        self._events: dict[str, set] = {}
        # a job can finish before its submitting request registers (the submission ran in
        # the thread pool and the worker was quicker than the hop back): its "done"
        # datagram is kept here, so the late request wakes at once, not at its next poll
        self._done: OrderedDict[str, None] = OrderedDict()
        self._loop = None

    @property
    def active(self) -> bool:
        return self._loop is not None

    def attach(self, loop) -> None:
        if self.socket.sock is not None:
            loop.add_reader(self.socket.fileno(), self._on_readable)
            self._loop = loop

    def detach(self) -> None:
        if self._loop is not None:
            self._loop.remove_reader(self.socket.fileno())
            self._loop = None
        self.socket.close()

    def register(self, job_id: str):
        import asyncio

        event = asyncio.Event()
        if job_id in self._done:
            event.set()
        self._events.setdefault(job_id, set()).add(event)
        return event

    def unregister(self, job_id: str, event) -> None:
        events = self._events.get(job_id)
        if events is not None:
            events.discard(event)
            if not events:
                del self._events[job_id]

    def _on_readable(self) -> None:
        for job_id in self.socket.drain():
            self._done[job_id] = None
            if len(self._done) > self.RECENT_DONE:
                self._done.popitem(last=False)
            for event in self._events.get(job_id, ()):
                event.set()
