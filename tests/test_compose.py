"""docker compose: the compose files, overrides and image recipe.

The real thing (an engine, a build, `up --exit-code-from gcs`, the report) is scripts/compose-e2e.sh,
which .ci/run runs; these tests check the files without an engine: Debian's docker-compose validates
every file and override, every service runs a skynet command its own parser accepts, and the
overrides cannot drift from the base file.
"""

import importlib
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from protocol.links import LINK_LEASE_S
from services.cli import COMMANDS
from services.netem.model import Impairment
from services.netem.sidecar import build_parser as sidecar_parser

ROOT = Path(__file__).resolve().parents[1]
COMPOSE = ROOT / "docker-compose.yml"
EDGE_ENV = {"SKYNET_UAV": "2", "SKYNET_GATEWAY": "ground"}  # compose/edge.yml's mandatory variables

#: (compose arguments, extra environment) of every documented way to run compose
VARIANTS = [
    ([], {}),
    (["--profile", "netem"], {}),
    (["--profile", "tc-netem"], {}),
    (["--env-file", "compose/netem.env"], {}),
    (["--env-file", "compose/realtime.env"], {}),
    (["-f", "docker-compose.yml", "-f", "compose/ports.yml"], {}),
    (["-f", "docker-compose.yml", "-f", "compose/mavlink.yml"], {}),
    (["-f", "docker-compose.yml", "-f", "compose/mavlink.yml"], {
        "SKYNET_UAV2_MAVLINK": "tcp:host.docker.internal:5770", "SKYNET_UAV3_MAVLINK": "/dev/ttyACM0,921600",
        "SKYNET_MAVLINK_ARGS": "--home-from-autopilot --flight auto"}),
    (["-f", "docker-compose.yml", "-f", "compose/camera.yml"], {}),
    (["-f", "docker-compose.yml", "-f", "compose/insecure.yml"], {}),
    (["-f", "docker-compose.yml", "-f", "compose/insecure.yml", "--env-file", "compose/netem.env"], {}),
    (["--profile", "web"], {}),
    (["-f", "docker-compose.yml", "-f", "compose/video.yml"], {}),
    (["-f", "docker-compose.yml", "-f", "compose/sites.yml"], {}),
    ([], {"SKYNET_FRAME_SIZE": "4000x3000"}),
    (["-f", "compose/ground.yml"], {}),
    (["-f", "compose/ground.yml"], {"SKYNET_BIND": "10.0.0.5", "SKYNET_SANS": "uav1=10.0.0.6 uav2=10.0.0.7,uav2.example"}),
    (["-f", "compose/edge.yml"], EDGE_ENV),
    (["-f", "compose/edge.yml"], EDGE_ENV | {"SKYNET_PEERS": "tls/10.0.0.6:7447?rel=1 tls/10.0.0.6:7448?rel=0",
                                            "SKYNET_BIND": "10.0.0.7"}),
]

needs_compose = pytest.mark.skipif(shutil.which("docker-compose") is None,
                                   reason="Debian's docker-compose is not installed (apt-get install docker-compose); "
                                          ".ci/run installs it")


def _load(path: Path) -> dict:
    return yaml.safe_load(path.read_text())


def _services(path: Path = COMPOSE) -> dict:
    return _load(path)["services"]


def _defaults(text: str) -> str:
    """Compose interpolation with every variable at its default (``${X:-d}`` → d, ``$$`` → ``$``)."""
    text = re.sub(r"\$\{[A-Z0-9_]+:-([^}]*)\}", r"\1", text)
    return text.replace("$$", "$")


def _env(extra: dict[str, str]) -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if not k.startswith(("SKYNET_", "NETEM", "COMPOSE_"))} | extra


@pytest.mark.docker
@needs_compose
def test_every_compose_variant_validates():
    """`docker-compose config` of every variant, run side by side (each takes a second or two)."""
    procs = [(args, subprocess.Popen(["docker-compose", *args, "config", "-q"], stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, cwd=ROOT, env=_env(env)))
             for args, env in VARIANTS]
    for args, proc in procs:
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, f"docker-compose {' '.join(args)} config: {err}"


@pytest.mark.docker
@needs_compose
def test_a_split_edge_without_its_endpoints_is_refused():
    out = subprocess.run(["docker-compose", "-f", "compose/edge.yml", "config", "-q"], capture_output=True,
                         text=True, cwd=ROOT, env=_env({}))
    assert out.returncode != 0 and "SKYNET_UAV" in out.stderr


def _skynet_argv(name: str, svc: dict) -> list[str] | None:
    """The skynet command line a service runs (None for a side-car that runs no skynet command)."""
    entry = svc.get("entrypoint")
    cmd = [_defaults(c) for c in svc["command"]]
    if entry is None:
        return cmd
    if entry[:2] == ["sh", "-c"]:
        script = cmd[0]
        part = next((p for p in script.split(";") if "skynet " in p), None)
        if part is None:
            return None
        # the shell's own variables at typical values
        part = re.sub(r"\$\{?SKYNET_(SPEED)\}?", "4", part)
        part = re.sub(r"\$\{?SKYNET_(UAVS|UAV)\}?", "2", part)
        part = re.sub(r"\$\{?SKYNET_(APPEAR_TIMEOUT)\}?", "60", part)
        part = re.sub(r"\$\{?SKYNET_(FLEET)\}?", "demo", part)
        part = re.sub(r"\$\{?SKYNET_(GATEWAY)\}?", "ground", part)
        part = re.sub(r"\$\{?SKYNET_(HOME)\}?", "0,0,0", part)
        part = re.sub(r"\$\{?SKYNET_(CAMERA)\}?", "synthetic", part)
        part = re.sub(r"\$\{?SKYNET_(FRAME_SIZE)\}?", "640x480", part)
        part = re.sub(r"\$\{?[A-Za-z_]+\}?", "", part)  # the rest: empty (extra args, peers, the run name)
        argv = shlex.split(part.strip().removeprefix("exec "))
        assert argv[0] == "skynet", f"{name}: {argv}"
        return argv[1:]
    return None


@pytest.mark.parametrize("path", ["docker-compose.yml", "compose/mavlink.yml", "compose/camera.yml", "compose/insecure.yml",
                                  "compose/ground.yml", "compose/edge.yml", "compose/sites.yml"])
def test_every_service_runs_a_skynet_command_that_parses(path):
    services = _services(ROOT / path)
    base = _services() if path in ("compose/mavlink.yml", "compose/camera.yml", "compose/insecure.yml",
                                   "compose/sites.yml") else {}
    for name, svc in services.items():
        if "command" not in svc:
            continue
        svc = {**base.get(name, {}), **svc}  # an override keeps the base file's entrypoint
        argv = _skynet_argv(name, svc)
        if argv is None:
            continue
        assert argv[0] in COMMANDS, f"{name}: {argv[0]} is not a skynet command"
        module = importlib.import_module(COMMANDS[argv[0]][0])  # the service's own parser accepts them
        module.build_parser().parse_args(argv[1:])


def test_the_base_network_and_its_gcs():
    services = _services()
    assert {"gateway", "uav1", "uav2", "uav3", "planner", "detector", "gcs"} <= set(services)
    gcs = services["gcs"]
    assert gcs["restart"] == "no" and "/reports" in gcs["volumes"][0]
    script = gcs["command"][0]
    assert "chown" in script and "stat -c %u:%g /reports" in script  # the report belongs to ./reports' owner
    assert "exit $$rc" in script                                     # ... and the mission's verdict is gcs's exit
    # gcs starts when the others are up (health checks), every long-running service restarts on failure
    assert set(gcs["depends_on"]) == {"uav1", "uav2", "uav3", "planner", "detector"}
    for name in ("gateway", "uav1", "uav2", "uav3", "planner", "detector"):
        assert "healthcheck" in services[name] and services[name]["restart"] == "on-failure", name
    # one image, built once (by the gateway)
    assert [n for n, s in services.items() if "build" in s] == ["gateway"]
    assert len({s["image"] for s in services.values()}) == 1


def test_no_port_is_published_unless_asked_and_then_on_localhost():
    services = _services()
    # only the optional web page (profile web) publishes, on 127.0.0.1
    assert [n for n, s in services.items() if "ports" in s] == ["web"] and services["web"]["profiles"] == ["web"]
    assert all(_defaults(p).startswith("127.0.0.1:") for p in services["web"]["ports"])
    ports = _services(ROOT / "compose/ports.yml")["gateway"]["ports"]
    assert ports and all(_defaults(p).startswith("127.0.0.1:") for p in ports)
    for path in ("compose/ground.yml", "compose/edge.yml", "compose/mavlink.yml", "compose/video.yml"):
        for svc in _services(ROOT / path).values():
            assert all(_defaults(p).startswith("127.0.0.1:") for p in svc.get("ports", [])), path


def test_netem_profile_is_a_user_space_side_car_that_fails_loudly():
    services = _services()
    env = dict(line.split("=", 1) for line in (ROOT / "compose/netem.env").read_text().splitlines()
               if line and not line.startswith("#"))
    assert "netem" in env["COMPOSE_PROFILES"].split(",")
    side = services["netem-uav2"]
    assert "netem" in side["profiles"] and side["restart"] == "no"
    assert side["entrypoint"] == ["python", "-m", "services.netem.sidecar"]
    args = sidecar_parser().parse_args([_defaults(c) for c in side["command"]])
    assert args.expect > 0  # an unused side-car ends the run
    assert not Impairment.parse(args.impair).is_null and not Impairment.parse(env["NETEM_UAV2"]).is_null
    # the env file points UAV 2 at its side-car, on both links of the TLS pair (both TCP: two TCP proxies)
    assert env["SKYNET_UAV2_UPLINK"] == "netem-uav2"
    uav2 = " ".join(services["uav2"]["command"])
    assert "tls/${SKYNET_UAV2_UPLINK:-gateway}:7447?rel=1" in uav2 and "tls/${SKYNET_UAV2_UPLINK:-gateway}:7448?rel=0" in uav2
    assert len(args.tcp) == 2 and not args.udp
    # ... and its SkyNet link to UAV 1 at the SkyNet side-car, which forwards to UAV 1's listeners
    assert env["SKYNET_UAV2_UAV1"] == "netem-uav1-uav2" and "netem" in services["netem-uav1-uav2"]["profiles"]
    assert "tls/${SKYNET_UAV2_UAV1:-uav1}:7447?rel=1" in uav2 and "tls/${SKYNET_UAV2_UAV1:-uav1}:7448?rel=0" in uav2
    sky = sidecar_parser().parse_args([_defaults(c) for c in services["netem-uav1-uav2"]["command"]])
    assert sky.tcp == ["0.0.0.0:7447=uav1:7447", "0.0.0.0:7448=uav1:7448"] and sky.expect > 0
    assert not Impairment.parse(env["NETEM_UAV1_UAV2"]).is_null
    # every side-car's name is a SAN of a new key set (a dialler checks the name it dialled)
    hosts = services["keys"]["command"]
    for name in ("netem-uav1", "netem-uav2", "netem-uav3", "netem-uav1-uav2"):
        assert name in services and name in hosts, name
    # the kernel variant exits non-zero where tc netem cannot be applied (and so ends `up --exit-code-from`)
    tc = services["tc-netem-uav2"]
    assert "NET_ADMIN" in tc["cap_add"] and tc["network_mode"] == "service:uav2"
    assert "exit 2" in tc["command"][0] and tc["restart"] == "no"


def _drop(argv: list[str], options: set[str]) -> list[str]:
    out, skip = [], False
    for a in argv:
        if skip:
            skip = False
        elif a in options:
            skip = True
        else:
            out.append(a)
    return out


@pytest.mark.parametrize("path,changed", [("compose/mavlink.yml", {"--vehicle", "--mavlink", "--speed", "--camera"}),
                                          ("compose/camera.yml", {"--camera"})])
def test_overrides_change_only_what_they_say(path, changed):
    base, over = _services(), _services(ROOT / path)
    for name, svc in over.items():
        if "command" in svc:
            argv = _skynet_argv(name, {**base[name], **svc})
            assert _drop(argv, changed) == _drop(_skynet_argv(name, base[name]), changed), f"{path}: {name}"


def _interpolated(text: str, env: dict[str, str]) -> str:
    """Compose interpolation with ``env`` (``${X:-d}``: env's X, else d)."""
    return re.sub(r"\$\{([A-Z0-9_]+):-([^}]*)\}", lambda m: env.get(m.group(1), m.group(2)), text).replace("$$", "$")


def test_the_mavlink_override_gives_every_uav_its_own_autopilot_endpoint():
    """compose/mavlink.yml: each edge flies the autopilot at its own ``SKYNET_UAVn_MAVLINK`` (default: listening on
    UDP 14550 in its container, published on the host's 14550/14551/14552), with ``SKYNET_MAVLINK_ARGS`` added;
    the edges and the ground station run in real time unless told otherwise."""
    from edge.board import build_parser as edge_parser

    over = _services(ROOT / "compose/mavlink.yml")
    assert {"uav1", "uav2", "uav3"} <= set(over)
    host_ports = [_defaults(over[f"uav{u}"]["ports"][0]) for u in (1, 2, 3)]
    assert host_ports == [f"127.0.0.1:{14549 + u}:14550/udp" for u in (1, 2, 3)]
    env = {"SKYNET_UAV1_MAVLINK": "udpin:0.0.0.0:14550", "SKYNET_UAV2_MAVLINK": "tcp:host.docker.internal:5770",
           "SKYNET_UAV3_MAVLINK": "/dev/ttyACM0,921600", "SKYNET_MAVLINK_ARGS": "--home-from-autopilot --flight auto"}
    for u in (1, 2, 3):
        svc = over[f"uav{u}"]
        assert "host.docker.internal:host-gateway" in svc["extra_hosts"]  # SITL's TCP port on the host
        for given, mavlink, extra in (({}, "udpin:0.0.0.0:14550", False), (env, env[f"SKYNET_UAV{u}_MAVLINK"], True)):
            script = _interpolated(svc["command"][0], given)
            argv = shlex.split(script.removeprefix("exec skynet "))
            a = edge_parser().parse_args(argv[1:])
            assert (argv[0], a.uav, a.vehicle, a.mavlink, a.speed) == ("edge", u, "mavlink", mavlink, 1.0)
            assert (a.home_from_autopilot, a.flight) == ((True, "auto") if extra else (False, "guided"))
    assert _defaults(over["gcs"]["environment"]["SKYNET_SPEED"]) == "1"


def test_image_builds_from_any_python_base_with_its_own_venv():
    docker = (ROOT / "Dockerfile").read_text()
    lines = [x for x in docker.splitlines() if x and not x.startswith("#")]
    assert lines[0].startswith("ARG BASE_IMAGE=python:3.11-slim") and lines[1] == "FROM ${BASE_IMAGE}"
    assert "python3 -m venv" in docker and "VIRTUAL_ENV=/opt/skynet" in docker  # PEP 668 bases too
    # dependencies (every service extra) in a layer before the code; the font cache made at build time
    assert docker.index("pip install -r") < docker.index("COPY services")
    assert "ARG EXTRAS=mavlink" in docker and "matplotlib.pyplot" in docker
    ignore = (ROOT / ".dockerignore").read_text().splitlines()
    assert ignore[ignore.index("*")] == "*" and "!services/" in ignore  # an allow-list: no .venv, reports, .git


def test_compose_check_reads_a_real_report(tmp_path):
    """scripts/compose_check.py (the e2e's assertions) on the report test's record: its failures are named."""
    sys.path.insert(0, str(ROOT / "scripts"))
    try:
        check = importlib.import_module("compose_check")
    finally:
        sys.path.pop(0)
    from services.gcs.report import write_report
    from tests.services.gcs.test_report import build_record

    rec = build_record()
    write_report(rec, tmp_path)
    assert check.main([str(tmp_path)]) == 1  # the record's mission failed (UAV 3 stopped half-way)
    report = json.loads((tmp_path / "report.json").read_text())
    record = json.loads((tmp_path / "record.json").read_text())
    fails, figures = check.check(report, record, impaired="uav2", delay_ms=100)
    assert any("mission failed" in f for f in fails) and any("impairment not applied" in f for f in fails)
    assert set(figures["telemetry_age_ms"]) == {1, 2, 3}


SKYNET_NODES = ("gateway", "uav1", "uav2", "uav3", "planner", "detector")


def _endpoints(argv: list[str]) -> list[str]:
    return [argv[i + 1] for i, a in enumerate(argv) if a in ("--connect", "--listen")]


def test_secure_by_default_keys_read_only_tls_everywhere():
    """a key set made or reused first, mounted read-only, --keys and tls/ endpoints everywhere."""
    from services.composekeys import build_parser as keys_parser

    services = _services()
    keys = services["keys"]
    # it makes or checks the set, then idles, healthy (a one-shot's exit would end `up --exit-code-from gcs`)
    assert keys["restart"] == "no" and keys["entrypoint"][:2] == ["sh", "-c"]
    assert keys["entrypoint"][2].startswith('python -m services.composekeys "$$@" && touch /tmp/keys-ready')
    assert keys["healthcheck"]["test"] == ["CMD", "test", "-f", "/tmp/keys-ready"]
    ka = keys_parser().parse_args(keys["command"])
    assert str(ka.dir) == "/keys" and ka.uavs == 3
    assert _defaults(keys["volumes"][0]) == "./.keys/compose:/keys"  # the only writable mount of the set
    for name, svc in services.items():
        mounts = [_defaults(v) for v in svc.get("volumes", [])]
        if name == "keys" or name.startswith(("netem-", "tc-netem")):
            continue
        assert "./.keys/compose:/keys:ro" in mounts, name
        argv = _skynet_argv(name, svc)
        ends = _endpoints(argv)
        assert ends and all(e.startswith("tls/") for e in ends), (name, ends)
        assert {e.rsplit("?", 1)[1] for e in ends} == {"rel=1", "rel=0"}, name  # both reliability classes
        assert argv[argv.index("--keys") + 1] == "/keys", name  # its own identity of the key set
        assert not any("/keys/" in a for a in argv), (name, argv)  # never another role's certificate
        seen, todo = set(), [name]  # it starts after the keys service (directly or through what it waits for)
        while todo:
            for dep in services[todo.pop()].get("depends_on", {}):
                if dep not in seen:
                    seen.add(dep)
                    todo.append(dep)
        assert "keys" in seen, name
    assert services["gateway"]["depends_on"]["keys"]["condition"] == "service_healthy"
    for u in (1, 2, 3):  # the replay window in a writable volume of the edge's own
        svc = services[f"uav{u}"]
        argv = svc["command"]
        assert argv[argv.index("--replay-state") + 1] == "/state/replay.json"
        assert f"uav{u}-state:/state" in svc["volumes"] and services["uav1"]["depends_on"]["keys"]
    assert set(_load(COMPOSE)["volumes"]) == {"uav1-state", "uav2-state", "uav3-state"}


def _insecure(argv: list[str], edge: bool) -> list[str]:
    """The secure base command made insecure: no --keys/--replay-state, TCP + UDP instead of the TLS pair."""
    out, skip = [], 0
    for a in argv:
        if skip:
            skip -= 1
        elif a in ("--keys", "--replay-state"):
            skip = 1
        else:
            out.append(("tcp/" if a.endswith("rel=1") else "udp/") + a[4:] if a.startswith("tls/") else a)
    if edge:
        out.insert(out.index("--mode") + 2, "--insecure")
    return out


def test_the_insecure_override_changes_only_the_trust_and_says_so():
    base, over = _services(), _services(ROOT / "compose/insecure.yml")
    for name in SKYNET_NODES:
        assert over[name]["command"] == _insecure(base[name]["command"], name.startswith("uav")), name
    gcs = over["gcs"]["command"][0]
    assert "--keys" not in gcs and "tls/" not in gcs and "SKYNET_BANNER" in gcs
    assert "INSECURE" in over["gcs"]["environment"]["SKYNET_BANNER"]
    assert "INSECURE" in over["keys"]["environment"]["SKYNET_BANNER"] and "BANNER" in over["keys"]["entrypoint"][2]
    for name in ("netem-uav1", "netem-uav2", "netem-uav3", "netem-uav1-uav2"):  # the UDP class back on UDP
        args = sidecar_parser().parse_args([_defaults(c) for c in over[name]["command"]])
        assert len(args.tcp) == 1 and len(args.udp) == 1, name
    web = over["web"]["command"]
    assert "--cfg" not in web and all(not e.startswith("tls/") for e in _endpoints(web))


def test_the_split_over_hosts_files_are_secure_by_default_with_the_hosts_addresses_as_sans():
    """compose/ground.yml makes (or reuses) a key set whose gateway certificate names SKYNET_BIND and whose
    certificates name what SKYNET_SANS adds; it and compose/edge.yml mount it read-only and run TLS only."""
    from services.composekeys import build_parser as keys_parser
    from services.keys import parse_sans

    ground, edge = _services(ROOT / "compose/ground.yml"), _services(ROOT / "compose/edge.yml")["edge"]
    keys = ground["keys"]
    ka = keys_parser().parse_args([_defaults(c) for c in keys["command"]])
    assert str(ka.dir) == "/keys" and "gateway=${SKYNET_BIND:-127.0.0.1}" in keys["command"]
    assert "${SKYNET_SANS:-}" in keys["command"] and parse_sans(ka.san) == {"gateway": ("127.0.0.1",)}
    assert _defaults(keys["volumes"][0]) == "../.keys/split:/keys"  # the only writable mount of the set
    for name in ("gateway", "planner", "detector", "gcs"):
        svc = ground[name]
        assert "../.keys/split:/keys:ro" in [_defaults(v) for v in svc.get("volumes", [])] or (
            name != "gcs" and "volumes" not in svc), name
        argv = _skynet_argv(name, svc)
        ends = _endpoints(argv)
        assert ends and all(e.startswith("tls/") for e in ends), (name, ends)
        assert {e.rsplit("?", 1)[1] for e in ends} == {"rel=1", "rel=0"} and argv[argv.index("--keys") + 1] == "/keys"
        assert float(argv[argv.index("--lease-s") + 1]) == LINK_LEASE_S, name  # the edges' lease on both ends
    # the anchor's read-only mount reaches every service that does not list its own volumes
    anchor = _load(ROOT / "compose/ground.yml")["x-skynet"]["volumes"]
    assert [_defaults(v) for v in anchor] == ["../.keys/split:/keys:ro"]
    assert ground["gateway"]["depends_on"]["keys"]["condition"] == "service_healthy"
    assert all(_defaults(p).endswith("/tcp") for p in ground["gateway"]["ports"])  # both links of the pair: TCP
    # the edge: TLS to the gateway and its peers, the ACL by certificate, the replay window, no gossip links
    argv = _skynet_argv("edge", edge)
    assert all(e.startswith("tls/") for e in _endpoints(argv)) and argv[argv.index("--keys") + 1] == "/keys"
    assert "--replay-state" in argv and "--uavs" in argv and float(argv[argv.index("--lease-s") + 1]) == LINK_LEASE_S
    assert "scouting/gossip/autoconnect:{router:[],peer:[]}" in argv
    assert [_defaults(v) for v in edge["volumes"]] == ["../.keys/split:/keys:ro", "edge-state:/state"]
    assert all(_defaults(p).endswith("/tcp") for p in edge["ports"])


def test_the_sites_override_is_the_launchers_two_site_layout():
    """compose/sites.yml is `skynet mission --uavs 6 --sites 2 --rcu-site detector=1` in containers: each UAV on
    its formation's site's gateway (services.orchestration.sites), gateway-1 dialling gateway, the homes of the
    launcher, a six-UAV key set naming gateway-1, the ground station flying six, the detector at site 1."""
    from protocol.scenario import load_scenario
    from services.orchestration.plan import homes as launch_points
    from services.orchestration.sites import gateway_process, site_of_uav

    over = _services(ROOT / "compose/sites.yml")
    homes = launch_points(load_scenario(None), 6)

    def dialled(cmd):
        return {_defaults(c).split("/")[1].split(":")[0] for k, c in zip(cmd, cmd[1:]) if k == "--connect"}

    base = _services()
    for u in range(1, 7):
        cmd = (over.get(f"uav{u}") or base[f"uav{u}"])["command"]
        gateways = dialled(cmd) & {"gateway", "gateway-1"}
        assert gateways == {gateway_process(site_of_uav(u, 2))}, (u, gateways)
        home = [float(x) for x in cmd[cmd.index("--home") + 1].split(",")]
        assert home == pytest.approx(list(homes[u - 1]), abs=0.06), u
        mates = dialled(cmd) - {"gateway", "gateway-1"}
        assert mates == {f"uav{v}" for v in range(3 * ((u - 1) // 3) + 1, u)}, (u, mates)  # its formation only
    assert dialled(over["gateway-1"]["command"]) == {"gateway"}
    assert over["gateway-1"]["command"][1:3] == ["--id", "gw1"] and over["gateway"]["command"][1:3] == ["--id", "gw0"]
    keys = over["keys"]["command"]
    assert keys[keys.index("--uavs") + 1] == "6" and "gateway-1" in keys
    assert over["gcs"]["environment"]["SKYNET_GCS_ARGS"].startswith("--uavs 6")
    assert dialled(over["detector"]["command"]) == {"gateway-1"}
    assert {"uav4", "uav5", "uav6"} <= set(over["gcs"]["depends_on"])


@pytest.mark.parametrize("path", ["docker-compose.yml", "compose/camera.yml", "compose/insecure.yml", "compose/mavlink.yml",
                                  "compose/sites.yml", "compose/edge.yml"])
def test_every_edge_takes_the_frame_size_from_skynet_frame_size(path):
    """``SKYNET_FRAME_SIZE=4000x3000`` gives every edge of every file the paper's 12 MP frames (capture
    frames above 1 MP then go on the reliable link: the edge's --capture-link auto); the default is 640x480."""
    edges = {n: s for n, s in _services(ROOT / path).items() if n.startswith("uav") or n == "edge"}
    assert edges
    for name, svc in edges.items():
        text = " ".join(svc["command"])
        if "$${SKYNET_FRAME_SIZE}" in text:  # compose/edge.yml's shell form
            assert svc["environment"]["SKYNET_FRAME_SIZE"] == "${SKYNET_FRAME_SIZE:-640x480}", name
        elif len(svc["command"]) == 1:  # compose/mavlink.yml's shell form, interpolated by compose
            assert '--frame-size "${SKYNET_FRAME_SIZE:-640x480}"' in text, (path, name)
        else:
            cmd = svc["command"]
            assert cmd[cmd.index("--frame-size") + 1] == "${SKYNET_FRAME_SIZE:-640x480}", (path, name)


def test_web_and_video_containers_run_as_their_own_identities():
    """``skynet web`` and ``skynet video`` read the fleet as the key set's ``web`` and ``video`` identities (the
    ACL's read-only subjects), not with the ground station's certificate: ``--keys /keys`` and the service's role
    (protocol.bus.config_from_args) pick ``/keys/web`` and ``/keys/video``."""
    from protocol.acl import ATTACHED_ROLES
    from services.keys import roles

    web = _services()["web"]
    video = _services(ROOT / "compose/video.yml")["video"]
    for role, svc in (("web", web), ("video", video)):
        argv = [_defaults(c) for c in svc["command"]]
        assert argv[0] == role and argv[argv.index("--keys") + 1] == "/keys", argv
        assert not any("gcs" in a for a in argv) and "--cfg" not in argv, argv
        assert "./.keys/compose:/keys:ro" in [_defaults(v) for v in svc["volumes"]]
        assert role in ATTACHED_ROLES and role in roles(3)  # the key set a compose run makes has that identity


def test_every_ground_node_has_the_edges_link_lease():
    """The base file's gateway, planner, detector and ground station run with the one link lease
    (protocol.links.LINK_LEASE_S) the edges have by default: equal leases on both ends of every link."""
    services = _services()
    for name in ("gateway", "planner", "detector", "gcs"):
        argv = _skynet_argv(name, services[name])
        assert float(argv[argv.index("--lease-s") + 1]) == LINK_LEASE_S, name


def test_the_base_files_homes_are_the_launchers():
    """Each edge of the base file launches where ``skynet mission`` launches it: the default scenario's formation
    offsets around its start (services.orchestration.plan.homes)."""
    from protocol.scenario import load_scenario
    from services.orchestration.plan import homes as launch_points

    services = _services()
    for u, home in enumerate(launch_points(load_scenario(None), 3), start=1):
        cmd = services[f"uav{u}"]["command"]
        assert [float(x) for x in cmd[cmd.index("--home") + 1].split(",")] == pytest.approx(list(home), abs=0.06), u

