#!/usr/bin/env bash
# Build every image the container test needs, from local sources only (no Docker Hub):
#   1. the Debian bookworm base (build-base.sh; reused when present),
#   2. Redis and PostgreSQL on it (reused when present; FORCE=1 rebuilds),
#   3. the otgeo image from the working tree (always; Docker's layer cache keeps reruns fast).
# Usage: docker/local/build-images.sh [OTGEO_TAG]   (default otgeo:test; otgeo:latest for compose)
# apt and pip inside the builds reach their registries through `--network host`.
set -euo pipefail
cd "$(dirname "$0")/../.."
DOCKER=$(docker/local/docker-client.sh)  # $DOCKER, else a client that can build (BuildKit)
BASE=${BASE_IMAGE:-otgeo-base:bookworm}
TAG=${1:-otgeo:test}
export DOCKER_BUILDKIT=1  # honours docker/Dockerfile.dockerignore (the context is the repo root)

t0=$(date +%s)
DOCKER=$DOCKER docker/local/build-base.sh "$BASE"
for svc in redis postgres; do
  if [ "${FORCE:-0}" != 1 ] && "$DOCKER" image inspect "otgeo-$svc:local" >/dev/null 2>&1; then
    echo "otgeo-$svc:local exists; reusing it"
  else
    "$DOCKER" build --network host --build-arg "BASE_IMAGE=$BASE" \
      -f "docker/local/$svc.Dockerfile" -t "otgeo-$svc:local" docker/local
  fi
done
"$DOCKER" build --network host --build-arg "BASE_IMAGE=$BASE" --label org.otgeo.local-build=1 \
  -f docker/Dockerfile -t "$TAG" .
# earlier builds of the tag, now untagged (their layers stay cached while the tag uses them)
"$DOCKER" image prune -f --filter label=org.otgeo.local-build=1 >/dev/null
# keep BuildKit's cache bounded (least recently used first; this build's layers stay)
"$DOCKER" builder prune -f --keep-storage "${BUILD_CACHE_KEEP:-8GB}" >/dev/null || true
echo "images ready in $(( $(date +%s) - t0 )) s"
