"""services.orchestration.process (issue 12): the log pumps never die, whatever the echo file does."""

import contextlib

from services.orchestration.process import ProcessGroup


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
