"""services.orchestration.process: the log pumps never die, whatever the echo file does; listening
ports are drawn where no outgoing connection takes them."""

import contextlib
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

from services.orchestration.process import (
    CLAIM_S,
    LOWEST_LISTEN_PORT,
    ProcessGroup,
    _cursor,
    claim,
    claims_dir,
    ephemeral_range,
    free_port,
    listen_ports,
)

ROOT = Path(__file__).resolve().parents[3]


def test_log_pump_survives_a_full_disk_and_keeps_reading(capfd):
    """Writing the services' log to a full disk (/dev/full: every write is ENOSPC) used to kill the pump
    thread after the first line, so the service's later output was never read (and a chatty service would
    block on its full pipe). Now every line is still read, the failure is counted and said once."""
    full = open("/dev/full", "w")
    group = ProcessGroup(echo=full)
    try:
        gw = group.start("gateway", ["gateway", "--fleet", "pump", "--listen", "tcp/127.0.0.1:0"], ready=True)
        assert gw.wait_ready(30), gw.lines
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


def test_a_service_ready_signal_is_noted_and_carried_over_restarts():
    """Readiness comes from the service's ready pipe (protocol.readiness), not from its log text."""
    from protocol.readiness import READY_FD_ENV
    from tests.conftest import wait_until

    with ProcessGroup(echo=None) as g:
        # a tool that cannot attach: a one-line error, exit 2, never ready
        bad = g.start("bad", ["video", "--network", "/nonexistent/network.json"], ready=True)
        assert wait_until(lambda: not bad.alive(), 30)
        assert not bad.wait_ready(5) and bad.ready_at is None and not bad.ever_ready
        assert bad.reason().startswith("skynet video: error: no network running here"), bad.lines
        again = g.restart("bad")
        assert again.ready and not again.was_ready and again.restarts == 1
        # a service that signalled was ready, and a later run of it was ready once
        gw = g.start("gateway", ["gateway", "--fleet", "ready", "--listen", "tcp/127.0.0.1:0"], ready=True)
        assert gw.wait_ready(30), gw.lines[-5:]
        assert gw.ready_as == ("gateway", "1") and READY_FD_ENV not in gw.env
        assert any("router up" in ln for ln in gw.lines)  # the line for humans stays
        assert g.restart("gateway").was_ready
        # a process that prints the words of a ready line is not ready: only its pipe counts
        liar = g.start("liar", ["schema"], ready=True)
        assert not liar.wait_ready(30) and liar.ready_at is None


def test_the_ready_line_is_checked():
    from protocol.readiness import parse_ready, ready_line

    assert parse_ready(ready_line("edge", "uav3")) == ("edge", "uav3")
    for bad in (b"ready edge uav3", b"ready edge\n", b"READY=1\n", b"ready e u x\n", b"ready \xff u\n",
                b"ready edge " + b"u" * 300 + b"\n", b"ready edge ../x\n"):
        assert parse_ready(bad) is None, bad
    for role, name in (("edge", "a b"), ("", "x"), ("edge", "x" * 65)):
        try:
            ready_line(role, name)
        except ValueError:
            continue
        raise AssertionError((role, name))


def test_notify_ready_writes_one_line_only_to_a_pipe(tmp_path, monkeypatch):
    """The service side: nothing without the variable; a pipe gets one line and is closed; anything else (a
    standard stream, a file, garbage) is left alone with a warning, never an exception."""
    import os

    from protocol.readiness import READY_FD_ENV, notify_ready

    monkeypatch.delenv(READY_FD_ENV, raising=False)
    assert notify_ready("edge", "uav1") is False
    r, w = os.pipe()
    try:
        monkeypatch.setenv(READY_FD_ENV, str(w))
        assert notify_ready("edge", "uav1") is True and READY_FD_ENV not in os.environ
        assert os.read(r, 100) == b"ready edge uav1\n" and os.read(r, 100) == b""  # written, then closed
    finally:
        os.close(r)
    with open(tmp_path / "f", "w") as f:
        for value in ("1", str(f.fileno()), "nope", "99999"):
            monkeypatch.setenv(READY_FD_ENV, value)
            assert notify_ready("edge", "uav1") is False
    assert (tmp_path / "f").read_text() == ""


class _Proc:
    """A stand-in for a child process: alive until ``ended`` is set."""

    def __init__(self) -> None:
        self.ended = False

    def poll(self):
        return 0 if self.ended else None


def test_the_ready_reader_takes_only_one_well_formed_line_and_never_hangs():
    """The child is untrusted: garbage, an endless line, a line never finished, or a child that exits without a
    word leave it not ready, and the reader always ends (bounded read, no wait past the child's exit)."""
    import os
    import threading
    import time

    from services.orchestration.process import Service, _read_ready

    def run(data: bytes | None, end: bool = True, close: bool = True) -> Service:
        svc = Service("x", _Proc(), ready=True)
        r, w = os.pipe()
        t = threading.Thread(target=_read_ready, args=(svc, r), daemon=True)
        t.start()
        if data:
            os.write(w, data)
        if close:
            os.close(w)
        if end:
            svc.proc.ended = True
        t.join(5)
        assert not t.is_alive()
        if not close:
            os.close(w)
        return svc

    assert run(b"ready edge uav1\n").ready_as == ("edge", "uav1")
    assert run(b"ready edge uav1\nready edge uav2\n").ready_as == ("edge", "uav1")  # the first line only
    for bad in (b"router up\n", b"ready\x00edge uav1\n", b"x" * 1000, b"ready edge uav1"):
        svc = run(bad)
        assert svc.ready_at is None and svc.ready_as is None, bad
    # a child that exits while a descendant still holds the write end: the reader ends on the exit
    t0 = time.monotonic()
    svc = run(b"ready ed", end=True, close=False)
    assert svc.ready_at is None and time.monotonic() - t0 < 5


def test_two_processes_whose_cursors_meet_never_hand_out_the_same_port():
    """A fault mission's edge could not listen ("Can not create a new TLS listener", exited 3 times): two
    launchers (two test workers' missions) whose port cursors met both found the same ports free before either
    service bound them. Each process claims what it hands out (a file per port, under a lock); this runs two
    processes whose cursors start at the same port, over claims an earlier run left stale (a CI machine that ran
    the suite before: two processes taking over one stale claim both won, one deleting the other's)."""
    code = ("import sys, services.orchestration.process as p\n"
            "p._cursor.next(); p._cursor._at = int(sys.argv[1])\n"
            "print(' '.join(str(p.free_port()) for _ in range(40)))\n")
    _cursor.next()
    for k in range(4):
        start = 7000 + (os.getpid() * 4 + k * 97) % 1000  # away from the other tests' cursors
        for port in _cursor._ports[start:start + 120]:
            stale = claims_dir() / f"tcp-{port}"
            stale.touch()
            os.utime(stale, (time.time() - CLAIM_S - 10,) * 2)
        runs = [subprocess.Popen([sys.executable, "-c", code, str(start)], stdout=subprocess.PIPE, text=True, cwd=ROOT)
                for _ in range(2)]
        got = [set(map(int, r.communicate(timeout=60)[0].split())) for r in runs]
        assert len(got[0]) == len(got[1]) == 40 and not got[0] & got[1], (k, sorted(got[0] & got[1]))


def test_a_claim_is_held_for_its_time_then_taken_over():
    port = 65000 + os.getpid() % 500
    path = claims_dir() / f"udp-{port}"
    path.unlink(missing_ok=True)
    assert claim(port, socket.SOCK_DGRAM)
    assert not claim(port, socket.SOCK_DGRAM)  # held (by anyone, this process included)
    assert claim(port, socket.SOCK_DGRAM, now=time.time() + CLAIM_S + 1)  # stale: taken over
    path.unlink(missing_ok=True)
