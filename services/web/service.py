"""The live web page bound to the bus: ``skynet web`` and ``skynet gcs mission --web :8080``.

:func:`attach` subscribes a :class:`~services.web.view.FleetView` to the fleet's states, events,
defect reports and live previews; :func:`follow_runner` hands it the ground station's plan when
the planner has answered, its phases and warnings for the timeline. ``skynet web`` is the page on
its own (for instance beside ``skynet replay``, to watch a recorded mission: samples the replay
marks, or a fleet named ``F-replay``, are shown as a replay, not as live data)::

    skynet web --listen-web :8080 -e tcp/127.0.0.1:7447

The page wants its access token (services.web.server): the URL to open is printed with it
(``web page at http://127.0.0.1:8080/?token=...``); ``--token`` or the environment variable
``SKYNET_WEB_TOKEN`` fix it, otherwise it is random per start. ``--frames DIR`` (the detector's
saved captures) gives the page the report's deduplicated defect count (services.web.tally).
"""

from __future__ import annotations

import argparse
import os
import threading

from protocol import binding, keys
from protocol.bus import Bus, add_bus_args, setup_logging, stop_event_on_signals
from protocol.imagery import unpack_image
from protocol.links import COMMAND, TELEMETRY
from protocol.messages import DefectReport, Event, VehicleState
from protocol.scenario import Scenario
from services.recording.replay import REPLAY_MARK

from .server import TOKEN_ENV, WebServer, parse_listen
from .tally import DefectTally
from .view import FleetView


def replayed(sample) -> bool:
    """Whether a sample was put by ``skynet replay`` (its attachment says so)."""
    att = getattr(sample, "attachment", None)
    return att is not None and att.to_bytes() == REPLAY_MARK


def attach(bus: Bus, view: FleetView) -> None:
    """Show the fleet's states, events, defect reports and previews; a state or event that speaks for
    another node than its key's (:mod:`protocol.binding`) is refused and counted, never shown."""
    fleet = bus.fleet

    def bound(ok: bool, key: str) -> bool:
        if not ok:
            bus.counters.reject(key, binding.MISMATCH)
        return ok

    def on_state(m: VehicleState, s) -> None:
        if bound(binding.matches(str(s.key_expr), m.uav), str(s.key_expr)):
            view.on_state(m, replayed=replayed(s))

    def on_event(m: Event, s) -> None:
        if bound(binding.source_matches(str(s.key_expr), m.source), str(s.key_expr)):
            view.on_event(m, replayed=replayed(s))

    def on_defects(m: DefectReport, s) -> None:  # one key for every detector instance (the ACL guards it)
        view.on_defects(m, replayed=replayed(s))

    bus.subscribe(keys.state(fleet, "*"), on_state, expect=VehicleState, link=TELEMETRY)
    bus.subscribe(keys.all_events(fleet), on_event, expect=Event, link=COMMAND)
    bus.subscribe(keys.defects(fleet), on_defects, expect=DefectReport, link=COMMAND)

    def on_preview(sample) -> None:
        try:
            _, meta, jpeg = unpack_image(sample.payload.to_bytes())
        except ValueError:
            return  # an announce frame or a bad one: nothing to show
        if len(jpeg) and binding.matches(str(sample.key_expr), meta.uav):  # only its own UAV's tile
            view.on_preview(meta.uav, bytes(jpeg))

    bus.subscribe_raw(keys.preview(fleet, "*"), on_preview)


#: phases after which every capture has been analysed (the page's defect count is then recounted at once)
LAST_PHASES = ("reports", "landing", "done")


def follow_runner(view: FleetView, runner, stop: threading.Event | None = None,
                  tally: DefectTally | None = None) -> threading.Thread:
    """Give the view the runner's plan as soon as it has one, its phases and its failures for the timeline,
    and the tally the surface the report uses (a daemon thread polling twice a second)."""
    stop = stop or threading.Event()

    def run() -> None:
        plan_sent, phases, failures, incidents, faults = False, set(), 0, 0, 0
        while not stop.wait(0.5):
            rec = runner.record
            if not plan_sent and rec.plan is not None:
                view.set_plan(rec.plan)
                plan_sent = True
            if tally is not None and rec.surface_corners:
                tally.corners = [tuple(c) for c in rec.surface_corners]
            for name, t in sorted(dict(rec.phases).items(), key=lambda kv: kv[1]):
                if name not in phases:
                    phases.add(name)
                    view.note(t, "gcs", "phase", name)
                    if tally is not None and name in LAST_PHASES:
                        tally.poke()
            for text in list(rec.failures)[failures:]:
                failures += 1
                view.note(view.clock(), "gcs", "failure", str(text), "warning")
            for inc in list(rec.incidents)[incidents:]:  # what the ground station saw of a fault and did
                incidents += 1
                view.note(inc.at, "gcs" if inc.uav is None else f"uav/{inc.uav}", inc.kind, inc.text, "warning")
            for f in list(rec.faults)[faults:]:  # faults injected into the run (or supervisor restarts)
                faults += 1
                view.note(f.at, "faults", f.action, f"{f.target} {f.text}".strip(), "warning")
            if "done" in phases:
                return

    t = threading.Thread(target=run, name="web-plan", daemon=True)
    t.start()
    return t


def start_web(bus: Bus, spec: str, scenario: Scenario | None, rate_hz: float = 10.0, log=None,
              token: str | None = None, allowed_hosts: tuple[str, ...] = (), frames: str | None = None,
              ) -> tuple[FleetView, WebServer]:
    """The page on ``spec``; its URL (with the token: ``token`` or the environment's, else random) is logged.
    ``frames``: the detector's saved captures, for the report's deduplicated defect count
    (``server.tally``)."""
    host, port = parse_listen(spec)
    view = FleetView(scenario, fleet=bus.fleet)
    attach(bus, view)
    server = WebServer(view, host, port, rate_hz, token=token or os.environ.get(TOKEN_ENV) or None,
                       allowed_hosts=allowed_hosts).start()
    if frames:
        corners = scenario.surface.corners if scenario is not None and scenario.surface is not None else None
        server.tally = DefectTally(view, frames, corners).start()
        server.on_stop = server.tally.stop
    if log:
        log.info("web page at %s", server.url)
    return view, server


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="skynet web", description=__doc__.split("\n\n")[0])
    add_bus_args(parser, mode="client")
    from services.orchestration.attach import add_network_arg

    add_network_arg(parser)
    parser.add_argument("--listen-web", default=":8080", help="[HOST]:PORT of the page (loopback by default)")
    parser.add_argument("--rate", type=float, default=10.0, help="snapshots per second on the WebSocket")
    parser.add_argument("--scenario", default=None, help="scenario file (default: the paper's monorail bridge)")
    parser.add_argument("--token", default=None,
                        help=f"the page's access token (default: ${TOKEN_ENV}, else random per start; at least 16 "
                             "characters)")
    parser.add_argument("--allow-host", action="append", default=[], metavar="NAME",
                        help="a host name the page also answers to besides its address and localhost (repeatable)")
    parser.add_argument("--frames", default=None, metavar="DIR",
                        help="the detector's saved captures (a report's frames/): the defect count as the report "
                             "counts it")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    token = args.token or os.environ.get(TOKEN_ENV)
    if token is not None and len(token) < 16:
        parser.error("--token: at least 16 characters")
    try:
        parse_listen(args.listen_web)
    except ValueError as exc:
        parser.error(str(exc))
    log = setup_logging("web")
    stop = stop_event_on_signals()
    from protocol.scenario import load_scenario
    from services.orchestration.attach import open_bus

    with open_bus(args, "web", argv) as bus:
        _, server = start_web(bus, args.listen_web, load_scenario(args.scenario), args.rate, log, token=args.token,
                              allowed_hosts=tuple(args.allow_host), frames=args.frames)
        log.info("web up")
        stop.wait()
        server.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
