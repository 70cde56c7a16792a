"""A guard in front of the gateway's TLS acceptor: only connections that start a TLS handshake reach zenoh.

Design notes: docs/security.md (services/gateway/guard.py).
"""

from __future__ import annotations

import collections
import contextlib
import logging
import selectors
import socket
import threading
import time
from collections.abc import Callable

log = logging.getLogger("skynet.gateway.guard")

#: the first byte of a TLS handshake record
TLS_HANDSHAKE = 0x16


class TokenBucket:
    """``rate`` tokens a second up to ``burst``; :meth:`take` is False when empty (pure; clock injectable)."""

    def __init__(self, rate: float, burst: float, clock: Callable[[], float] = time.monotonic):
        self.rate, self.burst, self.clock = rate, burst, clock
        self.tokens, self.t = burst, clock()

    def take(self) -> bool:
        now = self.clock()
        self.tokens = min(self.burst, self.tokens + (now - self.t) * self.rate)
        self.t = now
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        return False


def verdict(first: bytes) -> str:
    """What to do with a connection whose first bytes (a peek) are ``first``: ``pass``, ``closed`` or ``not-tls``."""
    if not first:
        return "closed"
    return "pass" if first[0] == TLS_HANDSHAKE else "not-tls"


def _pipe(src: socket.socket, dst: socket.socket) -> None:
    try:
        while True:
            data = src.recv(262144)
            if not data:
                break
            dst.sendall(data)
    except OSError:
        pass
    finally:
        for s, how in ((dst, socket.SHUT_WR), (src, socket.SHUT_RD)):
            with contextlib.suppress(OSError):
                s.shutdown(how)


class Guard:
    """Accept on ``listen`` (host, port); relay the TLS connections to ``target`` (host, port)."""

    def __init__(self, listen: tuple[str, int], target: tuple[str, int], first_byte_s: float = 1.0,
                 max_pending: int = 4096, per_source: float = 50.0):
        self.listen, self.target = listen, target
        self.first_byte_s, self.max_pending = first_byte_s, max_pending
        self.per_source = per_source
        self.counts: collections.Counter[str] = collections.Counter()
        self._buckets: dict[str, TokenBucket] = {}
        self._stop = threading.Event()
        self._sock = socket.create_server(listen, backlog=4096, reuse_port=False)
        self._sock.setblocking(False)
        self._thread = threading.Thread(target=self._run, name="accept-guard", daemon=True)

    def start(self) -> Guard:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self._sock.close()

    def _bucket(self, source: str) -> TokenBucket:
        if source not in self._buckets:
            if len(self._buckets) > 10000:  # bounded: forget the sources
                self._buckets.clear()
            self._buckets[source] = TokenBucket(self.per_source, 2 * self.per_source)
        return self._buckets[source]

    def _forward(self, conn: socket.socket) -> None:
        try:
            up = socket.create_connection(self.target, timeout=5.0)
        except OSError:
            conn.close()
            self.counts["backend-down"] += 1
            return
        conn.setblocking(True)
        up.settimeout(None)
        for s in (conn, up):
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        threading.Thread(target=_pipe, args=(conn, up), daemon=True).start()
        t = threading.Thread(target=_pipe, args=(up, conn), daemon=True)
        t.start()
        threading.Thread(target=self._close_after, args=((conn, up), t), daemon=True).start()

    @staticmethod
    def _close_after(socks, t: threading.Thread) -> None:
        t.join()
        time.sleep(0.1)
        for s in socks:
            s.close()

    def _run(self) -> None:
        sel = selectors.DefaultSelector()
        sel.register(self._sock, selectors.EVENT_READ, None)
        pending: collections.OrderedDict[socket.socket, tuple[float, str]] = collections.OrderedDict()
        while not self._stop.is_set():
            now = time.monotonic()
            for key, _ in sel.select(timeout=0.05):
                if key.data is None:  # the listener: take everything queued
                    while True:
                        try:
                            conn, addr = self._sock.accept()
                        except (BlockingIOError, InterruptedError):
                            break
                        except OSError:
                            self.counts["accept-error"] += 1
                            break
                        conn.setblocking(False)
                        pending[conn] = (now + self.first_byte_s, addr[0])
                        sel.register(conn, selectors.EVENT_READ, "conn")
                        while len(pending) > self.max_pending:
                            old, _ = pending.popitem(last=False)
                            sel.unregister(old)
                            old.close()
                            self.counts["dropped-full"] += 1
                    continue
                conn = key.fileobj
                _, source = pending.pop(conn)
                sel.unregister(conn)
                try:
                    what = verdict(conn.recv(1, socket.MSG_PEEK))
                except OSError:
                    what = "closed"
                if what == "pass" and not self._bucket(source).take():
                    what = "rate-limited"
                self.counts[what] += 1
                if what == "pass":
                    self._forward(conn)
                else:
                    conn.close()
            while pending:  # the silent ones, oldest first
                conn, (deadline, _) = next(iter(pending.items()))
                if deadline > now:
                    break
                pending.popitem(last=False)
                sel.unregister(conn)
                conn.close()
                self.counts["silent"] += 1
        for conn in pending:
            conn.close()
        sel.close()
