"""The gateway's shell around its router: what happens when a reopen fails."""

from __future__ import annotations

import logging
import socket

import pytest
import zenoh

from protocol.signals import StopEvent
from services.gateway import service
from services.orchestration.process import free_port


def test_a_router_that_cannot_reopen_is_retried_and_the_accept_guard_stops_at_the_end(monkeypatch, caplog):
    port = free_port(socket.SOCK_STREAM)
    calls: list[list[str]] = []

    def fake_run(self, config, names):
        calls.append(names)
        if len(calls) == 1:  # served, then the key set changed
            self.opened += 1
            return ["gcs"]
        if len(calls) == 2:  # the old listener not yet released
            raise zenoh.ZError("Can not create a new TCP listener bound to 127.0.0.1: Address already in use")
        with socket.create_connection(("127.0.0.1", port), timeout=2):  # the guard still accepts meanwhile
            pass
        return None

    monkeypatch.setattr(service.Relay, "run", fake_run)
    monkeypatch.setattr(service, "stop_event_on_signals", StopEvent)  # pytest's own handlers stay
    with caplog.at_level(logging.WARNING):
        assert service.main(["--listen", f"tls/127.0.0.1:{port}", "--period-s", "0.05"]) == 0
    assert calls == [[], ["gcs"], []]  # the retry reads the key set again (none here)
    assert any("did not reopen" in r.getMessage() and "Address already in use" in r.getMessage()
               for r in caplog.records), caplog.text
    with pytest.raises(OSError):  # the accept guard no longer listens once the gateway ended
        socket.create_connection(("127.0.0.1", port), timeout=1).close()


def test_a_router_that_cannot_open_at_all_is_an_error_not_a_retry(monkeypatch):
    def fake_run(self, config, names):
        raise zenoh.ZError("Can not create a new TCP listener")

    monkeypatch.setattr(service.Relay, "run", fake_run)
    with pytest.raises(zenoh.ZError, match="listener"):  # the command line's one-line error (services/cli.py)
        service.main(["--listen", "tcp/127.0.0.1:0"])
