"""Tests of services.netem.cli: arguments, the counter lines, a real proxy process stopped by Ctrl-C."""

from __future__ import annotations

import json
import re
import signal
import socket
import subprocess
import sys

import pytest

from services.netem.cli import main


def test_bad_impairment_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as e:
        main(["udp", "--target", "127.0.0.1:9", "--impair", "delay 50ms loss 2"])
    assert e.value.code == 2 and "'2'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["udp", "--target", "localhost"])  # no port
    with pytest.raises(SystemExit):
        main(["icmp", "--target", "127.0.0.1:9"])


def test_runs_for_a_duration_and_prints_counters(capsys):
    assert main(["tcp", "--target", "127.0.0.1:9", "--impair", "delay 5ms", "--duration", "0.2",
                 "--interval", "0.1", "--json"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert re.match(r"netem tcp listening on 127\.0\.0\.1:\d+ -> 127\.0\.0\.1:9 \[both: delay 5\.0ms\]", lines[0])
    final = json.loads(lines[-1])
    assert final["kind"] == "tcp" and final["impairment"] == "delay 5.0ms" and final["up"]["bytes_in"] == 0


def test_proxy_process_forwards_and_stops_on_ctrl_c():
    echo = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    echo.bind(("127.0.0.1", 0))
    echo.settimeout(10)
    proc = subprocess.Popen([sys.executable, "-m", "services.netem.cli", "udp", "--target",
                             "127.0.0.1:%d" % echo.getsockname()[1], "--impair", "delay 10ms", "--seed", "1"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        first = proc.stdout.readline()
        port = int(re.search(r"listening on 127\.0\.0\.1:(\d+)", first).group(1))
        client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        client.settimeout(10)
        client.sendto(b"hello", ("127.0.0.1", port))
        data, peer = echo.recvfrom(100)
        echo.sendto(data, peer)
        assert data == b"hello" and client.recvfrom(100)[0] == b"hello"
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=10)
        assert proc.returncode == 0, out
        assert "up: in 1/5B out 1/5B" in out.splitlines()[-1]
        client.close()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        echo.close()
