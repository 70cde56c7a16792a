"""services.orchestration.plan: the network of a launcher run as data, without a process, socket or session;
and ``skynet up|mission --dry-run`` printing it through the real command line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from edge.board import build_parser as edge_parser
from protocol.cliconfig import from_namespace
from protocol.links import LINK_LEASE_S
from protocol.scenario import load_scenario
from services.orchestration.launcher import parse
from services.orchestration.plan import CountingPorts, Trust, fleet_offsets, homes, network_plan
from tests.conftest import ROOT

SCENARIO = load_scenario(None)
TRUST = Trust(keys="/keys", tls=True, router_ca="/keys/router-ca.pem")


def plan_of(*argv: str, prog: str = "up", trust: Trust = TRUST, **kw):
    return network_plan(parse(prog, list(argv)), SCENARIO, trust, CountingPorts(7447),
                        ground_station=prog == "mission", epoch=100.0, workdir="/run", **kw)


def arg(argv, flag: str) -> str:
    """The value of ``flag`` in a command line (``--flag=value`` or ``--flag value``)."""
    values = args_of(argv, flag)
    assert values, (flag, argv)
    return values[0]


def args_of(argv, flag: str) -> list[str]:
    argv = list(argv)
    return [*(argv[k + 1] for k, a in enumerate(argv) if a == flag),
            *(a.split("=", 1)[1] for a in argv if a.startswith(flag + "="))]


def test_a_fleet_of_three_on_one_site():
    plan = plan_of()
    assert [p.name for p in plan.processes] == ["gateway", "uav1", "uav2", "uav3", "planner", "detector"]
    assert [p.role for p in plan.processes] == ["gateway", "edge", "edge", "edge", "planner", "detector"]
    assert all(p.site == 0 and p.ready and not p.in_process for p in plan.processes)
    assert [p.identity for p in plan.processes] == ["gateway", "uav1", "uav2", "uav3", "planner", "detector"]
    assert [p.wait for p in plan.processes] == [True] + [False] * 5  # the gateway first, up before the rest
    gw = plan.get("gateway")
    assert gw.listens == ("tls/127.0.0.1:7447?rel=1", "tls/127.0.0.1:7448?rel=0") == tuple(plan.gateway_endpoints)
    assert gw.config.listen == list(gw.listens) and gw.config.keys == "/keys"
    assert gw.config.lease is None  # no proxied link: zenoh's lease on the ground
    router = "#root_ca_certificate_file=/keys/router-ca.pem"
    for i in (1, 2, 3):
        edge = plan.get(f"uav{i}")
        connects = edge.config.connect
        assert connects[:2] == [e + router for e in plan.gateway_endpoints]  # dialled trusting the router CA only
        mates = [plan.get(f"uav{j}").listens for j in range(i + 1, 4)]
        assert connects[2:] == [e for ends in mates for e in ends]  # every later edge of its formation, no proxy
        assert edge.config.listen == list(edge.listens) and edge.config.mode == "peer"
        assert edge.config.epoch == 100.0 and edge.config.seed == i
        parsed = edge_parser().parse_args(list(edge.argv[1:]))  # the edge's own parser takes the whole line
        assert parsed.uav == i and parsed.keys == "/keys" and parsed.connect == connects
    for name in ("planner", "detector"):
        p = plan.get(name)
        assert p.listens == () and p.config.mode == "client"
        assert p.config.connect == [e + router for e in plan.gateway_endpoints] == list(p.connects)
    ports = [e for p in plan.processes for e in p.listens]
    assert len(ports) == len(set(ports)) == 8 and plan.files == {} and plan.proxies == {}


def test_homes_are_the_scenarios_offsets_and_the_fence_its_box():
    """The launch points come from the scenario's own formation offsets (its three, or offsets_for for other
    fleet sizes), rotated to its start→goal heading; every edge is configured with the scenario's box."""
    plan = plan_of()
    box = SCENARIO.box
    for i, home in enumerate(plan.homes, start=1):
        edge = plan.get(f"uav{i}")
        assert edge.config.home == pytest.approx(home)
        fence = edge_parser().parse_args(list(edge.argv[1:])).geofence
        assert tuple(fence.lo) == tuple(box.lo) and tuple(fence.hi) == tuple(box.hi)
        assert fence.contains(home)
    # a scenario with other offsets moves the homes with them (the launcher no longer has its own)
    wide = SCENARIO.model_copy(update={"formation": SCENARIO.formation.model_copy(
        update={"offsets": [(0.0, 0.0, 2.0), (6.0, 0.0, -1.0), (-6.0, 0.0, -1.0)]})})
    assert fleet_offsets(wide, 3) == [(0.0, 0.0, 2.0), (6.0, 0.0, -1.0), (-6.0, 0.0, -1.0)]
    assert len(fleet_offsets(wide, 5)) == 5  # not one per UAV: the fleet's own table (as the ground station)
    a, b = homes(SCENARIO, 3), homes(wide, 3)
    assert a != b and b[0] == a[0]  # slot 1 is the centroid in both
    spread = [((h[0] - b[0][0]) ** 2 + (h[1] - b[0][1]) ** 2) ** 0.5 for h in b]
    assert spread == pytest.approx([0.0, 6.0, 6.0], abs=1e-3)
    assert all(h[2] == box.lo[2] for h in b)  # on the ground


def test_two_sites():
    plan = plan_of("--uavs", "6", "--sites", "2", "--detectors", "2", "--rcu-site", "detector-1=1", prog="mission")
    names = [p.name for p in plan.processes]
    assert names[:2] == ["gateway", "gateway-1"] and names[-1] == "gcs"
    gcs = plan.get("gcs")
    assert gcs.in_process and not gcs.argv and gcs.identity == "gcs" and gcs.site == 0
    gw0, gw1 = plan.site_endpoints
    g1 = plan.get("gateway-1")
    # dials site 0 on one link (two between routers lose declarations: bench/router_links.py)
    assert g1.config.id == "gw1" and [e.split("#")[0] for e in g1.connects] == gw0[:1]
    assert g1.config.listen == gw1
    for i in range(1, 7):
        edge = plan.get(f"uav{i}")
        assert edge.site == (0 if i <= 3 else 1)
        assert [e.split("#")[0] for e in edge.connects[:2]] == (gw0 if i <= 3 else gw1)
        f = range(1, 4) if i <= 3 else range(4, 7)  # its formation's later edges only
        assert list(edge.connects[2:]) == [e for j in f if j > i for e in plan.get(f"uav{j}").listens]
        assert edge.config.config == f"/run/uav{i}.json5"  # several formations: no gossip autoconnect
    assert plan.get("detector-1").site == 1 and plan.get("detector-0").site == 0
    assert str(plan.get("detector-1").config.partition) == "1/2" and plan.get("detector-1").config.max_uav == 6
    assert set(plan.files) == {f"/run/uav{i}.json5" for i in range(1, 7)}
    assert json.loads(plan.files["/run/uav1.json5"])["scouting"]["gossip"]["autoconnect"] == {"router": [], "peer": []}
    assert plan.topology()[1].endswith("dialling gateway; attached: uav4 uav5 uav6 detector-1")


def test_impair_puts_proxies_on_the_named_link_only():
    plan = plan_of("--impair", "uav2=delay 50ms", prog="mission")
    assert set(plan.proxies) == {"uav2"}
    px = plan.proxies["uav2"]
    assert px.udp_kind == "tcp" and px.impairments == ("delay 50ms", "delay 50ms")  # TLS pair: two TCP proxies
    assert list(px.targets) == [e.split("/", 1)[1].split("?")[0] for e in plan.gateway_endpoints]
    uav2 = plan.get("uav2")
    assert [e.split("#")[0] for e in uav2.connects[:2]] == px.endpoints()  # through its proxies
    assert [e.split("#")[0] for e in plan.get("uav1").connects[:2]] == plan.gateway_endpoints
    # links are proxied: the ground's lease is the edges' (one constant), the clients' open timeout is longer
    assert plan.get("gateway").config.lease == LINK_LEASE_S
    for name in ("planner", "detector"):
        config = plan.get(name).config
        assert config.lease == LINK_LEASE_S and config.cfg[0][0] == "transport/unicast/open_timeout"
    assert "--lease-s" not in " ".join(plan.get("uav1").argv)  # the edges' own default is that constant
    assert edge_parser().get_default("lease") == LINK_LEASE_S  # (the edge config's default is that constant)
    ports = [*px.ports, *(e for p in plan.processes for e in p.listens)]
    assert len(set(ports)) == len(ports)
    # a SkyNet link: the proxied mesh, every formation link through a proxy pair
    mesh = plan_of("--impair", "uav1-uav2=loss 5%")
    assert mesh.checked.mesh == "proxied" and set(mesh.proxies) == {"uav1-uav2", "uav1-uav3", "uav2-uav3"}
    assert mesh.proxies["uav1-uav3"].impairments == (None, None)
    assert list(mesh.get("uav1").connects[2:4]) == mesh.proxies["uav1-uav2"].endpoints()


def test_insecure_has_no_identity_key_set_or_tls():
    plan = plan_of("--insecure", "--web", ":8080", "--video", "h264", trust=Trust())
    assert all(p.identity is None for p in plan.processes)
    assert all(p.config.keys is None for p in plan.processes)
    gw = plan.get("gateway")
    assert gw.listens[0].startswith("tcp/") and gw.listens[1].startswith("udp/")
    assert all("#" not in e for p in plan.processes for e in p.connects)
    web = plan.get("web")
    assert set(web.env) == {"SKYNET_WEB_TOKEN"} and web.config.listen_web == ":8080" and web.config.token is None
    assert plan.get("video").config.codec == "h264"
    shown = json.dumps(plan.to_json())
    assert '"SKYNET_WEB_TOKEN": "***"' in shown


def test_web_and_video_run_as_their_own_identities():
    plan = plan_of("--web", ":8080", "--video", "mjpeg", web_token="t" * 20)
    assert plan.get("web").identity == "web" and plan.get("video").identity == "video"
    assert plan.get("web").env == {"SKYNET_WEB_TOKEN": "t" * 20}
    assert "t" * 20 not in plan.table() and "t" * 20 not in json.dumps(plan.to_json())


def test_autopilot_sim_runs_beside_each_edge():
    plan = plan_of("--vehicle", "mavlink", "--flight", "auto", "--sim-boot-scale", "0.1")
    names = [p.name for p in plan.processes]
    assert names == ["gateway", "ap1", "uav1", "ap2", "uav2", "ap3", "uav3", "planner", "detector"]
    for i in (1, 2, 3):
        ap, edge = plan.get(f"ap{i}"), plan.get(f"uav{i}")
        assert ap.role == "autopilot" and not ap.ready and ap.identity is None  # no bus, not supervised as one
        port = int(ap.listens[0].rsplit(":", 1)[1])
        assert arg(ap.argv, "--port-base") == str(port - i + 1) and arg(ap.argv, "--boot-scale") == "0.1"
        assert tuple(map(float, arg(ap.argv, "--home").split(","))) == edge.config.home
        assert edge.config.mavlink == f"udpin:127.0.0.1:{port}" and edge.config.flight == "auto"


def test_the_sim_autopilots_options_come_from_the_launcher():
    """``--sim-*``: each sim autopilot's command line carries them, and its own parser reads them back."""
    from edge.vehicle.mavsim.cli import build_parser as sim_parser

    plan = plan_of("--vehicle", "mavlink", "--sim-boot-scale", "0.5", "--sim-firmware-version", "4.7",
                   "--sim-legacy-mission-request", "--sim-rc-centred")
    for i in (1, 2, 3):
        args = sim_parser().parse_args(list(plan.get(f"ap{i}").argv[1:]))
        assert (args.uav, args.boot_scale, args.firmware_version) == ([i], 0.5, "4.7")
        assert args.legacy_mission_request and args.rc_centred
        origin = SCENARIO.origin  # HOME_POSITION reckoned from the scenario's own origin (--home-from-autopilot)
        assert args.origin == pytest.approx((origin.lat, origin.lon, origin.alt), abs=1e-9)
    args = sim_parser().parse_args(list(plan_of("--vehicle", "mavlink").get("ap1").argv[1:]))
    assert not args.legacy_mission_request and not args.rc_centred and args.firmware_version == "4.6"


def test_an_autopilot_endpoint_replaces_that_uavs_sim_autopilot():
    """``--autopilot uavN=ENDPOINT`` (implies --vehicle mavlink): that edge's --mavlink is the endpoint, as pymavlink
    writes it, and no sim autopilot is started for it; the other UAVs keep theirs."""
    plan = plan_of("--autopilot", "uav1=serial:/dev/ttyACM0:921600", "--autopilot", "uav3=tcp:10.0.0.3:5760",
                   "--flight", "auto")
    assert [p.name for p in plan.processes] == ["gateway", "uav1", "ap2", "uav2", "uav3", "planner", "detector"]
    edges = {i: plan.get(f"uav{i}").config for i in (1, 2, 3)}
    assert [e.vehicle for e in edges.values()] == ["mavlink"] * 3 and {e.flight for e in edges.values()} == {"auto"}
    assert edges[1].mavlink == "/dev/ttyACM0,921600" and edges[3].mavlink == "tcp:10.0.0.3:5760"
    assert edges[2].mavlink == f"udpin:127.0.0.1:{plan.get('ap2').listens[0].rsplit(':', 1)[1]}"
    assert not any(e.home_from_autopilot for e in edges.values())
    for i in (1, 3):  # the edge's own parser takes the whole line
        parsed = edge_parser().parse_args(list(plan.get(f"uav{i}").argv[1:]))
        assert parsed.mavlink == edges[i].mavlink and parsed.vehicle == "mavlink"
    table = plan.table()
    assert "uav1: its own autopilot at /dev/ttyACM0,921600, auto, home 40,8,0" in table
    assert "uav2: sim autopilot ap2 at udpin:127.0.0.1:" in table
    every = plan_of(*(x for i in (1, 2, 3) for x in ("--autopilot", f"uav{i}=udpin:0.0.0.0:{14549 + i}")),
                    "--home-from-autopilot", prog="mission")
    assert not [p for p in every.processes if p.role == "autopilot"]
    assert [every.get(f"uav{i}").config.mavlink for i in (1, 2, 3)] == [f"udpin:0.0.0.0:{14549 + i}" for i in (1, 2, 3)]
    assert all(every.get(f"uav{i}").config.home_from_autopilot for i in (1, 2, 3))
    assert "uav3: its own autopilot at udpin:0.0.0.0:14552, guided, its autopilot's home" in every.table()
    assert "autopilots" not in plan_of().table()  # the built-in vehicle: no such section
    assert "note: --speed 4 runs the mission's clock at 4x real time" in every.table()  # the launcher's default
    assert "note:" not in plan_of("--autopilot", "uav1=udpin:0.0.0.0:14550", "--speed", "1").table()
    assert "note:" not in plan_of("--vehicle", "mavlink").table()  # sim autopilots keep the mission's speed


@pytest.mark.parametrize("argv, needle", [
    (("--autopilot", "uav4=udpin:0.0.0.0:14550"), "--autopilot uav4: the fleet has UAVs 1..3 (--uavs 3)"),
    (("--autopilot", "uav1=udpin:0.0.0.0:1", "--autopilot", "uav1=udpin:0.0.0.0:2"), "uav1: given twice"),
    (("--autopilot", "uav2=udpin:0.0.0.0"), "--autopilot uav2: endpoint 'udpin:0.0.0.0': expected udpin:HOST:PORT"),
    (("--autopilot", "uav1=/dev/ttyUSB0,12345"), "baud rate '12345'"),
    (("--autopilot", "uav1=udpin:0.0.0.0:1", "--autopilot", "uav2=udpin:0.0.0.0:1"), "uav1's already"),
    (("--home-from-autopilot",), "--home-from-autopilot: only with --vehicle mavlink or --autopilot"),
])
def test_a_bad_autopilot_option_is_a_one_line_error(argv, needle, capsys):
    with pytest.raises(SystemExit) as exc:
        parse("up", ["--dry-run", *argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and needle in err[-1] and "Traceback" not in "\n".join(err)


def test_dry_run_shows_the_autopilot_endpoints(tmp_path):
    proc = _skynet(tmp_path, "mission", "--dry-run", "--json", "--autopilot", "uav2=udpin:0.0.0.0:14551",
                   "--home-from-autopilot", "--out", "r")
    assert proc.returncode == 0, proc.stderr
    by = {p["name"]: p for p in json.loads(proc.stdout)["processes"]}
    assert "ap2" not in by and "ap1" in by and "ap3" in by
    assert by["uav2"]["config"]["mavlink"] == "udpin:0.0.0.0:14551" and by["uav2"]["config"]["home_from_autopilot"]
    proc = _skynet(tmp_path, "up", "--dry-run", "--autopilot", "uav2=udpin:0.0.0.0:99999")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "--autopilot uav2: endpoint 'udpin:0.0.0.0:99999': port '99999' is not in 1..65535" in proc.stderr
    assert list(tmp_path.iterdir()) == []


def test_the_plan_is_pure_and_quick(monkeypatch):
    """No socket, no process: a plan of 48 UAVs on four sites with faults in well under a second."""
    import socket
    import subprocess as sp
    import time

    def refuse(*a, **k):
        raise AssertionError("the plan touched a socket or a process")

    monkeypatch.setattr(socket, "socket", refuse)
    monkeypatch.setattr(sp, "Popen", refuse)
    t0 = time.perf_counter()
    plan = plan_of("--uavs", "48", "--sites", "4", "--fault", "20s kill gateway for 3s", "--impair",
                   "uplinks=delay 20ms", prog="mission")
    took = time.perf_counter() - t0
    assert len([p for p in plan.processes if p.role == "edge"]) == 48
    print(f"plan of 48 UAVs on 4 sites: {took * 1000:.1f} ms")


def _skynet(cwd: Path, *argv: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("SKYNET_KEYS", None)
    return subprocess.run([sys.executable, "-m", "services.cli", *argv], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=120)


def test_dry_run_prints_the_plan_and_starts_nothing(tmp_path):
    proc = _skynet(tmp_path, "up", "--dry-run", "--uavs", "4", "--web", ":8080")
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    header = out.splitlines()[0].split()
    assert header == ["NAME", "ROLE", "SITE", "IDENTITY", "LISTENS", "CONNECTS", "ENV"]
    rows = {}
    for line in out.splitlines()[1:]:
        if not line.strip():
            break
        rows[line.split()[0]] = line.split()
    assert list(rows) == ["gateway", "uav1", "uav2", "uav3", "uav4", "planner", "detector", "web"]
    assert rows["web"][:4] == ["web", "web", "0", "web"] and rows["uav4"][:4] == ["uav4", "edge", "0", "uav4"]
    assert "  uav4: skynet edge --" in out and " --uav=4 " in out and "  web: skynet web " in out and "--geofence" in out
    assert "SKYNET_WEB_TOKEN" in out and "<random>" not in out
    # nothing started, nothing written: no key set, no network description
    assert list(tmp_path.iterdir()) == []
    # the JSON, for tools; a mission's plan also has the in-process ground station
    proc = _skynet(tmp_path, "mission", "--dry-run", "--json", "--impair", "uav2=delay 5ms", "--out", "r")
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    by = {p["name"]: p for p in doc["processes"]}
    assert by["gcs"]["in_process"] and by["gcs"]["identity"] == "gcs"
    assert [x["link"] for x in doc["proxies"]] == ["uav2"]
    assert by["detector"]["config"]["save_frames"] == str(Path("r") / "frames")
    assert f"--save-frames={Path('r') / 'frames'}" in by["detector"]["argv"]
    assert by["uav1"]["config"]["frame_size"] == "640x480" and by["uav1"]["config"]["uav"] == 1
    assert doc["trust"]["tls"] and doc["trust"]["keys"].endswith(str(Path(".keys") / "dev"))
    assert list(tmp_path.iterdir()) == []
    # insecure, and a bad option still a one-line error
    proc = _skynet(tmp_path, "up", "--dry-run", "--json", "--insecure")
    assert proc.returncode == 0 and json.loads(proc.stdout)["trust"] == {"keys": None, "tls": False}
    proc = _skynet(tmp_path, "up", "--dry-run", "--uavs", "2", "--detectors", "3")
    assert proc.returncode == 2 and "--detectors 3" in proc.stderr.strip().splitlines()[-1]
    proc = _skynet(tmp_path, "up", "--json")
    assert proc.returncode == 2 and "--json: only with --dry-run" in proc.stderr


CHILD_PARSERS = {"gateway": "services.gateway.service", "edge": "edge.board", "planner": "services.planner.service",
                 "detector": "services.detector.service", "video": "services.video.service",
                 "web": "services.web.service"}


@pytest.mark.parametrize("prog, argv", [
    ("up", ()),
    ("mission", ("--uavs", "6", "--sites", "2", "--detectors", "2", "--rcu-site", "detector-1=1", "--vehicle",
                 "mavlink", "--flight", "auto", "--no-recovery", "--frame-size", "1280x960", "--preview-hz", "0.5",
                 "--gcs-state-hz", "5", "--state-ingress-hz", "150", "--detect-max-mp", "1.5", "--no-accept-guard",
                 "--impair", "uav4=delay 5ms", "--video", "mjpeg", "--preview-port", "6000", "--seed", "7",
                 "--speed", "2.5")),
    ("up", ("--uavs", "30", "--insecure", "--web", "0.0.0.0:8081", "--impair", "uav1-uav2=loss 5%")),
    ("mission", ("--autopilot", "uav1=/dev/ttyUSB0,57600", "--autopilot", "uav3=tcp:127.0.0.1:5770",
                 "--home-from-autopilot", "--flight", "auto")),
])
def test_every_process_config_round_trips_through_its_own_command_line(prog, argv):
    """Each process's typed config, rendered as its argv, parses back (by the service's own parser) to the same
    config: what the plan shows is what the child runs with."""
    import importlib

    from protocol.cliconfig import to_argv

    plan = plan_of(*argv, prog=prog, web_token="t" * 20)
    checked = 0
    for p in plan.processes:
        if p.role not in CHILD_PARSERS:
            assert p.config is None  # sim autopilots, in-process ground station: no config model
            continue
        parser = importlib.import_module(CHILD_PARSERS[p.role]).build_parser()
        assert p.argv == (p.role, *to_argv(p.config))
        assert from_namespace(type(p.config), parser.parse_args(list(p.argv[1:])), parser) == p.config, p.name
        checked += 1
    assert checked >= len([p for p in plan.processes if p.role in ("gateway", "edge", "planner", "detector")]) > 3
    if "--autopilot" in argv:
        assert plan.get("uav1").config.mavlink == "/dev/ttyUSB0,57600" and plan.get("uav2").config.home_from_autopilot
    elif prog == "mission":
        edge = plan.get("uav4").config
        assert (edge.frame_size, edge.preview_hz, edge.imagery_cache, edge.vehicle, edge.seed, edge.speed) == \
            ((1280, 960), plan.load.preview_hz, 0, "mavlink", 11, 2.5)
        assert plan.get("detector-0").config.detect_max_mp == 1.5 and plan.get("detector-1").config.no_recovery
        gw = plan.get("gateway").config
        assert gw.state_ingress_hz == 150.0 and not gw.accept_guard and gw.cfg[0][0] == "downsampling"
        assert plan.get("video").config.port == 6000


@pytest.mark.parametrize("argv, needle", [
    (("--speed", "0"), "uav1 would refuse its options: speed"),
    (("--detect-max-mp", "-1"), "detector would refuse its options: detect_max_mp"),
    (("--video", "h264", "--preview-port", "70000"), "video would refuse its options: port"),
    (("--web", "no-port-here"), "web would refuse its options: listen_web"),
    (("--fleet", "a/b"), "fleet"),
])
def test_a_value_a_child_would_refuse_fails_in_the_plan(argv, needle):
    """No child is started with options it refuses: the launcher's check builds every child's config first."""
    from services.orchestration.launcher import check

    with pytest.raises(ValueError, match=needle):
        check(parse("up", ["--dry-run", *argv]))


def test_a_refused_value_is_a_one_line_error_of_skynet_up_dry_run(tmp_path):
    for argv, needle in ((("--speed", "-1"), "uav1 would refuse its options: speed: Input should be greater than 0"),
                         (("--frame-size", "0x0"), "argument --frame-size: Input should be greater than or equal"),
                         (("--preview-hz", "-2"), "argument --preview-hz"),
                         (("--uavs", "0"), "argument --uavs")):
        proc = _skynet(tmp_path, "up", "--dry-run", *argv)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
        assert needle in proc.stderr.strip().splitlines()[-1], proc.stderr
        assert proc.stdout == "" and list(tmp_path.iterdir()) == []


def test_the_launchers_options_are_its_config_and_load_no_opencv():
    """``skynet up``/``mission`` list the same flags (mission: four more), with defaults from the services' configs;
    parsing, checking and planning load no OpenCV (the detector's config names its methods itself)."""
    from typing import get_args

    from services.detector.config import Method
    from services.orchestration.launcher import build_parser

    up, mission = (parse(p, []) for p in ("up", "mission"))
    assert up.frame_size is None and up.method == "it+r" and up.video_port == 5600 and up.speed == 4.0
    assert set(type(mission).model_fields) - set(type(up).model_fields) == {"out", "quiet", "algorithm", "no_record"}
    flags = [{a.option_strings[0] for a in build_parser(p)._actions} for p in ("up", "mission")]
    assert flags[1] - flags[0] == {"--out", "--quiet", "--algorithm", "--no-record"} and "--json" in flags[0]
    text = " ".join(build_parser("up").format_help().split())
    assert "(default: 640x480, or the camera" in text and "(default: it+r)" in text and "|gcs" not in text
    assert "|gcs" in " ".join(build_parser("mission").format_help().split())
    code = ("import sys; from services.orchestration.launcher import check, parse; "
            "check(parse('mission', ['--uavs', '4', '--video', 'h264'])); print(sorted(m for m in sys.modules if "
            "m == 'cv2' or m.startswith('cv2.')))")
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip() == "[]", proc.stderr
    from services.detector.detect import METHODS

    assert sorted(get_args(Method)) == sorted(METHODS)


def test_a_scenario_of_real_size_cracks_is_flown_at_the_cameras_full_resolution_one_flag_away():
    """``--scenario real-cracks`` alone gives the edges the camera's 4000 x 3000 frames (``camera.full_frames``);
    a frame size given by the user wins; the default scenario keeps the default capture size."""
    from edge.config import FRAME_SIZE
    from protocol.scenario import load_scenario
    from services.orchestration.launcher import parse
    from services.orchestration.plan import capture_size

    real, nominal = load_scenario("real-cracks"), load_scenario(None)
    assert capture_size(parse("mission", ["--scenario", "real-cracks"]), real) == (4000, 3000)
    assert capture_size(parse("mission", ["--scenario", "real-cracks", "--frame-size", "1280x960"]), real) == (1280, 960)
    assert capture_size(parse("mission", []), nominal) == FRAME_SIZE
