"""The impairment side-car of docker compose's ``netem`` profile: proxies on one named link, or a loud failure.

Design notes: docs/experiments.md (services/netem/sidecar.py).
"""

from __future__ import annotations

import argparse
import socket
import sys
import time
from dataclasses import dataclass

from protocol.cliconfig import show_defaults
from protocol.signals import stop_event_on_signals
from services.netem.cli import summary
from services.netem.model import parse_impair_arg
from services.netem.proxy import Address, TcpProxy, UdpProxy, format_address, parse_address

__all__ = ["LinkSpec", "parse_link", "idle_proxies", "build_parser", "main"]

#: Exit statuses (besides 0 = stopped by a signal after forwarding traffic).
EXIT_USAGE, EXIT_UNRESOLVED, EXIT_NO_TRAFFIC = 2, 3, 4


@dataclass(frozen=True)
class LinkSpec:
    """One proxy: ``kind`` tcp|udp, where it listens, and the ``HOST:PORT`` it forwards to."""

    kind: str
    listen: Address
    target: Address


def parse_link(kind: str, text: str) -> LinkSpec:
    """``LISTEN=TARGET`` (each ``HOST:PORT``) → :class:`LinkSpec`; ValueError saying why otherwise."""
    if kind not in ("tcp", "udp"):
        raise ValueError(f"link kind must be tcp or udp, got {kind!r}")
    listen, sep, target = text.partition("=")
    if not sep:
        raise ValueError(f"{kind} link {text!r}: expected LISTEN_HOST:PORT=TARGET_HOST:PORT")
    return LinkSpec(kind, parse_address(listen), parse_address(target))


def idle_proxies(stats: dict[str, dict]) -> list[str]:
    """Names of the proxies no packet has entered yet from the node's side (``up.packets_in`` = 0)."""
    return [name for name, s in stats.items() if not (s.get("up") or {}).get("packets_in")]


def _resolve(target: Address, deadline: float) -> Address:
    """``(host, port)`` with the host resolved once to an IPv4 address (the UDP proxy sends per datagram)."""
    while True:
        try:
            return socket.gethostbyname(target[0]), target[1]
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m services.netem.sidecar", description=__doc__.split("\n\n")[0])
    p.add_argument("--link", required=True, help="the link's name, for the log (e.g. uav2)")
    p.add_argument("--tcp", action="append", default=[], metavar="LISTEN=TARGET", help="a TCP proxy (repeatable)")
    p.add_argument("--udp", action="append", default=[], metavar="LISTEN=TARGET", help="a UDP proxy (repeatable)")
    p.add_argument("--impair", default="", metavar="SPEC",
                   help='netem-like impairment, e.g. "delay 100ms loss 2%% after 8s" (skynet netem --impair)')
    p.add_argument("--seed", type=int, default=None)
    p.add_argument("--expect-s", type=float, default=60.0, dest="expect", metavar="S",
                   help="fail (exit 4) when a proxy has seen no packet this long after the start, s; 0: never")
    p.add_argument("--resolve-timeout-s", type=float, default=30.0, dest="resolve_timeout", metavar="S",
                   help="how long to wait for a target's name, s")
    p.add_argument("--interval-s", type=float, default=10.0, dest="interval", metavar="S",
                   help="seconds between counter lines")
    return show_defaults(p)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        links = [parse_link("tcp", t) for t in args.tcp] + [parse_link("udp", t) for t in args.udp]
        impairment = parse_impair_arg(args.impair, named=False).impairment
    except ValueError as e:
        print(f"netem side-car {args.link}: {e}", file=sys.stderr, flush=True)
        return EXIT_USAGE
    if not links:
        print(f"netem side-car {args.link}: no --tcp or --udp link given", file=sys.stderr, flush=True)
        return EXIT_USAGE
    if impairment.is_null:
        print(f"netem side-car {args.link}: no impairment given (--impair is empty)", file=sys.stderr, flush=True)
        return EXIT_USAGE
    deadline = time.monotonic() + args.resolve_timeout
    proxies: dict[str, TcpProxy | UdpProxy] = {}
    try:
        for i, ln in enumerate(links):
            target = _resolve(ln.target, deadline)
            cls = TcpProxy if ln.kind == "tcp" else UdpProxy
            seed = None if args.seed is None else args.seed + i
            proxies[f"{ln.kind}:{ln.listen[1]}"] = cls(listen=ln.listen, target=target, impairment=impairment,
                                                       seed=seed)
    except OSError as e:
        print(f"netem side-car {args.link}: cannot resolve a target: {e}", file=sys.stderr, flush=True)
        return EXIT_UNRESOLVED
    stop = stop_event_on_signals()
    started = time.monotonic()
    try:
        for p in proxies.values():
            p.start()
        for name, p in proxies.items():
            print(f"netem side-car {args.link}: {name} listening on {format_address(p.address)} -> "
                  f"{format_address(p.target)} [{impairment.to_text()}]", flush=True)
        checked = args.expect <= 0
        next_print = started + args.interval
        while not stop.wait(0.5):
            now = time.monotonic()
            if not checked and now - started >= args.expect:
                idle = idle_proxies({n: p.stats() for n, p in proxies.items()})
                if idle:
                    print(f"netem side-car {args.link}: FAILED: no traffic through {', '.join(idle)} "
                          f"{args.expect:.0f} s after the start: the impairment is not applied (is the node "
                          f"pointed at this side-car?)", file=sys.stderr, flush=True)
                    return EXIT_NO_TRAFFIC
                checked = True
            if now >= next_print:
                next_print = now + args.interval
                for p in proxies.values():
                    print(f"netem side-car {args.link}: {summary(p.stats())}", flush=True)
        return 0
    finally:
        for p in proxies.values():
            p.stop()
        for p in proxies.values():
            print(f"netem side-car {args.link}: final {summary(p.stats())}", flush=True)


if __name__ == "__main__":
    raise SystemExit(main())
