"""Conditions changed while a proxy runs: update, cut, restore, schedules, the control
channel — on real sockets on 127.0.0.1. Bounds are generous: a step may be applied a scheduler
slice late on the 2 shared cores, so observations keep guard bands around every change."""

from __future__ import annotations

import os
import socket
import struct
import threading
import time

import pytest

from services.netem.control import ControlServer, send_control
from services.netem.model import Impairment
from services.netem.proxy import TcpProxy, UdpProxy
from services.netem.schedule import parse_schedule
from tests.services.netem.sockets import eventually, netem_threads, send_paced, udp_client


def stamped(i: int) -> bytes:
    """A datagram carrying its sequence number and send time."""
    return struct.pack("!Id", i, time.monotonic())


def unstamp(data: bytes) -> tuple[int, float]:
    return struct.unpack("!Id", data[:12])


# ------------------------------------------------------------------------------ API
def test_update_before_and_after_start_and_the_impairment_view(sink):
    proxy = UdpProxy(target=sink.address, impairment="delay 5ms", direction="up", seed=0)
    assert proxy.impairment("up") == Impairment.parse("delay 5ms") and proxy.impairment("down") == Impairment()
    with pytest.raises(ValueError, match="differ"):
        proxy.impairment("both")
    proxy.update("loss 1%", direction="down")  # before start: becomes the initial impairment
    with pytest.raises(RuntimeError):
        proxy.cut(1.0)
    with proxy:
        assert proxy.impairment("down") == Impairment.parse("loss 1%")
        assert proxy.stats()["impairment"] == "up: delay 5.0ms; down: loss 1.0%"
        assert proxy.update("") == Impairment() and proxy.impairment("both") == Impairment()
        for bad, kwargs in (("loss 2", {}), ("delay 5ms", {"direction": "sideways"}), (3, {})):
            with pytest.raises(ValueError):
                proxy.update(bad, **kwargs)
        for bad in (0.0, -1.0, float("nan"), float("inf"), "5s"):
            with pytest.raises(ValueError):
                proxy.cut(bad)
        s = proxy.stats()
        assert s["changes"] == 2 and s["impairment"] == "none" and s["up"]["impairment"] == "none"
        assert s["cut"] is False and s["cut_remaining_s"] is None
        proxy.cut(30.0)
        s = proxy.stats()
        assert s["cut"] is True and 0.0 < s["cut_remaining_s"] <= 30.0 and s["changes"] == 3
        proxy.restore()
        assert proxy.stats()["cut"] is False and proxy.apply("stats")["stats"]["changes"] == 4
        with pytest.raises(ValueError):
            proxy.apply("cut now")
    assert netem_threads() == []


# ------------------------------------------------------------------------------ UDP
def test_udp_update_mid_stream_changes_loss_and_delay(sink):
    n, p = 500, 0.3
    with UdpProxy(target=sink.address, seed=11) as proxy:
        c = udp_client()
        send_paced(c, proxy.address, [stamped(i) for i in range(n)])
        assert eventually(lambda: proxy.stats()["up"]["sent_packets"] == n)
        first = proxy.stats()["up"]
        proxy.update("delay 40ms loss 30%")
        send_paced(c, proxy.address, [stamped(n + i) for i in range(n)])
        assert eventually(lambda: proxy.stats()["up"]["packets_in"] == 2 * n)
        second = proxy.stats()["up"]
        sink.wait_count(second["packets_out"])
        c.close()
    assert first["dropped"]["loss"] == 0 and first["packets_out"] == n
    lost = second["dropped"]["loss"]
    assert abs(lost - n * p) < 4 * (n * p * (1 - p)) ** 0.5  # binomial, 4 sigma: 150 +- 41
    got = {unstamp(d)[0]: t - unstamp(d)[1] for t, d in sink.got}
    assert len(got) == len(sink.got) == 2 * n - lost
    before = sorted(v for k, v in got.items() if k < n)
    after = [v for k, v in got.items() if k >= n]
    assert len(before) == n and min(after) >= 0.040 - 0.0005  # the new delay, never early
    assert before[n // 2] < min(after)  # the clean half was not delayed (median below the delay)


def test_udp_cut_drops_everything_then_traffic_resumes(sink):
    with UdpProxy(target=sink.address, impairment="delay 1ms", seed=0) as proxy:
        c = udp_client()

        def burst(tag: bytes, k: int = 20) -> int:
            before = proxy.stats()["up"]["packets_in"]
            send_paced(c, proxy.address, [tag] * k)
            assert eventually(lambda: proxy.stats()["up"]["packets_in"] == before + k)
            return k

        burst(b"before")
        proxy.cut()  # until restore
        burst(b"cut")
        assert proxy.stats()["cut_remaining_s"] is None
        proxy.restore()
        burst(b"restored")
        proxy.cut(0.3)  # ends by itself
        burst(b"cut 0.3s")
        assert eventually(lambda: not proxy.stats()["cut"])
        burst(b"after")
        sink.wait_count(60)
        s = proxy.stats()
        c.close()
    assert s["up"]["dropped"]["outage"] == 40 and s["changes"] == 3
    assert [d for _, d in sink.got] == [b"before"] * 20 + [b"restored"] * 20 + [b"after"] * 20


# ------------------------------------------------------------------------------ TCP
def test_tcp_cut_stalls_both_ways_then_delivers_every_byte_in_order(tcp_echo):
    data = os.urandom(400_000)
    received = bytearray()
    with TcpProxy(target=tcp_echo.address, seed=0) as proxy, socket.create_connection(proxy.address, timeout=20) as c:
        reader = threading.Thread(target=lambda: [received.extend(b) for b in iter(lambda: c.recv(1 << 16), b"")])
        reader.start()
        c.sendall(data[:100_000])
        assert eventually(lambda: len(received) == 100_000)
        proxy.cut()
        c.sendall(data[100_000:200_000])  # accepted by the proxy's reader, held by its writer
        assert eventually(lambda: proxy.stats()["up"]["held_link_down"] > 0)
        # nothing crosses while cut: in 0.3 s not one more byte reached the echo and came back
        held = len(received)
        time.sleep(0.3)
        assert len(received) == held == 100_000
        assert proxy.stats()["up"]["sent_bytes"] == 100_000
        # a connection opened during the cut is accepted but not connected to the target
        with socket.create_connection(proxy.address, timeout=5) as late:
            late.sendall(b"hello")
            assert eventually(lambda: proxy.stats()["held_connections"] == 1)
            late.settimeout(0.3)
            with pytest.raises(TimeoutError):
                late.recv(10)
            assert tcp_echo.accepted == 1
            proxy.restore()
            late.settimeout(10)
            assert late.recv(10) == b"hello"
        c.sendall(data[200_000:])
        c.shutdown(socket.SHUT_WR)
        reader.join(20)
        s = proxy.stats()
    assert bytes(received) == data  # every byte, in order
    assert s["held_on_accept"] == 1 and s["held_connections"] == 0 and tcp_echo.accepted == 2


def test_tcp_update_changes_the_delay_of_a_live_connection(tcp_echo):
    def rtt(c: socket.socket) -> float:
        t = time.monotonic()
        c.sendall(b"ping")
        got = b""
        while len(got) < 4:
            got += c.recv(4 - len(got))
        return time.monotonic() - t

    with TcpProxy(target=tcp_echo.address) as proxy, socket.create_connection(proxy.address, timeout=5) as c:
        c.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        fast = sorted(rtt(c) for _ in range(9))
        proxy.update("delay 30ms")
        slow = [rtt(c) for _ in range(5)]
    assert min(slow) >= 0.060 - 0.0005 and fast[4] < min(slow)  # 30 ms each way from now on


# ------------------------------------------------------------------------------ schedule
SCHEDULE = """\
at 0s   "delay 60ms"
at 1s   "loss 100%"
at 2s   clear
at 2s   cut 1s
"""


def test_a_schedule_drives_the_proxy_through_its_steps(sink):
    """Probe every 10 ms for 4 s; judge each probe by its send time, 0.2 s away from any step.

    Expected: [0, 1) s delayed >= 60 ms, [1, 2) lost (loss), [2, 3) lost (cut), [3, 4) clean.
    """
    applied = []
    proxy = UdpProxy(target=sink.address, seed=2)
    proxy.play(parse_schedule(SCHEDULE), on_step=lambda step, err: applied.append((step.line, err)))
    with proxy:
        c = udp_client()
        sent: dict[int, float] = {}
        i = 0
        while (t := time.monotonic() - proxy._t0) < 4.0:
            sent[i] = t
            c.sendto(stamped(i), proxy.address)
            i += 1
            time.sleep(0.01)
        assert eventually(lambda: proxy.stats()["up"]["packets_in"] == i)
        sink.wait_count(proxy.stats()["up"]["packets_out"])
        s = proxy.stats()
        c.close()
    arrived = {unstamp(d)[0]: t - unstamp(d)[1] for t, d in sink.got}

    def phase(lo: float, hi: float) -> list[int]:
        return [k for k, t in sent.items() if lo + 0.2 <= t < hi - 0.2]

    assert all(arrived.get(k, 0.0) >= 0.060 - 0.0005 for k in phase(0.0, 1.0))  # delivered, delayed
    assert all(k not in arrived for k in phase(1.0, 2.0) + phase(2.0, 3.0))
    assert all(k in arrived for k in phase(3.0, 4.2))
    assert len(phase(1.0, 2.0)) <= s["up"]["dropped"]["loss"] <= len(phase(0.8, 2.2)) + 5
    assert len(phase(2.0, 3.0)) <= s["up"]["dropped"]["outage"] <= len(phase(1.8, 3.2)) + 5
    assert applied == [(1, None), (2, None), (3, None), (4, None)]
    assert s["schedule"] == {"steps": 4, "applied": 4, "errors": 0} and s["impairment"] == "none"


def test_play_after_start_applies_due_steps_at_once_and_stop_ends_the_schedule(sink):
    with UdpProxy(target=sink.address) as proxy:
        proxy.play("at 0s delay 5ms\nat 3600s cut")
        assert proxy.impairment("both") == Impairment.parse("delay 5ms")
        assert any(t.endswith("-schedule") for t in netem_threads())
        with pytest.raises(RuntimeError):
            proxy.play("at 0s clear")
    assert netem_threads() == []  # stop() joined the runner waiting for its 1 h step
    assert proxy.stats()["schedule"] == {"steps": 2, "applied": 1, "errors": 0}


# ------------------------------------------------------------------------------ control channel
def test_control_channel_applies_commands_and_answers_bad_ones_with_errors(udp_echo):
    with UdpProxy(target=udp_echo.address, seed=0) as proxy, ControlServer(proxy) as ctl:
        c = udp_client()
        reply = send_control(ctl.address, 'set "loss 100%"')
        assert reply == {"ok": True, "applied": "set 'loss 100.0%'", "impairment": "loss 100.0%", "changes": 1}
        c.sendto(b"lost", proxy.address)
        assert eventually(lambda: proxy.stats()["up"]["dropped"]["loss"] == 1)
        for bad in ("bogus", "cut 5", "set up", "", "restore now"):
            reply = send_control(ctl.address, bad)
            assert reply["ok"] is False and reply["error"], bad
        assert send_control(ctl.address, "clear")["impairment"] == "none"
        c.sendto(b"through", proxy.address)
        assert c.recvfrom(100)[0] == b"through"  # the proxy kept running
        stats = send_control(ctl.address, "stats")["stats"]
        assert stats["changes"] == 2 and stats["up"]["dropped"]["loss"] == 1
        assert ctl.requests == 8 and ctl.errors == 5
        c.close()
    assert netem_threads() == []


def test_control_channel_is_loopback_only(sink):
    proxy = UdpProxy(target=sink.address)
    for addr in (("0.0.0.0", 0), ("8.8.8.8", 9)):
        with pytest.raises(ValueError, match="loopback"):
            ControlServer(proxy, addr)
    with pytest.raises(TimeoutError), socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as nobody:
        nobody.bind(("127.0.0.1", 0))  # bound, never answers
        send_control(nobody.getsockname(), "stats", timeout_s=0.2)
