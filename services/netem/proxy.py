"""User-space impairment proxies on real sockets: :class:`UdpProxy` and :class:`TcpProxy`.

A node connects to the proxy's listen address instead of the router's; the proxy forwards to
the router and applies an :class:`~services.netem.model.Impairment` to the chosen directions
(``up`` = client → target, ``down`` = target → client, or ``both``). Zenoh's multilink setup
opens one TCP link (reliable) and one UDP link (best-effort) per session (ZENOH.md, "One link
per reliability class"), so a link class of DESIGN.md is impaired by putting one proxy of each
kind in front of the router's ``tcp/...?rel=1`` and ``udp/...?rel=0`` endpoints.

* :class:`UdpProxy` — one upstream socket per client address (a datagram association, as a
  NAT keeps one), idle associations closed after ``idle_timeout_s``. One receive thread
  (``selectors``) asks the direction's :class:`~services.netem.model.Impairer` for the release
  times of each datagram; one scheduler thread (a heap) sends them when due. Datagrams due at
  once with nothing queued are sent by the receive thread directly.
* :class:`TcpProxy` — a relay with, per connection and direction, a reader thread (receive,
  decide the release time with :meth:`~services.netem.model.Impairer.decide_stream`, queue) and
  a writer thread (send each chunk when due, in order). Bytes are never lost or reordered: an
  outage stalls the stream, loss becomes retransmission delay (``rto``), and a reader stops
  reading while ``max_pending_bytes`` wait, so TCP flow control pushes back on the sender.
  With a rate limit chunks are cut into pieces of about 1 ms of link time so that the rate
  spreads them smoothly. Both directions share one impairer per direction across connections:
  the proxy models *a link*, whose bandwidth the connections share.

Both proxies: ``start()``, ``stop()`` (joins every thread, closes every socket; queued data is
discarded), ``stats()``, ``with`` blocks, port 0 (read :attr:`address` after ``start``).
"""

from __future__ import annotations

import heapq
import itertools
import selectors
import socket
import threading
import time
from collections import deque
from typing import Any, Callable, Literal

import numpy as np

from services.netem.model import Impairer, Impairment

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
    """Shared life cycle: impairers per direction, start/stop, context manager, address."""

    kind = "?"

    def __init__(self, listen: Address | str, target: Address | str,
                 impairment: Impairment | str | dict[str, Any] | None, seed: int | None,
                 direction: Direction) -> None:
        if direction not in DIRECTIONS:
            raise ValueError(f"direction must be one of {DIRECTIONS}, got {direction!r}")
        self.listen = _check_address(listen, "listen")
        self.target = _check_address(target, "target")
        self.impairment = Impairment.coerce(impairment)
        self.direction = direction
        self.seed = seed
        self._address: Address | None = None
        self._started = self._stopped = False
        self._t0 = 0.0

    def _make_impairers(self) -> dict[str, Impairer]:
        self._t0 = time.monotonic()
        rngs = [np.random.default_rng(s) for s in np.random.SeedSequence(self.seed).spawn(2)]
        out = {}
        for name, rng in zip(("up", "down"), rngs):
            imp = self.impairment if self.direction in ("both", name) else None
            out[name] = Impairer(imp, rng, origin_s=self._t0)
        return out

    @property
    def address(self) -> Address:
        """The bound listen address (the real port when 0 was asked for); after :meth:`start`."""
        if self._address is None:
            raise RuntimeError(f"{type(self).__name__} not started")
        return self._address

    @property
    def port(self) -> int:
        return self.address[1]

    def start(self) -> _ProxyBase:
        raise NotImplementedError

    def stop(self) -> None:
        """Wake the listening thread and join it, release the proxy's own resources
        (:meth:`_release`), then close the listening and wake-up sockets. Idempotent."""
        if not self._started or self._stopped:
            return
        self._stopped = True
        self._running = False
        try:
            self._wake_w.send(b"x")
        except OSError:
            pass
        self._thread.join()
        self._release()
        for s in (self._lsock, self._wake_r, self._wake_w):
            s.close()

    def _release(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> _ProxyBase:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _header(self) -> dict[str, Any]:
        return {"kind": self.kind, "listen": format_address(self._address or self.listen),
                "target": format_address(self.target), "direction": self.direction,
                "impairment": self.impairment.to_text(),
                "uptime_s": round(time.monotonic() - self._t0, 3) if self._started else 0.0}


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
    """Impairing UDP forwarder, one upstream socket per client address.

    Parameters
    ----------
    listen, target : (host, port) or "host:port"
        Where clients send (port 0 = any free port) and where datagrams go.
    impairment : Impairment | str | dict | None
        Applied to ``direction`` (``"both"``, ``"up"`` client → target, ``"down"``).
    seed : int | None
        Seeds both directions' random streams (independent children of one SeedSequence).
    idle_timeout_s : float
        An association with no traffic for this long is closed (a NAT's UDP timeout).
    """

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
        if self._started:
            raise RuntimeError("UdpProxy already started")
        lfam, lsa = _resolve(self.listen, socket.SOCK_DGRAM)
        self._tfam, self._tsa = _resolve(self.target, socket.SOCK_DGRAM)
        self._lsock = socket.socket(lfam, socket.SOCK_DGRAM)
        try:
            for opt in (socket.SO_RCVBUF, socket.SO_SNDBUF):
                self._lsock.setsockopt(socket.SOL_SOCKET, opt, _SOCKBUF)
            self._lsock.bind(lsa)
        except OSError:
            self._lsock.close()
            raise
        self._lsock.setblocking(False)
        self._address = (self.listen[0], self._lsock.getsockname()[1])
        self._imp = self._make_impairers()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._sel = selectors.DefaultSelector()
        self._sel.register(self._lsock, selectors.EVENT_READ, None)
        self._sel.register(self._wake_r, selectors.EVENT_READ, "wake")
        self._running = True
        self._sched = _Scheduler(f"netem-udp-{self.port}-sched")
        self._sched.start()
        self._thread = threading.Thread(target=self._run, name=f"netem-udp-{self.port}-recv", daemon=True)
        self._thread.start()
        self._started = True
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
                self._sched.at(t, self._send_up, assoc.sock, data)

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
                self._sched.at(t, self._send_down, assoc.client, data)

    def _send_up(self, sock: socket.socket, data: bytes) -> None:
        c = self._sent["up"]
        try:
            sock.send(data)
        except OSError:  # closed association, full buffer, refused: the datagram is lost
            c["send_errors"] += 1
            return
        c["sent_packets"] += 1
        c["sent_bytes"] += len(data)

    def _send_down(self, client: tuple, data: bytes) -> None:
        c = self._sent["down"]
        try:
            self._lsock.sendto(data, client)
        except OSError:
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
        """Counters per direction (impairer decisions plus datagrams actually sent) and associations."""
        out = self._header()
        if self._started:
            for d in ("up", "down"):
                out[d] = {**self._imp[d].stats(), **self._sent[d]}
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
        piece = proxy._piece_bytes[self.name]
        limit = proxy.max_pending_bytes
        try:
            while True:
                data = self.src.recv(1 << 16)
                if not data:
                    break
                now = time.monotonic()
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
                        direct = not self.queue and not self.inflight and t <= time.monotonic()
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
        proxy = self.conn.proxy
        counts, lock = proxy._sent[self.name], proxy._locks[self.name]
        try:
            while True:
                with self.cond:
                    while True:
                        if self.aborted:
                            return
                        if self.queue and not self.inflight:
                            wait = self.queue[0][0] - time.monotonic()
                            if wait <= 0.0:
                                _, chunk = self.queue.popleft()
                                self.inflight = True
                                break
                            self.cond.wait(wait)
                        elif not self.queue and not self.inflight and self.eof:
                            try:  # pass the half-close on once everything before it is out
                                self.dst.shutdown(socket.SHUT_WR)
                            except OSError:
                                pass
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
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

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
    """Impairing TCP relay: delay, jitter, rate and outage on the byte stream, per direction.

    Parameters
    ----------
    listen, target : (host, port) or "host:port"
        Where clients connect (port 0 = any free port) and where the relay connects to.
    impairment : Impairment | str | dict | None
        Applied to ``direction`` (``"both"``, ``"up"`` client → target, ``"down"``). Duplicate
        and reorder do not apply to a stream; loss is retransmission delay (``rto``).
    seed : int | None
        Seeds both directions' random streams.
    connect_timeout_s : float
        How long to try the target for each accepted client before dropping the client.
    max_pending_bytes : int
        Bytes queued per connection and direction before the reader stops reading.
    """

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
        self._sent = {d: {"sent_bytes": 0} for d in ("up", "down")}
        self._accepted = self._connect_errors = 0

    def start(self) -> TcpProxy:
        if self._started:
            raise RuntimeError("TcpProxy already started")
        lfam, lsa = _resolve(self.listen, socket.SOCK_STREAM)
        self._tfam, self._tsa = _resolve(self.target, socket.SOCK_STREAM)
        self._lsock = socket.socket(lfam, socket.SOCK_STREAM)
        try:
            self._lsock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._lsock.bind(lsa)
            self._lsock.listen(64)
        except OSError:
            self._lsock.close()
            raise
        self._address = (self.listen[0], self._lsock.getsockname()[1])
        self._imp = self._make_impairers()
        self._locks = {d: threading.Lock() for d in ("up", "down")}
        self._piece_bytes = {}
        for d, imp in self._imp.items():
            rate = imp.impairment.rate_kbps
            # about 1 ms of link time per piece, so the rate releases a smooth stream
            self._piece_bytes[d] = max(1448, int(rate * 1000 / 8 * 1e-3)) if rate > 0 else 0
        self._wake_r, self._wake_w = socket.socketpair()
        self._running = True
        self._ids = itertools.count(1)
        self._thread = threading.Thread(target=self._accept_loop, name=f"netem-tcp-{self.port}-accept", daemon=True)
        self._thread.start()
        self._started = True
        return self

    def _release(self) -> None:
        """Reset every relayed connection and join its threads."""
        with self._conns_lock:
            conns = list(self._conns)
        for conn in conns:
            conn.abort()
        for conn in conns:
            conn.join()

    def _accept_loop(self) -> None:
        with selectors.DefaultSelector() as sel:
            sel.register(self._lsock, selectors.EVENT_READ, "listen")
            sel.register(self._wake_r, selectors.EVENT_READ, "wake")
            while self._running:
                for key, _ in sel.select():
                    if key.data == "wake" or not self._running:
                        return
                    try:
                        client, _ = self._lsock.accept()
                    except OSError:
                        continue
                    self._relay(client)

    def _relay(self, client: socket.socket) -> None:
        self._accepted += 1
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
        """Counters per direction (chunks decided, bytes in/out, stalls, retransmissions, bytes sent)."""
        out = self._header()
        if self._started:
            for d in ("up", "down"):
                with self._locks[d]:
                    out[d] = {**self._imp[d].stats(), **self._sent[d]}
            out["connections"] = len(self._conns)
            out["accepted"] = self._accepted
            out["connect_errors"] = self._connect_errors
        return out
