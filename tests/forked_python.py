"""Run Python programs (``python -c CODE`` or ``python FILE``) as forked children of one
interpreter that has already imported what earlier programs imported: each program still
runs as its own process, with its own working directory, argv, environment, ``sys.path[0]``,
``__main__`` module, standard streams (stdin ``/dev/null``, stdout and stderr captured) and
exit status, but not its own imports again (numpy, scipy, the solvers and the libraries they
import lazily: 1 to 1.7 CPU-s of each documentation example, tests/service/
test_readme_examples.py).

How it stays a fresh program:

- the runner (this file run as a script) only imports: it never runs a program's code. After
  each program it imports, in order, the modules that program imported (not those found in
  the program's own folder or working directory), so a later program finds them loaded, with
  the state their import left and nothing else;
- a child starts from that state: the environment the caller gives (the runner started with
  the same one except for the names the caller lists as ``late_env``, which nothing imported
  may read at import time), ``random`` and ``numpy.random`` reseeded from the OS as a new
  interpreter seeds them; uncaught exceptions and ``SystemExit`` end it as they end
  ``python`` (same traceback, message and status), and it exits through the interpreter's
  shutdown steps (non-daemon threads joined, ``atexit`` handlers, its own objects released
  so that files it left open are flushed, streams flushed), all but the teardown of the
  modules the runner had imported (~0.4 CPU-s a child);
- if an import left the runner with more than one thread, or the environment differs in
  another name, the child ``exec``s a fresh interpreter instead (the plain ``python``
  command, exactly): forking a threaded process is not safe. ``Result.forked`` says which.

What a forked program shares with the runner and cannot tell apart from a fresh start only
by timing: the hash seed of ``str`` (one per runner), and warnings printed when a module is
first imported (printed once, in the runner's log).

    with PythonRunner(env, cwd=tmp) as runner:
        result = runner.run(["-c", "print(1)"], cwd=work, env=env, timeout=60)
"""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path


@dataclass
class Result:
    """A finished program: as ``subprocess.CompletedProcess``, and whether it was forked."""

    args: list[str]
    returncode: int
    stdout: str
    stderr: str
    forked: bool


class PythonRunner:
    """The runner process (``env``: the environment its programs get, but for ``late_env``)."""

    def __init__(self, env: dict[str, str], cwd: Path, late_env: tuple[str, ...] = ()):
        self.cwd = Path(cwd)
        self.log_path = self.cwd / "python-runner.log"
        requests_r, self._requests = os.pipe()
        self._replies, replies_w = os.pipe()
        with open(self.log_path, "ab") as log:
            self.proc = subprocess.Popen(
                [sys.executable, __file__, str(requests_r), str(replies_w), *late_env],
                env=env, cwd=self.cwd, stdin=subprocess.DEVNULL, stdout=log,
                stderr=subprocess.STDOUT, pass_fds=(requests_r, replies_w))
        os.close(requests_r)
        os.close(replies_w)
        self._buffer = b""

    def run(self, argv: list[str], cwd: Path, env: dict[str, str], timeout: float) -> Result:
        """``python *argv`` in ``cwd`` with ``env``; ``subprocess.TimeoutExpired`` (the
        program killed) after ``timeout`` seconds."""
        out_dir = Path(tempfile.mkdtemp(prefix="program-", dir=self.cwd))
        request = {"argv": argv, "cwd": str(cwd), "env": env,
                   "stdout": str(out_dir / "stdout"), "stderr": str(out_dir / "stderr"),
                   "report": str(out_dir / "modules.json")}
        os.write(self._requests, json.dumps(request).encode() + b"\n")
        started = self._reply(30)
        try:
            ended = self._reply(timeout)
        except TimeoutError:
            os.kill(started["pid"], signal.SIGKILL)
            self._reply(30)
            raise subprocess.TimeoutExpired(argv, timeout, (out_dir / "stdout").read_bytes(),
                                            (out_dir / "stderr").read_bytes()) from None
        return Result(argv, ended["returncode"], (out_dir / "stdout").read_text(),
                      (out_dir / "stderr").read_text(errors="replace"), started["forked"])

    def _reply(self, timeout: float) -> dict:
        deadline = time.monotonic() + timeout
        while b"\n" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self._replies], [], [], left)[0]:
                if self.proc.poll() is not None:
                    raise RuntimeError(f"the Python runner exited:\n{self.log()}")
                raise TimeoutError
            chunk = os.read(self._replies, 65536)
            if not chunk:
                raise RuntimeError(f"the Python runner exited:\n{self.log()}")
            self._buffer += chunk
        line, self._buffer = self._buffer.split(b"\n", 1)
        return json.loads(line)

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")[-4000:]

    def close(self) -> None:
        """End the runner (it exits when its request pipe closes) and reap it."""
        os.close(self._requests)
        try:
            self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        os.close(self._replies)

    def __enter__(self) -> PythonRunner:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# -- the runner process -------------------------------------------------------------------
def _threads() -> int:
    return len(os.listdir("/proc/self/task"))


def _serve(requests_fd: int, replies_fd: int, late_env: frozenset) -> dict:
    """Fork a child per request; return the request in the child, exit when the caller
    closes the request pipe."""
    if not sys.flags.safe_path:
        sys.path.pop(0)  # this file's folder: each program gets its own sys.path[0]
    start_env = dict(os.environ)
    requests = os.fdopen(requests_fd, "rb")
    for line in requests:
        request = json.loads(line)
        changed = {k for k in start_env.keys() | request["env"].keys()
                   if start_env.get(k) != request["env"].get(k)}
        request["forked"] = changed <= late_env and _threads() == 1
        pid = os.fork()
        if pid == 0:
            requests.close()
            os.close(replies_fd)
            return request
        os.write(replies_fd, json.dumps({"pid": pid, "forked": request["forked"]}).encode()
                 + b"\n")
        _, status = os.waitpid(pid, 0)
        os.write(replies_fd, json.dumps(
            {"returncode": os.waitstatus_to_exitcode(status)}).encode() + b"\n")
        _import_what_it_imported(request)
    os._exit(0)  # nothing to flush (its prints flush): skip tearing down what it imported


def _import_what_it_imported(request: dict) -> None:
    """Import the modules the program imported, but those of its own folders."""
    import importlib

    try:
        modules = json.loads(Path(request["report"]).read_text())
    except (OSError, ValueError):
        return
    own = tuple(os.path.join(os.path.realpath(p), "") for p in modules["own_folders"])
    for name, file in modules["imported"]:
        if name in sys.modules or (file and os.path.realpath(file).startswith(own)):
            continue
        try:
            importlib.import_module(name)
        except BaseException as exc:  # noqa: BLE001 - any failure: the program imports it itself
            print(f"not preloaded: {name} ({type(exc).__name__}: {exc})", flush=True)


def _redirect(request: dict) -> None:
    for fd, path, flags in ((0, os.devnull, os.O_RDONLY),
                            (1, request["stdout"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC),
                            (2, request["stderr"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC)):
        new = os.open(path, flags, 0o644)
        os.dup2(new, fd)
        os.close(new)


def _run(request: dict) -> int:
    """The program, in this forked child (or a fresh interpreter exec'd in its place): its
    exit status."""
    _redirect(request)
    os.chdir(request["cwd"])
    argv, env = request["argv"], request["env"]
    if not request["forked"]:
        os.execve(sys.executable, [sys.executable, *argv], env)
    os.environ.clear()
    os.environ.update(env)
    if argv[0] == "-c":
        source, filename, sys.argv, home = argv[1], "<string>", ["-c", *argv[2:]], ""
    else:
        filename, sys.argv = argv[0], list(argv)
        source, home = Path(filename).read_bytes(), os.path.dirname(os.path.realpath(filename))
    if not sys.flags.safe_path:  # python -P / PYTHONSAFEPATH: no folder of its own
        sys.path.insert(0, home)
    _reseed()
    import types

    main = types.ModuleType("__main__")
    main.__dict__["__builtins__"] = __builtins__
    if filename != "<string>":
        main.__file__ = filename
    sys.modules["__main__"] = main
    before = set(sys.modules)
    try:
        return _execute(source, filename, main)
    finally:  # what the runner imports next, for the programs after this one
        imported = [(name, getattr(module, "__file__", None))
                    for name, module in list(sys.modules.items())
                    if name not in before and name != "__main__"]
        Path(request["report"]).write_text(json.dumps(
            {"imported": imported, "own_folders": [home or os.getcwd(), os.getcwd()]}))


def _execute(source, filename: str, main) -> int:
    """Run the code; end as the interpreter ends a program: the status of ``SystemExit``
    (its message printed when not a number), a traceback and 1 for an exception."""
    try:
        exec(compile(source, filename, "exec"), main.__dict__)
    except SystemExit as stop:
        if stop.code is None or isinstance(stop.code, int):
            return (stop.code or 0) & 0xFF  # as the OS reports it: exit(-1) is 255
        print(stop.code, file=sys.stderr)
        return 1
    except BaseException as exc:  # noqa: BLE001 - as python: any other exception is reported
        if isinstance(exc, KeyboardInterrupt):
            return -signal.SIGINT  # python dies by the signal (the only negative status)
        exc.with_traceback(exc.__traceback__.tb_next)  # from the program's frame, as python
        sys.excepthook(type(exc), exc, exc.__traceback__)
        return 1
    return 0


def _shut_down(status: int) -> None:
    """The interpreter's shutdown of a program, then exit: non-daemon threads joined, atexit
    handlers run, the program's own objects released (files it left open are flushed),
    streams flushed. Left out: tearing down the modules the runner had imported (identical
    in every program, and about 0.4 CPU-s of a child's time)."""
    import atexit
    import gc
    import threading

    threading._shutdown()  # what Py_FinalizeEx calls first
    atexit._run_exitfuncs()
    sys.modules["__main__"].__dict__.clear()
    gc.collect()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            status = status or 120  # as python when its standard streams fail at exit
    if status < 0:
        signal.signal(-status, signal.SIG_DFL)
        os.kill(os.getpid(), -status)
    os._exit(status)


def _reseed() -> None:
    """As a new interpreter: ``random`` and numpy's global generator seeded from the OS."""
    import random

    random.seed()
    if "numpy.random" in sys.modules:
        sys.modules["numpy.random"].seed()


if __name__ == "__main__":
    _shut_down(_run(_serve(int(sys.argv[1]), int(sys.argv[2]), frozenset(sys.argv[3:]))))
