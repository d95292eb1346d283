"""docker/: the image, the compose stack and the local test images.

Static checks (always): the Dockerfile's and compose services' commands are run (with
``--help``) from this checkout's installation, the compose environment names only real
settings and parses into them, and the wiring (queue on the password-protected redis service,
job table on the postgres service, one shared data volume for API and workers) is read from
the files.

The real thing (``@pytest.mark.docker``, selected by default): the local Debian base, Redis,
PostgreSQL and otgeo images are built (docker/local/build-images.sh), the stack runs with
docker-compose (api, two workers, redis, postgres on the project's private network; the test
override docker/compose.test.yaml), a real mesh is uploaded and a barycenter, a distance and a
W1 flow run through the API's port published on 127.0.0.1; a worker container is killed
mid-job and the other one finishes it; the API container is recreated and the jobs and results
are still there; everything is removed at the end, also on failure. It skips only when the
stack cannot run here, naming every missing part (a running engine, compose, the base image or
debootstrap); with ``OTGEO_REQUIRE_DOCKER=1`` (set by .ci/run once dockerd answers) that is a
failure instead.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import time
import tomllib
from pathlib import Path
from urllib.parse import urlparse

import numpy as np
import pytest
import yaml
from liveserver import otgeo_command

from service.settings import Settings

ROOT = Path(__file__).resolve().parents[2]
DOCKER = ROOT / "docker"
OTGEO_SERVICES = ("api", "worker")
# what a user would export; compose refuses to start without both (`${VAR:?...}`)
SAMPLE_ENV = {"REDIS_PASSWORD": "redis-secret", "POSTGRES_PASSWORD": "pg-secret"}


@pytest.fixture(scope="module")
def compose() -> dict:
    return yaml.safe_load((DOCKER / "compose.yaml").read_text())


@pytest.fixture(scope="module")
def compose_test() -> dict:
    return yaml.safe_load((DOCKER / "compose.test.yaml").read_text())


def dockerfile_instructions(path: Path = DOCKER / "Dockerfile") -> list[tuple[str, str]]:
    text = path.read_text().replace("\\\n", " ")
    out = []
    for line in text.splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            word, _, rest = line.partition(" ")
            out.append((word.upper(), rest.strip()))
    return out


def stages(ins: list[tuple[str, str]]) -> dict[str, list[tuple[str, str]]]:
    """Instructions per build stage (``FROM x AS name``), in order."""
    out: dict[str, list[tuple[str, str]]] = {}
    current = None
    for word, rest in ins:
        if word == "FROM":
            parts = rest.split()
            current = parts[2] if len(parts) == 3 and parts[1].upper() == "AS" else rest
            out[current] = [(word, parts[0])]
        elif current is not None:
            out[current].append((word, rest))
    return out


def interpolate(value: str, env: dict[str, str] | None = None) -> str:
    """Compose's ``${VAR:-default}`` / ``${VAR:?error}`` substitution."""
    env = SAMPLE_ENV if env is None else env

    def sub(m):
        name, op, arg = m.group(1), m.group(2), m.group(3) or ""
        if env.get(name):
            return env[name]
        if op == ":?":
            raise KeyError(f"{name} is required: {arg}")
        return arg

    return re.sub(r"\$\{(\w+)(?:(:-|:\?)([^}]*))?\}", sub, value)


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


def test_dockerfile_is_multi_stage_slim_non_root_and_installs_the_package():
    ins = dockerfile_instructions()
    # the base is a build argument defaulting to the official slim Python image
    args = dict(rest.split("=", 1) for word, rest in ins if word == "ARG" and "=" in rest)
    assert args["BASE_IMAGE"] == "python:3.11-slim"
    st = stages(ins)
    assert st["python"][0] == ("FROM", "${BASE_IMAGE}")
    assert st["build"][0] == ("FROM", "python") and st["runtime"][0] == ("FROM", "python")
    assert list(st)[-1] == "runtime"  # the image is the last stage
    runtime = st["runtime"]
    runs = {name: " ".join(r for w, r in body if w == "RUN") for name, body in st.items()}
    # compilers only in the build stage; the runtime stage takes the virtualenv from it
    assert re.search(r"\bgcc\b", runs["build"])
    for name in ("python", "runtime"):
        assert not re.search(r"\b(gcc|g\+\+|build-essential|python3-dev)\b", runs[name])
    assert ("COPY", "--from=build /opt/venv /opt/venv") in runtime
    users = [rest for word, rest in runtime if word == "USER"]
    assert users and users[-1] not in ("root", "0", "0:0")
    # the user is created in a RUN before USER, and owns the data directory
    assert "useradd" in runs["runtime"] and users[-1] in runs["runtime"]
    assert f"chown {users[-1]}" in runs["runtime"]
    # every source the package is built from is copied, and exists in the repository
    copied = [p for rest in (r for w, r in ins if w == "COPY" and not r.startswith("--from"))
              for p in shlex.split(rest)[:-1]]
    for src in copied:
        assert (ROOT / src).exists(), src
    packages = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"][
        "packages"]["find"]["include"]
    for pattern in packages:
        assert pattern.rstrip("*") in copied
    assert "pyproject.toml" in copied
    # the package from the tree (no dependencies: installed in the layer before, from the list)
    assert re.search(r"pip install -r /tmp/requirements.txt", runs["build"])
    assert re.search(r"pip install [^&]*--no-deps [^&]*\s\.(\s|$)", runs["build"])
    assert "pip check" in runs["runtime"]
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
        assert set(svc["depends_on"]) >= {"redis", "postgres"}
    # workers start after the API container, which seeds the shared numba-cache volume
    assert "api" in services["worker"]["depends_on"]
    assert services["api"]["image"] == services["worker"]["image"]
    assert services["api"]["command"][:2] == ["otgeo", "serve"]
    assert services["worker"]["command"][:2] == ["otgeo", "worker"]
    # the published port is the one the API listens on, on all interfaces
    cmd = services["api"]["command"]
    port = cmd[cmd.index("--port") + 1] if "--port" in cmd else "8000"
    assert cmd[cmd.index("--host") + 1] == "0.0.0.0"
    assert any(str(p).split(":")[-1] == port for p in services["api"]["ports"])
    assert port in " ".join(services["api"]["healthcheck"]["test"])

    # redis-server gets the password from its environment (see the refusal test below)
    script = services["redis"]["command"][-1]
    assert '--requirepass "$$REDIS_PASSWORD"' in script
    redis_password = interpolate(services["redis"]["environment"]["REDIS_PASSWORD"])
    assert redis_password == SAMPLE_ENV["REDIS_PASSWORD"]
    for name in OTGEO_SERVICES:
        env = {k: interpolate(str(v)) for k, v in services[name]["environment"].items()}
        settings = Settings(**{k[len("OTGEO_"):].lower(): v for k, v in env.items()})
        assert settings.queue == "redis"
        redis = urlparse(settings.redis_url)
        assert redis.scheme == "redis" and redis.hostname == "redis"
        assert redis.password == redis_password
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


def compose_values(svc: dict) -> list[str]:
    return [str(v) for v in [*(svc.get("environment") or {}).values(), *svc.get("command", [])]]


def test_compose_needs_passwords_to_start_not_to_stop(compose, tmp_path):
    """No default password anywhere; compose itself does not insist (so `down -v` runs
    without them), the servers do: redis's command and postgres's entrypoint exit."""
    services = compose["services"]
    for var in ("REDIS_PASSWORD", "POSTGRES_PASSWORD"):
        without = {k: x for k, x in SAMPLE_ENV.items() if k != var}
        for svc in services.values():
            for v in compose_values(svc):
                if var in v:
                    assert SAMPLE_ENV[var] not in interpolate(v, without)
    fake = tmp_path / "bin"
    fake.mkdir()
    (fake / "redis-server").write_text('#!/bin/sh\necho "redis-server $*"\n')
    (fake / "redis-server").chmod(0o755)
    script = services["redis"]["command"][-1].replace("$$", "$")  # compose's escape
    assert services["redis"]["command"][:2] == ["sh", "-c"]
    env = {"PATH": f"{fake}:/usr/bin:/bin"}
    refused = subprocess.run(["sh", "-c", script], env={**env, "REDIS_PASSWORD": ""},
                             capture_output=True, text=True)
    assert refused.returncode != 0 and "REDIS_PASSWORD" in refused.stderr
    ok = subprocess.run(["sh", "-c", script], env={**env, "REDIS_PASSWORD": "s3cret"},
                        capture_output=True, text=True)
    assert ok.returncode == 0 and "--requirepass s3cret" in ok.stdout, ok
    # the local postgres image's entrypoint (the official image refuses likewise)
    pg = subprocess.run(["sh", str(DOCKER / "local" / "postgres-entrypoint.sh"), "postgres"],
                        env={**env, "POSTGRES_PASSWORD": "", "PGDATA": str(tmp_path / "pg")},
                        capture_output=True, text=True)
    assert pg.returncode != 0 and "POSTGRES_PASSWORD" in pg.stderr
    assert not (tmp_path / "pg").exists()


def test_compose_checks_health_and_restarts(compose):
    services = compose["services"]
    for name in ("api", "redis", "postgres"):
        test = services[name]["healthcheck"]["test"]
        assert test[0] in ("CMD", "CMD-SHELL") and len(test) > 1
    assert "/healthz" in " ".join(services["api"]["healthcheck"]["test"])
    assert "redis-cli" in " ".join(services["redis"]["healthcheck"]["test"])
    # redis-cli in the health check authenticates through REDISCLI_AUTH
    assert interpolate(services["redis"]["environment"]["REDISCLI_AUTH"]) == \
        SAMPLE_ENV["REDIS_PASSWORD"]
    assert "pg_isready" in services["postgres"]["healthcheck"]["test"]
    # official images by default, local ones (docker/local) through the environment
    assert interpolate(services["redis"]["image"], {}) == "redis:7-alpine"
    assert interpolate(services["postgres"]["image"], {}) == "postgres:16-alpine"
    assert interpolate(services["redis"]["image"], {"OTGEO_REDIS_IMAGE": "otgeo-redis:local"}) \
        == "otgeo-redis:local"
    assert interpolate(services["postgres"]["image"], {
        "OTGEO_POSTGRES_IMAGE": "otgeo-postgres:local"}) == "otgeo-postgres:local"
    for name, svc in services.items():
        assert svc["restart"] in ("unless-stopped", "always", "on-failure"), name
        # everyone on the internal network; only the API also on the one with a way out
        assert svc["networks"] == (["backend", "edge"] if name == "api" else ["backend"]), name
    assert compose["networks"]["backend"]["internal"] is True
    assert not (compose["networks"]["edge"] or {}).get("internal")
    # only the API publishes a port
    assert [n for n, svc in services.items() if svc.get("ports")] == ["api"]


def test_compose_test_override_only_sets_clocks(compose, compose_test):
    services = compose_test["services"]
    assert set(services) == set(OTGEO_SERVICES)
    for name in OTGEO_SERVICES:
        env = services[name]["environment"]
        assert set(env) <= settings_env_names()
        s = Settings(**{k[len("OTGEO_"):].lower(): v for k, v in env.items()})
        # a killed worker's job is re-queued within seconds; heartbeats well inside that
        assert s.stale_after <= 10 and s.heartbeat_interval * 4 <= s.stale_after
        assert s.reaper_interval <= s.stale_after / 2
    for name in ("redis", "postgres"):
        ins = dockerfile_instructions(DOCKER / "local" / f"{name}.Dockerfile")
        assert ins[0] == ("ARG", "BASE_IMAGE=otgeo-base:bookworm")
        assert ins[1] == ("FROM", "${BASE_IMAGE}")
        users = [rest for word, rest in ins if word == "USER"]
        assert users and users[-1] == name


def test_compose_builds_on_any_base_and_shares_the_numba_cache(compose):
    env = dict(re.findall(r"(\w+)=(\S+)", " ".join(
        r for w, r in dockerfile_instructions() if w == "ENV")))
    cache = env["NUMBA_CACHE_DIR"]
    for name in OTGEO_SERVICES:
        svc = compose["services"][name]
        base = svc["build"]["args"]["BASE_IMAGE"]
        assert interpolate(base, {}) == "python:3.11-slim"  # the Dockerfile's default
        assert interpolate(base, {"OTGEO_BASE_IMAGE": "otgeo-base:bookworm"}) == \
            "otgeo-base:bookworm"
        mounts = dict(v.split(":")[:2][::-1] for v in svc["volumes"])
        assert mounts[cache] == "numba-cache" and "numba-cache" in compose["volumes"]
    # the image compiles the kernels into that directory, as the user that runs the jobs
    runtime = stages(dockerfile_instructions())["runtime"]
    warm = [i for i, (w, r) in enumerate(runtime) if w == "RUN" and "warm" in r]
    assert len(warm) == 1
    users = [r for w, r in runtime[:warm[0]] if w == "USER"]
    assert users[-1] == "otgeo"
    assert (ROOT / "docker" / "warm_numba.py").exists()


def fake_tools(tmp_path, tools: dict[str, str]) -> dict:
    """Executables named after ``tools`` that log their argv to ``calls`` and run the
    given shell snippet; returns the environment that finds them first."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir(exist_ok=True)
    for name, body in tools.items():
        (bin_dir / name).write_text(f'#!/bin/sh\necho "{name} $*" >> {tmp_path}/calls\n{body}\n')
        (bin_dir / name).chmod(0o755)
    return {"PATH": f"{bin_dir}:/usr/bin:/bin", "HOME": str(tmp_path)}


@pytest.mark.parametrize("plugin", [True, False], ids=["plugin", "docker-compose"])
def test_compose_sh_finds_the_compose_invocation(tmp_path, plugin):
    docker = ('case "$1" in buildx) exit 0;; compose) ' + ("exit 0" if plugin else "exit 1")
              + ';; esac')
    env = fake_tools(tmp_path, {"docker": docker, "docker-compose": "exit 0"})
    out = subprocess.run([str(DOCKER / "compose.sh"), "-f", "docker/compose.yaml", "down", "-v"],
                         env=env, cwd=ROOT, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    calls = (tmp_path / "calls").read_text().splitlines()
    expected = ("docker compose -f docker/compose.yaml down -v" if plugin
                else "docker-compose -f docker/compose.yaml down -v")
    assert calls[-1] == expected, calls


def test_docker_client_sh_skips_a_client_that_cannot_build(tmp_path):
    script = str(DOCKER / "local" / "docker-client.sh")
    old = fake_tools(tmp_path, {"docker": 'case "$1" in buildx) exit 1;; version) '
                                          'echo 20.10.24;; esac'})
    assert subprocess.run([script], env=old, capture_output=True, text=True).stdout.strip() \
        == str(tmp_path / "bin" / "docker")  # BuildKit built in
    new = fake_tools(tmp_path, {"docker": 'case "$1" in buildx) exit 1;; version) '
                                          'echo 28.2.2;; esac'})
    found = subprocess.run([script], env=new, capture_output=True, text=True)
    assert found.stdout.strip() != str(tmp_path / "bin" / "docker")  # no buildx: skipped
    assert subprocess.run([script], env={**new, "DOCKER": "/x/docker"}, capture_output=True,
                          text=True).stdout.strip() == "/x/docker"


DAEMON_DOWN = ('[ "$1" = info ] && { echo "Cannot connect to the Docker daemon at '
               'unix:///var/run/docker.sock. Is the docker daemon running?" >&2; exit 1; }')


@pytest.mark.parametrize("engine,compose_ok", [(False, True), (True, False), (False, False)],
                         ids=["daemon-down", "no-compose", "both"])
def test_skip_reason_names_what_is_missing(tmp_path, monkeypatch, engine, compose_ok):
    """The docker tests' skip message names the missing part: a stopped daemon is not
    reported as a missing compose, nor the other way round; both when both are missing."""
    from dockerstack import engine_problem

    docker = ('case "$1" in buildx) exit 0;; compose) ' + ("exit 0" if compose_ok else
                                                            "exit 1") + ';; esac\n'
              + ("" if engine else DAEMON_DOWN) + "\nexit 0")
    fake_tools(tmp_path, {"docker": docker, "debootstrap": "exit 0"})
    only = tmp_path / "only"  # the fakes and bash alone: no real docker-compose or docker
    only.mkdir()
    (only / "bash").symlink_to(shutil.which("bash"))
    monkeypatch.setenv("PATH", f"{tmp_path / 'bin'}:{only}")
    monkeypatch.delenv("DOCKER", raising=False)
    problem = engine_problem()
    assert problem is not None
    assert ("Docker engine" in problem) == (not engine), problem
    assert ("Is the docker daemon running?" in problem) == (not engine), problem
    assert ("compose" in problem) == (not compose_ok), problem


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


# -- the real thing: images built, stack up, jobs through the published port -------------------
# W1 flow by ADMM on cow.obj (2,903 vertices), never converging early (tol 1e-12): 0.4 ms per
# iteration in a container on a quiet machine, ~2 ms at load 16 (measured), so LONG_ITER runs
# 3-16 s: the kill lands mid-job and the rerun on the other worker stays short.
LONG_ITER = 8_000
SPOT_PAIR = ({"vertex": 0, "radius": 0.15}, {"vertex": 900, "radius": 0.15})


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    from dockerstack import ComposeStack, build_images, engine_problem, image_size

    problem = engine_problem()
    if problem is not None:
        if os.environ.get("OTGEO_REQUIRE_DOCKER") == "1":
            pytest.fail(f"OTGEO_REQUIRE_DOCKER=1 but no container can run: {problem}")
        pytest.skip(f"the compose stack cannot run here: {problem}")
    logs = tmp_path_factory.mktemp("docker")
    build_seconds = build_images(logs / "build.log")
    s = ComposeStack(workers=2)
    s.jobs = {}  # job id -> its result, for the API-restart check
    try:
        s.up_seconds = s.up()
        print(f"\nimages built/checked in {build_seconds:.1f} s; image {image_size()} bytes; "
              f"stack healthy in {s.up_seconds:.1f} s (project {s.project}, {s.url})")
        yield s
    except BaseException:
        print(s.logs(120))
        raise
    finally:
        s.down()


def upload(stack, meshes_dir, name: str) -> str:
    r = stack.post("/v1/domains", files={"file": (name, (meshes_dir / name).read_bytes())})
    assert r.status_code in (200, 201), r.text
    return r.json()["id"]


def job(stack, job_id: str) -> dict:
    r = stack.get(f"/v1/jobs/{job_id}")
    assert r.status_code == 200, r.text
    return r.json()


def wait_job(stack, job_id: str, predicate, timeout: float, what: str) -> dict:
    deadline = time.monotonic() + timeout
    while True:
        j = job(stack, job_id)
        if predicate(j):
            return j
        assert time.monotonic() < deadline, f"timed out waiting for {what}: {j}\n{stack.logs()}"
        time.sleep(0.1)


def run_job(stack, path: str, body: dict) -> tuple[dict, dict]:
    r = stack.post(f"{path}?wait=60", json=body)
    assert r.status_code in (200, 202), r.text
    j = wait_job(stack, r.json()["id"], lambda j: j["state"] not in ("queued", "running"), 120,
                 f"{path} to finish")
    assert j["state"] == "succeeded", (j, stack.logs())
    res = stack.get(f"/v1/jobs/{j['id']}/result")
    assert res.status_code == 200, res.text
    stack.jobs[j["id"]] = res.json()
    return j, res.json()


def worker_containers(stack) -> dict[str, str]:
    """hostname (what a job's ``worker`` column starts with) -> container id."""
    return {stack.hostname(c): c for c in stack.containers("worker")}


@pytest.mark.docker
def test_stack_is_healthy_private_and_non_root(stack):
    assert stack.health("api") == ["healthy"]
    assert stack.health("redis") == ["healthy"] and stack.health("postgres") == ["healthy"]
    workers = stack.containers("worker")
    assert len(workers) == 2
    assert all(stack.inspect(c)["State"]["Running"] for c in workers)
    assert stack.get("/healthz").json()["queue"] == "redis"
    # Redis refuses a client without the password; the password works
    anon = stack.exec("redis", "sh", "-c", "unset REDISCLI_AUTH; redis-cli ping", check=False)
    assert "NOAUTH" in anon.stdout + anon.stderr and "PONG" not in anon.stdout
    assert stack.exec("redis", "redis-cli", "ping").stdout.strip() == "PONG"
    # only the API's port is published, on 127.0.0.1
    ports = stack.inspect(stack.containers("api")[0])["NetworkSettings"]["Ports"]
    assert ports["8000/tcp"] == [{"HostIp": "127.0.0.1", "HostPort": str(stack.port)}]
    for name in ("redis", "postgres", "worker"):
        for c in stack.containers(name):
            assert not any(stack.inspect(c)["NetworkSettings"]["Ports"].values()), name
    # the otgeo processes run as the image's non-root user
    assert stack.exec("api", "id", "-u").stdout.strip() == "10001"
    # workers, redis and postgres only on the internal network (no route out of the stack)
    backend, edge = f"{stack.project}_backend", f"{stack.project}_edge"
    nets = stack.inspect(stack.containers("api")[0])["NetworkSettings"]["Networks"]
    assert sorted(nets) == [backend, edge]
    for name in ("worker", "redis", "postgres"):
        for c in stack.containers(name):
            assert list(stack.inspect(c)["NetworkSettings"]["Networks"]) == [backend], name
    from dockerstack import run

    internal = run([stack.docker, "network", "inspect", "-f", "{{.Internal}}", backend, edge])
    assert internal.stdout.split() == ["true", "false"]


@pytest.mark.docker
def test_barycenter_distance_and_flow_through_the_published_port(stack, meshes_dir):
    spot = upload(stack, meshes_dir, "spot.obj")
    domain = stack.get(f"/v1/domains/{spot}").json()
    path = f"/v1/domains/{spot}"
    _, bary = run_job(stack, f"{path}/barycenters",
                      {"distributions": list(SPOT_PAIR), "weights": [0.5, 0.5]})
    masses = np.asarray(bary["arrays"]["masses"])
    assert masses.shape == (2930,) and masses.min() >= 0
    assert abs(masses.sum() - 1) < 1e-6
    _, dist = run_job(stack, f"{path}/distances", {"mu0": SPOT_PAIR[0], "mu1": SPOT_PAIR[1]})
    assert np.isfinite(dist["values"]["value"]) and dist["values"]["value"] > 0
    _, same = run_job(stack, f"{path}/distances",
                      {"mu0": SPOT_PAIR[0], "mu1": SPOT_PAIR[0], "debiased": True})
    assert abs(same["values"]["value"]) < 1e-3 * dist["values"]["value"]
    flow_job, flow = run_job(stack, f"{path}/flows", {"mu0": SPOT_PAIR[0], "mu1": SPOT_PAIR[1]})
    assert flow["values"]["value"] > 0
    assert np.asarray(flow["arrays"]["flow"]).shape[1] == 3
    assert len(flow["arrays"]["potential"]) == 2930
    glb = stack.get(f"/v1/jobs/{flow_job['id']}/result.glb")
    assert glb.status_code == 200 and glb.content[:4] == b"glTF"
    assert domain["id"] == spot


@pytest.mark.docker
def test_killed_worker_container_job_finishes_on_the_other(stack, meshes_dir):
    cow = upload(stack, meshes_dir, "cow.obj")
    workers = worker_containers(stack)
    assert len(workers) == 2
    r = stack.post(f"/v1/domains/{cow}/flows", json={
        "mu0": {"vertex": 0, "radius": 0.15}, "mu1": {"vertex": 1500, "radius": 0.15},
        "method": "admm", "max_iter": LONG_ITER, "tol": 1e-12})  # ADMM: a long job
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    wait_job(stack, job_id, lambda j: j["state"] == "running"
             and (j["progress"]["iteration"] or 0) >= 10, 90, "the long job to run")
    host = stack.sql(f"SELECT worker FROM jobs WHERE id = '{job_id}'").rsplit(":", 1)[0]
    victim = workers.pop(host)
    (survivor_host,) = workers
    killed_at = time.monotonic()
    from dockerstack import run

    run([stack.docker, "kill", victim])
    state = stack.inspect(victim)["State"]
    assert not state["Running"] and state["ExitCode"] == 137
    at_kill = job(stack, job_id)  # killed mid-job: still running (its heartbeat not yet stale)
    assert at_kill["state"] == "running" and at_kill["attempts"] == 1, at_kill
    assert at_kill["progress"]["iteration"] < LONG_ITER
    j = wait_job(stack, job_id, lambda j: j["attempts"] == 2 and j["state"] != "queued", 60,
                 "the reaper to re-queue the job on the surviving worker")
    requeued_after = time.monotonic() - killed_at
    j = wait_job(stack, job_id, lambda j: j["state"] not in ("queued", "running"), 180,
                 "the re-run to finish")
    # tol 1e-12 is out of reach in LONG_ITER iterations: the full re-run ends not_converged
    # (never a success) and keeps its result
    assert j["state"] == "failed" and j["error"]["code"] == "not_converged", (j, stack.logs())
    assert j["attempts"] == 2 and j["progress"]["iteration"] == LONG_ITER
    assert stack.sql(f"SELECT worker FROM jobs WHERE id = '{job_id}'").startswith(
        survivor_host + ":")
    # a SIGKILLed container counts as stopped by hand: the restart policy leaves it down
    assert not stack.inspect(victim)["State"]["Running"]
    res = stack.get(f"/v1/jobs/{job_id}/result")
    assert res.status_code == 200 and res.json()["values"]["iterations"] == LONG_ITER
    stack.jobs[job_id] = res.json()
    print(f"\nkilled {host} mid-job; attempt 2 on {survivor_host} {requeued_after:.1f} s later")


@pytest.mark.docker
def test_crashed_worker_process_is_restarted_by_the_policy(stack):
    """A worker that dies by itself (not stopped by hand) comes back: restart unless-stopped."""
    import signal

    running = [c for c in stack.containers("worker") if stack.inspect(c)["State"]["Running"]]
    assert running, "no running worker left"
    target = running[0]
    before = stack.inspect(target)
    ready_before = run_logs(stack, target).count(" ready (queue ")
    assert ready_before >= 1
    os.kill(before["State"]["Pid"], signal.SIGKILL)  # the container's own otgeo process
    deadline = time.monotonic() + 60
    while True:
        now = stack.inspect(target)
        if now["RestartCount"] > before["RestartCount"] and now["State"]["Running"]:
            break
        assert time.monotonic() < deadline, f"not restarted: {now['State']}"
        time.sleep(0.2)
    deadline = time.monotonic() + 90  # the restarted worker connects and says so in its log
    while run_logs(stack, target).count(" ready (queue ") <= ready_before:
        assert time.monotonic() < deadline, run_logs(stack, target)[-3000:]
        time.sleep(0.5)


def run_logs(stack, container: str) -> str:
    from dockerstack import run

    proc = run([stack.docker, "logs", container], check=False)
    return proc.stdout + proc.stderr


@pytest.mark.docker
def test_recreated_api_container_keeps_jobs_and_results(stack):
    assert stack.jobs, "no finished jobs to look for (earlier tests failed)"
    (old,) = stack.containers("api")
    stack.compose("up", "-d", "--no-deps", "--no-build", "--force-recreate", "api")
    (new,) = stack.containers("api")
    assert new != old
    stack.wait_healthy(("api",), timeout=120)
    for job_id, result in stack.jobs.items():
        kept = job(stack, job_id)  # as finished before: succeeded, or the capped long job
        assert kept["state"] == "succeeded" or kept["error"]["code"] == "not_converged", kept
        again = stack.get(f"/v1/jobs/{job_id}/result")
        assert again.status_code == 200 and again.json() == result
    listed = {d["id"] for d in stack.get("/v1/domains", params={"limit": 1000}).json()["domains"]}
    assert {r["domain_id"] for r in stack.jobs.values()} <= listed


@pytest.mark.docker
def test_first_color_transfer_of_a_new_container_loads_compiled_kernels(stack):
    """The workers are new containers: their first color transfer loads the numba kernels the
    image compiled at build time (the numba-cache volume starts with them): the job writes no
    code file into the cache, which a compile would (0.33 s measured for such a first job,
    where a process compiling them took 7.7 s: README, Docker)."""
    import io

    from PIL import Image

    y, x = np.mgrid[0:36, 0:48]
    pictures = [np.stack([200 + 0 * x, 60 + x, 40 + y], -1).astype(np.uint8),
                np.stack([30 + 0 * x, 80 + y, 150 + x], -1).astype(np.uint8)]
    files = []
    for i, rgb in enumerate(pictures):
        buf = io.BytesIO()
        Image.fromarray(rgb).save(buf, format="PNG")
        files.append(("images", (f"{i}.png", buf.getvalue(), "image/png")))
    running = [c for c in worker_containers(stack).values()
               if stack.inspect(c)["State"]["Running"]]  # one was killed by an earlier test
    assert running
    # numba's code files, named and dated: a compile writes one (new, or over an old one)
    compiled = 'find "$NUMBA_CACHE_DIR" -name "*.nbc" -printf "%p %T@\\n" | sort | md5sum'
    before = {}
    for worker in running:
        listing = run_exec(stack, worker, "sh", "-c", 'find "$NUMBA_CACHE_DIR" -name "*.nbi" '
                           '| wc -l')
        assert int(listing) > 0, listing  # numba's index files, from the image
        before[worker] = run_exec(stack, worker, "sh", "-c", compiled)
    r = stack.post("/v1/color-transfers?wait=60", files=files,
                   data={"alphas": "[[0, 1]]", "bins": "64"})
    assert r.status_code in (200, 202), r.text
    j = wait_job(stack, r.json()["id"], lambda j: j["state"] not in ("queued", "running"), 120,
                 "the color transfer")
    assert j["state"] == "succeeded", j
    print(f"\nfirst color transfer in a new worker container: {j['duration_seconds']:.2f} s")
    for worker in running:  # a compile writes new code files into the shared cache volume
        assert run_exec(stack, worker, "sh", "-c", compiled) == before[worker], worker


def run_exec(stack, container: str, *argv: str) -> str:
    from dockerstack import run

    return run([stack.docker, "exec", container, *argv]).stdout.strip()


@pytest.mark.docker
def test_down_needs_no_password(stack):
    """Last: `down -v` as the README runs it, without REDIS_PASSWORD or POSTGRES_PASSWORD."""
    from dockerstack import run

    proc = stack.down(check=True)
    assert proc.returncode == 0, proc.stderr
    left = run([stack.docker, "volume", "ls", "-q", "--filter",
                f"label=com.docker.compose.project={stack.project}"]).stdout.split()
    assert left == [] and stack.containers("api") == []
