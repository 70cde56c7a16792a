"""Waiting for a service the way the launcher does: on its ready signal (protocol.readiness), not its log text.

``start_ready(group, name, argv)`` starts ``python -m services.cli ARGV`` in a
:class:`~services.orchestration.process.ProcessGroup` with a ready pipe and waits for its ``ready <role> <name>``
line; ``wait_ready(svc)`` waits on one already started with ``ready=True``. Either fails the test with the
service's last output lines when it does not come up. ``launched(argv)`` is the same for a command a user types
(``skynet up ...``) run on its own, and ``interrupt(proc)`` ends any of them as the user does, with Ctrl-C.
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from protocol.readiness import MAX_LINE, READY_FD_ENV, parse_ready
from services.orchestration.process import ProcessGroup, Service


class ServiceGroup(ProcessGroup):
    """A :class:`ProcessGroup` whose services each get a ready pipe (``ready=True``), so a test waits for a
    service with :meth:`Service.wait_ready` or :func:`wait_ready`, never on its log text."""

    def start(self, name: str, args: list[str], *a, ready: bool = True, **kw) -> Service:  # type: ignore[override]
        return super().start(name, args, *a, ready=ready, **kw)


def wait_ready(svc: Service, timeout: float = 30.0) -> Service:
    """``svc`` once it signalled it is up; AssertionError with its last lines otherwise."""
    assert svc.ready, f"{svc.name} was started without a ready pipe (ready=True)"
    assert svc.wait_ready(timeout), f"{svc.name} did not signal it is up within {timeout:g} s:\n" + "\n".join(
        list(svc.lines)[-20:])
    return svc


def start_ready(group: ProcessGroup, name: str, argv: list[str], timeout: float = 30.0, **kw) -> Service:
    """Start ``name`` with a ready pipe and wait until it is up (:func:`wait_ready`)."""
    return wait_ready(group.start(name, argv, ready=True, **kw), timeout)


class ReadyPipe:
    """A ready pipe for a process started without a process group (``subprocess.Popen``)::

        pipe = ReadyPipe()
        proc = subprocess.Popen(argv, env=pipe.env(os.environ), pass_fds=pipe.pass_fds)
        pipe.started()          # closes the parent's copy of the write end
        assert pipe.wait(proc, 60) == ("video", "video")
    """

    def __init__(self) -> None:
        self._r, self._w = os.pipe()
        self.pass_fds = (self._w,)
        self.seen: tuple[str, str] | None = None

    def env(self, base: dict[str, str]) -> dict[str, str]:
        return {**base, READY_FD_ENV: str(self._w)}

    def started(self) -> None:
        os.close(self._w)

    def wait(self, proc, timeout: float = 30.0) -> tuple[str, str] | None:
        """``(role, name)`` of the process's ready line, None if it ended or ``timeout`` passed first."""
        if self.seen is not None:
            return self.seen
        deadline, buf = time.monotonic() + timeout, b""
        while time.monotonic() < deadline and len(buf) <= MAX_LINE:
            if not select.select([self._r], [], [], 0.2)[0]:
                if proc.poll() is not None:
                    return None
                continue
            chunk = os.read(self._r, MAX_LINE + 1 - len(buf))
            if not chunk:
                return None
            buf += chunk
            if b"\n" in buf:
                self.seen = parse_ready(buf[:buf.index(b"\n") + 1])
                return self.seen
        return None


def interrupt(proc: subprocess.Popen, timeout: float = 60.0) -> int:
    """Ctrl-C ``proc`` (SIGINT) as a user would and wait for it; killed if it outlives ``timeout``."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        return proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait(10)


@dataclass
class Launched:
    """A command started by :func:`launched`: its process and its output lines so far (stdout and stderr)."""

    proc: subprocess.Popen
    lines: list[str] = field(default_factory=list)

    def tail(self, n: int = 40) -> str:
        return "".join(self.lines[-n:])


@contextmanager
def launched(argv: list[str], *, expect: tuple[str, str] | None = ("launcher", "up"), timeout: float = 120.0,
             cwd: str | Path | None = None, stop_timeout: float = 60.0) -> Iterator[Launched]:
    """``python -m services.cli ARGV`` with a ready pipe, its output read by a thread (never a full pipe); waits
    for its ready line ``expect`` (None: does not wait) and fails the test with its last lines if another or none
    comes; Ctrl-C (:func:`interrupt`) when the block ends."""
    pipe = ReadyPipe()
    proc = subprocess.Popen([sys.executable, "-m", "services.cli", *argv], cwd=cwd, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, errors="replace", env=pipe.env(dict(os.environ)),
                            pass_fds=pipe.pass_fds)
    pipe.started()
    run = Launched(proc)
    reader = threading.Thread(target=lambda: run.lines.extend(proc.stdout or ()), daemon=True)
    reader.start()
    try:
        if expect is not None:
            assert pipe.wait(proc, timeout) == expect, run.tail()
        yield run
    finally:
        interrupt(proc, stop_timeout)
        reader.join(10)
