#!/usr/bin/env bash
# Make a Docker engine available for tests/service/test_docker.py (used by .ci/run):
#   - apt-get install docker.io docker-compose debootstrap when one of them is missing,
#   - start dockerd (cgroupfs driver; overlay2, else vfs) when `docker info` does not answer.
# Exit 0 when the engine answers (then the docker test must pass, not skip); otherwise print
# why on stderr and exit 1 (the test then skips, printing the reason).
set -uo pipefail
LOG=${DOCKERD_LOG:-/var/log/dockerd-ci.log}
say() { echo "docker engine: $*" >&2; }

missing=()
command -v dockerd >/dev/null 2>&1 || missing+=(docker.io)
command -v docker-compose >/dev/null 2>&1 || missing+=(docker-compose)
command -v debootstrap >/dev/null 2>&1 || missing+=(debootstrap)
if [ ${#missing[@]} -gt 0 ]; then
  say "installing ${missing[*]}"
  if ! (export DEBIAN_FRONTEND=noninteractive; apt-get update -q \
        && apt-get install -y -q docker.io docker-compose debootstrap) >/tmp/docker-apt.log 2>&1
  then
    say "apt-get install failed:"; tail -n 15 /tmp/docker-apt.log >&2
  fi
fi

DOCKER=/usr/bin/docker
[ -x "$DOCKER" ] || DOCKER=$(command -v docker || true)
[ -n "$DOCKER" ] || { say "no docker client"; exit 1; }
answers() { timeout 20 "$DOCKER" info >/dev/null 2>&1; }

if answers; then
  say "running ($("$DOCKER" info --format '{{.ServerVersion}}, {{.Driver}}, {{.CgroupDriver}}'))"
  exit 0
fi
command -v dockerd >/dev/null 2>&1 || { say "dockerd is not installed"; exit 1; }
for driver in overlay2 vfs; do
  say "starting dockerd (storage driver $driver, cgroupfs), log $LOG"
  nohup dockerd --exec-opt native.cgroupdriver=cgroupfs --storage-driver "$driver" \
    >>"$LOG" 2>&1 </dev/null &
  pid=$!
  for _ in $(seq 120); do
    if answers; then
      say "running ($("$DOCKER" info --format '{{.ServerVersion}}, {{.Driver}}, {{.CgroupDriver}}'))"
      exit 0
    fi
    kill -0 "$pid" 2>/dev/null || break
    sleep 0.5
  done
  kill "$pid" 2>/dev/null; wait "$pid" 2>/dev/null
  say "dockerd with $driver did not come up:"; tail -n 10 "$LOG" >&2
done
say "cannot run here"
exit 1
