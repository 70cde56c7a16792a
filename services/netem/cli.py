"""``skynet netem``: run one impairment proxy in front of a link, printing its counters.

Design notes: docs/experiments.md (services/netem/cli.py).
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from typing import Any

from protocol.bus import stopping_on_signals
from protocol.cliconfig import show_defaults
from protocol.readiness import notify_ready
from services.netem.control import ControlServer, send_control
from services.netem.model import Impairment, parse_impair_arg
from services.netem.proxy import DIRECTIONS, TcpProxy, UdpProxy, format_address, parse_address
from services.netem.schedule import ScheduleError, Step, load_schedule

__all__ = ["main", "build_parser", "ctl", "summary"]


def build_parser() -> argparse.ArgumentParser:
    """``skynet netem udp|tcp ...`` (a proxy) and ``skynet netem ctl ...`` (a running proxy's control)."""
    parser = argparse.ArgumentParser(prog="skynet netem", description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="kind", required=True, metavar="udp|tcp|ctl")
    for kind in ("udp", "tcp"):
        _proxy_arguments(commands.add_parser(kind, help=f"run a {kind.upper()} impairment proxy"))
    _ctl_arguments(commands.add_parser("ctl", help="send one command to a running proxy's control channel"))
    return show_defaults(parser)


def _proxy_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--listen", type=parse_address, default=("127.0.0.1", 0),
                        help="HOST:PORT the node connects to (port 0 = any free port)")
    parser.add_argument("--target", type=parse_address, required=True, help="HOST:PORT of the router")
    parser.add_argument("--impair", default="", metavar="SPEC",
                        help='netem-like impairment of this link, e.g. "delay 50ms jitter 10ms loss 2%%" (the '
                             "launcher's --impair grammar without its LINK=)")
    parser.add_argument("--direction", choices=DIRECTIONS, default="both",
                        help="impair client->target (up), target->client (down) or both")
    parser.add_argument("--seed", type=int, default=None, help="random seed (reproducible decisions)")
    parser.add_argument("--interval-s", type=float, default=1.0, dest="interval", metavar="S",
                        help="seconds between counter lines")
    parser.add_argument("--duration-s", type=float, default=None, dest="duration", metavar="S",
                        help="stop after this many seconds")
    parser.add_argument("--json", action="store_true", help="print counters as JSON lines")
    parser.add_argument("--schedule", metavar="FILE", default=None,
                        help="play a schedule file of timed changes (at 10s cut 5s ...)")
    parser.add_argument("--control", metavar="HOST:PORT", type=parse_address, default=None,
                        help="open a loopback UDP control channel (skynet netem ctl HOST:PORT COMMAND)")


def _ctl_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("address", type=parse_address, help="HOST:PORT of the control channel")
    parser.add_argument("command", nargs="+", help='set SPEC | cut [T] | restore | clear | stats')
    parser.add_argument("--timeout-s", type=float, default=3.0, dest="timeout", metavar="S",
                        help="seconds to wait for the reply")


def ctl(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """``skynet netem ctl HOST:PORT COMMAND...``: print the reply; 0 accepted, 2 refused, 1 no reply."""
    if not args.timeout > 0:
        parser.error("--timeout-s must be > 0")
    command = args.command[0] if len(args.command) == 1 else shlex.join(args.command)
    try:
        reply = send_control(args.address, command, timeout_s=args.timeout)
    except (OSError, ValueError) as e:  # TimeoutError is an OSError
        print(f"netem ctl: {e}", file=sys.stderr)
        return 1
    print(json.dumps(reply), flush=True)
    if not reply.get("ok"):
        print(f"netem ctl: {reply.get('error', 'refused')}", file=sys.stderr)
        return 2
    return 0


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
    if stats.get("changes"):
        parts.append(f"changes={stats['changes']} now: {stats['impairment']}")
    if stats.get("cut"):
        left = stats.get("cut_remaining_s")
        parts.append("CUT" + (f" {left:.1f}s left" if left is not None else " until restore"))
    return " | ".join(parts)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(sys.argv[1:] if argv is None else list(argv))
    if args.kind == "ctl":
        return ctl(args, parser)
    if not args.interval > 0:
        parser.error("--interval-s must be > 0")
    try:
        impairment = parse_impair_arg(args.impair, named=False).impairment
    except ValueError as e:
        parser.error(str(e))
    steps: list[Step] = []
    if args.schedule is not None:
        try:
            steps = load_schedule(args.schedule)
        except ScheduleError as e:
            parser.error(f"--schedule: {e}")
    cls = UdpProxy if args.kind == "udp" else TcpProxy
    proxy = cls(listen=args.listen, target=args.target, impairment=impairment, seed=args.seed, direction=args.direction)
    control = None
    if args.control is not None:
        try:
            control = ControlServer(proxy, args.control)
        except ValueError as e:
            parser.error(f"--control: {e}")
    if args.schedule is not None:
        proxy.play(steps, on_step=_log_step)
    with stopping_on_signals() as stop:
        return _serve(args, proxy, control, impairment, stop)


def _serve(args: argparse.Namespace, proxy: UdpProxy | TcpProxy, control: ControlServer | None,
           impairment: Impairment, stop: Any) -> int:
    try:
        try:
            proxy.start()
            if control is not None:
                control.start()
        except (OSError, ValueError) as e:
            print(f"netem: cannot start: {e}", file=sys.stderr)
            return 1
        print(f"netem {args.kind} listening on {format_address(proxy.address)} -> "
              f"{format_address(proxy.target)} [{args.direction}: {impairment.to_text()}]", flush=True)
        notify_ready("netem")
        if control is not None:
            print(f"netem control on {format_address(control.address)}", flush=True)
        waited = 0.0
        while not stop.is_set():
            step = args.interval if args.duration is None else min(args.interval, args.duration - waited)
            if step <= 0 or stop.wait(step):
                break
            waited += step
            _print(proxy.stats(), args.json)
        if control is not None:
            control.stop()
        proxy.stop()
        _print(proxy.stats(), args.json)
        return 0
    finally:
        if control is not None:
            control.stop()
        proxy.stop()


def _log_step(step: Step, error: str | None) -> None:
    """A schedule step, logged on stderr (stdout carries the counters)."""
    text = f"netem: step at {step.at_s!r}s: {step.command.to_text()}"
    print(text + (f" FAILED: {error}" if error else ""), file=sys.stderr, flush=True)


def _print(stats: dict[str, Any], as_json: bool) -> None:
    print(json.dumps(stats) if as_json else summary(stats), flush=True)


if __name__ == "__main__":
    raise SystemExit(main())
