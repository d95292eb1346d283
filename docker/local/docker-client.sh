#!/usr/bin/env bash
# Print the path of a Docker client that can build the images: $DOCKER when set, else the
# first of `docker` on PATH, /usr/bin/docker and /usr/local/bin/docker that has the buildx
# plugin or builds with BuildKit itself (clients before 23.0, e.g. Debian's docker.io 20.10).
# A newer client without buildx (a static client in /usr/local/bin) cannot: it is skipped.
set -uo pipefail
if [ -n "${DOCKER:-}" ]; then echo "$DOCKER"; exit 0; fi
can_build() {
  "$1" buildx version >/dev/null 2>&1 && return 0
  local version
  version=$("$1" version --format '{{.Client.Version}}' 2>/dev/null) || return 1
  [ "${version%%.*}" -lt 23 ] 2>/dev/null
}
for c in "$(command -v docker 2>/dev/null)" /usr/bin/docker /usr/local/bin/docker; do
  [ -n "$c" ] && [ -x "$c" ] && can_build "$c" && { echo "$c"; exit 0; }
done
echo "no Docker client that can build: install the buildx plugin or Debian's docker.io" >&2
exit 1
