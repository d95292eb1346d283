"""docker/: no Docker engine runs here, so check what the containers would run.

The Dockerfile's and compose services' commands are run (with ``--help``) from this checkout's
installation, the compose environment must name only real settings and parse into them, and the
wiring (queue on the redis service, job table on the postgres service, one shared data volume
for API and workers) is checked from the file itself.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import tomllib
from pathlib import Path
from urllib.parse import urlparse

import pytest
import yaml
from liveserver import otgeo_command

from service.settings import Settings

ROOT = Path(__file__).resolve().parents[2]
DOCKER = ROOT / "docker"
OTGEO_SERVICES = ("api", "worker")


@pytest.fixture(scope="module")
def compose() -> dict:
    return yaml.safe_load((DOCKER / "compose.yaml").read_text())


def dockerfile_instructions() -> list[tuple[str, str]]:
    text = (DOCKER / "Dockerfile").read_text().replace("\\\n", " ")
    out = []
    for line in text.splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            word, _, rest = line.partition(" ")
            out.append((word.upper(), rest.strip()))
    return out


def interpolate(value: str, env: dict[str, str] | None = None) -> str:
    """Compose's ``${VAR:-default}`` substitution (with an empty host environment by default)."""
    env = env or {}
    return re.sub(r"\$\{(\w+)(?::-([^}]*))?\}",
                  lambda m: env.get(m.group(1)) or (m.group(2) or ""), value)


def otgeo_argv(command: list[str]) -> list[str]:
    """The container's argv, run with this checkout's installation of the console script."""
    assert command[0] == "otgeo"
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["otgeo"] == "service.cli:main"  # so `python -m service.cli` is equivalent
    return otgeo_command() + command[1:]


def run_help(command: list[str], env: dict[str, str]) -> subprocess.CompletedProcess:
    full_env = {**os.environ, **env}
    return subprocess.run(otgeo_argv(command) + ["--help"], env=full_env, cwd=ROOT,
                          capture_output=True, text=True, timeout=60)


def test_dockerfile_is_slim_non_root_and_installs_the_package():
    ins = dockerfile_instructions()
    froms = [rest for word, rest in ins if word == "FROM"]
    assert froms == ["python:3.11-slim"]
    users = [rest for word, rest in ins if word == "USER"]
    assert users and users[-1] not in ("root", "0", "0:0")
    # the user is created in a RUN before USER, and owns the data directory
    runs = " ".join(rest for word, rest in ins if word == "RUN")
    assert "useradd" in runs and users[-1] in runs and f"chown {users[-1]}" in runs
    # every source the package is built from is copied, and exists in the repository
    copied = [p for rest in (r for w, r in ins if w == "COPY") for p in shlex.split(rest)[:-1]]
    for src in copied:
        assert (ROOT / src).exists(), src
    packages = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"][
        "packages"]["find"]["include"]
    for pattern in packages:
        assert pattern.rstrip("*") in copied
    assert "pyproject.toml" in copied
    assert re.search(r"pip install \.(\s|$)", runs)
    # the build context (repository root) lets the copied files through the ignore file
    ignore = (DOCKER / "Dockerfile.dockerignore").read_text().split()
    for src in copied:
        assert f"!{src}" in ignore, src
    env = dict(re.findall(r"(\w+)=(\S+)", " ".join(r for w, r in ins if w == "ENV")))
    assert set(k for k in env if k.startswith("OTGEO_")) <= settings_env_names()


def settings_env_names() -> set[str]:
    prefix = Settings.model_config["env_prefix"]
    return {prefix + name.upper() for name in Settings.model_fields}


def test_dockerfile_cmd_runs():
    ins = dockerfile_instructions()
    cmd = json.loads([rest for word, rest in ins if word == "CMD"][-1])
    assert cmd == ["otgeo", "serve", "--host", "0.0.0.0"]
    proc = run_help(cmd, {})
    assert proc.returncode == 0, proc.stderr
    assert "--host" in proc.stdout and "--port" in proc.stdout


def test_compose_has_the_four_services_wired_together(compose):
    services = compose["services"]
    assert set(services) >= {"api", "worker", "redis", "postgres"}
    for name in OTGEO_SERVICES:
        svc = services[name]
        build = svc["build"]
        assert (DOCKER / build["context"] / build["dockerfile"]).resolve() == DOCKER / "Dockerfile"
        assert set(svc["depends_on"]) == {"redis", "postgres"}
    assert services["api"]["image"] == services["worker"]["image"]
    assert services["api"]["command"][:2] == ["otgeo", "serve"]
    assert services["worker"]["command"][:2] == ["otgeo", "worker"]
    # the published port is the one the API listens on, on all interfaces
    cmd = services["api"]["command"]
    port = cmd[cmd.index("--port") + 1] if "--port" in cmd else "8000"
    assert cmd[cmd.index("--host") + 1] == "0.0.0.0"
    assert any(str(p).split(":")[-1] == port for p in services["api"]["ports"])
    assert port in " ".join(services["api"]["healthcheck"]["test"])

    for name in OTGEO_SERVICES:
        env = {k: interpolate(str(v)) for k, v in services[name]["environment"].items()}
        settings = Settings(**{k[len("OTGEO_"):].lower(): v for k, v in env.items()})
        assert settings.queue == "redis"
        redis = urlparse(settings.redis_url)
        assert redis.scheme == "redis" and redis.hostname == "redis"
        db = urlparse(settings.database_url)
        pg = {k: interpolate(str(v)) for k, v in services["postgres"]["environment"].items()}
        assert db.scheme.startswith("postgresql") and db.hostname == "postgres"
        assert (db.username, db.password, db.path.lstrip("/")) == (
            pg["POSTGRES_USER"], pg["POSTGRES_PASSWORD"], pg["POSTGRES_DB"])
        # shared storage: the same named volume at the data directory in API and workers
        mounts = dict(v.split(":")[:2][::-1] for v in services[name]["volumes"])
        assert str(settings.data_dir) in mounts
        assert mounts[str(settings.data_dir)] in compose["volumes"]
    api_env, worker_env = (services[n]["environment"] for n in OTGEO_SERVICES)
    for key in ("OTGEO_QUEUE", "OTGEO_REDIS_URL", "OTGEO_DATABASE_URL", "OTGEO_DATA_DIR"):
        assert api_env[key] == worker_env[key]
    assert int(api_env.get("OTGEO_WORKERS", "1")) == 0  # the API container runs no jobs


@pytest.mark.parametrize("service", OTGEO_SERVICES)
def test_compose_env_names_are_settings(compose, service):
    env = compose["services"][service]["environment"]
    unknown = {k for k in env if k.startswith("OTGEO_")} - settings_env_names()
    assert not unknown, f"not fields of service.settings.Settings: {sorted(unknown)}"
    assert all(k.startswith("OTGEO_") for k in env)


@pytest.mark.parametrize("service", OTGEO_SERVICES)
def test_compose_commands_run(compose, service, tmp_path):
    svc = compose["services"][service]
    env = {k: interpolate(str(v)) for k, v in svc["environment"].items()}
    env["OTGEO_DATA_DIR"] = str(tmp_path)  # /data does not exist outside the container
    proc = run_help(svc["command"], env)
    assert proc.returncode == 0, proc.stderr
    assert "usage: otgeo" in proc.stdout
