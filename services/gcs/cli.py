"""``skynet gcs mission``: run a mission over the bus and write its report.

    skynet gcs mission --scenario FILE -e tcp/127.0.0.1:7447?rel=1 -e udp/127.0.0.1:7448?rel=0 --multilink

Exit status 0 only when every UAV reached the goal and every capture point was imaged.
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

from edge import formation
from protocol.bus import Bus, add_bus_args, config_from_args, setup_logging, stop_event_on_signals
from protocol.scenario import Scenario, load_scenario

from .mission import MissionOptions, MissionRunner
from .progress import HeadingHold, LiveDisplay, render
from .supervision import FRESH_STATE_S


def plan_verifier_of(root):
    """The ground station's verifier of plans: the planner's public key of the key set ``root``, its revocations."""
    from protocol import planauth
    from protocol.keyset import KeySet

    return planauth.plan_verifier(planauth.planner_public_key(root), KeySet(root, "gcs").revoked())


def run_mission(bus: Bus, scenario: Scenario, options: MissionOptions, out: str | None, quiet: bool, log,
                abort=None, ground_truth: bool = True, on_runner=None, record: bool = True, signer=None,
                plan_verifier=None) -> int:
    """Run the mission and write its report; ``ground_truth`` when the edges image the synthetic wall.

    With ``out`` and ``record``, everything on the fleet's keys is also logged to ``out/mission.mcap``
    (:mod:`services.recording`), from which the same report can be rebuilt.

    ``on_runner(runner)`` is called once, after the :class:`MissionRunner` is made and before it runs
    (the launcher's fault injector hooks in there: ``runner.note_fault``, ``runner.record.phases``).
    """
    display = None if quiet else LiveDisplay()
    heading = HeadingHold()  # the formation heading, held across slow moments (services.gcs.progress)
    offsets = {i + 1: tuple(o) for i, o in enumerate(formation.offsets_for(len(options.uavs)))}
    t_start = time.time()

    def progress(runner: MissionRunner, force: bool = False) -> None:
        if display is None:
            return
        snap = runner.snapshot()
        now = time.time()
        heard, lost = snap.last_heard, snap.lost
        notes = {u: "LOST" if u in lost else f"silent {now - heard[u]:.1f} s" for u in options.uavs
                 if u in lost or (u in heard and now - heard[u] > FRESH_STATE_S)}
        display.update(render(snap.phase, snap.states, options.uavs, snap.ages_ms, snap.reports,
                              len(runner.planned_captures()), offsets, now - t_start, notes, heading), force=force)

    journal = None
    if out:
        from .record import check_output_folder

        journal = check_output_folder(out) / "record.jsonl"  # RecordingError before anything flies
    recorder = None
    if out and record:  # before the runner subscribes, so the log holds every sample the runner gets
        from services.recording.recorder import Recorder, RecordingBus

        recorder = Recorder(bus, Path(out) / "mission.mcap", log)
    runner = MissionRunner(bus if recorder is None else RecordingBus(bus, recorder), scenario, options,
                           on_progress=progress, log=log, abort=abort, journal=journal, signer=signer,
                           plan_verifier=plan_verifier)
    if on_runner is not None:
        on_runner(runner)
    if ground_truth:  # before the flight, so that the journal's footer carries it (skynet report)
        from services.gcs.ground_truth import attach_ground_truth

        attach_ground_truth(runner.record)
    root = logging.getLogger()
    saved = list(root.handlers)
    if display is not None and display.tty:  # log lines go above the live block, not through it
        handler = display.handler()
        handler.setFormatter(saved[0].formatter if saved else None)
        root.handlers = [handler]
    try:
        record = runner.run()
        progress(runner, force=True)
    except BaseException:
        if recorder is not None:
            recorder.close()
        raise
    finally:
        root.handlers = saved
    if out:  # the report's input is the journal, read back (or the in-memory record if it failed: journal.py)
        from .journal import report_record

        record = report_record(runner.recorder, record, log)
    if recorder is not None:  # the MCAP log's summary: the report's record (services.recording.rebuild), so
        # that the log rebuilds the report even when a state came in after the journal was closed
        record = recorder.finish(record, runner._lock)
        from .report import write_report

        folder = Path(out)
        try:
            write_report(record, folder)
        except OSError as exc:  # a full or broken disk: the report goes elsewhere, and we say where
            import tempfile

            fallback = Path(tempfile.mkdtemp(prefix="skynet-report-"))
            log.error("could not write the report to %s (%s); writing it to %s instead (the journal %s keeps "
                      "the record up to the failure)", folder, exc.strerror or exc, fallback, journal)
            record.recording_errors.append(f"report not written to {folder} ({exc.strerror or exc}): it is in "
                                           f"{fallback}")
            folder = fallback
            write_report(record, folder)
        log.info("report written to %s", folder / "report.md")
        for err in record.recording_errors:
            log.error("recording: %s", err)
    if record.success:
        log.info("mission succeeded: %d UAVs reached the goal, %d capture points imaged", len(options.uavs),
                 len(runner.planned_captures()))
        return 0
    for f in record.failures:
        log.error("mission failed: %s", f)
    return 1


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="skynet gcs", description="ground control station")
    sub = parser.add_subparsers(dest="action", required=True)
    m = sub.add_parser("mission", help="run a mission over the bus")
    add_bus_args(m, mode="client")
    m.add_argument("--scenario", default=None, help="scenario file (default: the paper's monorail bridge)")
    m.add_argument("--uavs", type=int, default=3, help="number of UAVs (ids 1..N)")
    m.add_argument("--algorithm", default="theta-pso")
    m.add_argument("--seed", type=int, default=0)
    m.add_argument("--speed", type=float, default=1.0, help="the edges' simulation speed factor")
    m.add_argument("--out", default=None, help="report folder")
    m.add_argument("--quiet", action="store_true")
    m.add_argument("--appear-timeout", type=float, default=30.0)
    m.add_argument("--ready-timeout", type=float, default=120.0, metavar="S",
                   help="wait this long for every UAV's autopilot to be ready before takeoff, then refuse")
    m.add_argument("--no-record", action="store_true", help="do not log the mission to OUT/mission.mcap")
    m.add_argument("--web", default=None, metavar="[HOST]:PORT",
                   help="serve the live web page of the fleet there (e.g. :8080; loopback unless a host is given)")
    m.add_argument("--no-ground-truth", action="store_true",
                   help="the edges do not image the synthetic wall (real cameras, image folders): no defect scoring")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    log = setup_logging("gcs")
    scenario = load_scenario(args.scenario)
    options = MissionOptions(uavs=tuple(range(1, args.uavs + 1)), algorithm=args.algorithm, seed=args.seed,
                             speed=args.speed, appear_timeout_s=args.appear_timeout,
                             ready_timeout_s=args.ready_timeout)
    abort = stop_event_on_signals()
    signer = plan_verifier = None
    if args.keys:  # commands and heartbeats signed end to end, plans signed by the planner
        from protocol.keyset import KeySet
        signer = KeySet(args.keys, "gcs").signer()
        plan_verifier = plan_verifier_of(args.keys)
    else:
        log.warning("INSECURE: commands and heartbeats go unsigned (no --keys)")
    with Bus(config_from_args(args, role="gcs"), fleet=args.fleet, name="gcs") as bus:
        hooks, server = {}, None
        if args.web:  # services.web: the live page, fed by this session
            from services.web.service import follow_runner, start_web

            # the report's inspection section reads OUT/frames (the detector's --save-frames): the page counts those
            frames = str(Path(args.out) / "frames") if args.out else None
            view, server = start_web(bus, args.web, scenario, log=log, frames=frames)
            hooks["on_runner"] = lambda runner: follow_runner(view, runner, tally=server.tally)
        try:
            return run_mission(bus, scenario, options, args.out, args.quiet, log, abort=abort,
                               ground_truth=not args.no_ground_truth, record=not args.no_record, signer=signer,
                               plan_verifier=plan_verifier,
                               **hooks)
        finally:
            if server is not None:
                server.stop()


if __name__ == "__main__":
    raise SystemExit(main())
