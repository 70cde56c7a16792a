"""skynet bridge: TCP <-> Unix socket byte forwarding, real processes and sockets."""

import argparse
import select
import socket
import threading
from pathlib import Path

import pytest

from services.orchestration.bridge import Address, address
from services.orchestration.process import free_port
from tests.readiness import ServiceGroup


def test_address_parses_tcp_and_unix_and_refuses_the_rest():
    assert address("tcp:127.0.0.1:7447") == Address("tcp", host="127.0.0.1", port=7447)
    assert address("unix:/tmp/x.sock") == Address("unix", path="/tmp/x.sock")
    for bad in ("tcp:127.0.0.1", "tcp::80", "tcp:h:0", "tcp:h:70000", "unix:", "udp:h:1", "x"):
        with pytest.raises(argparse.ArgumentTypeError):
            address(bad)


def _echo_server() -> tuple[socket.socket, int]:
    srv = socket.create_server(("127.0.0.1", 0))

    def serve() -> None:
        while True:
            try:
                c, _ = srv.accept()
            except OSError:
                return
            threading.Thread(target=lambda c=c: [c.sendall(d) for d in iter(lambda: c.recv(65536), b"")],
                             daemon=True).start()

    threading.Thread(target=serve, daemon=True).start()
    return srv, srv.getsockname()[1]


def test_two_bridges_carry_a_tcp_stream_through_a_unix_socket_both_ways(tmp_path: Path):
    srv, port = _echo_server()
    sock, front = tmp_path / "b.sock", free_port()
    group = ServiceGroup(echo=None)
    try:
        inner = group.start("inner", ["bridge", "--listen", f"unix:{sock}", "--target", f"tcp:127.0.0.1:{port}"])
        outer = group.start("outer", ["bridge", "--listen", f"tcp:127.0.0.1:{front}", "--target", f"unix:{sock}"])
        for b in (inner, outer):
            assert b.wait_ready(30), b.lines
        payload = bytes(range(256)) * 4096  # 1 MiB
        with socket.create_connection(("127.0.0.1", front), timeout=10) as c:
            got = bytearray()
            sender = threading.Thread(target=c.sendall, args=(payload,))
            sender.start()
            while len(got) < len(payload):
                chunk = c.recv(65536)
                assert chunk, f"closed after {len(got)} bytes"
                got += chunk
            sender.join()
        assert bytes(got) == payload
    finally:
        group.stop()
        srv.close()
    assert any("bridge down: 1 connections" in line for line in outer.lines), outer.lines


def test_an_unreachable_target_closes_the_connection_and_is_counted(tmp_path: Path):
    front = free_port()
    group = ServiceGroup(echo=None)
    try:
        b = group.start("b", ["bridge", "--listen", f"tcp:127.0.0.1:{front}", "--target", f"unix:{tmp_path}/none"])
        assert b.wait_ready(30), b.lines
        with socket.create_connection(("127.0.0.1", front), timeout=10) as c:
            c.settimeout(10)
            assert c.recv(10) == b""  # closed, not hung
    finally:
        group.stop()
    assert any("1 target failures" in line for line in b.lines), b.lines


def test_connections_above_the_limit_are_closed_at_once_and_counted(tmp_path: Path):
    """A local flood of connections cannot grow the bridge without bound: above --max-conns each new one is
    closed at once (counted), while the one within the limit keeps flowing."""
    srv, port = _echo_server()
    front = free_port()
    group = ServiceGroup(echo=None)
    try:
        b = group.start("b", ["bridge", "--listen", f"tcp:127.0.0.1:{front}", "--target", f"tcp:127.0.0.1:{port}",
                              "--max-conns", "1"])
        assert b.wait_ready(30), b.lines
        with socket.create_connection(("127.0.0.1", front), timeout=10) as first:
            first.sendall(b"ping")
            assert first.recv(4) == b"ping"
            for _ in range(3):
                with socket.create_connection(("127.0.0.1", front), timeout=10) as extra:
                    assert extra.recv(10) == b""  # closed, not queued
            first.sendall(b"pong")
            assert first.recv(4) == b"pong"
    finally:
        group.stop()
        srv.close()
    assert any("1 connections, 3 refused" in line for line in b.lines), b.lines


def _hold_idle(front: int, n: int) -> list[socket.socket]:
    """``n`` connections that send nothing (what any local process can open)."""
    return [socket.create_connection(("127.0.0.1", front), timeout=10) for _ in range(n)]


def _closed_by_peer(c: socket.socket, timeout: float) -> bool:
    c.settimeout(timeout)
    try:
        return c.recv(10) == b""
    except (TimeoutError, OSError):
        return False


def test_64_idle_connections_are_closed_after_the_idle_timeout_and_a_real_one_flows():
    """The issue's lock-out: 64 idle connections (the default --max-conns) held by another local process.
    The bridge closes each after --idle-timeout-s, and a connection that carries bytes then flows."""
    srv, port = _echo_server()
    front = free_port()
    group = ServiceGroup(echo=None)
    idle: list[socket.socket] = []
    try:
        b = group.start("b", ["bridge", "--listen", f"tcp:127.0.0.1:{front}", "--target", f"tcp:127.0.0.1:{port}",
                              "--idle-timeout-s", "2"])
        assert b.wait_ready(30), b.lines
        idle = _hold_idle(front, 64)
        assert all(_closed_by_peer(c, 30) for c in idle)  # each one closed by the bridge, none left hanging
        with socket.create_connection(("127.0.0.1", front), timeout=10) as real:
            real.sendall(b"ping")
            assert real.recv(4) == b"ping"
    finally:
        for c in idle:
            c.close()
        group.stop()
        srv.close()
    assert any("64 closed idle" in line for line in b.lines), b.lines


def test_at_the_limit_a_new_connection_takes_the_place_of_one_idle_for_long():
    """With a long idle timeout, 64 idle connections still do not lock a new one out: at --max-conns the
    connection idle the longest (idle for 10 s or more) is closed for it; a fresh flood is refused."""
    srv, port = _echo_server()
    front = free_port()
    group = ServiceGroup(echo=None)
    idle: list[socket.socket] = []
    try:
        b = group.start("b", ["bridge", "--listen", f"tcp:127.0.0.1:{front}", "--target", f"tcp:127.0.0.1:{port}",
                              "--idle-timeout-s", "600"])
        assert b.wait_ready(30), b.lines
        idle = _hold_idle(front, 64)
        with socket.create_connection(("127.0.0.1", front), timeout=10) as early:  # all 64 fresh: refused
            assert _closed_by_peer(early, 10)
        threading.Event().wait(10.5)  # EVICT_IDLE_S
        with socket.create_connection(("127.0.0.1", front), timeout=10) as real:
            real.sendall(b"ping")
            assert real.recv(4) == b"ping"
        readable, _, _ = select.select(idle, [], [], 2.0)
        assert sum(_closed_by_peer(c, 1) for c in readable) == 1  # exactly one gave its place
    finally:
        for c in idle:
            c.close()
        group.stop()
        srv.close()
    assert any("1 refused" in line and "1 evicted idle" in line for line in b.lines), b.lines
