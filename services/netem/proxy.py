"""User-space impairment proxies on real sockets: :class:`UdpProxy` and :class:`TcpProxy`.

Design notes: docs/experiments.md (services/netem/proxy.py).
"""

from __future__ import annotations

import contextlib
import heapq
import itertools
import math
import selectors
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any, Literal

import numpy as np

from services.netem.model import Impairer, Impairment
from services.netem.schedule import Command, Step, parse_command, parse_schedule

__all__ = ["Address", "Direction", "parse_address", "format_address", "UdpProxy", "TcpProxy"]

Address = tuple[str, int]
Direction = Literal["both", "up", "down"]
DIRECTIONS = ("both", "up", "down")
_MAX_DATAGRAM = 65535
_SOCKBUF = 4 << 20


def parse_address(text: str) -> Address:
    """``"host:port"`` or ``"[v6addr]:port"`` → ``(host, port)``; port 0..65535."""
    if not isinstance(text, str) or ":" not in text:
        raise ValueError(f"address {text!r}: expected HOST:PORT")
    host, _, port = text.rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ValueError(f"address {text!r}: expected HOST:PORT with a port 0..65535")
    return host, int(port)


def format_address(addr: Address) -> str:
    host, port = addr[0], addr[1]
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def _check_address(addr: Any, what: str) -> Address:
    if isinstance(addr, str):
        return parse_address(addr)
    if (not isinstance(addr, tuple) or len(addr) != 2 or not isinstance(addr[0], str)
            or not isinstance(addr[1], int) or not 0 <= addr[1] <= 65535):
        raise ValueError(f"{what} must be (host, port) or 'host:port', got {addr!r}")
    return addr


def _resolve(addr: Address, kind: int) -> tuple[int, tuple]:
    """(family, sockaddr) of the first address getaddrinfo gives."""
    try:
        family, _, _, _, sockaddr = socket.getaddrinfo(addr[0], addr[1], type=kind)[0]
    except socket.gaierror as e:
        raise ValueError(f"cannot resolve {format_address(addr)}: {e}") from e
    return family, sockaddr


class _ProxyBase:
    """Shared life cycle: impairers per direction, start/stop, context manager, address, and the
    live changes (:meth:`update`, :meth:`cut`, :meth:`restore`, :meth:`apply`, :meth:`play`)."""

    kind = "?"
    # made by the subclass's start()
    _lsock: socket.socket
    _wake_r: socket.socket
    _wake_w: socket.socket
    _thread: threading.Thread
    _sent: dict[str, dict[str, int]]

    def __init__(self, listen: Address | str, target: Address | str,
                 impairment: Impairment | str | dict[str, Any] | None, seed: int | None, direction: Direction) -> None:
        if direction not in DIRECTIONS:
            raise ValueError(f"direction must be one of {DIRECTIONS}, got {direction!r}")
        self.listen = _check_address(listen, "listen")
        self.target = _check_address(target, "target")
        imp = Impairment.coerce(impairment)
        self._initial = {d: imp if direction in ("both", d) else Impairment() for d in ("up", "down")}
        self.direction = direction
        self.seed = seed
        self._address: Address | None = None
        self._started = self._stopped = False
        self._t0 = 0.0
        self._live = False  # impairers exist (from start on)
        self._change_lock = threading.Lock()
        self.changes = 0
        self._runner: _ScheduleRunner | None = None

    def _make_impairers(self) -> dict[str, Impairer]:
        self._t0 = time.monotonic()
        rngs = [np.random.default_rng(s) for s in np.random.SeedSequence(self.seed).spawn(2)]
        with self._change_lock:
            self._imp = {d: Impairer(self._initial[d], rng, origin_s=self._t0) for d, rng in zip(("up", "down"), rngs)}
            self._live = True
        return self._imp

    def _bind(self, kind: int, options: tuple[tuple[int, int], ...]) -> None:
        """Resolve both ends, bind the listening socket (socket ``options`` first; a stream socket listens), note
        its address and make the wake-up pair of the listening thread."""
        if self._started:
            raise RuntimeError(f"{type(self).__name__} already started")
        lfam, lsa = _resolve(self.listen, kind)
        self._tfam, self._tsa = _resolve(self.target, kind)
        self._lsock = socket.socket(lfam, kind)
        try:
            for opt, value in options:
                self._lsock.setsockopt(socket.SOL_SOCKET, opt, value)
            self._lsock.bind(lsa)
            if kind == socket.SOCK_STREAM:
                self._lsock.listen(64)
        except OSError:
            self._lsock.close()
            raise
        self._address = (self.listen[0], self._lsock.getsockname()[1])
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)

    def _launch(self, run: Callable[[], None], name: str) -> None:
        """Start the listening thread ``run``, then the runner of the schedule's later steps."""
        self._running = True
        self._thread = threading.Thread(target=run, name=f"netem-{self.kind}-{self.port}-{name}", daemon=True)
        self._thread.start()
        self._started = True
        self._schedule_start()

    def _schedule_due(self) -> None:
        """In start(), before any packet: apply the steps due at once (at 0 s)."""
        if self._runner is not None:
            self._runner.apply_due()

    def _schedule_start(self) -> None:
        """At the end of start(): the runner thread applies the rest."""
        if self._runner is not None:
            self._runner.start()

    @property
    def address(self) -> Address:
        """The bound listen address (the real port when 0 was asked for); after :meth:`start`."""
        if self._address is None:
            raise RuntimeError(f"{type(self).__name__} not started")
        return self._address

    @property
    def port(self) -> int:
        return self.address[1]

    # ---------------------------------------------------------------- live changes
    def impairment(self, direction: Direction = "both") -> Impairment:
        """The impairment applied now to ``"up"`` or ``"down"``; ``"both"`` when they are equal
        (a :class:`ValueError` when they differ)."""
        if direction not in DIRECTIONS:
            raise ValueError(f"direction must be one of {DIRECTIONS}, got {direction!r}")
        now = {d: (self._imp[d].impairment if self._live else self._initial[d]) for d in ("up", "down")}
        if direction != "both":
            return now[direction]
        if now["up"] != now["down"]:
            raise ValueError("up and down differ: ask for 'up' or 'down'")
        return now["up"]

    def update(self, spec: Impairment | str | dict[str, Any] | None, direction: Direction = "both") -> Impairment:
        """Replace the impairment of ``direction`` (default both) from now on; None or "" = a clean
        link. Packets already decided keep their release times; seeds, counters, outage origin and
        any cut carry over (:meth:`Impairer.update`). Bad input raises ValueError, changing nothing.
        Callable from any thread, before or after :meth:`start`."""
        if direction not in DIRECTIONS:
            raise ValueError(f"direction must be one of {DIRECTIONS}, got {direction!r}")
        imp = Impairment.coerce(spec)
        self._change(self._update, imp, direction)
        return imp

    def cut(self, duration_s: float | None = None) -> None:
        """Cut the link now in both directions, for ``duration_s`` seconds or (None) until
        :meth:`restore`. UDP: datagrams arriving meanwhile are dropped (reason ``outage``); those
        already queued keep their release times. TCP: no byte is sent either way while cut (the
        streams stall, nothing is lost), and new connections are accepted but held, not connected
        to the target, until the link is back."""
        self._require_started()
        self._change(self._cut, duration_s)

    def restore(self) -> None:
        """End any cut now (the impairment stays); held TCP bytes and connections go on."""
        self._require_started()
        self._change(self._restore)

    def apply(self, command: Command | str) -> dict[str, Any]:
        """Carry out one command of :mod:`services.netem.schedule` (``set``, ``cut``, ``restore``,
        ``clear``; ``stats`` returns the counters). Returns a JSON-ready reply; ValueError on a
        bad command."""
        cmd = parse_command(command) if isinstance(command, str) else command
        if not isinstance(cmd, Command):
            raise ValueError(f"a command is a Command or text, not {type(command).__name__}")
        if cmd.action == "stats":
            return {"ok": True, "stats": self.stats()}
        if cmd.action != "set":
            self._require_started()
        op, args = {"set": (self._update, (cmd.impairment, cmd.direction)), "cut": (self._cut, (cmd.duration_s,)),
                    "restore": (self._restore, ()), "clear": (self._clear, ())}[cmd.action]
        self._change(op, *args)
        return {"ok": True, "applied": cmd.to_text(), "impairment": self._impairment_text(), "changes": self.changes}

    def play(self, steps: list[Step] | str, on_step: Callable[[Step, str | None], None] | None = None) -> None:
        """Run a schedule (steps, or schedule text) relative to the proxy start, on a thread of its
        own; may be called before :meth:`start` (steps at 0 s then apply before the first packet)
        or after (steps already due apply at once, in order). ``on_step(step, error)`` is called
        after each step. One schedule per proxy; :meth:`stop` ends it."""
        if isinstance(steps, str):
            steps = parse_schedule(steps)
        if self._runner is not None:
            raise RuntimeError("a schedule is already playing")
        if self._stopped:
            raise RuntimeError(f"{type(self).__name__} stopped")
        self._runner = _ScheduleRunner(self, list(steps), on_step)
        if self._started:
            self._schedule_due()
            self._schedule_start()

    def _change(self, op: Callable[..., None], *args: Any) -> None:
        """Apply one change under the change lock, count it, then run the :meth:`_changed` hook."""
        with self._change_lock:
            op(*args)
            self.changes += 1
        self._changed()

    def _update(self, imp: Impairment, direction: str) -> None:
        for d in ("up", "down"):
            if direction in ("both", d):
                if self._live:
                    self._imp[d].update(imp)
                else:
                    self._initial[d] = imp

    def _cut(self, duration_s: float | None) -> None:
        now = time.monotonic()
        for d in ("up", "down"):
            self._imp[d].cut(now, duration_s)

    def _restore(self) -> None:
        for d in ("up", "down"):
            self._imp[d].restore()

    def _clear(self) -> None:
        self._update(Impairment(), "both")
        self._restore()

    def _changed(self) -> None:
        """Hook after a change (TCP: wake the writers and the acceptor)."""

    def _require_started(self) -> None:
        if not self._live or self._stopped:
            raise RuntimeError(f"{type(self).__name__} not running")

    def _down_until(self, now: float) -> float | None:
        """When the link is back if either direction is down now (``inf``: cut until restore)."""
        ends = [e for e in (self._imp[d].outage_end(now) for d in ("up", "down")) if e is not None]
        return max(ends) if ends else None

    # ---------------------------------------------------------------- life cycle
    def start(self) -> _ProxyBase:
        raise NotImplementedError

    def stop(self) -> None:
        """Stop the schedule, wake the listening thread and join it, release the proxy's own
        resources (:meth:`_release`), then close the listening and wake-up sockets. Idempotent."""
        if self._runner is not None:
            self._runner.stop()
        if not self._started or self._stopped:
            return
        self._stopped = True
        self._running = False
        with contextlib.suppress(OSError):
            self._wake_w.send(b"x")
        self._thread.join()
        self._release()
        for s in (self._lsock, self._wake_r, self._wake_w):
            s.close()

    def _release(self) -> None:
        raise NotImplementedError

    def stats(self) -> dict[str, Any]:
        raise NotImplementedError

    def __enter__(self) -> _ProxyBase:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _impairment_text(self) -> str:
        """One string for both directions: the text when they agree, else ``up: X; down: Y``."""
        up, down = (self.impairment(d) for d in ("up", "down"))
        return up.to_text() if up == down else f"up: {up.to_text()}; down: {down.to_text()}"

    def _header(self) -> dict[str, Any]:
        out = {"kind": self.kind, "listen": format_address(self._address or self.listen),
               "target": format_address(self.target), "direction": self.direction,
               "impairment": self._impairment_text(), "changes": self.changes,
               "uptime_s": round(time.monotonic() - self._t0, 3) if self._started else 0.0,
               "cut": False, "cut_remaining_s": None}
        if self._started:
            now = time.monotonic()
            end = self._imp["up"].cut_end(now)
            if end is not None:
                out["cut"] = True
                out["cut_remaining_s"] = None if math.isinf(end) else round(end - now, 3)
        if self._runner is not None:
            out["schedule"] = self._runner.stats()
        return out

    def _direction_stats(self, d: str) -> dict[str, Any]:
        return {"impairment": self._imp[d].impairment.to_text(), **self._imp[d].stats(), **self._sent[d]}


class _ScheduleRunner:
    """Applies a schedule's steps at ``proxy start + at_s`` on one thread (``netem-...-schedule``)."""

    def __init__(self, proxy: _ProxyBase, steps: list[Step],
                 on_step: Callable[[Step, str | None], None] | None) -> None:
        for s in steps:
            if not isinstance(s, Step):
                raise ValueError(f"a schedule is a list of Step, got {type(s).__name__}")
        self.proxy, self.on_step = proxy, on_step
        self.steps = sorted(steps, key=lambda s: (s.at_s, s.line))
        self.applied = self.errors = 0
        self._next = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def apply_due(self) -> bool:
        """Apply every step due by now; True when none is left."""
        with self._lock:
            while self._next < len(self.steps) and not self._stop.is_set():
                step = self.steps[self._next]
                if self.proxy._t0 + step.at_s > time.monotonic():
                    return False
                self._next += 1
                error = None
                try:
                    self.proxy.apply(step.command)
                    self.applied += 1
                except Exception as e:  # noqa: BLE001 - a bad step must not end the schedule
                    self.errors += 1
                    error = f"{type(e).__name__}: {e}"
                if self.on_step is not None:
                    self.on_step(step, error)
            return True

    def start(self) -> None:
        if self._thread is None and self._next < len(self.steps):
            self._thread = threading.Thread(target=self._run, name=f"netem-{self.proxy.kind}-{self.proxy.port}-schedule",
                                            daemon=True)
            self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set() and not self.apply_due():
            wait = self.proxy._t0 + self.steps[self._next].at_s - time.monotonic()
            if wait > 0.0:
                self._stop.wait(wait)

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join()

    def stats(self) -> dict[str, Any]:
        return {"steps": len(self.steps), "applied": self.applied, "errors": self.errors}


# ============================================================================ UDP
class _Scheduler:
    """A heap of (release time, callback) run by one thread; callbacks run under its lock."""

    def __init__(self, name: str) -> None:
        self._heap: list[tuple[float, int, Callable[..., None], tuple]] = []
        self._cond = threading.Condition()
        self._seq = itertools.count()
        self._stop = False
        self.discarded = 0
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def at(self, t: float, fn: Callable[..., None], *args: Any) -> None:
        with self._cond:
            if self._stop:
                self.discarded += 1
                return
            if not self._heap and t <= time.monotonic():
                fn(*args)  # due now and nothing ahead of it: no thread hop
                return
            heapq.heappush(self._heap, (t, next(self._seq), fn, args))
            self._cond.notify()

    def __len__(self) -> int:
        return len(self._heap)

    def _run(self) -> None:
        with self._cond:
            while not self._stop:
                if not self._heap:
                    self._cond.wait()
                    continue
                wait = self._heap[0][0] - time.monotonic()
                if wait > 0.0:
                    self._cond.wait(wait)
                    continue
                _, _, fn, args = heapq.heappop(self._heap)
                fn(*args)

    def stop(self) -> None:
        with self._cond:
            self._stop = True
            self.discarded += len(self._heap)
            self._heap.clear()
            self._cond.notify()
        if self._thread.is_alive():
            self._thread.join()


class _Association:
    __slots__ = ("client", "sock", "last")

    def __init__(self, client: tuple, sock: socket.socket, now: float) -> None:
        self.client, self.sock, self.last = client, sock, now


class UdpProxy(_ProxyBase):
    """Impairing UDP forwarder from ``listen`` (port 0: any) to ``target``, one upstream socket per client
    address, closed after ``idle_timeout_s`` without traffic (a NAT's UDP timeout); ``seed`` seeds both
    directions (independent children of one SeedSequence)."""

    kind = "udp"

    def __init__(self, listen: Address | str = ("127.0.0.1", 0), target: Address | str = ("127.0.0.1", 7448),
                 impairment: Impairment | str | dict[str, Any] | None = None, seed: int | None = None,
                 direction: Direction = "both", idle_timeout_s: float = 300.0) -> None:
        super().__init__(listen, target, impairment, seed, direction)
        if not idle_timeout_s > 0.0:
            raise ValueError(f"idle_timeout_s must be > 0, got {idle_timeout_s}")
        self.idle_timeout_s = float(idle_timeout_s)
        self._assocs: dict[tuple, _Association] = {}
        self._sent = {d: {"sent_packets": 0, "sent_bytes": 0, "send_errors": 0} for d in ("up", "down")}
        self._closed_assocs = 0

    def start(self) -> UdpProxy:
        self._bind(socket.SOCK_DGRAM, ((socket.SO_RCVBUF, _SOCKBUF), (socket.SO_SNDBUF, _SOCKBUF)))
        self._lsock.setblocking(False)
        self._make_impairers()
        self._schedule_due()
        self._sel = selectors.DefaultSelector()
        self._sel.register(self._lsock, selectors.EVENT_READ, None)
        self._sel.register(self._wake_r, selectors.EVENT_READ, "wake")
        self._sched = _Scheduler(f"netem-udp-{self.port}-sched")
        self._sched.start()
        self._launch(self._run, "recv")
        return self

    def _release(self) -> None:
        """Stop the scheduler and close every association; datagrams still queued are discarded."""
        self._sched.stop()
        self._sel.close()
        for assoc in self._assocs.values():
            assoc.sock.close()
        self._assocs.clear()

    # ---------------------------------------------------------------- threads
    def _run(self) -> None:
        last_sweep = time.monotonic()
        while self._running:
            events = self._sel.select(timeout=1.0)
            for key, _ in events:
                if key.data == "wake":
                    break
                if key.data is None:
                    self._from_clients()
                else:
                    self._from_target(key.data)
            now = time.monotonic()
            if now - last_sweep >= 1.0:
                last_sweep = now
                self._sweep(now)

    def _from_clients(self) -> None:
        up = self._imp["up"]
        for _ in range(64):
            try:
                data, client = self._lsock.recvfrom(_MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                continue  # e.g. an ICMP error reported on the socket
            now = time.monotonic()
            assoc = self._assocs.get(client)
            if assoc is None:
                assoc = self._associate(client, now)
                if assoc is None:
                    continue
            assoc.last = now
            for t in up.decide(now, len(data)):
                self._sched.at(t, self._send, "up", assoc.sock.send, data)

    def _associate(self, client: tuple, now: float) -> _Association | None:
        sock = socket.socket(self._tfam, socket.SOCK_DGRAM)
        try:
            for opt in (socket.SO_RCVBUF, socket.SO_SNDBUF):
                sock.setsockopt(socket.SOL_SOCKET, opt, _SOCKBUF)
            sock.connect(self._tsa)
        except OSError:
            sock.close()
            self._sent["up"]["send_errors"] += 1
            return None
        sock.setblocking(False)
        assoc = _Association(client, sock, now)
        self._assocs[client] = assoc
        self._sel.register(sock, selectors.EVENT_READ, assoc)
        return assoc

    def _from_target(self, assoc: _Association) -> None:
        down = self._imp["down"]
        for _ in range(64):
            try:
                data = assoc.sock.recv(_MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                continue  # ConnectionRefused: the target is not listening (yet)
            now = time.monotonic()
            assoc.last = now
            for t in down.decide(now, len(data)):
                self._sched.at(t, self._send, "down", self._lsock.sendto, data, assoc.client)

    def _send(self, direction: str, send: Callable[..., object], data: bytes, *to: tuple) -> None:
        """``send(data, *to)`` (up: the association's socket; down: the listening socket to the client), counted."""
        c = self._sent[direction]
        try:
            send(data, *to)
        except OSError:  # closed association, full buffer, refused: the datagram is lost
            c["send_errors"] += 1
            return
        c["sent_packets"] += 1
        c["sent_bytes"] += len(data)

    def _sweep(self, now: float) -> None:
        for client, assoc in list(self._assocs.items()):
            if now - assoc.last > self.idle_timeout_s:
                self._sel.unregister(assoc.sock)
                with self._sched._cond:  # a queued send to it then fails and is counted
                    assoc.sock.close()
                del self._assocs[client]
                self._closed_assocs += 1

    def stats(self) -> dict[str, Any]:
        """Counters per direction (the impairment applied now, impairer decisions, datagrams
        actually sent) and associations; the header has ``impairment``, ``changes``, ``cut``."""
        out = self._header()
        if self._started:
            for d in ("up", "down"):
                out[d] = self._direction_stats(d)
            out["associations"] = len(self._assocs)
            out["associations_closed"] = self._closed_assocs
            out["queued"] = len(self._sched)
        return out


# ============================================================================ TCP
class _Pump:
    """One direction of one relayed connection: a reader thread and a writer thread."""

    def __init__(self, conn: _TcpConnection, src: socket.socket, dst: socket.socket, name: str) -> None:
        self.conn, self.src, self.dst, self.name = conn, src, dst, name
        self.queue: deque[tuple[float, bytes]] = deque()
        self.cond = threading.Condition()
        self.pending = 0
        self.eof = self.aborted = self.inflight = False

    def reader(self) -> None:
        proxy = self.conn.proxy
        imp, lock, counts = proxy._imp[self.name], proxy._locks[self.name], proxy._sent[self.name]
        limit = proxy.max_pending_bytes
        try:
            while True:
                data = self.src.recv(1 << 16)
                if not data:
                    break
                now = time.monotonic()
                piece = proxy._piece_bytes[self.name]  # follows the rate of live updates
                chunks = [data] if piece == 0 or len(data) <= piece else \
                    [data[k:k + piece] for k in range(0, len(data), piece)]
                for chunk in chunks:
                    with lock:
                        t = imp.decide_stream(now, len(chunk))
                    with self.cond:
                        while self.pending > limit and not self.aborted:
                            self.cond.wait()
                        if self.aborted:
                            return
                        now = time.monotonic()
                        direct = (not self.queue and not self.inflight and t <= now and imp.outage_end(now) is None)
                        if direct:
                            self.inflight = True
                        else:
                            self.queue.append((t, chunk))
                            self.pending += len(chunk)
                            self.cond.notify_all()
                    if direct:
                        try:
                            self.dst.sendall(chunk)
                        finally:
                            with self.cond:
                                self.inflight = False
                                self.cond.notify_all()
                        with lock:
                            counts["sent_bytes"] += len(chunk)
        except OSError:
            self.conn.abort()
        finally:
            with self.cond:
                self.eof = True
                self.cond.notify_all()
            self.conn.thread_done()

    def writer(self) -> None:
        """Send each queued chunk when due, in order; hold everything (the FIN too) while the
        link is down (a cut or an outage window), woken by :meth:`TcpProxy.restore`."""
        proxy = self.conn.proxy
        imp, counts, lock = proxy._imp[self.name], proxy._sent[self.name], proxy._locks[self.name]
        held = False  # the head chunk has been counted as held by a down link
        try:
            while True:
                with self.cond:
                    while True:
                        if self.aborted:
                            return
                        now = time.monotonic()
                        due = self.queue and not self.inflight and self.queue[0][0] <= now
                        if (due or (self.eof and not self.queue and not self.inflight)) and \
                                (back := imp.outage_end(now)) is not None:
                            if due and not held:
                                held = True
                                with lock:
                                    counts["held_link_down"] += 1
                            self.cond.wait(min(back - now, 1.0))
                        elif due:
                            _, chunk = self.queue.popleft()
                            self.inflight = True
                            held = False
                            break
                        elif self.queue and not self.inflight:
                            self.cond.wait(self.queue[0][0] - now)
                        elif not self.queue and not self.inflight and self.eof:
                            with contextlib.suppress(OSError):  # the half-close, once everything before it is out
                                self.dst.shutdown(socket.SHUT_WR)
                            return
                        else:
                            self.cond.wait()
                try:
                    self.dst.sendall(chunk)
                except OSError:
                    self.conn.abort()
                    return
                with lock:
                    counts["sent_bytes"] += len(chunk)
                with self.cond:
                    self.inflight = False
                    self.pending -= len(chunk)
                    self.cond.notify_all()
        finally:
            self.conn.thread_done()

    def abort(self) -> None:
        with self.cond:
            self.aborted = True
            self.cond.notify_all()


class _TcpConnection:
    def __init__(self, proxy: TcpProxy, client: socket.socket, upstream: socket.socket, ident: int) -> None:
        self.proxy, self.client, self.upstream = proxy, client, upstream
        self.pumps = [_Pump(self, client, upstream, "up"), _Pump(self, upstream, client, "down")]
        self.threads = [threading.Thread(target=fn, name=f"netem-tcp-{proxy.port}-c{ident}-{p.name}-{fn.__name__}",
                                         daemon=True) for p in self.pumps for fn in (p.reader, p.writer)]
        self._lock = threading.Lock()
        self._alive = len(self.threads)
        self._aborted = False

    def start(self) -> None:
        for t in self.threads:
            t.start()

    def abort(self) -> None:
        """Reset both sides: wake every thread, discard what is queued."""
        with self._lock:
            if self._aborted:
                return
            self._aborted = True
        for p in self.pumps:
            p.abort()
        for s in (self.client, self.upstream):
            with contextlib.suppress(OSError):
                s.shutdown(socket.SHUT_RDWR)

    def thread_done(self) -> None:
        with self._lock:
            self._alive -= 1
            last = self._alive == 0
        if last:
            self.client.close()
            self.upstream.close()
            self.proxy._forget(self)

    def join(self, timeout: float | None = None) -> None:
        for t in self.threads:
            if t is not threading.current_thread():
                t.join(timeout)


class TcpProxy(_ProxyBase):
    """Impairing TCP relay from ``listen`` (port 0: any) to ``target``: delay, jitter, rate and outage on the
    byte stream of ``direction`` ("both", "up" client → target, "down"); loss is retransmission delay
    (``rto``), duplicate and reorder do not apply. A client is dropped when the target does not answer
    within ``connect_timeout_s``; a reader stops beyond ``max_pending_bytes`` queued."""

    kind = "tcp"

    def __init__(self, listen: Address | str = ("127.0.0.1", 0), target: Address | str = ("127.0.0.1", 7447),
                 impairment: Impairment | str | dict[str, Any] | None = None, seed: int | None = None,
                 direction: Direction = "both", connect_timeout_s: float = 5.0,
                 max_pending_bytes: int = 4 << 20) -> None:
        super().__init__(listen, target, impairment, seed, direction)
        if not connect_timeout_s > 0.0:
            raise ValueError(f"connect_timeout_s must be > 0, got {connect_timeout_s}")
        if not isinstance(max_pending_bytes, int) or max_pending_bytes <= 0:
            raise ValueError(f"max_pending_bytes must be a positive int, got {max_pending_bytes!r}")
        self.connect_timeout_s = float(connect_timeout_s)
        self.max_pending_bytes = max_pending_bytes
        self._conns: set[_TcpConnection] = set()
        self._conns_lock = threading.Lock()
        self._sent = {d: {"sent_bytes": 0, "held_link_down": 0} for d in ("up", "down")}
        self._accepted = self._connect_errors = self._held_on_accept = 0
        self._held_clients: list[socket.socket] = []  # accepted while the link was down

    def start(self) -> TcpProxy:
        self._bind(socket.SOCK_STREAM, ((socket.SO_REUSEADDR, 1),))
        self._locks = {d: threading.Lock() for d in ("up", "down")}
        self._make_impairers()
        self._set_pieces()
        self._schedule_due()
        self._ids = itertools.count(1)
        self._launch(self._accept_loop, "accept")
        return self

    def _set_pieces(self) -> None:
        """Chunk size per direction: about 1 ms of link time, so a rate releases a smooth stream."""
        rates = {d: imp.impairment.rate_kbps for d, imp in self._imp.items()}
        self._piece_bytes = {d: max(1448, int(rate * 1000 / 8 * 1e-3)) if rate > 0 else 0 for d, rate in rates.items()}

    def _changed(self) -> None:
        """After a change: new chunk sizes; wake every writer (a restore releases held bytes) and
        the acceptor (held connections go on)."""
        if not self._started or self._stopped:
            return
        self._set_pieces()
        with self._conns_lock:
            pumps = [p for c in self._conns for p in c.pumps]
        for p in pumps:
            with p.cond:
                p.cond.notify_all()
        with contextlib.suppress(OSError):
            self._wake_w.send(b"c")

    def _release(self) -> None:
        """Reset every relayed connection and join its threads."""
        with self._conns_lock:
            conns = list(self._conns)
        for conn in conns:
            conn.abort()
        for conn in conns:
            conn.join()

    def _accept_loop(self) -> None:
        """Accept clients; while the link is down, hold them (accepted, not yet connected to the
        target: the client's first bytes wait, as behind a cut link) and relay them once it is up."""
        held = self._held_clients
        with selectors.DefaultSelector() as sel:
            sel.register(self._lsock, selectors.EVENT_READ, "listen")
            sel.register(self._wake_r, selectors.EVENT_READ, "wake")
            try:
                while self._running:
                    timeout = None
                    if held:
                        now = time.monotonic()
                        back = self._down_until(now)
                        if back is None:
                            while held and self._running:
                                self._relay(held.pop(0))
                            continue
                        timeout = min(back - now, 1.0)
                    for key, _ in sel.select(timeout):
                        if not self._running:
                            return
                        if key.data == "wake":
                            with contextlib.suppress(OSError):
                                while self._wake_r.recv(64):
                                    pass
                            continue
                        try:
                            client, _ = self._lsock.accept()
                        except OSError:
                            continue
                        self._accepted += 1
                        if self._down_until(time.monotonic()) is not None:
                            self._held_on_accept += 1
                            held.append(client)
                        else:
                            self._relay(client)
            finally:
                for client in held:
                    client.close()
                held.clear()

    def _relay(self, client: socket.socket) -> None:
        upstream = socket.socket(self._tfam, socket.SOCK_STREAM)
        try:
            upstream.settimeout(self.connect_timeout_s)
            upstream.connect(self._tsa)
            upstream.settimeout(None)
        except OSError:
            self._connect_errors += 1
            upstream.close()
            client.close()
            return
        client.setblocking(True)
        for s in (client, upstream):
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        conn = _TcpConnection(self, client, upstream, next(self._ids))
        with self._conns_lock:
            self._conns.add(conn)
        conn.start()

    def _forget(self, conn: _TcpConnection) -> None:
        with self._conns_lock:
            self._conns.discard(conn)

    def stats(self) -> dict[str, Any]:
        """Counters per direction (the impairment applied now, chunks decided, bytes in/out, stalls,
        retransmissions, bytes sent, chunks ``held_link_down`` by a cut or outage at the writer),
        connections, and clients accepted while the link was down (``held_on_accept``, of which
        ``held_connections`` still wait)."""
        out = self._header()
        if self._started:
            for d in ("up", "down"):
                with self._locks[d]:
                    out[d] = self._direction_stats(d)
            out["connections"] = len(self._conns)
            out["accepted"] = self._accepted
            out["held_connections"] = len(self._held_clients)
            out["held_on_accept"] = self._held_on_accept
            out["connect_errors"] = self._connect_errors
        return out
