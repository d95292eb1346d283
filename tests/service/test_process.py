"""The process tree of ``otgeo serve``: workers die with their parent (also on SIGKILL), and
an unusable data directory stops start-up with one clear line."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import time

from liveserver import API, ROOT, otgeo_command

from service.cli import worker_queues


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            state = fh.read().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return False
    return state not in ("Z", "X")  # a zombie has exited (its new parent reaps it)


def test_workers_die_when_serve_is_killed(tmp_path):
    api = API({"OTGEO_DATA_DIR": str(tmp_path), "OTGEO_WORKERS": "2"}, tmp_path)
    pids: list[int] = []
    try:
        deadline = time.monotonic() + 60  # serve prints its workers' pids once spawned
        while not (m := re.search(r"worker process\(es\): ([\d, ]+)", api.log(10**6))):
            assert api.alive() and time.monotonic() < deadline, api.log()
            time.sleep(0.05)
        pids = [int(p) for p in m.group(1).replace(",", " ").split()]
        assert len(pids) == 2 and all(_alive(p) for p in pids)
        time.sleep(0.5)  # the workers are running their own code (whatever its stage)
        api.kill(signal.SIGKILL)
        killed = time.monotonic()
        while any(_alive(p) for p in pids) and time.monotonic() - killed < 10:
            time.sleep(0.05)
        gone_after = time.monotonic() - killed
        assert not any(_alive(p) for p in pids), api.log()
        assert gone_after < 5.0
    finally:
        for pid in pids:
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
        api.stop()


def test_serve_refuses_an_unusable_data_dir_in_one_line(tmp_path):
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("a file where the data directory should be")
    env = {k: v for k, v in os.environ.items() if not k.startswith("OTGEO_")}
    env.update({"OTGEO_DATA_DIR": str(blocker / "data"), "OTGEO_WORKERS": "0"})
    for command in ("serve", "worker"):
        proc = subprocess.run(otgeo_command() + [command], cwd=ROOT, env=env,
                              capture_output=True, text=True, timeout=60)
        assert proc.returncode == 2, proc.stderr
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
        assert "not writable" in lines[0] and "not a directory" in lines[0]


def test_worker_queue_assignment():
    assert worker_queues(1, 1) == ["short,long"]
    assert worker_queues(2, 1) == ["short,long", "short"]
    assert worker_queues(4, 1) == ["short,long"] * 3 + ["short"]
    assert worker_queues(2, 5) == ["short,long", "short"]  # one always serves long jobs
    assert worker_queues(3, 0) == ["short,long"] * 3
