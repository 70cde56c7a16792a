"""Shared fixtures: real services in real processes on loopback (no mock of the bus)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from protocol.bus import multilink_endpoints
from services.orchestration.process import ProcessGroup, free_port_pair

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


@pytest.fixture
def group():
    """A process group whose children are all stopped after the test."""
    g = ProcessGroup(echo=None)
    yield g
    g.stop()


@pytest.fixture
def gateway(group):
    """A running ``skynet gateway`` (router) with the multilink endpoints; yields the endpoints."""
    tcp, udp = free_port_pair()
    endpoints = multilink_endpoints("127.0.0.1", tcp, udp)
    svc = group.start("gateway", ["gateway", "--fleet", "test", "--multilink", "--period", "0.3",
                                  *[a for e in endpoints for a in ("--listen", e)]])
    assert svc.wait_for("router up", 20), "\n".join(svc.lines)
    return endpoints


def wait_until(pred, timeout: float = 20.0, poll: float = 0.02) -> bool:
    """Poll ``pred`` until it holds or ``timeout`` seconds pass; its last value."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(poll)
    return bool(pred())


def run_node(code: str, timeout: float = 30.0) -> subprocess.CompletedProcess:
    """Run a small Python program in its own process (a second Zenoh node)."""
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True,
                          timeout=timeout)


def spawn_node(code: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", textwrap.dedent(code)], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
