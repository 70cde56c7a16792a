"""services.orchestration.process: the log pumps never die, whatever the echo file does; listening
ports are drawn where no outgoing connection takes them."""

import contextlib
import socket

from services.orchestration.process import LOWEST_LISTEN_PORT, ProcessGroup, ephemeral_range, free_port, listen_ports


def test_log_pump_survives_a_full_disk_and_keeps_reading(capfd):
    """Writing the services' log to a full disk (/dev/full: every write is ENOSPC) used to kill the pump
    thread after the first line, so the service's later output was never read (and a chatty service would
    block on its full pipe). Now every line is still read, the failure is counted and said once."""
    full = open("/dev/full", "w")
    group = ProcessGroup(echo=full)
    try:
        gw = group.start("gateway", ["gateway", "--fleet", "pump", "--listen", "tcp/127.0.0.1:0"])
        assert gw.wait_for("router up", 30), gw.lines
    finally:
        group.stop()
        with contextlib.suppress(OSError):
            full.close()  # what is still buffered cannot be written either
    assert any("shutting down" in line for line in gw.lines), gw.lines  # read after the write errors
    assert group.echo_errors >= 2
    err = capfd.readouterr().err
    assert err.count("services' log /dev/full failed") == 1 and "No space left" in err


def test_pump_reads_undecodable_output():
    """Bytes that are not UTF-8 on a service's output would end a strict text pump; they are replaced."""
    group = ProcessGroup(echo=None)
    group.env["PYTHONIOENCODING"] = "latin-1"
    try:
        svc = group.start("gateway", ["gateway", "--fleet", "\u00e9t\u00e9", "--listen", "tcp/127.0.0.1:0"])
        svc.proc.wait(30)
        svc._reader.join(5)
    finally:
        group.stop()
    assert svc.lines and not svc._reader.is_alive()
    assert any("\ufffd" in line for line in svc.lines), svc.lines


def test_free_ports_are_outside_the_kernels_ephemeral_range_and_bindable():
    """A listening port is never one an outgoing connection may take meanwhile (the kernel's ephemeral range)."""
    lo, hi = ephemeral_range()
    for kind in (socket.SOCK_STREAM, socket.SOCK_DGRAM):
        ports = {free_port(kind) for _ in range(50)}
        assert all(LOWEST_LISTEN_PORT <= p and not lo <= p <= hi for p in ports), sorted(ports)
        assert len(ports) == 50  # never the same port twice in a process (a launcher's services would clash)
        with socket.socket(socket.AF_INET, kind) as s:
            s.bind(("127.0.0.1", ports.pop()))


def test_listen_ranges_around_the_ephemeral_one(tmp_path):
    assert listen_ports((32768, 60999)) == [range(20000, 32768), range(61000, 65536)]
    assert listen_ports((15000, 65535)) == []  # nothing outside it: free_port falls back to port 0
    assert listen_ports((1024, 25000)) == [range(25001, 65536)]
    bad = tmp_path / "range"
    bad.write_text("not numbers\n")
    assert ephemeral_range(str(bad)) == (32768, 60999) == ephemeral_range(str(tmp_path / "missing"))


def test_a_service_ready_line_is_noted_and_carried_over_restarts():
    from tests.conftest import wait_until

    with ProcessGroup(echo=None) as g:
        # a tool that cannot attach: a one-line error, exit 2, never ready
        bad = g.start("bad", ["video", "--network", "/nonexistent/network.json"], ready="video up")
        assert wait_until(lambda: not bad.alive(), 30)
        assert bad.ready_at is None and not bad.ever_ready
        assert bad.reason().startswith("skynet video: error: no network running here"), bad.lines
        again = g.restart("bad")
        assert again.ready_text == "video up" and not again.was_ready and again.restarts == 1
        # a service that printed its line was ready, and a later run of it was ready once
        ok = g.start("schema", ["schema"], ready="SkyNet wire contract")
        assert wait_until(lambda: ok.ready_at is not None, 30), ok.lines[-5:]
        assert g.restart("schema").was_ready
