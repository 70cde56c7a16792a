"""Subscribe to the fleet's vehicle states and print one line per state: UAV, position, mode, battery.

Beside a running network: `skynet up` in the same folder describes it in .skynet/network.json, and this
script attaches to its gateway with the key set's read-only `web` identity (mutual TLS: the default)::

    skynet up &
    python examples/fleet_states.py --count 20

Elsewhere: --network FILE, or -e ENDPOINT --keys DIR --fleet NAME. Ctrl-C stops it.
"""

from __future__ import annotations

import argparse
import sys
import threading

import zenoh

from protocol import binding, keys
from protocol.budget import for_topic
from protocol.cliconfig import add_options
from protocol.links import TELEMETRY
from protocol.messages import VehicleState
from protocol.signals import stop_event_on_signals
from services.attach import AttachOptions, open_bus

ROLE = "web"  # may receive everything of the fleet, put or ask nothing (protocol/acl.py)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_options(parser, AttachOptions)
    parser.add_argument("--count", type=int, default=0, help="stop after this many states (default: 0, never)")
    parser.add_argument("--duration-s", dest="duration", type=float, default=0.0, help="stop after this many s (default: 0, never)")
    args = parser.parse_args(argv)
    done, lock, seen = stop_event_on_signals(), threading.Lock(), [0]  # Ctrl-C, --count or --duration-s

    def on_state(msg: VehicleState, sample: zenoh.Sample) -> None:
        if not binding.matches(str(sample.key_expr), msg.uav):
            return  # a body speaking for another UAV than its key's: not shown
        with lock:
            if done.is_set():
                return
            seen[0] += 1
            x, y, z = msg.pos
            print(f"uav {msg.uav}  pos ({x:7.2f}, {y:7.2f}, {z:6.2f}) m  mode {msg.mode.value:<8}  "
                  f"battery {msg.battery:4.0%}", flush=True)
            if args.count and seen[0] >= args.count:
                done.set()

    try:  # malformed samples and floods are dropped and counted by the bus (expect, budget)
        with open_bus(args, ROLE, sys.argv[1:] if argv is None else argv, name="fleet-states") as bus:
            bus.subscribe(keys.state(args.fleet, "*"), on_state, expect=VehicleState, link=TELEMETRY,
                          budget=for_topic("state"))
            done.wait(args.duration or None)
    except (ValueError, OSError) as exc:  # AttachError included: what is missing, in one line
        parser.exit(1, f"{parser.prog}: error: {exc}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
