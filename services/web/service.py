"""The live web page bound to the bus: ``skynet web`` and ``skynet gcs --web :8080``.

Design notes: docs/operator-view.md (services/web/service.py).
"""

from __future__ import annotations

import argparse
import os
import threading

from protocol import binding, keys
from protocol.bus import Bus, setup_logging, stop_event_on_signals
from protocol.cliconfig import add_options, from_namespace
from protocol.imagery import unpack_image
from protocol.links import COMMAND, TELEMETRY
from protocol.messages import DefectReport, Event, VehicleState
from protocol.readiness import notify_ready
from protocol.scenario import Scenario
from services.recording.replay import REPLAY_MARK

from .config import WebConfig
from .server import TOKEN_ENV, WebServer, parse_listen
from .tally import DefectTally
from .view import FleetView

#: the rejection counted for a replay mark on a key outside a replay fleet (the mark is then ignored)
MISPLACED_MARK = "replay-mark"


def replayed(sample, counters=None) -> bool:
    """Whether a sample was put by ``skynet replay``: it carries the replay mark (its attachment) *and* came
    on a key of a replay fleet (``F-replay``: the only keys the replay identity may write, protocol.acl). Any
    node may attach the mark, so on another fleet's key it proves nothing: ignored, and counted in
    ``counters`` as :data:`MISPLACED_MARK`."""
    att = getattr(sample, "attachment", None)
    if att is None or att.to_bytes() != REPLAY_MARK:
        return False
    key = str(sample.key_expr)
    try:
        fleet = keys.parse(key).fleet
    except keys.KeyError_:
        fleet = ""
    if fleet.endswith(keys.REPLAY_SUFFIX):
        return True
    if counters is not None:
        counters.reject(key, MISPLACED_MARK)
    return False


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
            view.on_state(m, replayed=replayed(s, bus.counters))

    def on_event(m: Event, s) -> None:
        if bound(binding.source_matches(str(s.key_expr), m.source), str(s.key_expr)):
            view.on_event(m, replayed=replayed(s, bus.counters))

    def on_defects(m: DefectReport, s) -> None:  # one key for every detector instance (the ACL guards it)
        view.on_defects(m, replayed=replayed(s, bus.counters))

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
                if rec.scenario is not None and rec.scenario is not view.scenario:  # its formation: one offset per UAV
                    view.set_scenario(rec.scenario)
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


def start_web(bus: Bus, spec: str, scenario: Scenario | None, rate_hz: float = 10.0, log=None, token: str | None = None,
              allowed_hosts: tuple[str, ...] = (), frames: str | None = None) -> tuple[FleetView, WebServer]:
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
    """``skynet web``'s command line: the options of :class:`WebConfig`."""
    return add_options(argparse.ArgumentParser(prog="skynet web", description=__doc__.split("\n\n")[0]), WebConfig)


def main(argv: list[str] | None = None) -> int:
    """``skynet web``: parse the command line, then :func:`run` the page."""
    parser = build_parser()
    args = from_namespace(WebConfig, parser.parse_args(argv), parser)
    token = os.environ.get(TOKEN_ENV)
    if args.token is None and token is not None and len(token) < 16:
        parser.error(f"${TOKEN_ENV}: at least 16 characters")
    return run(args, argv)


def run(args: WebConfig, argv: list[str] | None = None) -> int:
    """The web page from its configuration (``argv``: whether ``--fleet`` was given), until SIGINT/SIGTERM."""
    log = setup_logging("web")
    stop = stop_event_on_signals()
    from protocol.scenario import load_scenario
    from services.attach import open_bus

    with open_bus(args, "web", argv) as bus:
        _, server = start_web(bus, args.listen_web, load_scenario(args.scenario), args.rate, log, token=args.token,
                              allowed_hosts=tuple(args.allow_host), frames=args.frames)
        log.info("web up")
        notify_ready("web")
        stop.wait()
        server.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
