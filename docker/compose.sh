#!/usr/bin/env bash
# Run Docker Compose, whichever is installed: the `docker compose` plugin, else
# `docker-compose` (1.29, Debian). Builds (`up --build`) go through a client that can build
# (docker/local/docker-client.sh) with BuildKit, which honours docker/Dockerfile.dockerignore.
#   docker/compose.sh -f docker/compose.yaml up --build --scale worker=4
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
client=$("$here/local/docker-client.sh" 2>/dev/null || command -v docker || true)
export DOCKER_BUILDKIT=1 COMPOSE_DOCKER_CLI_BUILD=1
if [ -n "$client" ]; then
  # compose calls `docker` from PATH for builds: make it the client that can build
  bin=$(mktemp -d)
  trap 'rm -rf "$bin"' EXIT
  ln -s "$client" "$bin/docker"
  export PATH="$bin:$PATH"
  if "$client" compose version >/dev/null 2>&1; then
    "$client" compose "$@"
    exit
  fi
fi
if command -v docker-compose >/dev/null 2>&1; then
  docker-compose "$@"
  exit
fi
echo "neither the docker compose plugin nor docker-compose is installed" >&2
exit 1
