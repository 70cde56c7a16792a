"""Fixtures of the netem proxy tests: real servers on 127.0.0.1, closed after each test."""

from __future__ import annotations

import pytest

from tests.services.netem.sockets import TcpEcho, UdpServer


@pytest.fixture
def sink():
    s = UdpServer()
    yield s
    s.close()


@pytest.fixture
def udp_echo():
    s = UdpServer(echo=True)
    yield s
    s.close()


@pytest.fixture
def tcp_echo():
    s = TcpEcho()
    yield s
    s.close()
