#!/usr/bin/env bash
# Build a local Debian bookworm base image (no registry needed):
#   debootstrap --variant=minbase bookworm <rootfs> [the host's Debian archive]
#   tar -C <rootfs> -c . | docker import - <tag>
# Usage: docker/local/build-base.sh [TAG]   (default otgeo-base:bookworm)
# An existing TAG is reused (FORCE=1 rebuilds). The host's CA bundle
# (/etc/ssl/certs/ca-certificates.crt) is copied in, so pip inside `docker build --network host`
# trusts the same registries the host does; PIP_CERT points at the copy.
set -euo pipefail
TAG=${1:-otgeo-base:bookworm}
DOCKER=${DOCKER:-docker}
SUITE=bookworm

if [ "${FORCE:-0}" != 1 ] && "$DOCKER" image inspect "$TAG" >/dev/null 2>&1; then
  echo "base image $TAG exists; reusing it (FORCE=1 rebuilds)"
  exit 0
fi
command -v debootstrap >/dev/null || { echo "debootstrap is not installed" >&2; exit 1; }

# The Debian archive apt is configured with (deb822 .sources or one-line sources.list).
mirror=${DEBIAN_MIRROR:-}
if [ -z "$mirror" ]; then
  mirror=$(sed -n 's/^URIs:[[:space:]]*\([^[:space:]]*\/debian\)[[:space:]]*$/\1/p' \
             /etc/apt/sources.list.d/*.sources 2>/dev/null | head -n1 || true)
fi
if [ -z "$mirror" ] && [ -f /etc/apt/sources.list ]; then
  mirror=$(awk '$1 == "deb" && $2 ~ /\/debian\/?$/ {print $2; exit}' /etc/apt/sources.list)
fi

root=$(mktemp -d /var/tmp/otgeo-rootfs.XXXXXX)
trap 'rm -rf "$root"' EXIT
start=$(date +%s)
echo "debootstrap --variant=minbase $SUITE $root ${mirror:-(debootstrap default)}"
debootstrap --variant=minbase "$SUITE" "$root" ${mirror:+"$mirror"} >"$root.log" 2>&1 || {
  tail -n 30 "$root.log" >&2; rm -f "$root.log"; exit 1; }
rm -f "$root.log"

# apt inside the image uses the same archive configuration as the host
if ls /etc/apt/sources.list.d/*.sources >/dev/null 2>&1; then
  rm -f "$root/etc/apt/sources.list"
  for f in /etc/apt/sources.list.d/*.sources; do
    grep -q '/debian' "$f" && cp "$f" "$root/etc/apt/sources.list.d/"
  done
fi
cat >"$root/etc/apt/apt.conf.d/90otgeo-slim" <<'CONF'
APT::Install-Recommends "false";
APT::Install-Suggests "false";
Acquire::Languages "none";
CONF
changes=()
if [ -f /etc/ssl/certs/ca-certificates.crt ]; then
  install -D -m 0644 /etc/ssl/certs/ca-certificates.crt "$root/etc/ssl/host-ca-bundle.crt"
  install -D -m 0644 /etc/ssl/certs/ca-certificates.crt "$root/etc/ssl/certs/ca-certificates.crt"
  changes+=(--change 'ENV PIP_CERT=/etc/ssl/host-ca-bundle.crt')
fi
rm -rf "$root"/var/cache/apt/archives/*.deb "$root"/var/lib/apt/lists/* \
       "$root"/usr/share/doc/* "$root"/usr/share/man/* "$root"/usr/share/locale/*

tar --numeric-owner -C "$root" -c . | "$DOCKER" import \
  --change 'ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
  "${changes[@]}" \
  --change 'ENV LANG=C.UTF-8' \
  --change 'CMD ["/bin/bash"]' \
  - "$TAG" >/dev/null
echo "built $TAG in $(( $(date +%s) - start )) s ($("$DOCKER" image inspect -f '{{.Size}}' "$TAG") bytes)"
