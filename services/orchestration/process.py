"""Running services as child processes: free ports, log prefixing, clean shutdown.

Design notes: docs/architecture.md (services/orchestration/process.py).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import random
import select
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from protocol.readiness import MAX_LINE, READY_FD_ENV, parse_ready
from protocol.textsafe import printable

#: the lowest port :func:`free_port` hands out (above the registered ports services commonly use on a
#: development machine: Zenoh's 7447/7448, MAVLink's 14550, video's 5600)
LOWEST_LISTEN_PORT = 20000


def ephemeral_range(path: str = "/proc/sys/net/ipv4/ip_local_port_range") -> tuple[int, int]:
    """The kernel's ephemeral port range (where outgoing connections take their local ports)."""
    try:
        lo, hi = (int(w) for w in Path(path).read_text().split())
        return lo, hi
    except (OSError, ValueError):
        return 32768, 60999  # Linux's default


def listen_ports(ephemeral: tuple[int, int]) -> list[range]:
    """The ranges :func:`free_port` draws from: from :data:`LOWEST_LISTEN_PORT` up, outside ``ephemeral``."""
    lo, hi = ephemeral
    return [r for r in (range(LOWEST_LISTEN_PORT, min(lo, 65536)), range(max(hi + 1, LOWEST_LISTEN_PORT), 65536))
            if len(r) > 0]


class _PortCursor:
    """Walks the listening ranges one port after the other from a random start, so one process never hands
    out a port twice (until it has gone round) and two processes start far apart."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._ports: list[int] | None = None
        self._at = 0

    def next(self) -> int | None:
        with self._lock:
            if self._ports is None:
                self._ports = [p for r in listen_ports(ephemeral_range()) for p in r]
                self._at = random.SystemRandom().randrange(len(self._ports)) if self._ports else 0
            if not self._ports:
                return None
            port = self._ports[self._at]
            self._at = (self._at + 1) % len(self._ports)
            return port


_cursor = _PortCursor()

#: how long a port one process handed out stays claimed against this user's other processes, s: longer than a
#: launcher takes to start the service that listens on it
CLAIM_S = 300.0


def claims_dir() -> Path:
    """Where this user's processes claim the ports they hand out (one empty file per port)."""
    return Path(tempfile.gettempdir()) / f"skynet-ports-{os.getuid()}"


def claim(port: int, kind: int = socket.SOCK_STREAM, now: float | None = None) -> bool:
    """Whether this process may hand out ``port``: no other process of this user claimed it in the last
    :data:`CLAIM_S` (a file per port, its time the claim's; an older claim is taken over). The check and the
    claim are one step under an exclusive lock on the folder (``flock``): two launchers whose cursors meet would
    otherwise both find a port free before either service binds it, and two taking over one stale claim could
    each delete the other's. True when the claims folder cannot be used (the bind check alone then)."""
    folder = claims_dir()
    path = folder / f"{'udp' if kind == socket.SOCK_DGRAM else 'tcp'}-{port}"
    now = time.time() if now is None else now
    try:
        folder.mkdir(mode=0o700, exist_ok=True)
        with open(folder / ".lock", "a") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
            try:
                if now - path.stat().st_mtime < CLAIM_S:
                    return False
            except FileNotFoundError:
                pass
            path.touch(mode=0o600)
            os.utime(path, (now, now))
            return True
    except OSError:
        return True


def free_port(kind: int = socket.SOCK_STREAM, host: str = "127.0.0.1") -> int:
    """A port for a service to listen on, free now, outside the kernel's ephemeral range, from a cursor
    (:class:`_PortCursor`; docs/architecture.md, services/orchestration/process.py) and not handed out by
    another of this user's processes lately (:func:`claim`); port 0 when no port of the ranges is free."""
    for _ in range(64):
        port = _cursor.next()
        if port is None:
            break
        with socket.socket(socket.AF_INET, kind) as s:
            try:
                s.bind((host, port))
            except OSError:
                continue
        if claim(port, kind):
            return port
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def free_port_pair(host: str = "127.0.0.1") -> tuple[int, int]:
    """A TCP port and a UDP port, both free (for the multilink endpoints)."""
    return free_port(socket.SOCK_STREAM, host), free_port(socket.SOCK_DGRAM, host)


@dataclass
class Service:
    name: str
    proc: subprocess.Popen
    lines: list[str] = field(default_factory=list)
    _reader: threading.Thread | None = None
    _ready_reader: threading.Thread | None = field(default=None, repr=False)
    args: list[str] = field(default_factory=list)
    env: dict[str, str] = field(default_factory=dict, repr=False)
    on_line: Callable[[str, str], None] | None = None
    #: ended on purpose by :meth:`ProcessGroup.kill` (not a failure of the service)
    killed: bool = False
    #: how many times this service was started before this run of it
    restarts: int = 0
    #: time.monotonic() when this run of it started
    started: float = field(default_factory=time.monotonic)
    #: the command it runs under besides the group's (``ip netns exec NS``: a site's namespace)
    prefix: list[str] = field(default_factory=list)
    #: it signals when it is up (a ready pipe, :mod:`protocol.readiness`); :attr:`ready_at` is set when it does
    ready: bool = False
    #: time.monotonic() when this run signalled it is up (None: not yet, or not watched)
    ready_at: float | None = None
    #: ``(role, name)`` of its ready line
    ready_as: tuple[str, str] | None = None
    #: an earlier run of it came up (so an exit of this one is a crash after working, not a failure to start)
    was_ready: bool = False

    def alive(self) -> bool:
        return self.proc.poll() is None

    @property
    def ever_ready(self) -> bool:
        """This run or an earlier one came up (signalled it is up)."""
        return self.was_ready or self.ready_at is not None

    def reason(self, lines: int = 200) -> str:
        """Why it ended, in one line: its last line saying error (a one-line CLI error, an exception's
        last line), else its last non-empty line, else its exit status."""
        tail = [ln.strip() for ln in list(self.lines)[-lines:] if ln.strip()]
        for ln in reversed(tail):
            low = ln.lower()
            if "error" in low or "exception" in low or "refused" in low or "cannot" in low:
                return ln[:400]
        if tail:
            return tail[-1][:400]
        code = self.proc.poll()
        return f"exited with code {code} without a word" if code is not None else "no output"

    def wait_ready(self, timeout: float = 20.0) -> bool:
        """Wait until this run signalled it is up (True), or it ended or ``timeout`` passed (False)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.ready_at is not None:
                return True
            if not self.alive():
                if self._ready_reader is not None:
                    self._ready_reader.join(1.0)  # a line written just before the exit
                return self.ready_at is not None
            time.sleep(0.02)
        return self.ready_at is not None

    def wait_for(self, text: str, timeout: float = 20.0) -> bool:
        """Wait until a line containing ``text`` was printed (or the process ended)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if any(text in line for line in list(self.lines)):
                return True
            if not self.alive():
                return any(text in line for line in list(self.lines))
            time.sleep(0.05)
        return False


def _read_ready(svc: Service, fd: int) -> None:
    """Read ``svc``'s ready pipe until its ready line, its end, or the process's exit (a descendant that kept
    the write end open does not hold the reader); anything but one well-formed line is ignored."""
    buf = b""
    try:
        while len(buf) <= MAX_LINE:
            readable, _, _ = select.select([fd], [], [], 0.2)
            if not readable:
                if svc.proc.poll() is not None:
                    return
                continue
            chunk = os.read(fd, MAX_LINE + 1 - len(buf))
            if not chunk:
                return
            buf += chunk
            if b"\n" in buf:
                who = parse_ready(buf[:buf.index(b"\n") + 1])
                if who is not None:
                    svc.ready_as = who
                    svc.ready_at = time.monotonic()
                return
    finally:
        os.close(fd)


class ProcessGroup:
    """Child services of one run; ``stop()`` ends them all, no orphans."""

    def __init__(self, echo: IO[str] | None = sys.stdout, env: dict[str, str] | None = None,
                 prefix: list[str] | None = None):
        self.services: list[Service] = []
        #: run every service under this command (``ip netns exec NS``: :mod:`.netns`); it must exec the rest
        self.prefix = list(prefix or [])
        self.echo = echo
        self.env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
        self._echo_lock = threading.Lock()
        self._width = 10  # service names are right-aligned in this many columns
        self._lock = threading.Lock()  # membership: start/restart against stop
        self._closed = False
        #: lines the echo file refused (full disk, closed file): they are kept in ``Service.lines`` only
        self.echo_errors = 0

    @property
    def closed(self) -> bool:
        """True once :meth:`stop` began (no more starts or restarts)."""
        return self._closed

    def _echo(self, name: str, line: str) -> None:
        """One prefixed line to the echo file; a write error is counted and said once on stderr, never
        raised: a pump that died would leave the service blocked on a full pipe."""
        try:
            with self._echo_lock:
                print(f"{name:>{self._width}} | {printable(line)}", file=self.echo, flush=True)
        except (OSError, ValueError) as exc:  # ENOSPC, EFBIG, EIO, a closed file
            with self._echo_lock:
                self.echo_errors += 1
                first = self.echo_errors == 1
            if first:
                where = getattr(self.echo, "name", "the log")
                with contextlib.suppress(OSError, ValueError):
                    print(f"services' log {where} failed ({exc}); their output is still read, the last lines "
                          f"of each are kept in memory only", file=sys.stderr, flush=True)

    def start(self, name: str, args: list[str], on_line: Callable[[str, str], None] | None = None,
              prefix: list[str] | None = None, ready: bool = False, env: dict[str, str] | None = None) -> Service:
        """Start ``name`` (``prefix``: a command of its own to run under, e.g. its site's namespace; kept
        for its restarts; ``ready``: give it a ready pipe and watch it, :attr:`Service.ready_at`; ``env``:
        variables of its own over the group's)."""
        with self._lock:
            if self._closed:
                raise RuntimeError(f"cannot start {name}: the process group is stopping")
            svc = self._spawn(name, list(args), {**self.env, **(env or {})}, on_line, prefix=list(prefix or []),
                              ready=ready)
            self.services.append(svc)
        return svc

    def _spawn(self, name: str, args: list[str], env: dict[str, str],
               on_line: Callable[[str, str], None] | None, restarts: int = 0,
               prefix: list[str] | None = None, ready: bool = False, was_ready: bool = False) -> Service:
        cmd = [*self.prefix, *(prefix or []), sys.executable, "-m", "services.cli", *args]
        env = {k: v for k, v in env.items() if k != READY_FD_ENV}  # never an inherited one
        rfd = wfd = None
        if ready:
            rfd, wfd = os.pipe()
        try:
            proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                    text=True, errors="replace", bufsize=1, start_new_session=True,
                                    env=env if wfd is None else {**env, READY_FD_ENV: str(wfd)},
                                    pass_fds=() if wfd is None else (wfd,))
        except BaseException:
            for fd in (rfd, wfd):
                if fd is not None:
                    os.close(fd)
            raise
        if wfd is not None:
            os.close(wfd)  # the child holds the only write end: its exit ends the pipe
        svc = Service(name, proc, args=args, env=env, on_line=on_line, restarts=restarts, prefix=list(prefix or []),
                      ready=ready, was_ready=was_ready)
        if rfd is not None:
            svc._ready_reader = threading.Thread(target=_read_ready, args=(svc, rfd), name=f"ready:{name}", daemon=True)
            svc._ready_reader.start()

        def pump() -> None:
            assert proc.stdout is not None
            listener = on_line
            for line in proc.stdout:
                line = line.rstrip("\n")
                svc.lines.append(line)
                if len(svc.lines) > 5000:
                    del svc.lines[:1000]
                if listener:
                    try:
                        listener(name, line)
                    except Exception:  # the pump outlives its listener: the child must never block on its pipe
                        listener = None
                if self.echo is not None:
                    self._echo(name, line)

        svc._reader = threading.Thread(target=pump, name=f"log:{name}", daemon=True)
        svc._reader.start()
        return svc

    def get(self, name: str) -> Service:
        """The current run of the service ``name``; KeyError if there is none."""
        for s in self.services:
            if s.name == name:
                return s
        raise KeyError(f"no service named {name!r}")

    def kill(self, name: str, timeout: float = 5.0) -> int | None:
        """SIGKILL the service's whole process group (a crash: no clean session close) and reap it.

        Returns its exit status (``-9``), None if it did not die within ``timeout``.
        """
        svc = self.get(name)
        svc.killed = True
        with contextlib.suppress(ProcessLookupError):
            os.killpg(svc.proc.pid, signal.SIGKILL)
        try:
            svc.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            return None
        if svc._reader:
            svc._reader.join(1.0)
        return svc.proc.returncode

    def restart(self, name: str) -> Service:
        """Start ``name`` again with its command line and environment (after :meth:`kill`, or after it
        ended); a still-running one is killed first. Refused (RuntimeError) once :meth:`stop` began."""
        old = self.get(name)
        if old.alive():
            self.kill(name)
        with self._lock:
            if self._closed:
                raise RuntimeError(f"cannot restart {name}: the process group is stopping")
            svc = self._spawn(name, old.args, old.env, old.on_line, restarts=old.restarts + 1, prefix=old.prefix,
                              ready=old.ready, was_ready=old.ever_ready)
            self.services[self.services.index(old)] = svc
        return svc

    def stop(self, grace: float = 5.0) -> dict[str, int | None]:
        """SIGINT everyone (sessions close cleanly), then SIGTERM, then SIGKILL stragglers.
        No service can be started or restarted once this has begun."""
        with self._lock:
            self._closed = True
        for sig, wait in ((signal.SIGINT, grace), (signal.SIGTERM, 2.0), (signal.SIGKILL, 2.0)):
            live = [s for s in self.services if s.alive()]
            if not live:
                break
            for s in live:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(s.proc.pid, sig)
            deadline = time.monotonic() + wait
            for s in live:
                with contextlib.suppress(subprocess.TimeoutExpired):
                    s.proc.wait(max(0.0, deadline - time.monotonic()))
        for s in self.services:
            if s._reader:
                s._reader.join(1.0)
        return {s.name: s.proc.returncode for s in self.services}

    def __enter__(self) -> ProcessGroup:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
