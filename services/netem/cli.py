"""``skynet netem``: run one impairment proxy in front of a link, printing its counters.

    skynet netem udp --listen 127.0.0.1:9000 --target 127.0.0.1:7448 --impair "delay 50ms loss 2%"
    skynet netem tcp --listen 127.0.0.1:9001 --target 127.0.0.1:7447 --impair "delay 50ms rate 2mbit"

Point the node at the listen address instead of the router's (``tcp/127.0.0.1:9001?rel=1``,
``udp/127.0.0.1:9000?rel=0``). Counters are printed once a second (``--json`` for one JSON
object per line); Ctrl-C or SIGTERM stops the proxy and prints the final counters. The first
line, ``netem <kind> listening on HOST:PORT -> TARGET``, tells a launcher the bound port.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
from typing import Any

from services.netem.model import Impairment
from services.netem.proxy import DIRECTIONS, TcpProxy, UdpProxy, format_address, parse_address

__all__ = ["main", "build_parser", "summary"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="skynet netem", description=__doc__.split("\n\n")[0])
    parser.add_argument("kind", choices=("udp", "tcp"), help="which proxy")
    parser.add_argument("--listen", type=parse_address, default=("127.0.0.1", 0),
                        help="HOST:PORT the node connects to (port 0 = any free port)")
    parser.add_argument("--target", type=parse_address, required=True, help="HOST:PORT of the router")
    parser.add_argument("--impair", default="", help='netem-like impairment, e.g. "delay 50ms jitter 10ms loss 2%%"')
    parser.add_argument("--direction", choices=DIRECTIONS, default="both",
                        help="impair client->target (up), target->client (down) or both")
    parser.add_argument("--seed", type=int, default=None, help="random seed (reproducible decisions)")
    parser.add_argument("--interval", type=float, default=1.0, help="seconds between counter lines")
    parser.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    parser.add_argument("--json", action="store_true", help="print counters as JSON lines")
    return parser


def summary(stats: dict[str, Any]) -> str:
    """One human line of a proxy's counters."""
    parts = [f"{stats['kind']} {stats['listen']}->{stats['target']} t={stats['uptime_s']:.0f}s"]
    for d in ("up", "down"):
        c = stats.get(d)
        if not c:
            continue
        drops = " ".join(f"{k}={v}" for k, v in c["dropped"].items() if v)
        extra = " ".join(f"{k}={c[k]}" for k in ("duplicated", "reordered", "stalled", "retransmitted") if c[k])
        parts.append(f"{d}: in {c['packets_in']}/{c['bytes_in']}B out {c['packets_out']}/{c['bytes_out']}B"
                     + (f" drop {drops}" if drops else "") + (f" {extra}" if extra else ""))
    for k in ("associations", "connections"):
        if k in stats:
            parts.append(f"{k}={stats[k]}")
    return " | ".join(parts)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not args.interval > 0:
        parser.error("--interval must be > 0")
    try:
        impairment = Impairment.parse(args.impair)
    except ValueError as e:
        parser.error(f"--impair: {e}")
    cls = UdpProxy if args.kind == "udp" else TcpProxy
    proxy = cls(listen=args.listen, target=args.target, impairment=impairment, seed=args.seed,
                direction=args.direction)
    stop = threading.Event()
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda *_: stop.set())
    try:
        try:
            proxy.start()
        except (OSError, ValueError) as e:
            print(f"netem: cannot start: {e}", file=sys.stderr)
            return 1
        print(f"netem {args.kind} listening on {format_address(proxy.address)} -> "
              f"{format_address(proxy.target)} [{args.direction}: {impairment.to_text()}]", flush=True)
        waited = 0.0
        while not stop.is_set():
            step = args.interval if args.duration is None else min(args.interval, args.duration - waited)
            if step <= 0 or stop.wait(step):
                break
            waited += step
            _print(proxy.stats(), args.json)
        proxy.stop()
        _print(proxy.stats(), args.json)
        return 0
    finally:
        proxy.stop()
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _print(stats: dict[str, Any], as_json: bool) -> None:
    print(json.dumps(stats) if as_json else summary(stats), flush=True)


if __name__ == "__main__":
    raise SystemExit(main())
