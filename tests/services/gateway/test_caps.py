"""Per-identity declaration caps: the pure policy over the router's admin space, and a real gateway process (mutual
TLS, the default key set layout, the accept guard on by default) cutting a valid identity's declaration flood while
the other identities keep their sessions (bench/declarations.py measures the memory)."""

from __future__ import annotations

import json
import socket
import time
from pathlib import Path

from protocol import keys
from protocol.bus import Bus, BusConfig
from protocol.keyset import KeySet
from protocol.messages import LinkStats
from services.gateway.caps import DeclarationCaps, Link, parse, selectors
from services.keys import init
from services.orchestration.process import free_port
from tests.conftest import wait_until

R = "@/aa"


def _decl(kind: str, key: str, clients: list[str]) -> tuple[str, bytes]:
    return f"{R}/router/{kind}/{key}", json.dumps({"routers": ["aa"], "peers": [], "clients": clients}).encode()


def _link(zid: str, lid: int, cn: str, port: int) -> tuple[str, bytes]:
    return (f"{R}/session/transport/unicast/{zid}/link/{lid}",
            json.dumps({"src": "tls/127.0.0.1:7447", "dst": f"tls/127.0.0.1:{port}?rel=1", "auth_identifier": cn})
            .encode())


def test_parse_counts_distinct_keys_per_session_and_reads_each_links_identity_and_port():
    declared, links = parse([
        _decl("queryable", "f/uav/2/camera/@adv/pub/x/1/_", ["z2"]),
        _decl("queryable", "f/uav/2/camera/@adv/pub/x/1/_", ["z2"]),  # the same key from the second selector
        _decl("subscriber", "f/uav/*/state", ["z1", "z2"]),
        _decl("token", "f/uav/1/alive", ["z1"]),
        _link("z1", 1, "uav1", 50001), _link("z2", 2, "uav2", 50002), _link("z2", 3, "uav2", 50003),
        (f"{R}/router/queryable/bad", b"not json"), (f"{R}/router/metrics", b"\x1f\x8b"),
        (f"{R}/session/transport/unicast/z3/link/4", b"[]"),
    ])
    assert declared == {"z1": 2, "z2": 2}
    assert links == [Link("z1", "uav1", 50001), Link("z2", "uav2", 50002), Link("z2", "uav2", 50003)]


def test_selectors_ask_for_every_declaration_kind_and_every_link():
    assert selectors("aa") == ["@/aa/router/subscriber/**", "@/aa/router/queryable/**", "@/aa/router/token/**",
                               "@/aa/session/transport/unicast/*/link/*"]


def test_an_identity_over_its_cap_over_all_its_sessions_is_cut_and_banned_for_a_while():
    now = [0.0]
    caps = DeclarationCaps(cap=10, ban_s=30.0, clock=lambda: now[0])
    a, b, c = Link("z2a", "uav2", 1), Link("z2b", "uav2", 2), Link("z1", "uav1", 3)
    assert caps.check({"z2a": 6, "z1": 10}, [a, c]) == []  # at the cap is fine
    assert caps.check({"z2a": 6, "z2b": 5, "z1": 10}, [a, b, c]) == [a, b]  # 11 over two sessions
    assert caps.counts() == {"decl-cap-uav2": 2} and caps.peak["uav2"] == 11
    assert caps.check({"z2a": 6, "z2b": 5}, [a, b]) == [a, b]  # still there: cut again, not counted again
    assert caps.counts() == {"decl-cap-uav2": 2}
    now[0] = 10.0
    fresh = Link("z2c", "uav2", 4)
    assert caps.check({"z2c": 1}, [fresh, c]) == [fresh]  # a new session of a banned identity: cut on sight
    assert caps.counts() == {"decl-cap-uav2": 3}
    now[0] = 31.0
    assert caps.check({"z2d": 1}, [Link("z2d", "uav2", 5)]) == []  # the ban is over
    assert caps.check({"x": 99}, [Link("x", "", 6)]) == []  # no identity (no TLS): nothing to name, nothing cut


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def test_a_valid_identitys_declaration_flood_is_cut_and_counted_and_the_others_keep_their_sessions(tmp_path, group):
    """uav2's own certificate declares subscribers on ever new keys that its ACL grant on ``uav/*/state`` allows
    until the gateway (default secure mode: mutual TLS, the ACL, the accept guard) cuts it at its cap; the ground
    station's and uav1's sessions stay up, the cut is counted in the gateway's statistics, and the gateway's memory
    stays within a few MB of where it started."""
    fleet, cap = "caps", 150
    ks_dir = init(tmp_path / "keys", uavs=2)
    ends = [f"tls/127.0.0.1:{free_port(socket.SOCK_STREAM)}?rel=1", f"tls/127.0.0.1:{free_port(socket.SOCK_STREAM)}?rel=0"]
    gw = group.start("gateway", ["gateway", "--fleet", fleet, "--keys", str(ks_dir), "--multilink", "--period", "0.3",
                                 "--declaration-cap", str(cap), *[x for e in ends for x in ("--listen", e)]])
    assert gw.wait_for("router up", 30), "\n".join(gw.lines)
    assert any("accept guard on" in line for line in gw.lines), "\n".join(gw.lines)

    def config(role: str) -> BusConfig:
        ks = KeySet(ks_dir, role)
        return BusConfig(mode="client", connect=ends, multilink=True, tls_ca=str(ks.tls_ca), tls_cert=str(ks.tls_cert),
                         tls_key=str(ks.tls_key))

    stats: list[LinkStats] = []
    with Bus(config("gcs"), fleet, "gcs") as gcs, Bus(config("uav1"), fleet, "uav1") as uav1:
        gcs.subscribe(keys.gateway_stats(fleet, "1"), lambda m, s: stats.append(m), expect=LinkStats)
        legit = [uav1.session.declare_queryable(keys.cmd(fleet, 1), lambda q: None),
                 uav1.session.declare_subscriber(keys.state(fleet, 2), lambda s: None)]
        assert wait_until(lambda: len(stats) >= 2, 20)
        router = gcs.routers()[0]
        seen = [str(r.ok.key_expr) for r in gcs.session.get("@/**", timeout=3) if r.ok is not None]
        assert not [k for k in seen if k.startswith(f"@/{router}/")], seen  # the gateway's admin space is its own
        rss0 = _rss_mb(gw.proc.pid)
        flooder = Bus(config("uav2"), fleet, "uav2")
        try:
            assert flooder.routers()
            cut_at = None
            for i in range(4 * cap):
                flooder.session.declare_subscriber(f"{keys.fleet_root(fleet)}/uav/x{i}/state", lambda s: None)
                if i % 50 == 0 and not flooder.routers():
                    cut_at = i
                    break
            assert wait_until(lambda: any(m.rejected.get("decl-cap-uav2", 0) >= 1 for m in stats), 60), \
                "\n".join(gw.lines[-30:])
            assert any("uav2 holds" in line and f"(cap {cap})" in line for line in gw.lines), "\n".join(gw.lines[-20:])
            assert cut_at is None or cut_at > cap, cut_at  # not cut below the cap
            time.sleep(1.0)
            # the others were never cut, and they still talk through the gateway
            assert gcs.routers() and uav1.routers()
            assert not any(k.startswith("decl-cap-") and k != "decl-cap-uav2" for m in stats for k in m.rejected)
            n_stats = len(stats)
            assert wait_until(lambda: len(stats) > n_stats + 2, 30)  # the gcs still hears the gateway
            # banned: the flooder's reconnections are cut again (its session holds no route to the router for long)
            assert wait_until(lambda: not flooder.routers(), 30), "\n".join(gw.lines[-30:])
        finally:
            flooder.close()
        time.sleep(2.0)
        rss1 = _rss_mb(gw.proc.pid)
        assert rss1 - rss0 < 20.0, (rss0, rss1)
        for q in legit:
            q.undeclare()
