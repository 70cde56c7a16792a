#!/usr/bin/env bash
# Print the base image to build SkyNet Inspect's image FROM, making a local one when needed.
#
#   BASE_IMAGE=$(bash scripts/docker-base.sh)   # then: docker-compose build --build-arg BASE_IMAGE=$BASE_IMAGE
#
# The Dockerfile's default base is the official python:3.11-slim. On a machine that cannot pull it
# (no Docker Hub, see shared/DOCKER.md) this makes skynet-local/python:3.11-bookworm once with
# Debian's debootstrap from the machine's own Debian mirror (python3 3.11 + venv, iproute2, and the
# host's CA bundle so TLS to the package registries verifies), about 3 minutes, and then keeps it in
# the engine's data root (kept between runs, scripts/docker-lib.sh). Needs a running engine
# (DOCKER_HOST), root and debootstrap for the local base. Progress goes to stderr.
set -euo pipefail
DEFAULT_BASE="${DEFAULT_BASE:-python:3.11-slim}"
LOCAL_BASE="${LOCAL_BASE:-skynet-local/python:3.11-bookworm}"
DOCKER="${DOCKER:-$( [ -x /usr/bin/docker ] && echo /usr/bin/docker || command -v docker )}"

have() { "$DOCKER" image inspect "$1" >/dev/null 2>&1; }

if have "$DEFAULT_BASE"; then echo "$DEFAULT_BASE"; exit 0; fi
if have "$LOCAL_BASE"; then echo "$LOCAL_BASE"; exit 0; fi
if timeout 60 "$DOCKER" pull -q "$DEFAULT_BASE" >/dev/null 2>&1; then echo "$DEFAULT_BASE"; exit 0; fi

echo "docker-base: cannot pull $DEFAULT_BASE; making $LOCAL_BASE with debootstrap (once, about 3 minutes)" >&2
command -v debootstrap >/dev/null 2>&1 || { echo "docker-base: needs debootstrap (apt-get install debootstrap)" >&2; exit 3; }
[ "$(id -u)" = 0 ] || { echo "docker-base: debootstrap needs root" >&2; exit 3; }
# the Debian mirror this machine already uses (deb822 or one-line sources)
mirror="$(grep -hoE '^(URIs:|deb) +https?://[^ ]+' /etc/apt/sources.list.d/*.sources /etc/apt/sources.list 2>/dev/null \
  | grep -v security | head -n1 | awk '{print $NF}' || true)"
mirror="${mirror:-http://deb.debian.org/debian}"
suite="$(. /etc/os-release 2>/dev/null && echo "${VERSION_CODENAME:-bookworm}")"
rootfs="$(mktemp -d /tmp/skynet-rootfs.XXXXXX)"
trap 'rm -rf "$rootfs"' EXIT
debootstrap --variant=minbase --include=python3,python3-venv,ca-certificates,iproute2 \
  "$suite" "$rootfs" "$mirror" >&2
cp /etc/ssl/certs/ca-certificates.crt "$rootfs/etc/ssl/certs/ca-certificates.crt"
rm -rf "$rootfs"/var/cache/apt/archives/*.deb "$rootfs"/var/lib/apt/lists/*
tar -C "$rootfs" -c . | "$DOCKER" import -c 'ENV LANG=C.UTF-8' - "$LOCAL_BASE" >/dev/null
echo "$LOCAL_BASE"
