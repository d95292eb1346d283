"""Every shell, Python and JSON example of the documentation runs, against a live
``otgeo serve`` (one API process with one worker, on a free port).

The examples are read from the documents (tests/doc_examples.py: Markdown fences and
includes, reStructuredText code blocks and literalinclude, so a later docs/ tree is read the
same way). Shell examples run with ``bash -e -o pipefail`` and ``OTGEO_URL`` pointing at the
live server; Python examples with this interpreter, each as its own process forked from one
that has imported what the examples before it imported (tests/forked_python.py: its own cwd,
argv, environment, streams and exit status, without paying for numpy's, scipy's and the
solvers' imports again); JSON examples are domain bodies, each line POSTed to
``/v1/domains``. Each runs in a scratch folder laid out like a checkout (links to the
repository's top-level entries, ``../shared`` beside it), so relative paths work and nothing
is written into the repository.

A block that cannot run here is listed in SKIP with the reason (and not collected); a block
made smaller to keep the suite fast is listed in SMALLER, and the document must say so; a block
that shows a server with API keys is listed in doc_examples.KEYED and runs in
tests/service/test_sdk.py, against that file's keyed server (``OTGEO_API_KEYS`` set, the key
in ``OTGEO_API_KEY``), which refuses a request without it: a second server here would cost
its start-up."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import httpx
import pytest
from doc_examples import KEYED, ROOT, Example, checkout, documents, environment, extract, matching
from forked_python import PythonRunner
from liveserver import API

# substring of the block -> why it does not run in this test
SKIP = {
    "make serve": "installs into .venv and runs a server until stopped, and `make test` runs "
                  "the whole suite (this test among it)",
    "up --build --scale worker=4": "pulls from Docker Hub, builds and runs containers for "
                                   "minutes: tests/service/test_docker.py runs the same "
                                   "compose file",
    "build-images.sh otgeo:latest": "needs a Docker engine and minutes: "
                                    "tests/service/test_docker.py runs these commands (with "
                                    "the tag otgeo:test and its own project name)",
    "build-images.sh otgeo:test": "the commands tests/service/test_docker.py runs "
                                  "(tests/service/dockerstack.py), with placeholders",
    "otgeo worker ": "a scaled-out deployment (Redis, PostgreSQL, shared storage, servers "
                     "that run until stopped): tests/service/test_scale.py runs the same "
                     "API/worker split",
}
# substring of the block -> (text, replacement run instead, what the document says about it)
SMALLER: dict[str, tuple[str, str, str]] = {}
# substring of the block -> patterns its standard output must match (what the text claims)
OUTPUT = {
    "quickstart.py": [r"^2930 vertices, genus 0$", r"^W2\^2 = \d", r"converged=True"],
    "propagate_histograms": [r"^\[0\.2\d*\s", r"\s0\.8\d*\s*\]$"],
    "soft_map(lion, cat": [r"^\(5000,\)$", r"^1\.0\d*$|^0\.99\d*$"],
}
TIMEOUT = 300


def examples() -> list[Example]:
    return [e for doc in documents() for e in extract(doc)]


RUNNABLE = [e for e in examples() if e.runnable]
RUN = [e for e in RUNNABLE if matching(SKIP, e) is None and matching(KEYED, e) is None]


def test_every_code_block_is_an_example_or_named():
    """No block escapes: each has a language, and each entry of SKIP/KEYED matches a block,
    each of SMALLER/OUTPUT a block that runs here (no stale entries)."""
    blocks = examples()
    assert blocks, documents()
    for e in blocks:
        assert e.language, f"{e.document.name}:{e.line}: a code block without a language"
    for table, among in ((SKIP, RUNNABLE), (KEYED, RUNNABLE), (SMALLER, RUN), (OUTPUT, RUN)):
        for key in table:  # no stale entry (a key may name the same example in two pages)
            assert any(matching({key: 0}, e) is not None for e in among), \
                (key, "matches no example" + (" run here" if among is RUN else ""))
    for e in RUNNABLE:
        if e.include is not None:  # a Markdown block standing for a file holds its text
            assert e.code == e.include.read_text(), f"{e.id}: differs from {e.include}"
    for key, (_, new, says) in SMALLER.items():
        for doc in {e.document for e in RUNNABLE if key in e.code}:
            text = " ".join(doc.read_text().split())  # across line breaks
            assert says in text, f"{doc.name} must say that the suite runs {new}"


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("readme")
    api = API({"OTGEO_DATA_DIR": str(tmp / "data"), "OTGEO_WORKERS": "1",
               "OTGEO_REAPER_INTERVAL": "1"}, tmp)
    try:
        api.wait_healthy(60)
        yield api
    finally:
        api.stop(timeout=5)


@pytest.fixture
def work(tmp_path) -> Path:
    return checkout(tmp_path)


# what differs between the examples' environments (set after the Python runner started;
# nothing it imports reads them at import time)
LATE_ENV = ("OTGEO_URL", "PYTEST_CURRENT_TEST")


@pytest.fixture(scope="module")
def python_runner(tmp_path_factory):
    """The Python examples' runner: one interpreter the examples are forked from."""
    with PythonRunner(environment(), tmp_path_factory.mktemp("python"),
                      late_env=LATE_ENV) as runner:
        yield runner


def run_example(e: Example, cwd: Path, env: dict, live, python: PythonRunner) -> str:
    code = e.code
    change = matching(SMALLER, e)
    if change is not None:
        old, new, _ = change
        assert old in code
        code = code.replace(old, new)
    if e.language == "json":
        for line in filter(None, map(str.strip, code.splitlines())):
            spec = json.loads(line)
            assert "kind" in spec, f"{e.id}: a JSON example that is not a domain: {line}"
            r = httpx.post(f"{live.url}/v1/domains", json=spec, timeout=60)
            assert r.status_code == 201, (line, r.text)
        return ""
    if e.include is not None and change is None:
        out = python.run([str(cwd / e.include.relative_to(ROOT))], cwd, env, TIMEOUT)
    elif e.language == "python":
        out = python.run(["-c", code], cwd, env, TIMEOUT)
    else:
        out = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", code], cwd=cwd, env=env,
                             capture_output=True, text=True, timeout=TIMEOUT)
    assert out.returncode == 0, f"{e.id} exited {out.returncode}:\n{out.stdout[-2000:]}\n" \
                                f"{out.stderr[-3000:]}\n{live.log()}"
    return out.stdout


@pytest.mark.parametrize("example", RUN, ids=[e.id for e in RUN])
def test_example_runs(example, live, python_runner, work):
    stdout = run_example(example, work, environment(live.url), live, python_runner)
    for pattern in matching(OUTPUT, example) or []:
        assert re.search(pattern, stdout, re.M), (example.id, pattern, stdout)
