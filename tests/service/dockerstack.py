"""Drive a real Docker engine for tests/service/test_docker.py and bench/docker.py: build the
local images (docker/local/build-images.sh) and run docker/compose.yaml with the test override
docker/compose.test.yaml through docker/compose.sh (the `docker compose` plugin or Debian's
docker-compose 1.29, found at run time), as the README's route without Docker Hub does: the
local images through OTGEO_IMAGE, OTGEO_REDIS_IMAGE and OTGEO_POSTGRES_IMAGE. Traffic goes
only to the API's port published on 127.0.0.1."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import time
import uuid
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[2]
DOCKER_DIR = ROOT / "docker"
IMAGE = "otgeo:test"
BASE_IMAGE = "otgeo-base:bookworm"
BUILD_TIMEOUT = 80 * 60  # a cold machine builds everything within CI's 90 minutes


COMPOSE = DOCKER_DIR / "compose.sh"  # finds the compose invocation at run time


def docker_cli() -> str | None:
    """The Docker client that can build (docker/local/docker-client.sh: $DOCKER, else one with
    buildx or BuildKit built in), else any on PATH."""
    found = subprocess.run([str(DOCKER_DIR / "local" / "docker-client.sh")],
                           capture_output=True, text=True)
    return found.stdout.strip() if found.returncode == 0 else shutil.which("docker")


def compose_cli() -> list[str] | None:
    """docker/compose.sh when it finds the compose plugin or docker-compose."""
    cli = docker_cli()
    plugin = cli and subprocess.run([cli, "compose", "version"],
                                    capture_output=True).returncode == 0
    return [str(COMPOSE)] if plugin or shutil.which("docker-compose") else None


def engine_problem() -> str | None:
    """What is missing for the containers to run here, every missing part named (None: the
    client, the engine, compose and the base image or its builder are all there)."""
    cli = docker_cli()
    if cli is None:
        return "no docker client on PATH (apt-get install docker.io)"
    missing = []
    try:
        info = subprocess.run([cli, "info", "--format", "{{json .ServerVersion}}"],
                              capture_output=True, text=True, timeout=30)
    except subprocess.TimeoutExpired:
        info = None
        missing.append("the Docker engine: `docker info` did not answer within 30 s")
    if info is not None and info.returncode != 0:
        lines = [ln.strip() for ln in (info.stderr or info.stdout).splitlines() if ln.strip()]
        # the engine's own words (e.g. "Cannot connect to the Docker daemon ... Is the docker
        # daemon running?") rather than the client's section that precedes them
        said = next((ln for ln in lines if "daemon" in ln.lower()), lines[-1] if lines else
                    "no output")
        missing.append(f"a running Docker engine (`{cli} info` exit {info.returncode}: {said})")
    if compose_cli() is None:
        missing.append("docker compose (neither the compose plugin nor docker-compose is "
                       "installed)")
    if info is not None and info.returncode == 0:  # the image store answers only then
        probe = subprocess.run([cli, "image", "inspect", BASE_IMAGE], capture_output=True)
        if probe.returncode != 0 and shutil.which("debootstrap") is None:
            missing.append(f"the {BASE_IMAGE} image, or debootstrap to build it")
    return "missing " + "; ".join(missing) if missing else None


def run(args: list[str], timeout: float = 300, env: dict | None = None, check: bool = True,
        cwd: Path = ROOT, base: dict | None = None) -> subprocess.CompletedProcess:
    """``args`` with ``env`` over ``base`` (default: this process's environment)."""
    proc = subprocess.run(args, capture_output=True, text=True, timeout=timeout, cwd=cwd,
                          env={**(os.environ if base is None else base), **(env or {})})
    if check and proc.returncode != 0:
        raise RuntimeError(f"{' '.join(args)} exited {proc.returncode}:\n"
                           f"{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    return proc


def build_images(log_path: Path) -> float:
    """docker/local/build-images.sh otgeo:test (base, redis, postgres reused when present;
    the otgeo image rebuilt from the tree with the layer cache). Returns seconds."""
    t0 = time.monotonic()
    with open(log_path, "w") as log:
        proc = subprocess.run([str(DOCKER_DIR / "local" / "build-images.sh"), IMAGE],
                              cwd=ROOT, stdout=log, stderr=subprocess.STDOUT,
                              timeout=BUILD_TIMEOUT, env={**os.environ, "DOCKER": docker_cli()})
    if proc.returncode != 0:
        raise RuntimeError(f"building the images failed ({proc.returncode}):\n"
                           f"{log_path.read_text()[-4000:]}")
    return time.monotonic() - t0


def image_size(tag: str = IMAGE) -> int:
    return int(run([docker_cli(), "image", "inspect", "-f", "{{.Size}}", tag]).stdout)


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class ComposeStack:
    """One compose project (unique name, random passwords, API on 127.0.0.1:<free port>)."""

    def __init__(self, workers: int = 2):
        self.project = f"otgeotest{uuid.uuid4().hex[:8]}"
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.workers = workers
        self.env = {
            "REDIS_PASSWORD": uuid.uuid4().hex,
            "POSTGRES_PASSWORD": uuid.uuid4().hex,
            "OTGEO_HOST_IP": "127.0.0.1",
            "OTGEO_PORT": str(self.port),
            "OTGEO_IMAGE": IMAGE,
            "OTGEO_REDIS_IMAGE": "otgeo-redis:local",
            "OTGEO_POSTGRES_IMAGE": "otgeo-postgres:local",
        }
        self.docker = docker_cli()

    # -- compose ------------------------------------------------------------------
    def compose_argv(self, *args: str) -> list[str]:
        return [*compose_cli(), "-f", "docker/compose.yaml", "-f", "docker/compose.test.yaml",
                "-p", self.project, *args]

    def compose(self, *args: str, timeout: float = 300, check: bool = True,
                passwords: bool = True):
        env = self.env if passwords else {k: v for k, v in self.env.items()
                                          if not k.endswith("_PASSWORD")}
        full = None if passwords else {k: v for k, v in os.environ.items()
                                       if not k.endswith("_PASSWORD")}
        return run(self.compose_argv(*args), timeout=timeout, env=env, check=check, base=full)

    def up(self) -> float:
        """Create and start everything; seconds until /healthz answers and the API, Redis
        and PostgreSQL containers report healthy."""
        t0 = time.monotonic()
        self.compose("up", "-d", "--no-build", "--scale", f"worker={self.workers}")
        self.wait_healthy(("api", "redis", "postgres"), timeout=180)
        return time.monotonic() - t0

    def down(self, check: bool = False) -> subprocess.CompletedProcess:
        """Remove containers, networks and volumes; needs no password (as in the README)."""
        return self.compose("down", "-v", "--remove-orphans", "-t", "5", check=check,
                            timeout=180, passwords=False)

    def containers(self, service: str) -> list[str]:
        """Container ids of a service, stopped ones included, oldest first (the labels
        compose sets; `docker ps` answers much faster than `docker-compose ps`)."""
        out = run([self.docker, "ps", "-a", "-q", "--no-trunc",
                   "--filter", f"label=com.docker.compose.project={self.project}",
                   "--filter", f"label=com.docker.compose.service={service}"]).stdout.split()
        return out[::-1]

    def inspect(self, container: str) -> dict:
        return json.loads(run([self.docker, "inspect", container]).stdout)[0]

    def health(self, service: str) -> list[str]:
        states = []
        for c in self.containers(service):
            st = self.inspect(c)["State"]
            states.append(st.get("Health", {}).get("Status") or st["Status"])
        return states

    def wait_healthy(self, services, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while True:
            states = {s: self.health(s) for s in services}
            if all(v and all(x == "healthy" for x in v) for v in states.values()):
                try:
                    if httpx.get(self.url + "/healthz", timeout=2).status_code == 200:
                        return
                except httpx.HTTPError:
                    pass
            if time.monotonic() > deadline:
                raise TimeoutError(f"not healthy after {timeout} s: {states}\n{self.logs()}")
            time.sleep(0.25)

    def logs(self, tail: int = 60) -> str:
        return self.compose("logs", "--no-color", "--tail", str(tail), check=False).stdout

    def exec(self, service: str, *argv: str, env: dict | None = None,
             check: bool = True) -> subprocess.CompletedProcess:
        (container,) = self.containers(service)[:1]
        extra = [a for k, v in (env or {}).items() for a in ("-e", f"{k}={v}")]
        return run([self.docker, "exec", *extra, container, *argv], check=check, timeout=60)

    def sql(self, query: str) -> str:
        """A query on the job table, inside the postgres container (not published)."""
        return self.exec("postgres", "psql", "-U", "otgeo", "-d", "otgeo", "-tAc",
                         query).stdout.strip()

    def hostname(self, container: str) -> str:
        return self.inspect(container)["Config"]["Hostname"]

    # -- HTTP (published port on 127.0.0.1 only) -------------------------------------
    def post(self, path: str, **kw) -> httpx.Response:
        return httpx.post(self.url + path, timeout=kw.pop("timeout", 90), **kw)

    def get(self, path: str, **kw) -> httpx.Response:
        return httpx.get(self.url + path, timeout=kw.pop("timeout", 30), **kw)
