"""``skynet bridge``: a byte stream forwarder between a TCP port and a Unix socket, either way.

Design notes: docs/architecture.md (services/orchestration/bridge.py).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import os
import signal
import time
from dataclasses import dataclass

from protocol.cliconfig import show_defaults
from protocol.readiness import notify_ready

log = logging.getLogger("skynet.bridge")
CHUNK = 1 << 16
#: default --idle-timeout-s, s: six Zenoh leases (10 s), 24 keep-alive periods
IDLE_TIMEOUT_S = 60.0
#: a connection idle this long gives its place to a new one at --max-conns: four keep-alive periods of the
#: default lease, so a live Zenoh link is never taken for an idle one
EVICT_IDLE_S = 10.0


@dataclass(frozen=True)
class Address:
    """``tcp:HOST:PORT`` or ``unix:PATH``."""

    kind: str
    host: str = ""
    port: int = 0
    path: str = ""

    def __str__(self) -> str:
        return f"unix:{self.path}" if self.kind == "unix" else f"tcp:{self.host}:{self.port}"


def address(text: str) -> Address:
    """argparse type: ``tcp:HOST:PORT`` (port 1..65535) or ``unix:PATH``."""
    kind, _, rest = text.partition(":")
    if kind == "unix" and rest:
        return Address("unix", path=rest)
    if kind == "tcp":
        host, _, port = rest.rpartition(":")
        if host and port.isdigit() and 1 <= int(port) <= 65535:
            return Address("tcp", host=host, port=int(port))
    raise argparse.ArgumentTypeError(f"expected tcp:HOST:PORT or unix:PATH, got {text!r}")


async def _open(target: Address):
    if target.kind == "unix":
        return await asyncio.open_unix_connection(target.path)
    return await asyncio.open_connection(target.host, target.port)


class _Conn:
    """One bridged connection: its two writers and when a byte last went either way."""

    def __init__(self, writer: asyncio.StreamWriter) -> None:
        self.writers = [writer]
        self.last = time.monotonic()

    def idle_s(self, now: float) -> float:
        return now - self.last

    def close(self) -> None:
        for w in self.writers:
            with contextlib.suppress(ConnectionError, OSError, RuntimeError):
                w.close()


async def _pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter, conn: _Conn | None = None) -> None:
    try:
        while data := await reader.read(CHUNK):
            if conn is not None:
                conn.last = time.monotonic()
            writer.write(data)
            await writer.drain()
    except (ConnectionError, OSError):
        pass
    finally:
        with contextlib.suppress(ConnectionError, OSError):
            writer.close()


class Bridge:
    def __init__(self, listen: Address, target: Address, max_conns: int = 64, idle_timeout_s: float = IDLE_TIMEOUT_S,
                 evict_idle_s: float = EVICT_IDLE_S):
        self.listen, self.target, self.max_conns = listen, target, max_conns
        self.idle_timeout_s, self.evict_idle_s = idle_timeout_s, min(evict_idle_s, idle_timeout_s)
        self.open = self.accepted = self.refused = self.failed = self.idle_closed = self.evicted = 0
        self._conns: set[_Conn] = set()

    def _evict_one(self) -> bool:
        """Close the connection idle the longest if it has been idle :attr:`evict_idle_s`; whether one was."""
        now = time.monotonic()
        oldest = max(self._conns, key=lambda c: c.idle_s(now), default=None)
        if oldest is None or oldest.idle_s(now) < self.evict_idle_s:
            return False
        self._conns.discard(oldest)
        oldest.close()
        self.evicted += 1
        self.open -= 1  # its place is taken now; its own task no longer counts it (see _serve)
        oldest.writers.clear()
        return True

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self.open >= self.max_conns and not self._evict_one():
            self.refused += 1
            writer.close()
            return
        self.open += 1
        self.accepted += 1
        conn = _Conn(writer)
        self._conns.add(conn)
        try:
            try:
                t_reader, t_writer = await _open(self.target)
            except OSError as exc:
                self.failed += 1
                log.warning("bridge: cannot reach %s: %s", self.target, exc)
                writer.close()
                return
            if conn not in self._conns:  # evicted or timed out while the target was opening
                t_writer.close()
                return
            conn.writers.append(t_writer)
            await asyncio.gather(_pipe(reader, t_writer, conn), _pipe(t_reader, writer, conn))
        finally:
            if conn in self._conns:
                self._conns.discard(conn)
                self.open -= 1
            conn.close()

    async def _reap_idle(self) -> None:
        """Close every connection idle for :attr:`idle_timeout_s` (checked a few times per timeout)."""
        while True:
            await asyncio.sleep(min(1.0, self.idle_timeout_s / 4))
            now = time.monotonic()
            for conn in [c for c in self._conns if c.idle_s(now) >= self.idle_timeout_s]:
                self._conns.discard(conn)
                self.open -= 1
                self.idle_closed += 1
                conn.close()

    async def run(self, stop: asyncio.Event) -> None:
        if self.listen.kind == "unix":
            if os.path.exists(self.listen.path):
                os.unlink(self.listen.path)
            server = await asyncio.start_unix_server(self._serve, self.listen.path)
        else:
            server = await asyncio.start_server(self._serve, self.listen.host, self.listen.port)
        print(f"bridge up: {self.listen} -> {self.target}", flush=True)
        notify_ready("bridge")
        reaper = asyncio.ensure_future(self._reap_idle())
        try:
            async with server:
                await stop.wait()
        finally:
            reaper.cancel()
        print(f"bridge down: {self.accepted} connections, {self.refused} refused, {self.failed} target failures, "
              f"{self.idle_closed} closed idle, {self.evicted} evicted idle at the limit", flush=True)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="skynet bridge", description=__doc__.split("\n\n")[0])
    p.add_argument("--listen", type=address, required=True, help="tcp:HOST:PORT or unix:PATH to accept on")
    p.add_argument("--target", type=address, required=True, help="tcp:HOST:PORT or unix:PATH to forward to")
    p.add_argument("--max-conns", type=int, default=64, help="connections at once (more are closed, counted)")
    p.add_argument("--idle-timeout-s", type=float, default=IDLE_TIMEOUT_S, metavar="S", dest="idle_timeout",
                   help=f"close a connection that carries no byte either way for S seconds (default "
                        f"{IDLE_TIMEOUT_S:g}; keep it above the Zenoh keep-alive period, lease/4, of the links "
                        "it carries)")
    return show_defaults(p)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.max_conns < 1:
        raise SystemExit("skynet bridge: --max-conns must be at least 1")
    if not 0.1 <= args.idle_timeout <= 86400:
        raise SystemExit("skynet bridge: --idle-timeout-s must be within 0.1..86400 s")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    bridge = Bridge(args.listen, args.target, args.max_conns, args.idle_timeout)

    async def go() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        await bridge.run(stop)

    asyncio.run(go())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
