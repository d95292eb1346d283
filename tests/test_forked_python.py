"""tests/forked_python.py runs each program as a fresh ``python`` would: its own working
directory, argv, environment, ``sys.path[0]``, ``__main__``, streams and exit status, nothing
left by the programs before it, and a timeout that kills it; forked only when that is safe."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from forked_python import PythonRunner

SHOW = """import os, sys
print(os.getcwd(), sys.argv, os.environ.get("LATE"), os.environ.get("GONE"), sys.path[0])
print(__name__, globals().get("__file__"), "json.marked" if hasattr(__import__("json"),
      "marked") else "json fresh", "forked" if "email.mime.text" in sys.modules else "cold")
print("to stderr", file=sys.stderr)
import email.mime.text, json
json.marked = True
"""


@pytest.fixture(scope="module")
def runner(tmp_path_factory):
    env = {**os.environ, "GONE": "at start"}
    env.pop("LATE", None)
    with PythonRunner(env, tmp_path_factory.mktemp("runner"),
                      late_env=("LATE", "PYTEST_CURRENT_TEST")) as r:
        yield r, env


def test_each_program_runs_as_its_own_python(runner, tmp_path):
    r, base = runner
    env = {**base, "LATE": "set late"}
    (tmp_path / "prog.py").write_text(SHOW)
    first = r.run(["-c", SHOW, "a1"], tmp_path, env, 60)
    assert first.returncode == 0 and first.forked, first
    assert first.stdout.splitlines() == [
        f"{tmp_path} ['-c', 'a1'] set late at start ",
        "__main__ None json fresh cold"]
    assert first.stderr == "to stderr\n"
    # the next program: what the first imported is loaded, what it changed is not
    second = r.run([str(tmp_path / "prog.py"), "b"], tmp_path, env, 60)
    assert second.returncode == 0 and second.forked, second
    assert second.stdout.splitlines() == [
        f"{tmp_path} ['{tmp_path / 'prog.py'}', 'b'] set late at start {tmp_path}",
        f"__main__ {tmp_path / 'prog.py'} json fresh forked"]


def test_exit_status_and_errors_as_python_reports_them(runner, tmp_path):
    r, env = runner
    for code, status, err in [("raise SystemExit(3)", 3, ""), ("import sys; sys.exit('no')", 1,
                              "no\n"), ("1 / 0", 1, "ZeroDivisionError: division by zero\n"),
                              ("import os; os._exit(5)", 5, "")]:
        result = r.run(["-c", code], tmp_path, env, 60)
        assert (result.returncode, result.forked) == (status, True), (code, result)
        assert result.stderr.endswith(err), (code, result.stderr)
    assert r.run(["-c", "print('alive')"], tmp_path, env, 60).stdout == "alive\n"


def test_a_changed_environment_gets_a_fresh_interpreter(runner, tmp_path):
    """A variable outside ``late_env`` may have been read by an import: ``exec`` python."""
    r, env = runner
    result = r.run(["-c", "import os, sys; print(os.environ['GONE'], 'email' in sys.modules)"],
                   tmp_path, {**env, "GONE": "changed"}, 60)
    assert (result.returncode, result.stdout, result.forked) == (0, "changed False\n", False)


def test_a_program_past_its_timeout_is_killed(runner, tmp_path):
    r, env = runner
    with pytest.raises(subprocess.TimeoutExpired):
        r.run(["-c", "import time; print('started', flush=True); time.sleep(60)"],
              tmp_path, env, 1)
    assert r.run(["-c", "print(2)"], tmp_path, env, 60).stdout == "2\n"  # the runner serves on


@pytest.mark.parametrize("code", [
    "import sys; print(sys.argv, __name__); sys.exit(4)",
    "import sys; sys.exit(-1)",
    "def f():\n    return {}['key']\nprint('before')\nf()",
    "1 +",
    "import atexit, threading, time\natexit.register(print, 'at exit')\n"
    "threading.Thread(target=lambda: (time.sleep(0.2), print('thread'))).start()",
    "f = open('left-open.txt', 'w'); f.write('flushed at exit')\n"
    "print(open('left-open.txt').read() == '')",
])
def test_same_output_as_the_python_command(runner, tmp_path, code):
    """Status, output, tracebacks and exit steps as ``python -c`` gives them."""
    r, env = runner
    fresh = subprocess.run([sys.executable, "-c", code, "x"], cwd=tmp_path, env=env,
                           capture_output=True, text=True, timeout=60)
    fresh_file = (tmp_path / "left-open.txt").read_text() if "open(" in code else None
    forked = r.run(["-c", code, "x"], tmp_path, env, 60)
    assert (forked.returncode, forked.stdout, forked.stderr) == \
        (fresh.returncode, fresh.stdout, fresh.stderr) and forked.forked
    if fresh_file is not None:
        assert (tmp_path / "left-open.txt").read_text() == fresh_file == "flushed at exit"
