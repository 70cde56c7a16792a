"""The gateway's accept guard: its pure rules, and a real gateway process that admits a session while its TLS
port is flooded with connect-and-close and silent connections (bench/accept.py measures how fast)."""

from __future__ import annotations

import json
import socket
import threading

from protocol import keys
from protocol.bus import Bus, BusConfig
from protocol.keyset import KeySet
from protocol.messages import LinkStats
from services.gateway.guard import TokenBucket, verdict
from services.keys import init
from services.orchestration.process import free_port
from tests.conftest import wait_until


def test_verdict_passes_only_a_tls_handshake_record():
    assert verdict(b"\x16") == "pass"
    assert verdict(b"") == "closed"
    assert verdict(b"G") == "not-tls" and verdict(b"\x17") == "not-tls"


def test_token_bucket_refills_at_its_rate_up_to_its_burst():
    now = [0.0]
    b = TokenBucket(2.0, 3.0, clock=lambda: now[0])
    assert [b.take() for _ in range(4)] == [True, True, True, False]
    now[0] = 0.5
    assert b.take() and not b.take()
    now[0] = 100.0
    assert sum(b.take() for _ in range(10)) == 3


def test_a_flooded_guarded_gateway_still_admits_a_session(tmp_path, group):
    ks_dir = init(tmp_path / "keys", uavs=1)
    port = free_port(socket.SOCK_STREAM)
    where = f"tls/127.0.0.1:{port}"
    gw = group.start("gateway", ["gateway", "--fleet", "guard", "--keys", str(ks_dir), "--listen", where,
                                 "--period-s", "0.3"])
    assert gw.wait_ready(20), "\n".join(gw.lines)
    stop = threading.Event()
    held: list[socket.socket] = []

    def flood() -> None:
        while not stop.is_set():
            try:
                s = socket.create_connection(("127.0.0.1", port), timeout=1.0)
            except OSError:
                continue
            if len(held) < 300:
                held.append(s)  # silent
            else:
                s.close()  # connect-and-close
            stop.wait(0.001)

    threads = [threading.Thread(target=flood) for _ in range(2)]
    for t in threads:
        t.start()
    try:
        stop.wait(1.0)
        ks = KeySet(ks_dir, "gcs")
        config = BusConfig(mode="client", connect=[where], tls_ca=str(ks.tls_ca), tls_cert=str(ks.tls_cert),
                           tls_key=str(ks.tls_key))
        stats: list[LinkStats] = []
        with Bus(config, "guard", "gcs") as bus:  # (zenoh's own 10 s connect timeout: without the guard it fails)
            assert bus.routers()
            bus.subscribe(keys.gateway_stats("guard", "1"), lambda m, s: stats.append(m), expect=LinkStats)
            assert wait_until(lambda: any(m.rejected.get("guard-closed", 0) + m.rejected.get("guard-silent", 0) > 100
                                          for m in stats), 20), json.dumps([m.rejected for m in stats[-1:]])
    finally:
        stop.set()
        for t in threads:
            t.join()
        for s in held:
            s.close()


def _gateway_of_plan(*argv: str) -> dict:
    import subprocess
    import sys

    from tests.conftest import ROOT

    out = subprocess.run([sys.executable, "-m", "services.cli", "up", "--dry-run", "--json", *argv], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    return next(p for p in json.loads(out.stdout)["processes"] if p["role"] == "gateway")


def test_the_launchers_gateway_runs_the_accept_guard_by_default():
    """``skynet up --dry-run --json`` (default secure mode): the gateway's TLS listeners sit behind the guard;
    ``--no-accept-guard`` turns it off and says so on the gateway's argv."""
    gw = _gateway_of_plan()
    assert gw["config"]["no_accept_guard"] is False
    assert "--no-accept-guard" not in gw["argv"] and all(e.startswith("tls/") for e in gw["listens"])
    off = _gateway_of_plan("--no-accept-guard")
    assert off["config"]["no_accept_guard"] is True and "--no-accept-guard" in off["argv"]

