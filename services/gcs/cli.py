"""``skynet gcs``: run a mission over the bus and write its report.

Design notes: docs/ground-station.md (services/gcs/cli.py).
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from dataclasses import replace
from pathlib import Path

from edge.geometry import formation
from protocol.bus import Bus, config_from_args, setup_logging, stop_event_on_signals
from protocol.cliconfig import add_options, from_namespace
from protocol.links import transports
from protocol.scenario import Scenario, load_scenario

from .config import GcsMissionConfig
from .mission import MissionOptions, MissionRunner
from .progress import HeadingHold, LiveDisplay, render
from .supervision import FRESH_STATE_S


def plan_verifier_of(root):
    """The ground station's verifier of plans: the planner's public key of the key set ``root``, its revocations."""
    from protocol import planauth
    from protocol.keyset import KeySet

    return planauth.plan_verifier(planauth.planner_public_key(root), KeySet(root, "gcs").revoked())


def run_mission(bus: Bus, scenario: Scenario, options: MissionOptions, out: str | None, quiet: bool, log, abort=None,
                ground_truth: bool = True, on_runner=None, record: bool = True, signer=None, plan_verifier=None) -> int:
    """Run the mission and write its report; ``ground_truth`` when the edges image the synthetic wall.

    With ``out`` and ``record``, the mission is logged to ``out/mission.mcap`` (:mod:`services.recording`:
    everything on the fleet's keys and the ground station's own entries), and the report is computed from that
    log read back, as ``skynet report`` does (the inspection section from its capture frames).

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

    if out:
        from services.recording.record import check_output_folder

        check_output_folder(out)  # RecordingError before anything flies
    writer = None
    if out and record:  # before the runner subscribes, so the log holds every sample the runner gets
        from services.recording.recorder import MissionLogWriter, RecordingBus

        from .surface import surface_problem

        writer = MissionLogWriter(bus, Path(out) / "mission.mcap", log, surface_check=surface_problem)
    if options.transport is None:  # what the report's link figures rode on: this session's own links
        options = replace(options, transport=transports(list(bus.config.connect)))
    runner = MissionRunner(bus if writer is None else RecordingBus(bus, writer), scenario, options,
                           on_progress=progress, log=log, abort=abort, sink=writer, signer=signer,
                           plan_verifier=plan_verifier, witness=None if writer is None else writer.witness)
    if on_runner is not None:
        on_runner(runner)
    if ground_truth:  # before the flight, so that the log's footer carries it (skynet report)
        from services.inspection.ground_truth import attach_ground_truth

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
        if writer is not None:
            writer.close()
        raise
    finally:
        root.handlers = saved
    if writer is not None:
        writer.finish(record)  # the footer: plan, phases, verdict, counters
    if out:  # the report's input is the log, read back (or the in-memory record if it failed: journal.py)
        from .journal import report_record
        from .report import write_report

        record = report_record(writer, record, log)
        folder = Path(out)
        frames = writer.path if writer is not None else None  # the capture frames the log holds
        try:
            write_report(record, folder, frames)
        except OSError as exc:  # a full or broken disk: the report goes elsewhere, and we say where
            import tempfile

            fallback = Path(tempfile.mkdtemp(prefix="skynet-report-"))
            log.error("could not write the report to %s (%s); writing it to %s instead (the log %s keeps "
                      "the record up to the failure)", folder, exc.strerror or exc, fallback, frames)
            record.recording_errors.append(f"report not written to {folder} ({exc.strerror or exc}): it is in "
                                           f"{fallback}")
            folder = fallback
            write_report(record, folder, frames)
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
    """``skynet gcs``'s command line: the options of :class:`GcsMissionConfig`."""
    parser = argparse.ArgumentParser(prog="skynet gcs",
                                     description="ground control station: run a mission over the bus, write its report")
    return add_options(parser, GcsMissionConfig)


def main(argv: list[str] | None = None) -> int:
    """``skynet gcs [mission]``: parse the command line, then :func:`run` the mission."""
    args = list(sys.argv[1:] if argv is None else argv)
    if args[:1] == ["mission"]:  # the mission named as an action: the same command
        args = args[1:]
    parser = build_parser()
    return run(from_namespace(GcsMissionConfig, parser.parse_args(args), parser))


def run(args: GcsMissionConfig) -> int:
    """A mission over the bus from its configuration; the exit status of :func:`run_mission`."""
    log = setup_logging("gcs")
    scenario = load_scenario(args.scenario)
    options = MissionOptions(uavs=tuple(range(1, args.uavs + 1)), algorithm=args.algorithm, seed=args.seed,
                             speed=args.speed, appear_timeout_s=args.appear_timeout,
                             ready_timeout_s=args.ready_timeout, method=args.method)
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

            # a detector started with --save-frames OUT/frames: the page counts those
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
