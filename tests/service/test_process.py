"""The process tree of ``otgeo serve``: workers die with their parent (also on SIGKILL), and
an unusable data directory stops start-up with one clear line."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import time
from pathlib import Path

import httpx
from liveserver import API, ROOT, free_port, otgeo_command

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


def _in_private_mount_ns(script: str, env: dict, log) -> subprocess.Popen:
    """Run ``script`` (sh) in its own mount namespace (root: read-only bind mounts that the
    rest of the machine does not see)."""
    return subprocess.Popen(["unshare", "-m", "--propagation", "private", "sh", "-c", script],
                            cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT,
                            start_new_session=True)


def _env(data: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("OTGEO_")}
    env.update({"OTGEO_DATA_DIR": str(data), "OTGEO_WORKERS": "0", "PYTHONUNBUFFERED": "1"})
    return env


def test_read_only_data_dir_at_start_and_while_running(tmp_path):
    """A real read-only file system (a read-only bind mount; chmod does not stop root)."""
    data = tmp_path / "data"
    data.mkdir()
    cmd = " ".join(otgeo_command())
    proc = subprocess.run(
        ["unshare", "-m", "--propagation", "private", "sh", "-c",
         f"mount --bind {data} {data} && mount -o remount,bind,ro {data} {data} && "
         f"exec {cmd} serve"], cwd=ROOT, env=_env(data), capture_output=True, text=True,
        timeout=60)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "read-only file system" in lines[0], proc.stderr

    # while running: the domains directory becomes read-only (a remount of the whole data
    # directory is refused while SQLite holds its files open for writing)
    port, trigger, domains = free_port(), tmp_path / "make-read-only", data / "domains"
    domains.mkdir()
    script = (f"mount --bind {domains} {domains} || exit 90\n"
              f"{cmd} serve --port {port} &\nPID=$!\n"
              f"while [ ! -e {trigger} ]; do sleep 0.05; done\n"
              f"mount -o remount,bind,ro {domains} {domains} || exit 91\n"
              f"touch {trigger}.done\nwait $PID\n")
    url = f"http://127.0.0.1:{port}"
    with open(tmp_path / "serve.log", "ab") as log:
        server = _in_private_mount_ns(script, _env(data), log)
        try:
            deadline = time.monotonic() + 60
            while True:
                assert server.poll() is None, (tmp_path / "serve.log").read_text()
                try:
                    if httpx.get(url + "/healthz", timeout=1).status_code == 200:
                        break
                except httpx.HTTPError:
                    pass
                assert time.monotonic() < deadline
                time.sleep(0.1)
            grid = {"kind": "grid", "shape": [4, 4]}
            assert httpx.post(url + "/v1/domains", json=grid).status_code == 201
            trigger.touch()
            while not Path(f"{trigger}.done").exists():
                assert server.poll() is None and time.monotonic() < deadline
                time.sleep(0.05)
            r = httpx.post(url + "/v1/domains", json={"kind": "grid", "shape": [5, 5]})
            assert r.status_code == 503, r.text
            err = r.json()["error"]
            assert err["code"] == "storage_unavailable"
            assert "read-only file system" in err["message"] and str(data) not in err["message"]
            time.sleep(1.1)  # past the health check's probe cache
            health = httpx.get(url + "/healthz")
            assert health.status_code == 503
            storage = health.json()["storage"]
            assert storage["writable"] is False and storage["reason"] == "read-only file system"
        finally:
            try:
                os.killpg(server.pid, signal.SIGTERM)
                server.wait(15)
            except (ProcessLookupError, subprocess.TimeoutExpired):
                os.killpg(server.pid, signal.SIGKILL)
