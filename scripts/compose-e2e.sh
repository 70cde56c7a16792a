#!/usr/bin/env bash
# docker compose, end to end, on a real Docker engine; .ci/run runs it after the test suite.
#
#   bash scripts/compose-e2e.sh            # the impaired mission (proves the plain path too), two sites, the tc check
#   COMPOSE_E2E_RUNS="plain netem sites split tc" bash scripts/compose-e2e.sh   # split: compose/ground.yml + edge.yml;
#                                                                       # sites: compose/sites.yml (two gateways)
#   COMPOSE_E2E_RUNS=mavlink bash scripts/compose-e2e.sh   # compose/mavlink.yml: each edge on its own autopilot
#                                                            (three sim autopilots on the host, homes of their own)
#
# 1. an engine: the one DOCKER_HOST points at, else our own dockerd (scripts/docker-lib.sh: persistent
#    data root /var/cache/skynet-docker, so the base image and the build layers are kept between runs);
# 2. a base: python:3.11-slim if it can be pulled, else a local Debian one (scripts/docker-base.sh, once);
# 3. `docker-compose build`, then per run `up --exit-code-from gcs`, asserting its exit status and the
#    report (scripts/compose_check.py): success, every capture, formation RMS < 1 m; with `netem`
#    (compose/netem.env: 100 ms on UAV 2's uplink and 50 ms on the SkyNet link uav1-uav2, user-space
#    side-cars) also that UAV 2's telemetry age grew by the delay and only UAV 2's, and that traffic
#    crossed both proxies of the SkyNet side-car; every mission runs secure (the default): each edge
#    logs mutual TLS with the certificate ACL and signed commands, and afterwards a plain (non-TLS)
#    Zenoh client is refused by the gateway while a client with the ground station's certificate gets
#    in (a control); `tc` checks that the kernel-netem side-car fails `up` where the kernel has no
#    netem qdisc (skipped where it has one);
# 4. `down -v`, then no container and no network of the project may be left. Cleanup (down, the
#    dockerd we started) runs on every exit, failure included.
# Figures (image size, build times, up-to-verdict time, per-container CPU and memory) are printed and
# written to bench/results/compose-e2e.json. Exit 0 when all holds; 0 with "SKIPPED: reason" when
# this machine cannot run an engine (not root, no docker.io); 1 otherwise.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT="$PWD"
RUNS="${COMPOSE_E2E_RUNS:-netem sites tc}"
PROJECT="skynet-e2e-$$"
PY="${PYTHON:-$ROOT/.venv/bin/python}"
[ -x "$PY" ] || PY=python3
OUT="$ROOT/bench/results"
WORK="$(mktemp -d /tmp/skynet-e2e.XXXXXX)"
REPORTS="$WORK/reports"
mkdir -p "$OUT" "$REPORTS"
# the report must be handed to the owner of the reports folder: make that someone other than root
[ "$(id -u)" = 0 ] && chown 4321:4321 "$REPORTS"
chmod 755 "$WORK"
export SKYNET_REPORTS="$REPORTS"
# the compose key set: made by the keys service on the first run, reused after (kept out of the repository)
export SKYNET_KEYS="${SKYNET_KEYS:-$WORK/keys}"
. scripts/docker-lib.sh

log() { echo "compose-e2e: $*"; }
now() { date +%s.%N; }
since() { awk -v a="$1" -v b="$(now)" 'BEGIN { printf "%.1f", b - a }'; }
compose() { docker-compose -p "$PROJECT" "$@"; }

# wait until container $1 is healthy (at most $2 s); 1 if it is not
wait_healthy() {
  local end=$(( $(date +%s) + $2 )) st
  while [ "$(date +%s)" -lt "$end" ]; do
    st="$("$DOCKER" inspect -f '{{if .State.Health}}{{.State.Health.Status}}{{end}}' "$1" 2>/dev/null || true)"
    [ "$st" = healthy ] && return 0
    sleep 0.5
  done
  log "$1 not healthy after $2 s (${st:-no such container})"; return 1
}
# where an `up` spent its time, from the engine's own events (streamed while it runs: the engine keeps
# only its last 256 events, and every health check makes three): when the first container started, when
# each service first turned healthy, when gcs started and exited, when the last container went down
events_start() {  # project, file
  "$DOCKER" events --filter "label=com.docker.compose.project=$1" --filter type=container \
    --filter event=start --filter event=die --filter event=health_status \
    --format '{{.TimeNano}} {{.Status}} {{index .Actor.Attributes "com.docker.compose.service"}}' >"$2" 2>/dev/null &
  EVENTS_PID=$!
}
up_phases() {  # file, epoch of the up's start
  [ -n "$EVENTS_PID" ] && { kill "$EVENTS_PID" 2>/dev/null; wait "$EVENTS_PID" 2>/dev/null || true; EVENTS_PID=""; }
  awk -v t0="$2" '
      function at(ns) { return sprintf("%.1f", ns / 1e9 - t0) }
      $2 == "start" && first == "" { first = at($1) }
      $2 == "start" && $3 == "gcs" { gs = at($1) }
      $2 == "health_status:" && $3 == "healthy" && !(($4) in h) { h[$4] = at($1); order[++n] = $4 }
      $2 == "die" && $3 == "gcs" { gd = at($1) }
      $2 == "die" { last = at($1) }
      END { printf "first start +%s s; healthy:", first
            for (i = 1; i <= n; i++) printf " %s +%s", order[i], h[order[i]]
            printf "; gcs start +%s, exit +%s; last container down +%s s\n", gs, gd, last }' "$1"
}
EVENTS_PID=""
STATS_PID=""
aps=()  # the mavlink run's sim autopilots on the host
WEB_PID=""
cleanup() {
  rc=$?
  set +e
  [ -n "$STATS_PID" ] && kill "$STATS_PID" 2>/dev/null && wait "$STATS_PID" 2>/dev/null
  [ -n "$WEB_PID" ] && kill "$WEB_PID" 2>/dev/null && wait "$WEB_PID" 2>/dev/null
  [ -n "$EVENTS_PID" ] && kill "$EVENTS_PID" 2>/dev/null && wait "$EVENTS_PID" 2>/dev/null
  for pid in "${aps[@]}"; do kill "$pid" 2>/dev/null && wait "$pid" 2>/dev/null; done
  if [ -n "${DOCKER_HOST:-}" ] || [ -S /var/run/docker.sock ]; then
    compose --env-file compose/netem.env down -v --remove-orphans --timeout 5 >/dev/null 2>&1
    compose --profile web down -v --remove-orphans --timeout 5 >/dev/null 2>&1
    compose --profile tc-netem down -v --remove-orphans --timeout 5 >/dev/null 2>&1
    # whatever a profile or the split run left behind (compose v1 leaves a disabled profile's containers alone)
    ids="$("$DOCKER" ps -aq --filter "name=^$PROJECT")"
    [ -n "$ids" ] && "$DOCKER" rm -f $ids >/dev/null 2>&1
    ids="$("$DOCKER" network ls -q --filter "name=^$PROJECT")"
    [ -n "$ids" ] && "$DOCKER" network rm $ids >/dev/null 2>&1
    ids="$("$DOCKER" volume ls -q --filter "name=^$PROJECT")"
    [ -n "$ids" ] && "$DOCKER" volume rm $ids >/dev/null 2>&1
  fi
  skynet_engine_down
  # a failed run keeps its logs (every up, the split edges', the probe) for the post-mortem
  if [ "$rc" != 0 ] || [ "${failed:-0}" != 0 ]; then
    rm -rf "$OUT/compose-e2e-logs"; mkdir -p "$OUT/compose-e2e-logs"
    cp "$WORK"/*.log "$OUT/compose-e2e-logs/" 2>/dev/null
    echo "compose-e2e: logs kept in bench/results/compose-e2e-logs/"
  fi
  rm -rf "$WORK"
  exit "$rc"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

if ! command -v docker-compose >/dev/null 2>&1; then
  log "SKIPPED: Debian's docker-compose is not installed (.ci/run installs docker.io docker-compose debootstrap)"
  exit 0
fi
set +e; skynet_engine_up; up_rc=$?; set -e
if [ "$up_rc" != 0 ]; then
  if [ "$(id -u)" != 0 ] || ! command -v dockerd >/dev/null 2>&1; then
    log "SKIPPED: no Docker engine here and none can be started (needs root and docker.io)"; exit 0
  fi
  log "FAIL: could not start a Docker engine"; exit 1
fi
log "engine $(docker version --format '{{.Server.Version}}' 2>/dev/null) at ${DOCKER_HOST:-/var/run/docker.sock}"

t=$(now)
BASE_IMAGE="$(bash scripts/docker-base.sh)"
export BASE_IMAGE
base_s=$(since "$t")
log "base image $BASE_IMAGE (${base_s} s)"

t=$(now)
compose build gateway >"$WORK/build.log" 2>&1 || { tail -n 40 "$WORK/build.log"; log "FAIL: build"; exit 1; }
build_s=$(since "$t")
steps="$(grep -c '^Step ' "$WORK/build.log" || true)"; cached="$(grep -c 'Using cache' "$WORK/build.log" || true)"
image_mb=$(( $("$DOCKER" image inspect "skynet-inspect:${SKYNET_TAG:-latest}" --format '{{.Size}}') / 1000000 ))
log "image ${image_mb} MB; build ${build_s} s (${cached} of ${steps} steps from the cache)"

# per-container CPU and memory, sampled while a mission runs
sample_stats() {
  while sleep 5; do
    "$DOCKER" stats --no-stream --format '{{.Name}} {{.CPUPerc}} {{.MemUsage}}' 2>/dev/null \
      | grep "^${PROJECT}_" >>"$1" || true
  done
}

# the gateway refuses a plain client (no TLS), and admits one with the ground station's certificate (control);
# both tries in one container. The gateway is left running: the tc check reuses it (and its keys service).
PROBED=""
probe_gateway() {
  PROBED=1
  local t; t=$(now)
  if compose up -d gateway >"$WORK/probe.log" 2>&1 && wait_healthy "${PROJECT}_gateway_1" 90 >>"$WORK/probe.log"; then
    local probe='import sys, zenoh
for ep in sys.argv[1:]:
    c = zenoh.Config()
    c.insert_json5("mode", "\"client\"")
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("connect/endpoints", "[\"" + ep + "\"]")
    if ep.startswith("tls/"):
        c.insert_json5("transport/link/tls", "{root_ca_certificate: \"/keys/ca.pem\", enable_mtls: true, "
                       "connect_certificate: \"/keys/gcs/tls.pem\", connect_private_key: \"/keys/gcs/tls.key\"}")
    try:
        zenoh.open(c).close()
        print("probe", ep, "connected", flush=True)
    except Exception as e:
        print("probe", ep, "refused:", str(e)[:200], flush=True)'
    "$DOCKER" run --rm --network "${PROJECT}_default" -v "$SKYNET_KEYS:/keys:ro" -e RUST_LOG=off --entrypoint timeout \
      "skynet-inspect:${SKYNET_TAG:-latest}" 90 python -c "$probe" "tcp/gateway:7447" "tls/gateway:7447" \
      >>"$WORK/probe.log" 2>&1 || true
    if grep -q "^probe tcp/gateway:7447 refused" "$WORK/probe.log" && grep -q "^probe tls/gateway:7447 connected" "$WORK/probe.log"; then
      log "secure: a plain client is refused by the gateway, one with the gcs certificate connects ($(since "$t") s)"
    else
      cat "$WORK/probe.log"; log "FAIL: secure: a plain client must be refused and a TLS one with the gcs certificate admitted"; failed=1
    fi
    # a node revoked the compose way (docs/compose.md: `exec keys skynet keys revoke /keys NODE`, the keys service
    # holds the set read-write) reaches the running gateway through its read-only mount, live
    t=$(now)
    local seen=""
    if compose exec -T keys skynet keys revoke /keys planner >>"$WORK/probe.log" 2>&1; then
      for _ in $(seq 1 40); do
        compose logs --no-color gateway 2>/dev/null | grep -q "key set changed (revoked: planner" && { seen=1; break; }
        sleep 0.5
      done
    fi
    if [ -n "$seen" ]; then
      log "secure: planner revoked through the keys service; the running gateway reopened without it ($(since "$t") s)"
    else
      cat "$WORK/probe.log"; compose logs --no-color gateway 2>/dev/null | tail -n 20
      log "FAIL: secure: a node revoked through the keys service must reach the running gateway within 20 s"; failed=1
    fi
  else
    cat "$WORK/probe.log"; log "FAIL: secure: could not start the gateway for the probe"; failed=1
  fi
}

failed=0
declare -A UP_S
for run in $RUNS; do
  case "$run" in
    plain) env=(); check=() ;;
    mavlink)
      # compose/mavlink.yml as a user with three vehicles runs it: the autopilots on the host (three sim
      # autopilots, 3 m south of the scenario's slots), each sending to its edge's published UDP port; the edges
      # take their homes from them (SKYNET_MAVLINK_ARGS) and fly at the sim autopilots' speed
      env=(-f docker-compose.yml -f compose/mavlink.yml); check=()
      aps=(); homes=(--home 40,5,0 --home 40.7,7.9,0 --home 39.3,2.1,0)
      for u in 1 2 3; do
        export "SKYNET_UAV${u}_MAVLINK_PORT=$("$PY" -c 'import socket; s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')"
        port_var="SKYNET_UAV${u}_MAVLINK_PORT"
        "$PY" -m services.cli sim-autopilot --uav "$u" --port-base $(( ${!port_var} - u + 1 )) \
          "${homes[@]:$(( 2 * (u - 1) )):2}" --speed 4 --boot-scale 0.1 --wind moderate --seed "$u" \
          >"$WORK/autopilot-$u.log" 2>&1 & aps+=($!)
      done
      export SKYNET_SPEED=4 SKYNET_MAVLINK_ARGS="--home-from-autopilot" ;;
    netem) env=(--env-file compose/netem.env); check=(--impaired uav2 --delay-ms 100) ;;  # + the web page
    sites) env=(-f docker-compose.yml -f compose/sites.yml); check=(--gateways 2) ;;  # six UAVs, two gateways
    tc)
      # only meaningful where the kernel has no netem qdisc: there the profile must fail the run
      if "$DOCKER" run --rm --network none --cap-add NET_ADMIN --entrypoint sh "skynet-inspect:${SKYNET_TAG:-latest}" \
           -c 'tc qdisc add dev lo root netem delay 1ms' >/dev/null 2>&1; then
        log "tc: this kernel has netem; the fail-loudly check does not apply (skipped)"; continue
      fi
      probe_gateway   # its gateway (and keys) stay up for this check
      t=$(now)
      set +e
      # only the side-car and what it needs (gateway, uav1, uav2): compose v1 starts every container
      # (gcs after the health checks) before it watches for exits, so a whole `up --exit-code-from gcs`
      # would end just as loudly (exit 143 when tried), only a minute later
      timeout 300 docker-compose -p "$PROJECT" --profile tc-netem up --exit-code-from tc-netem-uav2 tc-netem-uav2 \
        >"$WORK/up-tc.log" 2>&1
      rc=$?
      set -e
      compose --profile tc-netem down -v --remove-orphans --timeout 5 >/dev/null 2>&1 || true
      if [ "$rc" = 0 ] || ! grep -q "cannot apply netem" "$WORK/up-tc.log"; then
        tail -n 30 "$WORK/up-tc.log"; log "FAIL: tc: the kernel-netem profile did not fail the run (exit $rc)"; failed=1
      else
        log "tc: the kernel-netem profile failed the run as it must (exit $rc, $(since "$t") s)"
      fi
      continue ;;
    split)
      # compose/ground.yml + one compose/edge.yml project per UAV, as on four hosts, secure like the
      # others: the ground's keys service makes a set whose certificates name the "hosts" (SKYNET_SANS),
      # as a dialler checks. The hosts' network is one bridge of our own engine that every node joins
      # under its host's name (nothing else is reached): between real hosts a published port's traffic
      # is forwarded by the kernel, while this engine (--iptables=false) would relay it through a
      # user-space docker-proxy per port, whose stalls under load outlasted the edges' 2 s lease (the
      # split run's lost liveliness tokens); the ports are still published (on that bridge's address).
      # Each node starts once the one it dials is healthy (gateway, then uav1, uav2, uav3: the launcher's
      # order), so no edge's first dials hit a port with nothing behind it.
      "$DOCKER" network create "$PROJECT-split" >/dev/null
      hostip="$("$DOCKER" network inspect -f '{{(index .IPAM.Config 0).Gateway}}' "$PROJECT-split")"
      name="e2e-split-$$"; t=$(now); rc=0
      export SKYNET_BIND="$hostip" SKYNET_SANS="gateway=ground-host uav1=uav1-host uav2=uav2-host"
      split_keys="$WORK/keys-split"
      hosts_net() {  # an override: service $1 also on the hosts' network, as host name $2
        printf 'networks:\n  hosts: {external: true, name: %s}\nservices:\n  %s:\n    networks:\n      default: {}\n      hosts: {aliases: [%s]}\n' \
          "$PROJECT-split" "$1" "$2" >"$WORK/net-$2.yml"; echo "$WORK/net-$2.yml"; }
      ground_net="$(hosts_net gateway ground-host)"
      ground() { SKYNET_KEYS="$split_keys" docker-compose -p "$PROJECT-ground" -f compose/ground.yml -f "$ground_net" "$@"; }
      edge() { local i=$1; shift; SKYNET_KEYS="$split_keys" SKYNET_UAV=$i SKYNET_GATEWAY=ground-host \
        SKYNET_EDGE_TCP_PORT=$((27440 + i)) SKYNET_EDGE_PAIR_PORT=$((27450 + i)) \
        docker-compose -p "$PROJECT-uav$i" -f compose/edge.yml -f "$(hosts_net edge "uav$i-host")" "$@"; }
      ground up -d gateway >"$WORK/up-split.log" 2>&1 || rc=$?
      [ "$rc" = 0 ] && { wait_healthy "${PROJECT}-ground_gateway_1" 120 || rc=$?; }
      homes=("" "40,8,0" "40.7,10.9,0" "39.3,5.1,0"); peers=""
      for i in 1 2 3; do
        [ "$rc" = 0 ] || break
        SKYNET_HOME="${homes[$i]}" SKYNET_PEERS="$peers" edge "$i" up -d >>"$WORK/up-split.log" 2>&1 || rc=$?
        [ "$rc" = 0 ] && { wait_healthy "${PROJECT}-uav${i}_edge_1" 120 || rc=$?; }
        peers="$peers tls/uav$i-host:7447?rel=1 tls/uav$i-host:7448?rel=0"
      done
      if [ "$rc" = 0 ]; then
        set +e
        SKYNET_RUN="$name" SKYNET_KEYS="$split_keys" timeout 600 docker-compose -p "$PROJECT-ground" \
          -f compose/ground.yml -f "$ground_net" up --no-color --exit-code-from gcs >>"$WORK/up-split.log" 2>&1
        rc=$?
        set -e
      fi
      UP_S[$run]=$(since "$t")
      for i in 1 2 3; do edge "$i" logs --no-color >"$WORK/edge-split-$i.log" 2>&1 || true; done
      for i in 1 2 3; do edge "$i" down -v --timeout 5 >/dev/null 2>&1 || true; done
      ground down -v --timeout 5 >/dev/null 2>&1 || true
      unset SKYNET_BIND SKYNET_SANS
      "$DOCKER" network rm "$PROJECT-split" >/dev/null 2>&1 || true
      log "split: ground + 3 edge projects, up --exit-code-from gcs exited $rc after ${UP_S[$run]} s"
      if [ "$rc" != 0 ]; then
        for i in 1 2 3; do grep -v "^\s*$" "$WORK/edge-split-$i.log" | tail -n 15; done
        grep -v "^\s*$" "$WORK/up-split.log" | tail -n 60; log "FAIL: split: the mission's exit status is $rc"; failed=1
      elif ! "$PY" scripts/compose_check.py "$REPORTS/$name" --json "$OUT/compose-e2e-split.json"; then
        log "FAIL: split: the report"; failed=1
      fi
      # secure like the one-host file: every edge ran mutual TLS with the certificate ACL and signed commands
      for i in 1 2 3; do
        { grep -q "trust: commands signed by gcs" "$WORK/edge-split-$i.log" \
          && grep -q "mutual TLS as uav${i}, ACL by certificate" "$WORK/edge-split-$i.log"; } \
          || { log "FAIL: split: uav$i did not log mutual TLS + ACL + signed commands"; failed=1; }
      done
      continue ;;
    *) log "unknown run '$run' (plain, netem, sites, split, tc, mavlink)"; exit 1 ;;
  esac
  name="e2e-$run-$$"
  : >"$WORK/stats-$run.txt"
  sample_stats "$WORK/stats-$run.txt" & STATS_PID=$!
  profiles=()
  # compose/sites.yml: a six-UAV key set of its own (the keys service never overwrites the three-UAV one)
  [ "$run" = sites ] && profiles=(env SKYNET_KEYS="$WORK/keys-sites")
  if [ "$run" = netem ]; then
    # the optional web page rides along (profile web, published on 127.0.0.1 only): poll its snapshot
    web_port="$("$PY" -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')"
    web_token="$("$PY" -c 'import secrets; print(secrets.token_urlsafe(24))')"
    profiles=(env COMPOSE_PROFILES=netem,web SKYNET_WEB_PORT="$web_port" SKYNET_WEB_TOKEN="$web_token")
    ( while sleep 3; do
        "$PY" -c 'import sys, urllib.request; sys.stdout.write(urllib.request.urlopen(urllib.request.Request(sys.argv[1], headers={"Authorization": "token " + sys.argv[2]}), timeout=2).read().decode())' \
          "http://127.0.0.1:$web_port/snapshot.json" "$web_token" >"$WORK/web.tmp" 2>/dev/null \
          && grep -q '"mode"' "$WORK/web.tmp" && mv "$WORK/web.tmp" "$WORK/web.json"
      done ) & WEB_PID=$!
  fi
  events_start "$PROJECT" "$WORK/events-$run.txt"
  t=$(now)
  set +e
  SKYNET_RUN="$name" timeout 600 "${profiles[@]}" docker-compose -p "$PROJECT" "${env[@]}" up --no-color \
    --exit-code-from gcs >"$WORK/up-$run.log" 2>&1
  rc=$?
  set -e
  [ -n "$WEB_PID" ] && { kill "$WEB_PID" 2>/dev/null; wait "$WEB_PID" 2>/dev/null || true; WEB_PID=""; }
  if [ "$run" = mavlink ]; then
    for pid in "${aps[@]}"; do kill "$pid" 2>/dev/null; wait "$pid" 2>/dev/null || true; done
    unset SKYNET_SPEED SKYNET_MAVLINK_ARGS SKYNET_UAV1_MAVLINK_PORT SKYNET_UAV2_MAVLINK_PORT SKYNET_UAV3_MAVLINK_PORT
    for u in 1 2 3; do  # each edge flew its own autopilot, from the home that autopilot reported
      grep -Eq "uav${u}_1 +\| .*UAV ${u}: home from the autopilot" "$WORK/up-$run.log" \
        || { log "FAIL: $run: uav$u did not take its home from its autopilot"; failed=1; }
    done
  fi
  UP_S[$run]=$(since "$t")
  kill "$STATS_PID" 2>/dev/null; wait "$STATS_PID" 2>/dev/null || true; STATS_PID=""
  log "$run: phases: $(up_phases "$WORK/events-$run.txt" "$t")"
  t=$(now)
  "${profiles[@]}" docker-compose -p "$PROJECT" "${env[@]}" down -v --remove-orphans --timeout 5 >/dev/null 2>&1
  down_s=$(since "$t")
  log "$run: up --exit-code-from gcs exited $rc after ${UP_S[$run]} s; down ${down_s} s"
  awk '{ n[$1]++; c[$1] += $2 + 0; m = $3; sub(/MiB/, "", m); if (m ~ /GiB/) { sub(/GiB/, "", m); m *= 1024 }
         if (m + 0 > mx[$1]) mx[$1] = m + 0 }
       END { for (k in n) printf "compose-e2e:   %-28s cpu mean %5.1f %%  mem max %6.1f MiB\n", k, c[k] / n[k], mx[k] }' \
    "$WORK/stats-$run.txt" | sort
  cp "$WORK/stats-$run.txt" "$OUT/compose-e2e-stats-$run.txt"
  if [ "$rc" != 0 ]; then
    rm -rf "$OUT/compose-e2e-$run-report"; mkdir -p "$OUT/compose-e2e-$run-report"  # the failed run's report too
    cp "$REPORTS/$name"/report.json "$REPORTS/$name"/report.md "$OUT/compose-e2e-$run-report/" 2>/dev/null || true
    grep -v "^\s*$" "$WORK/up-$run.log" | tail -n 60; log "FAIL: $run: the mission's exit status is $rc"; failed=1; continue
  fi
  if ! "$PY" scripts/compose_check.py "$REPORTS/$name" "${check[@]}" --json "$OUT/compose-e2e-$run.json"; then
    log "FAIL: $run: the report"; failed=1
  fi
  # the report folder and its files belong to the owner of the reports folder, not to root
  owner="$(stat -c %u "$REPORTS")"; got="$(stat -c %u "$REPORTS/$name" "$REPORTS/$name/report.json" | sort -u)"
  [ "$owner" = "$got" ] || { log "FAIL: $run: report owned by uid $got, the reports folder by uid $owner"; failed=1; }
  # secure by default: every edge ran mutual TLS with the certificate ACL and verified signed commands
  uavs="1 2 3"; [ "$run" = sites ] && uavs="1 2 3 4 5 6"
  for u in $uavs; do
    { grep -E "uav${u}_1 +\| .*trust: commands signed by gcs" "$WORK/up-$run.log" >/dev/null \
      && grep -E "uav${u}_1 +\| .*mutual TLS as uav${u}, ACL by certificate" "$WORK/up-$run.log" >/dev/null; } \
      || { log "FAIL: $run: uav$u did not log mutual TLS + ACL + signed commands"; failed=1; }
  done
  if [ "$run" = netem ]; then
    # the SkyNet link uav1-uav2 ran through its side-car: traffic entered both proxies from UAV 2's side
    for port in 7447 7448; do
      grep -E "netem side-car uav1-uav2: .*tcp 0\.0\.0\.0:${port}->.* up: in [1-9]" "$WORK/up-$run.log" >/dev/null \
        || { log "FAIL: $run: no traffic through the SkyNet side-car's tcp:$port"; failed=1; }
    done
    grep -E "netem side-car uav1-uav2: .*up: in" "$WORK/up-$run.log" | tail -n 2 | sed 's/^/compose-e2e:   /'
    # the web page, on 127.0.0.1, showed the three UAVs (heard over TLS with the gcs certificate)
    if [ -s "$WORK/web.json" ] && "$PY" -c 'import json, sys; d = json.load(open(sys.argv[1]))
u = d["uavs"]; print("compose-e2e:   web page: UAVs", sorted(u), "modes", [u[k].get("mode") for k in sorted(u)])
sys.exit(0 if {"1", "2", "3"} <= set(u) and all("mode" in u[k] for k in ("1", "2", "3")) else 1)' "$WORK/web.json"; then :
    else log "FAIL: $run: the web page on 127.0.0.1:$web_port showed no fleet"; failed=1; fi
  fi
  rm -rf "$OUT/compose-e2e-$run-report"; mkdir -p "$OUT/compose-e2e-$run-report"
  cp "$REPORTS/$name"/report.json "$REPORTS/$name"/record.json "$OUT/compose-e2e-$run-report/" 2>/dev/null || true
done

[ -n "$PROBED" ] || probe_gateway
compose down -v --remove-orphans --timeout 5 >/dev/null 2>&1 || true

# nothing of the project may be left
left_c="$("$DOCKER" ps -aq --filter "name=^$PROJECT" | wc -l)"
left_n="$("$DOCKER" network ls -q --filter "name=^$PROJECT" | wc -l)"
if [ "$left_c" != 0 ] || [ "$left_n" != 0 ]; then
  log "FAIL: down left $left_c containers and $left_n networks"; failed=1
fi
"$DOCKER" image prune -f >/dev/null 2>&1 || true   # the previous build's dangling layers, not the cache in use

ups="{}"
for k in "${!UP_S[@]}"; do ups=$(echo "$ups" | "$PY" -c "import json,sys; d=json.load(sys.stdin); d['$k']=${UP_S[$k]}; print(json.dumps(d))"); done
cat >"$OUT/compose-e2e.json" <<JSON
{"base_image": "$BASE_IMAGE", "base_s": $base_s, "image_mb": $image_mb, "build_s": $build_s,
 "build_steps": $steps, "build_steps_cached": $cached, "up_to_verdict_s": $ups, "ok": $([ "$failed" = 0 ] && echo true || echo false)}
JSON
log "figures in bench/results/compose-e2e*.json"
if [ "$failed" != 0 ]; then log "FAILED"; exit 1; fi
log "passed"
