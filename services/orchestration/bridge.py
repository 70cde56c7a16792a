"""``skynet bridge``: a byte stream forwarder between a TCP port and a Unix socket, either way (issue 18).

Network namespaces share the file system, not the network: a node of the machine's own namespace (the
ground station of ``skynet mission --netns``) reaches site 0's gateway inside its namespace through a
Unix socket. Two bridges make that hop for a TLS link: one in the site's namespace (``--listen
unix:PATH --target tcp:127.0.0.1:PORT``), one in the machine's (``--listen tcp:127.0.0.1:PORT --target
unix:PATH``), so the ground station dials ``tls/127.0.0.1:PORT`` as on loopback and the TLS session (and
the certificate's name check) runs end to end: the bridges carry ciphertext.

Each accepted connection opens one to the target and copies both ways until either side closes; a
target that refuses is logged and the accepted connection closed. Bounded: at most ``--max-conns``
connections at once (further ones are closed at once, counted), 64 KiB reads.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import os
import signal
from dataclasses import dataclass

log = logging.getLogger("skynet.bridge")
CHUNK = 1 << 16


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


async def _pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    try:
        while data := await reader.read(CHUNK):
            writer.write(data)
            await writer.drain()
    except (ConnectionError, OSError):
        pass
    finally:
        try:
            writer.close()
        except (ConnectionError, OSError):
            pass


class Bridge:
    def __init__(self, listen: Address, target: Address, max_conns: int = 64):
        self.listen, self.target, self.max_conns = listen, target, max_conns
        self.open = self.accepted = self.refused = self.failed = 0

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self.open >= self.max_conns:
            self.refused += 1
            writer.close()
            return
        self.open += 1
        self.accepted += 1
        try:
            try:
                t_reader, t_writer = await _open(self.target)
            except OSError as exc:
                self.failed += 1
                log.warning("bridge: cannot reach %s: %s", self.target, exc)
                writer.close()
                return
            await asyncio.gather(_pipe(reader, t_writer), _pipe(t_reader, writer))
        finally:
            self.open -= 1

    async def run(self, stop: asyncio.Event) -> None:
        if self.listen.kind == "unix":
            if os.path.exists(self.listen.path):
                os.unlink(self.listen.path)
            server = await asyncio.start_unix_server(self._serve, self.listen.path)
        else:
            server = await asyncio.start_server(self._serve, self.listen.host, self.listen.port)
        print(f"bridge up: {self.listen} -> {self.target}", flush=True)
        async with server:
            await stop.wait()
        print(f"bridge down: {self.accepted} connections, {self.refused} refused, {self.failed} target failures",
              flush=True)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="skynet bridge", description=__doc__.split("\n\n")[0])
    p.add_argument("--listen", type=address, required=True, help="tcp:HOST:PORT or unix:PATH to accept on")
    p.add_argument("--target", type=address, required=True, help="tcp:HOST:PORT or unix:PATH to forward to")
    p.add_argument("--max-conns", type=int, default=64, help="connections at once (more are closed, counted)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.max_conns < 1:
        raise SystemExit("skynet bridge: --max-conns must be at least 1")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    bridge = Bridge(args.listen, args.target, args.max_conns)

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
