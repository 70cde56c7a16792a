"""``skynet replay FILE [--speed K]``: a recorded mission played back onto the bus.

Design notes: docs/recording.md (services/recording/replay.py).
"""

from __future__ import annotations

import argparse
import time
from collections import Counter
from pathlib import Path

from protocol import keys
from protocol.bus import Bus, Publisher, add_bus_args, setup_logging, stop_event_on_signals
from protocol.cliconfig import show_defaults
from protocol.links import COMMAND, class_of_topic
from services.attach import add_network_arg, open_bus

from .mcap_log import bus_bytes, read

#: the Zenoh attachment of every replayed sample (services.web.service reads it)
REPLAY_MARK = b"skynet-replay"


def plan_of(path: str | Path):
    """(key, data, rx) of every bus sample of the file, in order (a generator; streams the file)."""
    for item in read(path):
        data = bus_bytes(item)
        if data is not None:
            yield item.topic, data, item.rx


def rename_fleet(key: str, fleet: str | None) -> str:
    if fleet is None:
        return key
    parts = key.split("/")
    parts[1] = fleet
    return "/".join(parts)


def replay(bus: Bus, path: str | Path, speed: float = 1.0, fleet: str | None = None, stop=None,
           reliable: bool = False) -> Counter:
    """Put the file's samples on ``bus``; returns counts per link class (and ``skipped``).

    ``reliable`` puts every sample on the command class (reliable, blocking) instead of its own
    class: nothing is dropped, at the price of the live run's timing under load.
    """
    if not (speed >= 0.0):
        raise ValueError(f"speed must be >= 0, got {speed!r}")
    pubs: dict[str, Publisher] = {}
    counts: Counter[str] = Counter()
    t_file0 = t_wall0 = None
    for key, data, rx in plan_of(path):
        if stop is not None and stop.is_set():
            break
        key = rename_fleet(key, fleet)
        try:
            topic = keys.parse(key).topic
        except ValueError:
            counts["skipped"] += 1
            continue
        if t_file0 is None:
            t_file0, t_wall0 = rx, time.monotonic()
        if speed > 0:
            delay = t_wall0 + (rx - t_file0) / speed - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        if key not in pubs:
            pubs[key] = bus.publisher(key, COMMAND if reliable else class_of_topic(topic))
        pubs[key].put_bytes(data, attachment=REPLAY_MARK)
        counts[class_of_topic(topic).name] += 1
    return counts


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="skynet replay", description=__doc__.split("\n\n")[0])
    add_bus_args(parser, mode="client")
    add_network_arg(parser)
    parser.add_argument("file", help="an MCAP file written by the ground station (reports/.../mission.mcap)")
    parser.add_argument("--speed", type=float, default=1.0, help="times the recorded pace (0: as fast as possible)")
    parser.add_argument("--as-fleet", default=None,
                        help="replay under this fleet name (default: FLEET-replay, beside the live fleet: the replay "
                             "identity may put nothing on the live fleet's keys)")
    parser.add_argument("--reliable", action="store_true",
                        help="every sample reliable and blocking (nothing dropped), not on its own link class")
    return show_defaults(parser)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if not Path(args.file).is_file():
        raise OSError(f"no such file: {args.file}")
    log = setup_logging("replay")
    stop = stop_event_on_signals()
    with open_bus(args, "replay", argv) as bus:
        as_fleet = args.as_fleet or keys.replay_fleet(args.fleet)
        log.info("replay up: %s at %gx as fleet %s", args.file, args.speed, as_fleet)
        counts = replay(bus, args.file, args.speed, as_fleet, stop, reliable=args.reliable)
        time.sleep(0.5)  # let the last samples leave before the session closes
        log.info("replayed: %s", dict(counts))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
