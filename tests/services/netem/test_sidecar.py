"""services.netem.sidecar: compose's impairment side-car forwards with its impairment, or fails the run loudly."""

from __future__ import annotations

import re
import signal
import socket
import subprocess
import sys
import time

import pytest

from services.netem.sidecar import EXIT_NO_TRAFFIC, EXIT_USAGE, idle_proxies, main, parse_link


def test_link_specs_parse_or_say_why():
    ln = parse_link("tcp", "0.0.0.0:7447=gateway:7447")
    assert (ln.kind, ln.listen, ln.target) == ("tcp", ("0.0.0.0", 7447), ("gateway", 7447))
    for kind, text in (("tcp", "0.0.0.0:7447"), ("tcp", "0.0.0.0:7447=gateway"), ("sctp", "a:1=b:2"),
                       ("udp", "0.0.0.0:99999=gateway:7448")):
        with pytest.raises(ValueError):
            parse_link(kind, text)


def test_idle_proxies_are_those_without_an_incoming_packet():
    stats = {"tcp:7447": {"up": {"packets_in": 3}}, "udp:7448": {"up": {"packets_in": 0}}, "udp:9": {}}
    assert idle_proxies(stats) == ["udp:7448", "udp:9"]


def test_no_impairment_or_a_bad_one_is_refused(capsys):
    assert main(["--link", "uav2", "--udp", "127.0.0.1:0=127.0.0.1:9", "--impair", ""]) == EXIT_USAGE
    assert "no impairment" in capsys.readouterr().err
    assert main(["--link", "uav2", "--udp", "127.0.0.1:0=127.0.0.1:9", "--impair", "delay 5"]) == EXIT_USAGE
    assert main(["--link", "uav2", "--impair", "delay 5ms"]) == EXIT_USAGE
    assert "no --tcp or --udp" in capsys.readouterr().err


def test_a_link_nobody_uses_fails_the_run(capsys):
    """The node was not pointed at the side-car: the impairment is not applied, so exit non-zero."""
    code = main(["--link", "uav2", "--tcp", "127.0.0.1:0=127.0.0.1:9", "--udp", "127.0.0.1:0=127.0.0.1:9",
                 "--impair", "delay 50ms", "--expect-s", "0.6"])
    assert code == EXIT_NO_TRAFFIC
    err = capsys.readouterr().err
    assert "FAILED: no traffic through tcp:0, udp:0" in err and "not applied" in err


def test_forwards_delayed_and_stops_on_sigterm():
    echo = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    echo.bind(("127.0.0.1", 0))
    echo.settimeout(10)
    target = echo.getsockname()[1]
    proc = subprocess.Popen([sys.executable, "-m", "services.netem.sidecar", "--link", "uav2",
                             "--udp", f"127.0.0.1:0=127.0.0.1:{target}", "--impair", "delay 200ms",
                             "--expect-s", "2", "--interval-s", "0.2"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        m = re.search(r"udp:0 listening on 127\.0\.0\.1:(\d+) -> 127\.0\.0\.1:(\d+) \[delay 200\.0ms\]", line)
        assert m and int(m.group(2)) == target, line
        client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sent = time.monotonic()
        client.sendto(b"state", ("127.0.0.1", int(m.group(1))))
        data, _ = echo.recvfrom(100)
        assert data == b"state"
        assert time.monotonic() - sent >= 0.19  # the impairment is applied (not a speed measurement)
        time.sleep(2.5)  # past --expect-s: traffic was seen, so the side-car keeps running
        assert proc.poll() is None
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=10)
        assert proc.returncode == 0, err
        assert "final udp" in out and "up: in 1/5B out 1/5B" in out
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        echo.close()
