"""A worker's queue consumer: one job at a time from the short queue and (unless the worker
is reserved for short jobs) the long queue, short jobs first.

Replaces Huey's consumer (which reads one queue): on the embedded SQLite queue the job table
is the queue (the worker claims the oldest queued job of its queues in one statement, see
``JobRepository.claim_next``; Huey messages, e.g. from an older API, are still read), then it
blocks on the wake-up socket (service.jobs.wake); on
Redis it blocks in one ``BRPOP`` over both lists (Redis serves the first non-empty key in
order: short before long). Messages are decoded by the queues' JSON serializer
(service.jobs.queue): a message that is not one of ours is logged and dropped.

SIGTERM / SIGINT stop the consumer at once; the caller hands the running job back.
"""

from __future__ import annotations

import logging
import signal
import threading
import time

from service.jobs.queue import QUEUES

log = logging.getLogger("otgeo.worker")

CLAIMED = "claimed"  # next_message's tag of a job claimed from the job table


class Consumer:
    def __init__(self, runtime, queues=QUEUES, wake=None):
        unknown = set(queues) - set(QUEUES)
        if unknown or not queues:
            raise ValueError(f"queues must be among {QUEUES}, got {list(queues)}")
        self.rt = runtime
        self.queues = [q for q in QUEUES if q in queues]  # short first
        self.wake = wake
        self.stop_event = threading.Event()
        self.dropped = 0
        self._thread: threading.Thread | None = None
        self.poll = runtime.settings.worker_poll_interval
        self._woken = False  # the last wait ended with a datagram (an enqueue, most likely)

    # -- reading ---------------------------------------------------------------
    def _read_sqlite(self, timeout: float):
        woken, self._woken = self._woken, False
        claim = self.rt.repo.claim_next(tuple(self.queues), self.rt.runner.worker_id,
                                        probe=not woken)
        if claim is not None:
            return CLAIMED, claim
        for q in self.queues:
            data = self.rt.hueys[q].storage.dequeue_now()
            if data is not None:
                return q, data
        if self.wake is not None and self.wake.sock is not None:
            self._woken = bool(self.wake.wait(timeout))
        else:
            time.sleep(min(self.poll, timeout))
        return None

    def _read_redis(self, timeout: float):
        storages = [self.rt.hueys[q].storage for q in self.queues]
        keys = [s.queue_key for s in storages]
        got = storages[0].conn.brpop(keys, timeout=max(int(round(timeout)), 1))
        if not got:
            return None
        key, data = got
        key = key.decode() if isinstance(key, bytes) else key
        return self.queues[keys.index(key)], data

    def next_message(self, timeout: float = 1.0):
        """``(queue, raw bytes)`` of the next message, or None after ``timeout``."""
        if self.rt.settings.queue == "redis":
            return self._read_redis(timeout)
        return self._read_sqlite(timeout)

    def decode(self, queue: str, data) -> str | None:
        """The job id of a raw message; None (logged, dropped) for anything else."""
        try:
            task = self.rt.hueys[queue].deserialize_task(data)
            return task.args[0]
        except Exception as exc:  # never unpickled: the serializer only reads JSON
            self.dropped += 1
            log.warning("dropped a queue message that is not a job id (%s queue, %d bytes): %s",
                        queue, len(data) if data is not None else 0, exc)
            return None

    # -- running ---------------------------------------------------------------
    def step(self, timeout: float = 1.0) -> str | None:
        """Read one message and run its job; returns the job id run (None if none)."""
        msg = self.next_message(timeout)
        if msg is None:
            return None
        if msg[0] == CLAIMED:
            self.rt.runner.run_claimed(msg[1])
            return msg[1].job.id
        job_id = self.decode(*msg)
        if job_id is not None:
            self.rt.runner.run(job_id)
        return job_id

    def _loop(self) -> None:
        backoff = 0.05
        while not self.stop_event.is_set():
            try:
                self.step()
                backoff = 0.05
            except Exception:  # broker or database briefly unavailable
                log.exception("worker loop error; retrying in %.2f s", backoff)
                self.stop_event.wait(backoff)
                backoff = min(backoff * 2, 1.0)  # back within a second of a broker restart

    def run(self) -> None:
        """Consume until SIGTERM/SIGINT (or :meth:`stop`); the job thread is a daemon, so
        a job still running is abandoned (the caller releases it to the queue)."""
        previous = {}
        if threading.current_thread() is threading.main_thread():
            for signum in (signal.SIGTERM, signal.SIGINT):
                previous[signum] = signal.signal(signum, lambda *_: self.stop_event.set())
        self._thread = threading.Thread(target=self._loop, daemon=True, name="consumer")
        self._thread.start()
        try:
            while not self.stop_event.wait(0.5):
                if not self._thread.is_alive():  # pragma: no cover - the loop catches all
                    self._thread = threading.Thread(target=self._loop, daemon=True,
                                                    name="consumer")
                    self._thread.start()
        finally:
            for signum, handler in previous.items():
                signal.signal(signum, handler)

    def stop(self) -> None:
        self.stop_event.set()
