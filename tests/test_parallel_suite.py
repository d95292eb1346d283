"""``make test`` runs the suite with pytest-xdist, one test file per worker at a time (its
module-scoped fixtures, a live server or a browser, set up once), each worker with one BLAS
thread (tests/conftest.py)."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

TESTS = Path(__file__).resolve().parent
PROBE = '''
import os
import threadpoolctl


def record(name):
    threads = {{p["num_threads"] for p in threadpoolctl.threadpool_info()}}
    with open("{name}-" + name + ".txt", "w") as fh:
        fh.write(os.environ["PYTEST_XDIST_WORKER"] + " " + ",".join(map(str, threads)))


def test_{name}_{i}():
    record("{i}")
'''


def make_test_flags() -> list[str]:
    """The pytest options of the Makefile's ``test`` target (after ``-m pytest``)."""
    line = next(ln for ln in (TESTS.parent / "Makefile").read_text().splitlines()
                if "-m pytest" in ln)
    return shlex.split(line.split("-m pytest", 1)[1].replace("$(TEST_WORKERS)", "2"))


def test_make_test_runs_each_file_on_one_worker_with_one_blas_thread(tmp_path):
    flags = make_test_flags()
    assert re.search(r"-n \S+ --dist loadfile", " ".join(flags)), flags
    for name in ("one", "two", "three"):
        (tmp_path / f"test_{name}.py").write_text("".join(PROBE.format(name=name, i=i)
                                                          for i in range(4)))
    # a fresh run, as make test starts it (not this run's worker settings)
    env = {k: v for k, v in os.environ.items()
           if not k.endswith("_NUM_THREADS") and not k.startswith("PYTEST_")}
    env["PYTHONPATH"] = os.pathsep.join([str(TESTS), str(TESTS.parent),
                                         env.get("PYTHONPATH", "")])
    done = subprocess.run([sys.executable, "-m", "pytest", "-p", "conftest", "-p",
                           "no:cacheprovider", *flags, str(tmp_path)], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    for name in ("one", "two", "three"):
        seen = {(tmp_path / f"{name}-{i}.txt").read_text() for i in range(4)}
        assert len(seen) == 1, seen  # one worker ran the whole file
        assert seen.pop().endswith(" 1")  # BLAS pools of one thread


def test_longest_files_named_for_the_order_exist():
    import ast

    tree = ast.parse((TESTS / "conftest.py").read_text())
    names = next(ast.literal_eval(node.value) for node in ast.walk(tree)
                 if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") ==
                 "LONGEST_FILES")
    assert names and all((TESTS / name).is_file() for name in names), names
