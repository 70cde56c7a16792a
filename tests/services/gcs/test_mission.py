"""Ground-station failures end the mission with a clear message, never a hang."""

import time

import pytest

from protocol.bus import Bus, BusConfig
from protocol.scenario import load_scenario
from services.gcs.mission import MissionOptions, MissionRunner

FLEET = "test"


def _edge(group, gateway, uav, *extra):
    return group.start(f"uav{uav}", ["edge", "--uav", str(uav), "--fleet", FLEET, "--multilink", "--camera", "none",
                                     *[a for e in gateway for a in ("--connect", e)], "--listen", "tcp/127.0.0.1:0",
                                     "--home", f"{38 + 2 * uav},8,0", "--speed", "8", *extra])


@pytest.fixture
def planner(group, gateway):
    svc = group.start("planner", ["planner", "--fleet", FLEET, "--multilink",
                                  *[a for e in gateway for a in ("--connect", e)]])
    assert svc.wait_ready(30)
    return svc


def _run(gateway, uavs, appear_timeout=20.0):
    opts = MissionOptions(uavs=uavs, speed=8, appear_timeout_s=appear_timeout, command_timeout_s=1.0,
                          command_attempts=2, particles=40, iterations=40)
    with Bus(BusConfig(mode="client", connect=gateway, multilink=True), FLEET, "gcs") as bus:
        t0 = time.monotonic()
        record = MissionRunner(bus, load_scenario(), opts).run()
        return record, time.monotonic() - t0


def test_a_uav_that_never_appears_fails_the_mission(group, gateway, planner):
    for uav in (1, 2):
        assert _edge(group, gateway, uav).wait_ready(30)
    record, elapsed = _run(gateway, (1, 2, 3), appear_timeout=4.0)
    assert not record.success
    assert any("UAV 3 never appeared" in f for f in record.failures), record.failures
    assert elapsed < 30  # did not hang (the appear timeout is 4 s)
    assert record.plan is None and not record.commands


def test_a_uav_that_refuses_its_upload_fails_the_mission(group, gateway, planner):
    _edge(group, gateway, 1)
    # UAV 2's own geofence is a small box: the plan's trajectory leaves it
    fenced = _edge(group, gateway, 2, "--geofence", "0,0,0,60,30,40")
    for svc in group.services[-2:]:
        assert svc.wait_ready(30)
    record, _ = _run(gateway, (1, 2))
    assert not record.success
    assert any("UAV 2 refused its trajectory upload" in f and "geofence" in f for f in record.failures), record.failures
    refused = [c for c in record.commands if c.uav == 2 and c.kind == "upload"]
    assert refused and refused[0].ok and not refused[0].accepted
    assert not any(c.kind == "takeoff" for c in record.commands)
    assert fenced.alive()


def test_scenario_formation_follows_the_number_of_uavs():
    from services.gcs.mission import with_formation_size

    doc = load_scenario()
    assert with_formation_size(doc, 3) is doc
    two = with_formation_size(doc, 2)
    assert two.formation.offsets == [(0.0, 0.0, 2.0), (3.0, 0.0, -1.0)]
    assert len(with_formation_size(doc, 5).formation.offsets) == 5
    assert len(doc.formation.offsets) == 3  # the caller's scenario is not changed


def test_the_common_start_leaves_time_for_every_start_command():
    """t0 must lie beyond the Start commands' round trip, or a UAV begins behind the others (seen
    with 200 ms on every link: 2.7 m short of the goal)."""
    from services.recording.record import CommandRecord

    with Bus(BusConfig(mode="peer"), FLEET, "gcs") as bus:
        runner = MissionRunner(bus, load_scenario(), MissionOptions(uavs=(1, 2, 3)))
        assert runner.start_margin_s() == 2.0  # nothing measured yet: the least margin
        runner.record.commands += [
            CommandRecord(uav=1, kind="takeoff", cmd_id=1, ok=True, accepted=True, elapsed_s=0.01, ack_s=[0.01]),
            CommandRecord(uav=2, kind="takeoff", cmd_id=2, ok=True, accepted=True, elapsed_s=0.8, ack_s=[0.8]),
        ]
        assert runner.start_margin_s() == pytest.approx(2.0)  # 2 x 0.8 s is less than the least margin
        runner.record.commands.append(
            CommandRecord(uav=3, kind="takeoff", cmd_id=3, ok=True, accepted=True, elapsed_s=1.5, ack_s=[1.5]))
        assert runner.start_margin_s() == pytest.approx(3.0)
        runner.record.commands.append(
            CommandRecord(uav=3, kind="takeoff", cmd_id=4, ok=True, accepted=True, elapsed_s=60, ack_s=[60.0]))
        assert runner.start_margin_s() == 30.0  # bounded


@pytest.mark.mission
def test_a_detector_reporting_frames_the_ground_station_never_received_fails_the_mission(group, gateway, planner,
                                                                                        tmp_path):
    """A session holding the detector's role reported every capture ok, each naming a frame of the UAV's capture
    camera (a sequence number, a digest) and corroborated by its own statistics, while no camera sent a frame
    (for UAV 2 it sent black frames itself and called them fine):
    the mission ended "success, every capture imaged" and its report counted every capture. Now a capture counts
    only on a frame the ground station's own log received as the report names it. (Its reports naming no frame at
    all were already not counted; with no statistics, not corroborated: test_evidence.py.)"""
    import hashlib
    import logging
    import threading

    import numpy as np

    from protocol import keys
    from protocol.imagecodec import encode_jpeg
    from protocol.imagery import pack_image
    from protocol.links import COMMAND, IMAGERY_RELIABLE, TELEMETRY
    from protocol.messages import DefectReport, FrameEvidence, LinkStats, VehicleState
    from protocol.rtp import RtpSender, ssrc_for
    from services.gcs.cli import run_mission
    from services.inspection.captures import capture_meta
    from services.recording.load import load_record

    for uav in (1, 2):
        assert _edge(group, gateway, uav).wait_ready(30)  # no camera: no frame is ever sent
    stop = threading.Event()
    t0 = time.time()

    def forge() -> None:
        with Bus(BusConfig(mode="client", connect=gateway, multilink=True), FLEET, "detector") as bus:
            reports, stats = bus.publisher(keys.defects(FLEET), COMMAND), bus.publisher(
                keys.rcu_stats(FLEET, "detector"), TELEMETRY)
            camera = bus.publisher(keys.camera(FLEET, 2), IMAGERY_RELIABLE)
            # a UAV's state counts its captures: at its k-th, its k-th capture id either way round (the plan gives
            # UAV 1 the odd ones of 0-25, UAV 2 the even ones), stamped then: each report is taken where planned
            taken = {1: 0, 2: 0}

            def on_state(msg, sample) -> None:
                if msg.uav in taken and msg.captures > taken[msg.uav]:
                    taken[msg.uav] = k = msg.captures
                    mine = list(range(2 - msg.uav, 26, 2))
                    reports.put(DefectReport(uav=msg.uav, capture_id=mine[0], stamp_capture=msg.stamp,
                                             stamp_report=time.time(), method="it+"))  # no evidence at all
                    for cid in {mine[(k - 1) % 13], mine[-k % 13]}:
                        digest = f"{cid:064x}"
                        if msg.uav == 2:  # UAV 2's frames sent (black: a covered lens) and called fine
                            jpeg = encode_jpeg(np.zeros((240, 320), np.uint8))
                            meta = capture_meta(2, cid, np.asarray(msg.pos), np.eye(3), (320, 240), 300.0, 300.0,
                                                160.0, 120.0, 5.0)
                            camera.put_bytes(pack_image(RtpSender(ssrc_for(2), initial_seq=cid), meta, jpeg,
                                                        time.time()))
                            digest = hashlib.sha256(jpeg).hexdigest()
                        reports.put(DefectReport(uav=msg.uav, capture_id=cid, stamp_capture=msg.stamp,
                                                 stamp_report=time.time(), method="it+", frame=FrameEvidence(
                                                     ssrc=ssrc_for(msg.uav), seq=cid, digest=digest)))

            bus.subscribe(keys.state(FLEET, "*"), on_state, expect=VehicleState, link=TELEMETRY)
            while not stop.wait(0.5):
                now = time.time()
                stats.put(LinkStats(source="detector", stamp=now, uptime_s=now - t0, metrics={
                    f"uav{u}.cam0.{n}": 100.0 for u in (1, 2) for n in ("received", "analysed")}))

    forger = threading.Thread(target=forge, daemon=True)
    forger.start()
    opts = MissionOptions(uavs=(1, 2), speed=8, appear_timeout_s=20, command_timeout_s=1.0, command_attempts=2,
                          particles=40, iterations=40)
    try:
        with Bus(BusConfig(mode="client", connect=gateway, multilink=True), FLEET, "gcs") as bus:
            rc = run_mission(bus, load_scenario(), opts, str(tmp_path), True, logging.getLogger("test"),
                             ground_truth=False)
    finally:
        stop.set()
        forger.join(10)
    record, _ = load_record(tmp_path / "mission.mcap")
    assert rc == 1 and not record.success
    assert record.held_captures == []
    assert any("never received" in f for f in record.failures), record.failures
    assert record.imagery[1]["reported"] == 0 and record.imagery[1]["not_received"] == 13
    assert record.imagery[1]["unevidenced"] > 0 and record.imagery[1]["analysed"] == 100
    # UAV 2's frames reached the ground station, but its own look finds no surface in them: not counted either
    assert record.imagery[2]["reported"] == 0 and record.imagery[2]["no_surface"] == 13, record.imagery[2]
    assert any("UAV 2: 13 capture(s) reported ok on a frame that shows no surface" in f for f in record.failures)
    md = (tmp_path / "report.md").read_text()
    assert "Captures imaged (a report came back, on a frame the ground station received itself): 0 of" in md


def test_snapshot_copies_the_live_figures():
    """What the live display reads, taken under the runner's lock (the CLI does not reach into it)."""
    from protocol import keys
    from protocol.links import TELEMETRY
    from protocol.messages import Mode, VehicleState
    from tests.conftest import wait_until

    with Bus(BusConfig(mode="peer"), FLEET, "gcs") as bus:
        runner = MissionRunner(bus, load_scenario(), MissionOptions(uavs=(1, 2)))
        snap = runner.snapshot()
        assert (snap.phase, snap.states, snap.ages_ms, snap.reports, snap.lost) == ("-", {}, [], 0, {})
        msg = VehicleState(uav=1, seq=0, t=0.0, stamp=time.time() - 0.25, pos=(0, 0, 5), vel=(0, 0, 0),
                           att=(0, 0, 0), rates=(0, 0, 0), mode=Mode.HOLD, armed=True)
        bus.publisher(keys.state(FLEET, 1), TELEMETRY).put(msg)  # the session hears its own sample
        assert wait_until(lambda: runner.snapshot().states, 10.0)
        runner.phase("takeoff")
        snap = runner.snapshot()
        assert snap.phase == "takeoff" and snap.states == {1: msg} and len(snap.ages_ms) == 1
        assert snap.ages_ms[0] >= 250.0
        assert set(snap.last_heard) == {1}
        snap.states.clear()
        assert runner.snapshot().states == {1: msg}  # a copy


@pytest.mark.mission
def test_a_camera_that_shows_no_surface_fails_the_mission_and_is_not_coverage(tmp_path):
    """Through the launcher in the default secure mode, each UAV's camera a folder (`--camera DIR`, a stand-in for
    a real camera) of which one frame in four is black (a covered lens) and one white (a failed exposure): the
    detector reports those captures failed and why, the mission fails naming each, and the inspection deliverable
    counts neither their frames in its coverage nor them as witnesses (it used to say: success, 100 %)."""
    import json

    import cv2
    import numpy as np

    from edge.world.surface import textured_background
    from tests.conftest import fly_mission

    cam = tmp_path / "camera"
    cam.mkdir()
    rng = np.random.default_rng(2)
    for k in range(2):
        g = textured_background((480, 640), rng, roughness=6.0)
        cv2.line(g, (80, 120), (560, 360), 40, 3)
        cv2.imwrite(str(cam / f"a{k}.png"), g)
    cv2.imwrite(str(cam / "b-covered.png"), np.zeros((480, 640), np.uint8))
    cv2.imwrite(str(cam / "c-overexposed.png"), np.full((480, 640), 255, np.uint8))
    run = fly_mission(tmp_path / "report", "--speed", "8", "--camera", str(cam), timeout=300)
    assert run.proc.returncode == 1, run.failure()
    report = run.report()
    blank = [f for f in report["failures"] if "capture points were not imaged" in f]
    assert len(blank) == 1 and "frame shows no surface: under-exposed, 100% of the frame black" in blank[0] \
        and "frame shows no surface: over-exposed, 100% of the frame white" in blank[0], report["failures"]
    planned, imaged = report["captures"]["planned"], report["captures"]["imaged"]
    assert 0.3 * planned <= planned - imaged <= 0.7 * planned, report["captures"]  # two frames of four, per UAV
    assert "capture points were not imaged: uav" in run.proc.stderr, run.failure()
    assert "not analysed: frame shows no surface: under-exposed" in run.proc.stderr, run.failure()  # while flying
    summary = json.loads((run.out / "inspection" / "defects.json").read_text())
    assert len(summary["unusable"]) == planned - imaged and summary["frames_used"] == imaged, summary
    assert summary["coverage"] < 0.9, summary
    text = (run.out / "report.md").read_text()
    assert f"{planned - imaged} of the {planned} captures show no surface and are not counted" in text


def test_failed_reports_are_told_while_flying_once_per_capture_and_bounded(caplog):
    import logging

    from protocol.messages import DefectReport
    from services.gcs.mission import MAX_FAILED_TOLD

    def failed(c: int) -> DefectReport:
        return DefectReport(uav=2, capture_id=c, stamp_capture=1.0, stamp_report=1.1, method="it+", ok=False,
                            error="frame shows no surface: blank\x1b[2J")

    with Bus(BusConfig(mode="peer"), FLEET, "gcs") as bus:
        runner = MissionRunner(bus, load_scenario(), MissionOptions(uavs=(1, 2)), log=logging.getLogger("t"))
        with caplog.at_level(logging.WARNING, logger="t"):
            for c in [0, 0, 1, *range(2, MAX_FAILED_TOLD + 20)]:
                runner._on_defects(failed(c), None)
    told = [r.getMessage() for r in caplog.records]
    assert len(told) == MAX_FAILED_TOLD and told[0].startswith("capture uav2-00000 not analysed: frame shows no surface")
    from protocol.textsafe import SafeFormatter  # the detector's text as the ground station's log prints it

    line = SafeFormatter("%(message)s").format(caplog.records[0])
    assert line == "capture uav2-00000 not analysed: frame shows no surface: blank\\x1b[2J", line
    assert len(runner.record.defects) == MAX_FAILED_TOLD + 21 and runner.reports == {}  # all kept, none counted
