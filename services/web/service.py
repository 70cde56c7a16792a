"""The live web page bound to the bus: ``skynet web`` and ``skynet gcs mission --web :8080``.

:func:`attach` subscribes a :class:`~services.web.view.FleetView` to the fleet's states, events,
defect reports and live previews; :func:`follow_runner` hands it the ground station's plan when
the planner has answered. ``skynet web`` is the page on its own (for instance beside ``skynet
replay``, to watch a recorded mission)::

    skynet web --listen-web :8080 -e tcp/127.0.0.1:7447
"""

from __future__ import annotations

import argparse
import threading

from protocol import binding, keys
from protocol.bus import Bus, add_bus_args, config_from_args, setup_logging, stop_event_on_signals
from protocol.imagery import unpack_image
from protocol.links import COMMAND, TELEMETRY
from protocol.messages import DefectReport, Event, VehicleState
from protocol.scenario import Scenario

from .server import WebServer, parse_listen
from .view import FleetView


def attach(bus: Bus, view: FleetView) -> None:
    fleet = bus.fleet
    bus.subscribe(keys.state(fleet, "*"), lambda m, s: view.on_state(m), expect=VehicleState, link=TELEMETRY)
    bus.subscribe(keys.all_events(fleet), lambda m, s: view.on_event(m), expect=Event, link=COMMAND)
    bus.subscribe(keys.defects(fleet), lambda m, s: view.on_defects(m), expect=DefectReport, link=COMMAND)

    def on_preview(sample) -> None:
        try:
            _, meta, jpeg = unpack_image(sample.payload.to_bytes())
        except ValueError:
            return  # an announce frame or a bad one: nothing to show
        if len(jpeg) and binding.matches(str(sample.key_expr), meta.uav):  # only its own UAV's tile
            view.on_preview(meta.uav, bytes(jpeg))

    bus.subscribe_raw(keys.preview(fleet, "*"), on_preview)


def follow_runner(view: FleetView, runner, stop: threading.Event | None = None) -> threading.Thread:
    """Give the view the runner's plan as soon as it has one (a daemon thread polling twice a second)."""
    stop = stop or threading.Event()

    def run() -> None:
        while not stop.wait(0.5):
            plan = runner.record.plan
            if plan is not None:
                view.set_plan(plan)
                return

    t = threading.Thread(target=run, name="web-plan", daemon=True)
    t.start()
    return t


def start_web(bus: Bus, spec: str, scenario: Scenario | None, rate_hz: float = 10.0, log=None) -> tuple[FleetView, WebServer]:
    host, port = parse_listen(spec)
    view = FleetView(scenario, fleet=bus.fleet)
    attach(bus, view)
    server = WebServer(view, host, port, rate_hz).start()
    if log:
        log.info("web page at http://%s:%d/", host, server.port)
    return view, server


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="skynet web", description=__doc__.split("\n\n")[0])
    add_bus_args(parser, mode="client")
    from services.orchestration.attach import add_network_arg

    add_network_arg(parser)
    parser.add_argument("--listen-web", default=":8080", help="[HOST]:PORT of the page (loopback by default)")
    parser.add_argument("--rate", type=float, default=10.0, help="snapshots per second on the WebSocket")
    parser.add_argument("--scenario", default=None, help="scenario file (default: the paper's monorail bridge)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    log = setup_logging("web")
    stop = stop_event_on_signals()
    from protocol.scenario import load_scenario

    from services.orchestration.attach import open_bus

    with open_bus(args, "web", argv) as bus:
        _, server = start_web(bus, args.listen_web, load_scenario(args.scenario), args.rate, log)
        log.info("web up")
        stop.wait()
        server.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
