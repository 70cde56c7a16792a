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
from protocol.links import LINK_LEASE_S
from protocol.scenario import load_scenario
from services.orchestration.launcher import build_parser
from services.orchestration.plan import CountingPorts, LaunchOptions, Trust, fleet_offsets, homes, network_plan
from tests.conftest import ROOT

SCENARIO = load_scenario(None)
TRUST = Trust(keys="/keys", tls=True, router_ca="/keys/router-ca.pem")


def plan_of(*argv: str, prog: str = "up", trust: Trust = TRUST, **kw):
    args = build_parser(prog).parse_args(list(argv))
    return network_plan(LaunchOptions.from_args(args), SCENARIO, trust, CountingPorts(7447),
                        ground_station=prog == "mission", epoch=100.0, workdir="/run", **kw)


def arg(argv, flag: str) -> str:
    argv = list(argv)
    return argv[argv.index(flag) + 1]


def args_of(argv, flag: str) -> list[str]:
    argv = list(argv)
    return [argv[k + 1] for k, a in enumerate(argv) if a == flag]


def test_a_fleet_of_three_on_one_site():
    plan = plan_of()
    assert [p.name for p in plan.processes] == ["gateway", "uav1", "uav2", "uav3", "planner", "detector"]
    assert [p.role for p in plan.processes] == ["gateway", "edge", "edge", "edge", "planner", "detector"]
    assert all(p.site == 0 and p.ready and not p.in_process for p in plan.processes)
    assert [p.identity for p in plan.processes] == ["gateway", "uav1", "uav2", "uav3", "planner", "detector"]
    assert [p.wait for p in plan.processes] == [True] + [False] * 5  # the gateway first, up before the rest
    gw = plan.get("gateway")
    assert gw.listens == ("tls/127.0.0.1:7447?rel=1", "tls/127.0.0.1:7448?rel=0") == tuple(plan.gateway_endpoints)
    assert args_of(gw.argv, "--listen") == list(gw.listens) and arg(gw.argv, "--keys") == "/keys"
    assert "--lease" not in gw.argv  # no proxied link: zenoh's lease on the ground
    router = "#root_ca_certificate_file=/keys/router-ca.pem"
    for i in (1, 2, 3):
        edge = plan.get(f"uav{i}")
        connects = args_of(edge.argv, "--connect")
        assert connects[:2] == [e + router for e in plan.gateway_endpoints]  # dialled trusting the router CA only
        mates = [plan.get(f"uav{j}").listens for j in range(i + 1, 4)]
        assert connects[2:] == [e for ends in mates for e in ends]  # every later edge of its formation, no proxy
        assert args_of(edge.argv, "--listen") == list(edge.listens) and arg(edge.argv, "--mode") == "peer"
        assert arg(edge.argv, "--epoch") == "100.0" and arg(edge.argv, "--seed") == str(i)
        parsed = edge_parser().parse_args(list(edge.argv[1:]))  # the edge's own parser takes the whole line
        assert parsed.uav == i and parsed.keys == "/keys"
    for name in ("planner", "detector"):
        p = plan.get(name)
        assert p.listens == () and arg(p.argv, "--mode") == "client"
        assert args_of(p.argv, "--connect") == [e + router for e in plan.gateway_endpoints] == list(p.connects)
    ports = [e for p in plan.processes for e in p.listens]
    assert len(ports) == len(set(ports)) == 8 and plan.files == {} and plan.proxies == {}


def test_homes_are_the_scenarios_offsets_and_the_fence_its_box():
    """The launch points come from the scenario's own formation offsets (its three, or offsets_for for other
    fleet sizes), rotated to its start→goal heading; every edge is configured with the scenario's box."""
    plan = plan_of()
    box = SCENARIO.box
    for i, home in enumerate(plan.homes, start=1):
        edge = plan.get(f"uav{i}")
        assert [float(x) for x in arg(edge.argv, "--home").split(",")] == pytest.approx(list(home))
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
    assert arg(g1.argv, "--id") == "gw1" and [e.split("#")[0] for e in g1.connects] == gw0  # dials site 0
    assert args_of(g1.argv, "--listen") == gw1
    for i in range(1, 7):
        edge = plan.get(f"uav{i}")
        assert edge.site == (0 if i <= 3 else 1)
        assert [e.split("#")[0] for e in edge.connects[:2]] == (gw0 if i <= 3 else gw1)
        f = range(1, 4) if i <= 3 else range(4, 7)  # its formation's later edges only
        assert list(edge.connects[2:]) == [e for j in f if j > i for e in plan.get(f"uav{j}").listens]
        assert "--config" in edge.argv  # several formations: no gossip autoconnect
    assert plan.get("detector-1").site == 1 and plan.get("detector-0").site == 0
    assert arg(plan.get("detector-1").argv, "--partition") == "1/2"
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
    assert arg(plan.get("gateway").argv, "--lease") == str(LINK_LEASE_S)
    for name in ("planner", "detector"):
        argv = plan.get(name).argv
        assert arg(argv, "--lease") == str(LINK_LEASE_S) and arg(argv, "--cfg").startswith("transport/unicast/open_timeout:")
    assert "--lease" not in plan.get("uav1").argv  # the edges' own default is that constant
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
    assert all("--keys" not in p.argv for p in plan.processes)
    gw = plan.get("gateway")
    assert gw.listens[0].startswith("tcp/") and gw.listens[1].startswith("udp/")
    assert all("#" not in e for p in plan.processes for e in p.connects)
    web = plan.get("web")
    assert set(web.env) == {"SKYNET_WEB_TOKEN"} and arg(web.argv, "--listen-web") == ":8080"
    assert arg(plan.get("video").argv, "--codec") == "h264"
    shown = json.dumps(plan.to_json())
    assert '"SKYNET_WEB_TOKEN": "***"' in shown


def test_web_and_video_run_as_their_own_identities():
    plan = plan_of("--web", ":8080", "--video", "mjpeg", web_token="t" * 20)
    assert plan.get("web").identity == "web" and plan.get("video").identity == "video"
    assert plan.get("web").env == {"SKYNET_WEB_TOKEN": "t" * 20}
    assert "t" * 20 not in plan.table() and "t" * 20 not in json.dumps(plan.to_json())


def test_autopilot_sim_runs_beside_each_edge():
    plan = plan_of("--vehicle", "mavlink", "--flight", "auto", "--autopilot-boot-scale", "0.1")
    names = [p.name for p in plan.processes]
    assert names == ["gateway", "ap1", "uav1", "ap2", "uav2", "ap3", "uav3", "planner", "detector"]
    for i in (1, 2, 3):
        ap, edge = plan.get(f"ap{i}"), plan.get(f"uav{i}")
        assert ap.role == "autopilot" and not ap.ready and ap.identity is None  # no bus, not supervised as one
        port = int(ap.listens[0].rsplit(":", 1)[1])
        assert arg(ap.argv, "--port-base") == str(port - i + 1) and arg(ap.argv, "--boot-scale") == "0.1"
        assert arg(ap.argv, "--home") == arg(edge.argv, "--home")
        assert arg(edge.argv, "--mavlink") == f"udpin:127.0.0.1:{port}" and arg(edge.argv, "--flight") == "auto"


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
    assert "  uav4: skynet edge --uav 4 " in out and "  web: skynet web " in out and "--geofence" in out
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
    assert by["detector"]["argv"][by["detector"]["argv"].index("--save-frames") + 1] == str(Path("r") / "frames")
    assert doc["trust"]["tls"] and doc["trust"]["keys"].endswith(str(Path(".keys") / "dev"))
    assert list(tmp_path.iterdir()) == []
    # insecure, and a bad option still a one-line error
    proc = _skynet(tmp_path, "up", "--dry-run", "--json", "--insecure")
    assert proc.returncode == 0 and json.loads(proc.stdout)["trust"] == {"keys": None, "tls": False}
    proc = _skynet(tmp_path, "up", "--dry-run", "--uavs", "2", "--detectors", "3")
    assert proc.returncode == 2 and "--detectors 3" in proc.stderr.strip().splitlines()[-1]
    proc = _skynet(tmp_path, "up", "--json")
    assert proc.returncode == 2 and "--json: only with --dry-run" in proc.stderr
