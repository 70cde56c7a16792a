"""Print the detector's defect reports as they arrive: one line per analysed capture point.

The detector analyses each capture frame of a mission and publishes a report. Beside `skynet up`, while a
mission flies (`skynet gcs ...`; or run it beside `skynet mission`)::

    python examples/watch_defects.py --count 10

It attaches with the key set's read-only `web` identity. Ctrl-C stops it.
"""

from __future__ import annotations

import argparse
import sys
import threading

import zenoh

from protocol import keys
from protocol.budget import for_topic
from protocol.cliconfig import add_options
from protocol.links import COMMAND
from protocol.messages import DefectReport
from protocol.signals import stop_event_on_signals
from protocol.textsafe import printable
from services.attach import AttachOptions, open_bus

ROLE = "web"  # may receive everything of the fleet, put or ask nothing (protocol/acl.py)


def describe(r: DefectReport) -> str:
    if not r.ok:
        return f"uav {r.uav} capture {r.capture_id}: not analysed ({printable(r.error)})"
    longest = max((d.length_m for d in r.defects if d.length_m is not None), default=None)
    size = "" if longest is None else f", longest {longest:.2f} m"
    return (f"uav {r.uav} capture {r.capture_id}: {len(r.defects)} defects ({r.defect_fraction:.2%} of the frame"
            f"{size}), {r.stamp_report - r.stamp_capture:.2f} s after capture, method {printable(r.method)}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_options(parser, AttachOptions)
    parser.add_argument("--count", type=int, default=0, help="stop after this many reports (default: 0, never)")
    parser.add_argument("--duration-s", dest="duration", type=float, default=0.0, help="stop after this many s (default: 0, never)")
    args = parser.parse_args(argv)
    done, lock, seen = stop_event_on_signals(), threading.Lock(), [0]  # Ctrl-C, --count or --duration-s

    def on_report(msg: DefectReport, sample: zenoh.Sample) -> None:
        with lock:
            if not done.is_set():
                seen[0] += 1
                print(describe(msg), flush=True)
                if args.count and seen[0] >= args.count:
                    done.set()

    try:  # malformed samples and floods are dropped and counted by the bus (expect, budget)
        with open_bus(args, ROLE, sys.argv[1:] if argv is None else argv, name="watch-defects") as bus:
            bus.subscribe(keys.defects(args.fleet), on_report, expect=DefectReport, link=COMMAND,
                          budget=for_topic("defects"))
            done.wait(args.duration or None)
    except (ValueError, OSError) as exc:  # AttachError included: what is missing, in one line
        parser.exit(1, f"{parser.prog}: error: {exc}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
