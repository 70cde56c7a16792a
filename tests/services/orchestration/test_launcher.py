"""The whole system through the launcher at an accelerated clock."""

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from tests.conftest import fly_mission
from tests.readiness import interrupt, launched, wait_ready

#: stated bounds of the end-to-end mission (README, "Mission")
FORMATION_RMS_BOUND_M = 1.0
DEFECT_RECALL_BOUND = 0.7
PLOTS = ["trajectories.png", "altitudes.png", "path_error.png", "formation_error.png", "convergence.png",
         "defects_map.png", "links.png"]


@pytest.mark.mission
def test_mission_through_the_launcher(nominal_mission, nominal_report_again):
    out, proc = nominal_mission.out, nominal_mission.proc
    assert proc.returncode == 0, nominal_mission.failure()
    report = json.loads((out / "report.json").read_text())
    assert report["success"] and not report["failures"]
    assert set(report["uavs"]) == {"1", "2", "3"}
    for uav, fig in report["uavs"].items():
        assert fig["reached_goal"], (uav, fig)
    assert report["formation"]["rms_m"] < FORMATION_RMS_BOUND_M
    assert report["captures"]["planned"] > 0 and report["captures"]["imaged"] == report["captures"]["planned"]
    assert report["defects"]["n_truth"] > 0 and report["defects"]["recall"] >= DEFECT_RECALL_BOUND
    for name in ["report.md", "record.json", "report.json", *PLOTS]:
        assert (out / name).stat().st_size > 0, name
    md = (out / "report.md").read_text()
    assert all(f"({p})" in md for p in PLOTS)
    # secure by default: mutual TLS, ACL by certificate on the gateway and every edge, signed commands
    services = (out / "services.log").read_text()
    assert "ACL by certificate common name" in services and "INSECURE" not in services, services[-3000:]
    assert all(f"mutual TLS as uav{i}" in services for i in (1, 2, 3))
    assert not any(e["kind"] == "trust-refused" for e in report.get("events", []) if isinstance(e, dict))
    # one record: the report is computed from the mission log read back, and `skynet report` makes the same
    # figures from it alone
    assert "mission.mcap read back" in md and not (out / "record.jsonl").exists()
    again, folder = nominal_report_again  # `skynet report OUT` (tests/conftest.py)
    assert again.returncode == 0, again.stdout + again.stderr
    rebuilt = json.loads((folder / "report.json").read_text())
    assert {k: v for k, v in rebuilt.items() if k != "files"} == {k: v for k, v in report.items() if k != "files"}
    # the deliverable's captures came through the bus: the detector was given no folder (no --save-frames, no
    # frames/ in the report folder), and the inspection section has every capture point's frame
    assert not (out / "frames").exists()
    table = json.loads((out / "inspection" / "defects.json").read_text())
    assert table["frames"] == report["captures"]["planned"] and len(table["defects"]) > 0
    assert "## Inspection deliverable" in md and "inspection/mosaic.png" in md


def test_up_starts_everything_and_ctrl_c_leaves_no_orphans(monkeypatch):
    """``skynet up`` signals it is up (its own ready pipe, as its services do to it) once every service it
    started has signalled; Ctrl-C then ends them all. Zenoh's own lines (``RUST_LOG=info`` here) come through
    the launcher's output without colour codes."""
    monkeypatch.setenv("RUST_LOG", "info")
    monkeypatch.delenv("NO_COLOR", raising=False)
    with launched(["up", "--speed", "4"], timeout=90, stop_timeout=30) as up:
        pids = [int(p) for p in subprocess.run(["pgrep", "-P", str(up.proc.pid)], capture_output=True,
                                               text=True).stdout.split()]
        assert len(pids) == 6
    rest = "".join(up.lines)
    assert up.proc.returncode == 0, rest[-2000:]
    for pid in pids:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)
    assert "shutting down" in rest
    assert "network up" in rest and "all services up: gateway uav1 uav2 uav3 planner detector" in rest, rest[-3000:]
    zenoh_lines = [line for line in up.lines if "zenoh::" in line]
    assert zenoh_lines, rest[-3000:]
    assert not any("\x1b" in line or "\\x1b" in line for line in zenoh_lines), zenoh_lines[:3]


def test_impairment_proxy_on_one_uav_delays_only_its_link(dev_keys, tmp_path):
    from protocol import keys
    from protocol.bus import Bus, BusConfig
    from protocol.keyset import KeySet
    from protocol.links import TELEMETRY
    from protocol.messages import VehicleState

    with launched(["up", "--speed", "4", "--fleet", "imp", "--impair", "uav2=delay 100ms"], cwd=tmp_path):
        endpoints = json.loads((tmp_path / ".skynet" / "network.json").read_text())["endpoints"]
        ages: dict[int, list[float]] = {1: [], 2: []}
        ks = KeySet(dev_keys, "gcs")  # an impaired network keeps mutual TLS: the probe is the ground station
        config = BusConfig(mode="client", connect=endpoints, multilink=True, tls_ca=str(ks.tls_ca),
                           tls_cert=str(ks.tls_cert), tls_key=str(ks.tls_key))
        with Bus(config, "imp", "probe") as bus:
            bus.subscribe(keys.state("imp", "*"), lambda m, s: ages.get(m.uav, []).append(time.time() - m.stamp),
                          expect=VehicleState, link=TELEMETRY)
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline and min(len(a) for a in ages.values()) < 40:
                time.sleep(0.1)
        med = {u: sorted(a)[len(a) // 2] for u, a in ages.items()}
        assert med[2] > 0.09, med  # 100 ms added on uav2 <-> gateway
        assert med[1] < 0.05, med  # uav1 is not impaired


@pytest.mark.mission
def test_mission_with_200ms_on_every_link_keeps_its_plan(impaired_secure_mission):
    """Every link, reliable ones too, 200 ms each way (the impairment goals' delay): the formation must not
    read late states as lagging neighbours, and the common start must wait for the last UAV's
    Start; either fault left the fleet 2.7 m behind its plan and the mission failed. The delay
    starts once the sessions are open (``after 4s``, before the upload): opened through 200 ms
    links, a zenoh 1.10 multilink session sometimes stays broken ("Route data with unknown
    scope" at the gateway for that UAV, which then never appears). The run is shared with the trust test
    of the proxied links (tests/conftest.py, ``impaired_secure_mission``)."""
    out, proc = impaired_secure_mission.out, impaired_secure_mission.proc
    assert (out / "report.json").exists(), impaired_secure_mission.failure()
    report = json.loads((out / "report.json").read_text())
    logs = (out / "services.log").read_text()[-4000:] if (out / "services.log").exists() else ""
    assert proc.returncode == 0 and report["success"], f"{report['failures']}\n{proc.stderr[-2000:]}\n{logs}"
    for uav, fig in report["uavs"].items():
        assert fig["reached_goal"], (uav, fig)
    assert report["formation"]["rms_m"] < FORMATION_RMS_BOUND_M
    assert report["links"]["telemetry"]["latency_ms"]["p50"] > 380  # the delay was there: two hops of 200 ms


@pytest.mark.parametrize("argv, needle", [
    (["up", "--impair", "uav9=loss 5%"], "uav9"),
    (["up", "--impair", "gcs=loss 5%"], "gcs"),
    (["mission", "--impair", "uav1/sctp=loss 5%"], "sctp"),
    (["mission", "--impair", "skynet=loss 5%", "--mesh", "direct"], "--mesh proxied"),
    (["mission", "--fault", "3s kill gcs"], "gcs"),
    (["mission", "--fault", "3 kill gateway"], "'3'"),
    (["up", "--fault", "3s partition uav1-uav5 for 2s"], "uav5"),
    (["up", "--uavs", "2", "--detectors", "3"], "--detectors 3"),
    (["mission", "--uavs", "4", "--detectors", "2", "--fault", "3s kill detector"], "detector-0"),
    (["up", "--uavs", "6", "--sites", "3"], "--sites 3"),
    (["mission", "--uavs", "6", "--sites", "2", "--rcu-site", "planner=5"], "planner=5"),
])
def test_bad_links_and_faults_are_one_line_errors(argv, needle):
    proc = subprocess.run([sys.executable, "-m", "services.cli", *argv], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert "error:" in last and needle in last, proc.stderr
    assert "Traceback" not in proc.stderr


def test_no_recovery_reaches_the_edges_and_the_detector():
    from services.orchestration.launcher import Network, parse

    net = Network(parse("up", ["--speed", "8", "--fleet", "norec", "--no-recovery", "--uavs", "2"]),
                  echo=None)
    try:
        net.start()
        for name, flag in [("uav1", "--imagery-cache=0"), ("uav2", "--imagery-cache=0"), ("detector", "--no-recovery")]:
            svc = net.group.get(name)
            assert flag in svc.args
            wait_ready(svc)
        assert net.check_alive() == []
    finally:
        net.stop()


def test_up_restarts_a_service_that_dies_instead_of_stopping_the_network():
    """one service ending (here the planner, SIGKILLed from outside: a crash) used to stop the whole
    network; now the supervisor restarts it after its back-off, says so, and the rest keeps running."""
    proc = subprocess.Popen([sys.executable, "-m", "services.cli", "up", "--speed", "4", "--fleet", "restart"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []

    def read_until(pred, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                return False
            lines.append(line)
            if pred(line):
                return True
        return False

    try:
        assert read_until(lambda ln: "network up" in ln, 60), "".join(lines[-40:])
        children = subprocess.run(["pgrep", "-P", str(proc.pid)], capture_output=True, text=True).stdout.split()
        planner = [int(p) for p in children
                   if " planner " in open(f"/proc/{p}/cmdline").read().replace("\0", " ") + " "]
        assert len(planner) == 1, children
        os.killpg(planner[0], signal.SIGKILL)
        assert read_until(lambda ln: "planner exited with code -9" in ln, 10), "".join(lines[-20:])
        assert read_until(lambda ln: "restarted by the supervisor" in ln, 10), "".join(lines[-20:])
        assert read_until(lambda ln: ln.strip().startswith("planner |") and "planner up" in ln, 30), \
            "".join(lines[-20:])
        assert proc.poll() is None  # the network is still up
        after = subprocess.run(["pgrep", "-P", str(proc.pid)], capture_output=True, text=True).stdout.split()
        assert len(after) == 6 and str(planner[0]) not in after
    finally:
        interrupt(proc, 30)
    assert proc.returncode == 0


@pytest.mark.mission
def test_two_formations_and_two_detectors_fly_the_mission(tmp_path):
    """In one mission: six UAVs fly as two formations (1-3, 4-6), each edge hears only its formation;
    ``--detectors 2`` (detector-0 and detector-1 sharing the six cameras, secure by default): every capture is
    reported once, and the ledger's analysed counts sum both instances. ``--sites 2``: formation 1 and
    detector-0 on site 0's gateway (with the ground station and the planner), formation 2 and detector-1 on
    site 1's, the two gateways linked by mutual TLS: everything of formation 2 reaches the ground station, and
    each detector the other site's cameras, across the router link."""
    run = fly_mission(tmp_path / "report", "--uavs", "6", "--detectors", "2", "--speed", "4",
                      "--sites", "2", "--rcu-site", "detector-1=1")
    assert run.proc.returncode == 0, run.failure()
    # the launcher's topology: each formation's edges on its site's gateway, gateway-1 dialling gateway
    assert "site 0: gateway at tls/" in run.proc.stderr and "attached: uav1 uav2 uav3 gcs detector-0 planner" \
        in run.proc.stderr, run.failure()
    assert "site 1: gateway-1 at tls/" in run.proc.stderr and "dialling gateway; attached: uav4 uav5 uav6 " \
        "detector-1" in run.proc.stderr, run.failure()
    services = (run.out / "services.log").read_text()
    assert services.count("ACL by certificate common name") == 2, services[-3000:]  # both gateways, secure
    report = run.report()
    assert report["success"] and not report["failures"]
    assert set(report["uavs"]) == {str(u) for u in range(1, 7)}
    assert all(fig["reached_goal"] for fig in report["uavs"].values()), report["uavs"]
    assert report["formation"]["rms_m"] < FORMATION_RMS_BOUND_M
    assert report["captures"]["planned"] > 0 and report["captures"]["imaged"] == report["captures"]["planned"]
    record = run.record()
    joined = {(int(e["msg"]["source"].split("/")[1]), e["msg"]["data"]["neighbour"]) for e in record["events"]
              if e["msg"]["kind"] == "neighbour-up"}
    formations = [(1, 2, 3), (4, 5, 6)]
    assert joined == {(i, j) for f in formations for i in f for j in f if i != j}, sorted(joined)
    assert {s["msg"]["source"] for s in record["detector_stats"]} == {"detector-0", "detector-1"}
    for uav, row in record["imagery"].items():
        assert row["analysed"] == row["reported"] == row["sent"] > 0, (uav, row)
    reported = [(d["msg"]["uav"], d["msg"]["capture_id"]) for d in record["defects"] if d["msg"]["ok"]]
    assert len(reported) == len(set(reported))  # no capture analysed twice
    # the mesh as the gateways saw it (their last statistics): two gateways, one router link between them,
    # three edges (peers) on each, the ground station, the planner and detector-0 (clients) on gw0, detector-1 on gw1
    last = {}
    for st in record["gateway_stats"]:
        last[st["msg"]["source"]] = st["msg"]["sessions"]
    assert set(last) == {"gateway/gw0", "gateway/gw1"}, last
    assert last["gateway/gw0"] == {"peer": 3, "router": 1, "client": 3}, last
    assert last["gateway/gw1"] == {"peer": 3, "router": 1, "client": 1}, last


def test_frame_size_preview_and_ground_view_options_reach_the_edges_and_the_gateway():
    """--frame-size, --capture-link, --preview-hz reach every edge; --gcs-state-hz the gateway's config
    (and --state-ingress-hz its option)."""
    from edge.config import EdgeConfig
    from protocol.scenario import load_scenario
    from services.orchestration.launcher import Network, parse

    box = load_scenario(None).box

    def arg(argv: list[str], flag: str) -> str:  # the children's command lines are --flag=value
        return next(a.split("=", 1)[1] for a in argv if a.startswith(flag + "="))

    net = Network(parse("up", ["--speed", "8", "--fleet", "opts", "--uavs", "4", "--frame-size",
                                                 "1280x960", "--capture-link", "reliable", "--preview-hz", "0",
                                                 "--gcs-state-hz", "5", "--detect-max-mp", "1.5",
                                                 "--state-ingress-hz", "150"]), echo=None)
    try:
        net.start()
        for i in range(1, 5):
            svc = net.group.get(f"uav{i}")
            a = svc.args
            assert arg(a, "--frame-size") == "1280x960" and arg(a, "--capture-link") == "reliable"
            assert float(arg(a, "--preview-hz")) == 0.0
            fence = EdgeConfig.model_validate({"uav": i, "geofence": arg(a, "--geofence")}).geofence
            assert (fence.lo, fence.hi) == (box.lo, box.hi)  # the scenario's box, the ceiling of any upload's fence
            assert wait_ready(svc).ready_as == ("edge", f"uav{i}")
        gw = net.group.get("gateway").args
        conf = {"downsampling": json.loads(arg(gw, "--cfg").split(":", 1)[1])}
        assert [r["key_expr"] for r in conf["downsampling"][0]["rules"]] == [f"skynet/opts/uav/{u}/state" for u in range(1, 5)]
        assert float(arg(gw, "--state-ingress-hz")) == 150.0  # the gateway's ingress limit
        assert float(arg(net.group.get("detector").args, "--detect-max-mp")) == 1.5
        assert net.check_alive() == []
    finally:
        net.stop()
    with pytest.raises(SystemExit):
        parse("up", ["--frame-size", "big"])


def test_detectors_option_starts_partitioned_instances():
    """``--detectors 2`` starts detector-0 and detector-1, each on its partition of the UAV ids."""
    from services.orchestration.launcher import Network, parse

    net = Network(parse("up", ["--speed", "8", "--fleet", "parts", "--uavs", "4", "--detectors", "2"]),
                  echo=None)
    try:
        net.start()
        for k in (0, 1):
            svc = net.group.get(f"detector-{k}")
            assert f"--partition={k}/2" in svc.args and "--uavs=4" in svc.args
            assert wait_ready(svc, 60).ready_as == ("detector", f"detector-{k}")
        assert net.check_alive() == []
    finally:
        net.stop()


def test_sites_option_lays_out_one_gateway_per_site_and_attaches_each_node_to_its_own():
    """``--sites``: each edge's uplink goes to its formation's site, the ground station and the default
    RCUs to site 0, ``--rcu-site`` elsewhere; a bad count or RCU site is refused before anything starts."""
    from services.orchestration.launcher import Network, make_plan
    from services.orchestration.launcher import parse as parse_config

    def parse(*argv, prog="mission"):
        return parse_config(prog, ["--fleet", "layout", *argv])

    net = Network(parse("--uavs", "6", "--sites", "2", "--detectors", "2", "--rcu-site", "detector-1=1"), echo=None,
                  ground_station=True)
    try:
        gw0, gw1 = net.site_endpoints
        assert len(set(gw0) | set(gw1)) == 4 and all(e.startswith("tls/127.0.0.1:") for e in gw0 + gw1)
        for i in range(1, 7):
            connect = [e.split("#")[0] for e in net.layout.get(f"uav{i}").config.connect]  # (#router CA)
            assert connect[:2] == (gw0 if i <= 3 else gw1), (i, connect)
        assert [e.split("#")[0] for e in net.gcs_config().connect] == gw0
        assert [net.site_of(n) for n in ("planner", "detector-0", "detector-1", "gcs")] == [0, 0, 1, 0]
        lines = net.topology()
        assert lines[0].startswith("site 0: gateway at ") and lines[0].endswith("uav1 uav2 uav3 gcs detector-0 planner")
        assert "site 1: gateway-1" in lines[1] and "dialling gateway" in lines[1]
        assert lines[1].endswith("uav4 uav5 uav6 detector-1")
    finally:
        net.stop()
    # an impaired uplink: its proxies stand in front of its own site's gateway (the TLS sessions through them)
    net = Network(parse("--uavs", "6", "--sites", "2", "--impair", "uav4=delay 5ms"), echo=None, ground_station=True)
    try:
        from protocol.bus import endpoint_address

        proxy = net.layout.proxies["uav4"]
        assert list(proxy.targets) == [endpoint_address(e) for e in net.site_endpoints[1]], (proxy, net.site_endpoints)
        uav4 = net.layout.get("uav4").connects
        assert [e.split("#")[0] for e in uav4[:2]] == proxy.endpoints()
        assert [e.split("#")[0] for e in net.layout.get("uav1").connects[:2]] == net.site_endpoints[0]
    finally:
        net.stop()
    for argv, why in ((("--uavs", "6", "--sites", "3"), "at most one site per formation"),
                      (("--uavs", "6", "--sites", "0"), "at least one site"),
                      (("--uavs", "6", "--sites", "2", "--rcu-site", "planner=2"), "not one of 0..1"),
                      (("--uavs", "6", "--sites", "2", "--detectors", "2", "--rcu-site", "detector-1=1",
                        "--impair", "detector=delay 5ms"), "different sites")):
        with pytest.raises(ValueError, match=why):
            make_plan(parse(*argv), ground_station=True)
