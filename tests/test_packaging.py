"""The library installs without the service (issue 44, item 9): ``pip install otgeo`` is the
library; ``otgeo[service]`` adds the web stack. The built wheel itself is checked in a fresh
virtualenv outside the checkout by ``.ci/check_wheel.py`` (a step of .ci/run)."""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from importlib.metadata import packages_distributions
from pathlib import Path

from service.cli import SERVICE_PACKAGES

ROOT = Path(__file__).resolve().parents[1]
PROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]


def _distribution(requirement: str) -> str:
    name = re.match(r"[A-Za-z0-9._-]+", requirement).group(0)
    return re.sub(r"[-_.]+", "-", name).lower()


def _modules_of(requirements: list[str]) -> dict[str, set[str]]:
    """Top-level modules each required distribution installs (in this environment)."""
    installed: dict[str, set[str]] = {}
    for module, dists in packages_distributions().items():
        for dist in dists:
            installed.setdefault(_distribution(dist), set()).add(module)
    return {_distribution(r): installed.get(_distribution(r), set()) for r in requirements}


def test_service_packages_are_an_extra_not_core_dependencies():
    service = _modules_of(PROJECT["optional-dependencies"]["service"])
    assert all(service.values()), f"service extra not installed here: {service}"
    unnamed = {d: m - SERVICE_PACKAGES for d, m in service.items() if m - SERVICE_PACKAGES}
    assert not unnamed, f"service.cli.SERVICE_PACKAGES misses {unnamed}"
    core = _modules_of(PROJECT["dependencies"])
    in_core = {d: m & SERVICE_PACKAGES for d, m in core.items() if m & SERVICE_PACKAGES}
    assert not in_core, f"service packages among the core dependencies: {in_core}"


def run_without(blocked, code: str, timeout: float) -> subprocess.CompletedProcess:
    """``code`` in a new interpreter in which the modules ``blocked`` cannot be imported
    (``sys.modules[name] = None``: ``import name`` raises ModuleNotFoundError)."""
    preamble = f"import sys\nfor name in {sorted(blocked)!r}:\n    sys.modules[name] = None\n"
    return subprocess.run([sys.executable, "-c", preamble + code], capture_output=True,
                          text=True, cwd=ROOT, timeout=timeout)


# Every module under solvers/ imported with the service's packages made unimportable
IMPORT_ALL_SOLVERS = """
import importlib, pkgutil
import solvers
names = [m.name for m in pkgutil.walk_packages(solvers.__path__, "solvers.")]
for name in names:
    importlib.import_module(name)
print(len(names))
"""


def test_every_solvers_module_imports_without_the_service_packages():
    done = run_without(SERVICE_PACKAGES, IMPORT_ALL_SOLVERS, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert int(done.stdout) > 20  # the walk found the library's modules


def test_otgeo_serve_without_the_service_extra_says_what_to_install():
    done = run_without(SERVICE_PACKAGES, "from service.cli import main\n"
                       "main(['serve', '--port', '1'])\n", timeout=120)
    assert done.returncode == 2, done.stderr[-3000:]
    assert "pip install 'otgeo[service]'" in done.stderr
    assert "Traceback" not in done.stderr


WEB_PACKAGES = ("fastapi", "fastapi_offline", "starlette", "uvicorn", "multipart",
                "python_multipart")
# What a worker process imports before it takes a job (service.cli.run_worker), and every
# operation it may run: none of it is web code, so a worker does not pay for FastAPI's import
IMPORT_WORKER = """
from service.jobs.consumer import Consumer
from service.runtime import Runtime
from service import warm
from service.operations import build_registry
print(len(build_registry()))
"""


def test_a_worker_imports_no_web_framework():
    done = run_without(WEB_PACKAGES, IMPORT_WORKER, timeout=120)
    assert done.returncode == 0, done.stderr[-3000:]
    assert int(done.stdout) > 10  # the registry's operations were all imported
