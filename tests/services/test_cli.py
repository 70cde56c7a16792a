"""The skynet command: every subcommand exists, bad input gives a one-line error and exit 2."""

import subprocess
import sys

import pytest

from services.cli import COMMANDS


def skynet(*args, timeout=30):
    return subprocess.run([sys.executable, "-m", "services.cli", *args], capture_output=True, text=True,
                          timeout=timeout)


def test_help_lists_every_command():
    out = skynet("--help")
    assert out.returncode == 0
    for name in COMMANDS:
        assert f"  {name}" in out.stdout


@pytest.mark.parametrize("args,needle", [
    (["teleport"], "unknown command"),
    (["edge", "--uav", "300", "--camera", "none"], "argument --uav: Input should be less than or equal to 255"),
    (["gateway", "--listen", "garbage"], "Endpoints must be of the form"),
    (["gateway", "--listen", "tls/127.0.0.1:abc"], "invalid port value"),  # the accept guard, on by default, passes it on
    (["gateway", "--listen", "tls/nohost"], "invalid socket address"),
    (["mission", "--impair", "foo"], "--impair 'foo': unknown keyword 'foo'"),
    (["mission", "--impair", "uav2/sctp=delay 5ms"], "class 'sctp' is not udp or tcp"),
    (["mission", "--impair", "uav9=delay 5ms", "--dry-run"], "--impair 'uav9=delay 5ms': link 'uav9'"),
    (["netem", "udp", "--target", "127.0.0.1:9", "--impair", "uav2=delay 5ms"], "this proxy is one link"),
    (["netem", "udp", "--target", "127.0.0.1:9", "--impair", "delay 5xs"], "--impair 'delay 5xs': bad time unit"),
    (["detector"], "No peer specified"),
    (["gcs", "--scenario", "/nonexistent.toml"], "cannot read scenario file"),
    (["edge", "--uav", "1", "--home", "1,2"], "expected x,y,z"),
    (["web", "--network", "n.json", "-e", "tcp/127.0.0.1:9"], "--network: not with -e/--connect"),
    (["video", "--network", "n.json", "-c", "zenoh.json5"], "--network: not with -e/--connect, -c/--config"),
])
def test_bad_input_is_a_clear_error_not_a_traceback(args, needle):
    out = skynet(*args)
    assert out.returncode == 2
    assert needle in out.stderr
    assert "Traceback" not in out.stderr
