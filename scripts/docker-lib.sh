# Sourced by scripts/docker-base.sh and scripts/compose-e2e.sh: a Docker engine to talk to.
#
# skynet_engine_up: use the engine DOCKER_HOST (or /var/run/docker.sock) points at when one answers;
# otherwise, as root with Debian's docker.io installed, start our own dockerd in the background with
# its own folders (no systemd here, see shared/DOCKER.md): the data root is a fixed, persistent folder
# (SKYNET_DOCKER_CACHE, default /var/cache/skynet-docker) so images and build layers survive between
# runs; the socket, pid file and exec root are in a fresh temporary folder. --iptables=false: the
# engine touches no host firewall and containers get no route off this machine (they reach each
# other on the compose bridge; builds use the host network to reach the package registries).
# skynet_engine_down stops the dockerd we started (by its pid), never one we found running.

SKYNET_DOCKER_CACHE="${SKYNET_DOCKER_CACHE:-/var/cache/skynet-docker}"
SKYNET_ENGINE_STARTED=""
SKYNET_ENGINE_TMP=""

_skynet_docker_bin() {
  # Debian's docker.io client (the one the engine comes with) before any other docker on PATH
  if [ -x /usr/bin/docker ]; then echo /usr/bin/docker; else command -v docker; fi
}
DOCKER="${DOCKER:-$(_skynet_docker_bin)}"

skynet_engine_up() {
  if [ -z "${DOCKER:-}" ]; then echo "no docker client (apt-get install docker.io)" >&2; return 3; fi
  if [ -n "${DOCKER_HOST:-}" ] && "$DOCKER" info >/dev/null 2>&1; then return 0; fi
  if [ -z "${DOCKER_HOST:-}" ] && [ -S /var/run/docker.sock ] && "$DOCKER" info >/dev/null 2>&1; then return 0; fi
  command -v dockerd >/dev/null 2>&1 || { echo "no dockerd (apt-get install docker.io)" >&2; return 3; }
  [ "$(id -u)" = 0 ] || { echo "no Docker engine running, and starting one needs root" >&2; return 3; }
  mkdir -p "$SKYNET_DOCKER_CACHE/data"
  # one engine per data root at a time (a second run on this machine waits for the first)
  exec 8>"$SKYNET_DOCKER_CACHE/lock"
  flock -w 900 8 || { echo "the Docker cache $SKYNET_DOCKER_CACHE stays locked" >&2; return 3; }
  SKYNET_ENGINE_TMP="$(mktemp -d /tmp/skynet-dockerd.XXXXXX)"
  dockerd --data-root "$SKYNET_DOCKER_CACHE/data" --exec-root "$SKYNET_ENGINE_TMP/exec" \
    -H "unix://$SKYNET_ENGINE_TMP/docker.sock" --pidfile "$SKYNET_ENGINE_TMP/pid" \
    --iptables=false --bridge=none >"$SKYNET_ENGINE_TMP/dockerd.log" 2>&1 8>&- &
  SKYNET_ENGINE_STARTED=$!
  export DOCKER_HOST="unix://$SKYNET_ENGINE_TMP/docker.sock"
  for _ in $(seq 1 120); do
    if "$DOCKER" info >/dev/null 2>&1; then return 0; fi
    if ! kill -0 "$SKYNET_ENGINE_STARTED" 2>/dev/null; then break; fi
    sleep 0.5
  done
  echo "dockerd did not come up; its log:" >&2
  tail -n 30 "$SKYNET_ENGINE_TMP/dockerd.log" >&2
  skynet_engine_down
  return 3
}

skynet_engine_down() {
  if [ -n "$SKYNET_ENGINE_STARTED" ]; then
    kill "$SKYNET_ENGINE_STARTED" 2>/dev/null || true
    for _ in $(seq 1 60); do kill -0 "$SKYNET_ENGINE_STARTED" 2>/dev/null || break; sleep 0.5; done
    kill -9 "$SKYNET_ENGINE_STARTED" 2>/dev/null || true
    wait "$SKYNET_ENGINE_STARTED" 2>/dev/null || true
    SKYNET_ENGINE_STARTED=""
  fi
  if [ -n "$SKYNET_ENGINE_TMP" ]; then
    umount "$SKYNET_ENGINE_TMP"/exec/netns/* 2>/dev/null || true
    rm -rf "$SKYNET_ENGINE_TMP" 2>/dev/null || true
    SKYNET_ENGINE_TMP=""
  fi
}
