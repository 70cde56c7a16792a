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
    assert main(["tcp", "--target", "127.0.0.1:9", "--impair", "delay 5ms", "--duration-s", "0.2",
                 "--interval-s", "0.1", "--json"]) == 0
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


def _ctl(port: int, *command: str) -> subprocess.CompletedProcess:
    """``skynet netem ctl`` in its own process."""
    return subprocess.run([sys.executable, "-m", "services.netem.cli", "ctl", f"127.0.0.1:{port}", *command],
                          capture_output=True, text=True, timeout=20)


def test_bad_schedule_and_control_are_usage_errors(tmp_path, capsys):
    bad = tmp_path / "bad.txt"
    bad.write_text("at 0s clear\nat 5 cut\n")
    with pytest.raises(SystemExit) as e:
        main(["udp", "--target", "127.0.0.1:9", "--schedule", str(bad)])
    assert e.value.code == 2 and f"{bad}:2: bad time '5'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(["udp", "--target", "127.0.0.1:9", "--control", "0.0.0.0:0"])
    assert e.value.code == 2 and "loopback" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(["ctl", "127.0.0.1:9"])  # no command
    assert e.value.code == 2


def test_schedule_and_control_from_another_process(tmp_path):
    echo = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    echo.bind(("127.0.0.1", 0))
    echo.settimeout(10)
    schedule = tmp_path / "s.txt"
    schedule.write_text('at 0s "loss 100%"\n')
    proc = subprocess.Popen([sys.executable, "-m", "services.netem.cli", "udp", "--target",
                             "127.0.0.1:%d" % echo.getsockname()[1], "--schedule", str(schedule),
                             "--control", "127.0.0.1:0", "--json", "--interval-s", "60"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    client.settimeout(10)
    try:
        port = int(re.search(r"listening on 127\.0\.0\.1:(\d+)", proc.stdout.readline()).group(1))
        ctl_port = int(re.fullmatch(r"netem control on 127\.0\.0\.1:(\d+)\n", proc.stdout.readline()).group(1))
        client.sendto(b"lost", ("127.0.0.1", port))  # the schedule's 'loss 100%' applied at start
        stats = json.loads(_ctl(ctl_port, "stats").stdout)["stats"]
        for _ in range(100):
            if stats["up"]["packets_in"]:
                break
            stats = json.loads(_ctl(ctl_port, "stats").stdout)["stats"]
        assert stats["up"]["dropped"]["loss"] == 1 and stats["impairment"] == "loss 100.0%"
        done = _ctl(ctl_port, "set", "delay 1ms loss 0%")
        assert done.returncode == 0, done.stderr
        assert json.loads(done.stdout) == {"ok": True, "applied": "set 'delay 1.0ms'", "impairment": "delay 1.0ms",
                                           "changes": 2}
        bad = _ctl(ctl_port, "cut", "5")
        assert bad.returncode == 2 and "bad time '5'" in bad.stderr and json.loads(bad.stdout)["ok"] is False
        client.sendto(b"hello", ("127.0.0.1", port))  # the proxy kept running
        data, peer = echo.recvfrom(100)
        echo.sendto(data, peer)
        assert data == b"hello" and client.recvfrom(100)[0] == b"hello"
        assert _ctl(ctl_port, "cut").returncode == 0
        stats = json.loads(_ctl(ctl_port, "stats").stdout)["stats"]
        assert stats["cut"] is True and stats["cut_remaining_s"] is None and stats["changes"] == 3
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=10)
        assert proc.returncode == 0, err
        final = json.loads(out.splitlines()[-1])
        assert final["up"]["dropped"]["loss"] == 1 and final["up"]["sent_packets"] == 1
        assert "netem: step at 0.0s: set 'loss 100.0%'" in err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        client.close()
        echo.close()
    assert _ctl(ctl_port, "stats", "--timeout-s", "0.2").returncode == 1  # nobody answers now
