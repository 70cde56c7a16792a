"""Pure parts of the launcher's faults: link names and ``--impair`` grammar, ``--fault`` parsing and schedule,
the injector's bookkeeping (no processes: the injector acts on a recording target)."""

from __future__ import annotations

import json
import time

import pytest

from services.orchestration.faults import FaultInjector, parse_duration, parse_fault, plan_faults, resolve, schedule
from services.orchestration.launcher import make_plan, parse
from services.orchestration.topology import Links, edge_mesh_config, link_seed, parse_impair
from tests.conftest import wait_until

L3 = Links(3)
UP3 = Links(3, ("planner", "detector"))


# ----------------------------------------------------------------------------- --impair
def test_impair_names_groups_and_classes():
    imp = parse_impair(["all/udp=delay 200ms loss 20%"], L3)
    assert set(imp.specs) == {"uav1", "uav2", "uav3", "planner", "detector", "gcs",
                              "uav1-uav2", "uav1-uav3", "uav2-uav3"}
    assert all(v == {"udp": "delay 200ms loss 20%"} for v in imp.specs.values())
    imp = parse_impair(["uav3-uav1=loss 5%", "uplinks/tcp=delay 10ms", "uav2=delay 50ms"], L3)
    assert imp.spec("uav1-uav3", "tcp") == imp.spec("uav1-uav3", "udp") == "loss 5%"
    assert imp.spec("uav2", "tcp") == "delay 50ms" and imp.spec("uav2", "udp") == "delay 50ms"  # later wins
    assert imp.spec("uav1", "tcp") == "delay 10ms" and imp.spec("uav1", "udp") is None
    assert set(parse_impair(["skynet=loss 1%"], L3).specs) == {"uav1-uav2", "uav1-uav3", "uav2-uav3"}
    # no NAME: every link, as all=SPEC
    assert parse_impair(["delay 5ms"], L3).specs == parse_impair(["all=delay 5ms"], L3).specs


def test_one_impair_grammar_for_the_launcher_and_a_proxy():
    from services.netem.model import parse_impair_arg

    arg = parse_impair_arg("uplinks/tcp=delay 10ms loss 2%")
    assert (arg.link, arg.cls, arg.spec, arg.impairment.delay_ms) == ("uplinks", "tcp", "delay 10ms loss 2%", 10.0)
    assert parse_impair_arg("delay 10ms", named=False).link is None
    with pytest.raises(ValueError, match="this proxy is one link"):
        parse_impair_arg("uav2=delay 10ms", named=False)
    with pytest.raises(ValueError, match="name the link"):
        parse_impair_arg("delay 10ms", named=True)


@pytest.mark.parametrize("item, needle", [
    ("uav4=loss 1%", "uav4"), ("uav0=loss 1%", "uav0"), ("uav1-uav1=loss 1%", "two different"),
    ("uav1-uav7=loss 1%", "uav7"), ("rover=loss 1%", "rover"), ("uav1/sctp=loss 1%", "sctp"),
    ("uav1=", "no SPEC"), ("uav1", "unknown keyword 'uav1'"), ("=loss 1%", "no LINK"),
    ("uav1=loss 120%", "uav1=loss 120%"), ("uav1=delay 5", "unit"),
])
def test_bad_impair_items_are_named(item, needle):
    with pytest.raises(ValueError, match=None) as e:
        parse_impair([item], L3)
    assert needle in str(e.value) and "\n" not in str(e.value)


def test_gcs_link_only_with_a_ground_station():
    with pytest.raises(ValueError, match="gcs"):
        parse_impair(["gcs=loss 1%"], UP3)
    assert "gcs" not in parse_impair(["uplinks=loss 1%"], UP3).specs


def test_proxy_seeds_are_distinct_per_link_and_repeatable():
    seeds = {link_seed(7, link, c) for link in [*L3.uplinks, *L3.skynet] for c in ("tcp", "udp")}
    assert len(seeds) == 2 * (6 + 3)
    assert link_seed(7, "uav1-uav2", "udp") == link_seed(7, "uav1-uav2", "udp") != link_seed(8, "uav1-uav2", "udp")


def test_mesh_plan_follows_skynet_impairments_and_faults():
    def plan(*argv, prog="mission"):
        return make_plan(parse(prog, list(argv)), ground_station=prog == "mission")

    assert plan().mesh == "direct" and plan().proxied == set()
    p = plan("--impair", "uav2=delay 50ms")
    assert p.mesh == "direct" and p.proxied == {"uav2"}
    p = plan("--impair", "uav1-uav2/udp=loss 5%")
    assert p.mesh == "proxied" and p.proxied == {"uav1-uav2", "uav1-uav3", "uav2-uav3"}
    p = plan("--fault", "5s partition uav3 for 2s", "--fault", "9s cut uplinks for 1s")
    assert p.mesh == "proxied" and p.proxied == {"uav1-uav2", "uav1-uav3", "uav2-uav3", "uav1", "uav2", "uav3"}
    assert plan("--mesh", "proxied").proxied == {"uav1-uav2", "uav1-uav3", "uav2-uav3"}
    with pytest.raises(ValueError, match="--mesh proxied"):
        plan("--mesh", "direct", "--impair", "skynet=loss 1%")
    with pytest.raises(ValueError, match="gcs"):
        plan("--fault", "1s cut gcs", prog="up")


def test_edge_mesh_config_keeps_the_secured_base():
    base = {"transport": {"auth": {"usrpwd": {"dictionary_file": "/x"}}},
            "scouting": {"gossip": {"autoconnect_strategy": {"peer": {"to_peer": "greater-zid"}}}}}
    doc = edge_mesh_config("proxied", base)
    assert doc["scouting"]["gossip"]["autoconnect"] == {"router": [], "peer": []}
    assert doc["scouting"]["gossip"]["autoconnect_strategy"] == base["scouting"]["gossip"]["autoconnect_strategy"]
    assert doc["transport"]["auth"] == base["transport"]["auth"] and "unicast" not in base["transport"]
    assert edge_mesh_config("direct")["scouting"]["gossip"]["autoconnect"]["peer"] == ["peer"]
    import zenoh

    zenoh.Config.from_json5(json.dumps(doc))  # zenoh accepts it


# ----------------------------------------------------------------------------- --fault
def test_parse_faults():
    f = parse_fault("20s kill gateway for 3s")
    assert (f.at_s, f.action, f.target, f.duration_s) == (20.0, "kill", "gateway", 3.0)
    f = parse_fault("  1.5min   cut uplinks ")
    assert (f.at_s, f.duration_s, f.text) == (90.0, None, "1.5min cut uplinks")
    assert parse_duration("500ms", "x") == 0.5


@pytest.mark.parametrize("text, needle", [
    ("20 kill gateway", "'20'"), ("20s explode gateway", "'explode'"), ("20s kill gateway during 3s", "'during'"),
    ("20s kill gateway for 0s", "'0s'"), ("20s kill", "AT ACTION TARGET"), ("20s kill gateway for 3h", "'3h'"),
])
def test_bad_faults_name_the_token(text, needle):
    with pytest.raises(ValueError) as e:
        parse_fault(text)
    assert needle in str(e.value)


def test_fault_targets_are_checked_against_the_run():
    assert resolve(parse_fault("1s kill uav3"), L3).service == "uav3"
    assert resolve(parse_fault("1s cut uplinks for 8s"), L3).links == ("uav1", "uav2", "uav3")
    assert resolve(parse_fault("1s cut gcs"), L3).links == ("gcs",)
    assert resolve(parse_fault("1s partition uav2"), L3).links == ("uav1-uav2", "uav2-uav3")
    assert resolve(parse_fault("1s partition uav2-uav1"), L3).links == ("uav1-uav2",)
    assert len(resolve(parse_fault("1s partition skynet"), L3).links) == 3
    for text, needle in [("1s kill uav4", "uav4"), ("1s kill gcs", "gcs"), ("1s cut skynet", "partition"),
                         ("1s cut uav1-uav2", "partition"), ("1s partition gateway", "gateway"),
                         ("1s cut uav9", "uav9"), ("1s cut gcs", "gcs")]:
        with pytest.raises(ValueError) as e:
            resolve(parse_fault(text), UP3 if "gcs" in text and "cut" in text else L3)
        assert needle in str(e.value), text
    with pytest.raises(ValueError, match="2 UAVs"):
        resolve(parse_fault("1s partition skynet"), Links(1))


def test_schedule_order_and_overlapping_kills():
    items = plan_faults(["10s cut uav2 for 5s", "15s cut uav2 for 5s", "12s kill gateway for 1s"], L3)
    steps = [(s.t_s, s.action, s.item.fault.target) for s in schedule(items)]
    assert steps == [(10, "cut", "uav2"), (12, "kill", "gateway"), (13, "restart", "gateway"),
                     (15, "restore", "uav2"), (15, "cut", "uav2"), (20, "restore", "uav2")]
    with pytest.raises(ValueError, match="still down"):
        plan_faults(["10s kill uav1 for 5s", "12s kill uav1"], L3)
    with pytest.raises(ValueError, match="still down"):
        plan_faults(["10s kill uav1", "30s kill uav1 for 1s"], L3)
    plan_faults(["10s kill uav1 for 2s", "12s kill uav1 for 1s"], L3)


class _Proxy:
    def __init__(self, log, name):
        self.log, self.name = log, name

    def cut(self):
        self.log.append(("cut", self.name))

    def restore(self):
        self.log.append(("restore", self.name))


class _Target:
    """Records what the injector does (the real one is the launcher's Network, see test_topology)."""

    def __init__(self):
        self.log = []

    def kill(self, name):
        self.log.append(("kill", name))

    def restart(self, name):
        self.log.append(("restart", name))
        return 0.5

    def link_proxies(self, link):
        return [_Proxy(self.log, f"{link}/tcp"), _Proxy(self.log, f"{link}/udp")]


class _Record:
    def __init__(self):
        self.phases = {}


class _Runner:
    def __init__(self):
        self.record = _Record()
        self.notes = []

    def note_fault(self, action, target, text=""):
        self.notes.append((action, target, text))


def test_injector_waits_for_the_mission_counts_overlapping_cuts_and_stops_at_done():
    target, runner = _Target(), _Runner()
    items = plan_faults(["0s cut uav1 for 0.3s", "0.1s cut uplinks for 0.1s", "0.4s kill uav2 for 0.1s",
                         "5s kill gateway"], L3)
    inj = FaultInjector(target, items)
    inj.attach(runner)
    inj.start()
    time.sleep(0.3)
    assert target.log == [] and runner.notes == []  # no mission phase yet
    runner.record.phases["mission"] = time.time()
    wait_until(lambda: len(runner.notes) >= 6, 5.0)
    runner.record.phases["done"] = time.time()
    inj.stop()
    assert inj.done()
    assert [(a, t) for a, t, _ in runner.notes] == [
        ("cut", "uav1"), ("cut", "uplinks"), ("restore", "uplinks"), ("restore", "uav1"), ("kill", "uav2"),
        ("restart", "uav2")]
    # uav1 is cut once and restored once, by the last fault that holds it
    assert [e for e in target.log if "uav1/" in e[1]] == [("cut", "uav1/tcp"), ("cut", "uav1/udp"),
                                                          ("restore", "uav1/tcp"), ("restore", "uav1/udp")]
    assert ("kill", "gateway") not in target.log  # the mission ended first
    assert runner.notes[1][2].endswith("cut uav2, uav3") and runner.notes[2][2].endswith("restored uav2, uav3")
    # ... and says so, once: the run the user asked for did not happen
    assert inj.finish() == ["5s kill gateway"]
    assert runner.notes[6:] == [("not-injected", "gateway", "5s kill gateway")]


def test_a_mission_that_never_reaches_its_mission_phase_injected_none_of_its_faults():
    runner = _Runner()
    inj = FaultInjector(_Target(), plan_faults(["0s cut uav1 for 1s", "1s kill uav2"], L3))
    inj.attach(runner)
    inj.start()
    assert inj.finish() == ["0s cut uav1 for 1s", "1s kill uav2"] and inj.done()
    assert [a for a, _, _ in runner.notes] == ["not-injected", "not-injected"]


@pytest.mark.parametrize("text", ["1e999s kill gateway", "nans kill gateway", "10s kill gateway for 1e999s",
                                  "100000s kill gateway", "-1s kill gateway"])
def test_fault_times_out_of_range_are_refused(text):
    """Fuzzing found that ``1e999s`` was accepted as an AT that never comes; times are now 0..MAX_FAULT_S."""
    from services.orchestration.faults import MAX_FAULT_S, parse_fault

    with pytest.raises(ValueError):
        parse_fault(text)
    assert parse_fault(f"{MAX_FAULT_S:.0f}s kill gateway").at_s == MAX_FAULT_S
