"""The mission's deliverable (services.inspection.mission): the mosaic, defect table, GeoJSON and KML built
from the captures the ground station's mission log received over the real bus (the detector in another folder,
keeping nothing), or from a folder of posed photos (the detector's --save-frames, for its own use)."""

from __future__ import annotations

import json
import time

import pytest

from edge.world.wall import synthetic_surface
from protocol import keys
from protocol.bus import Bus, BusConfig
from protocol.imagery import pack_image
from protocol.links import IMAGERY_RELIABLE
from protocol.messages import DefectReport
from protocol.rtp import RtpSender, ssrc_for
from protocol.scenario import load_scenario
from services.inspection.captures import synthetic_captures
from services.inspection.deliverable import load_folder
from services.inspection.mission import append_deliverable
from services.recording.record import MissionRecord
from tests.conftest import wait_until

FLEET = "test"


def send_captures(uav: Bus, caps) -> None:
    """UAV 1's camera sends ``caps`` (reliably: these tests are about keeping frames, not UDP loss)."""
    pub = uav.publisher(keys.camera(FLEET, 1), IMAGERY_RELIABLE)
    sender = RtpSender(ssrc_for(1))
    for c in caps:
        meta = c.meta.model_copy(update={"uav": 1, "stamp": time.time()})
        pub.put_bytes(pack_image(sender, meta, c.jpeg, time.time()))
        time.sleep(0.05)


def test_detector_keeps_captures_and_the_report_builds_the_deliverable(group, gateway, tmp_path):
    sc = load_scenario()
    surf = synthetic_surface(sc, seed=7)
    caps = synthetic_captures(sc, surf)[:8]
    frames = tmp_path / "frames"
    svc = group.start("detector", ["detector", "--fleet", FLEET, "--multilink", "--save-frames", str(frames),
                                   *[a for e in gateway for a in ("--connect", e)]])
    assert svc.wait_ready(30), "\n".join(svc.lines)
    reports: list[DefectReport] = []
    with Bus(BusConfig(mode="client", connect=gateway, multilink=True), FLEET, "uav") as uav:
        uav.subscribe(keys.defects(FLEET), lambda m, s: reports.append(m), expect=DefectReport)
        assert wait_until(lambda: uav.alive(keys.rcu_alive(FLEET, "detector")), 10)
        time.sleep(0.5)
        send_captures(uav, caps)
        assert wait_until(lambda: len(reports) >= len(caps), 60), (len(reports), "\n".join(svc.lines[-20:]))
    kept, _, _ = load_folder(frames)
    assert len(kept) == len(caps)
    assert kept[0].meta.cam_pos == caps[0].meta.cam_pos

    report = tmp_path / "report"
    report.mkdir()
    (frames).rename(report / "frames")
    (report / "report.md").write_text("# report\n")
    record = MissionRecord(fleet=FLEET, scenario=sc, speed=1.0, started=0.0,
                           surface_corners=[tuple(map(float, p)) for p in surf.corners])
    files: list[str] = []
    written = append_deliverable(record, report, files)
    assert files == written and "inspection/defects.geojson" in written
    md = (report / "report.md").read_text()
    assert "## Inspection deliverable" in md and "| id |" in md
    doc = json.loads((report / "inspection" / "defects.json").read_text())
    assert doc["frames"] == len(caps) and doc["defects"]
    assert all(d["lla"] is not None for d in doc["defects"])


def test_the_deliverable_comes_from_the_frames_the_ground_station_logged_not_from_the_detector(group, gateway,
                                                                                              tmp_path):
    """The detector runs in a folder of its own without --save-frames (as on another host); the ground station's
    log writer receives the captures over the bus, and the report's inspection section is built from its log."""
    from services.recording.recorder import MissionLogWriter

    sc = load_scenario()
    surf = synthetic_surface(sc, seed=7)
    caps = synthetic_captures(sc, surf)[:8]
    elsewhere = tmp_path / "detector-host"
    elsewhere.mkdir()
    svc = group.start("detector", ["detector", "--fleet", FLEET, "--multilink",
                                   *[a for e in gateway for a in ("--connect", e)]],
                      prefix=["env", f"--chdir={elsewhere}"])
    assert svc.wait_ready(30), "\n".join(svc.lines)
    report = tmp_path / "report"
    report.mkdir()
    reports: list[DefectReport] = []
    cfg = BusConfig(mode="client", connect=gateway, multilink=True)
    with Bus(cfg, FLEET, "uav") as uav, Bus(cfg, FLEET, "gcs") as gcs:
        writer = MissionLogWriter(gcs, report / "mission.mcap")
        gcs.subscribe(keys.defects(FLEET), lambda m, s: reports.append(m), expect=DefectReport)
        assert wait_until(lambda: uav.alive(keys.rcu_alive(FLEET, "detector")), 10)
        time.sleep(0.5)
        send_captures(uav, caps)
        assert wait_until(lambda: len(reports) >= len(caps), 60), (len(reports), "\n".join(svc.lines[-20:]))
        writer.close()
    assert list(elsewhere.iterdir()) == []  # the detector kept nothing
    (report / "report.md").write_text("# report\n")
    record = MissionRecord(fleet=FLEET, scenario=sc, speed=1.0, started=0.0,
                           surface_corners=[tuple(map(float, p)) for p in surf.corners])
    written = append_deliverable(record, report, [], report / "mission.mcap")
    assert "inspection/defects.geojson" in written
    assert "## Inspection deliverable" in (report / "report.md").read_text()
    doc = json.loads((report / "inspection" / "defects.json").read_text())
    assert doc["frames"] == len(caps) and doc["defects"]


def test_no_saved_captures_no_section(tmp_path):
    (tmp_path / "report.md").write_text("# report\n")
    record = MissionRecord(fleet=FLEET, speed=1.0, started=0.0)
    assert append_deliverable(record, tmp_path) == []
    assert (tmp_path / "report.md").read_text() == "# report\n"
    (tmp_path / "frames").mkdir()
    assert append_deliverable(record, tmp_path) == []
    assert "Not built: no captures in frames" in (tmp_path / "report.md").read_text()


def test_the_deliverable_names_the_planned_captures_its_mosaic_lacks():
    from types import SimpleNamespace

    from protocol.messages import Box, MissionPlan, Trajectory, Waypoint
    from services.inspection.mission import absent_text

    plan = MissionPlan(algorithm="test", seed=0, cost=1.0, collision_free=True, centroid_path=[(0, 0, 5), (9, 0, 5)],
                       trajectories=[Trajectory(uav=u, waypoints=[Waypoint(t=0.0, pos=(0, 0, 5)),
                                                                  *(Waypoint(t=float(c), pos=(c, 0, 5), capture_id=c)
                                                                    for c in (u, u + 3))]) for u in (1, 2)],
                       geofence=Box(lo=(0.0, 0.0, 0.0), hi=(10.0, 10.0, 10.0)), origin=(0.0, 0.0, 0.0))
    record = MissionRecord(fleet=FLEET, speed=1.0, started=0.0, plan=plan)
    posed = [SimpleNamespace(meta=SimpleNamespace(uav=u, capture_id=c)) for u, c in ((1, 1), (1, 4), (2, 5))]
    assert absent_text(record, posed) == ("1 of the 4 planned captures are not among its frames (not taken, or lost "
                                          "on the way to the ground station's log): uav2-00002.")
    assert absent_text(record, [*posed, SimpleNamespace(meta=SimpleNamespace(uav=2, capture_id=2))]) == ""
    assert absent_text(MissionRecord(fleet=FLEET, speed=1.0, started=0.0), posed) == ""  # no plan: nothing to miss


def test_the_findings_name_the_deliverables_method_and_the_detectors(tmp_path):
    """The deliverable segments with IT+ whatever the mission's detector ran (on the real-size wall the default
    it+r put a false defect on a true crack and a 60 % length error, where IT+ stays within tolerance), and says
    so beside the detector's method, which the log's header keeps."""
    from edge.world.wall import synthetic_surface
    from services.detector.frames import save_frame
    from services.inspection.captures import synthetic_captures

    sc = load_scenario(None)
    surf = synthetic_surface(sc)
    for c in synthetic_captures(sc, surf)[:4]:
        save_frame(tmp_path / "frames", c.meta, c.jpeg)
    confirmed = "Segmented with `it+`, each crack confirmed by `learned`"
    for method, said in (("learned", f"{confirmed} (the mission's detector ran `learned`)"),
                         ("it+", f"{confirmed}: "), (None, f"{confirmed}: ")):
        (tmp_path / "report.md").write_text("# Mission report\n\nOutcome: **success**.\n\n## Experimental setup\n")
        rec = MissionRecord(fleet="f", scenario=sc, speed=1.0, started=0.0, method=method,
                            surface_corners=[tuple(map(float, p)) for p in surf.corners])
        assert append_deliverable(rec, tmp_path)
        assert said in (tmp_path / "report.md").read_text()


def test_frames_without_a_range_over_the_scenarios_surface_make_a_deliverable(tmp_path):
    """A mission flown with an image-folder camera has no ground truth, so its record has no surface corners, and
    its frames no range (no rangefinder): the deliverable was "Not built: no frame has a range". The scenario's
    surface gives the plane, and where each optical axis meets it the frame's scale."""
    from edge.world.wall import synthetic_surface
    from protocol.scenario import load_scenario
    from services.detector.frames import save_frame
    from services.inspection.captures import synthetic_captures
    from services.inspection.mission import append_deliverable
    from services.inspection.mosaic import Plane, frame_gsd, plane_gsd
    from services.recording.record import MissionRecord

    sc = load_scenario(None)
    caps = synthetic_captures(sc, synthetic_surface(sc))[:4]
    plane = Plane.from_corners(sc.surface.corners)
    for c in caps:
        assert plane_gsd(c.meta, plane) == pytest.approx(frame_gsd(c.meta), rel=1e-6)
        save_frame(tmp_path / "frames", c.meta.model_copy(update={"range_m": None}), c.jpeg)
    (tmp_path / "report.md").write_text("# Mission report\n\nOutcome: **success**.\n\n## Experimental setup\n")
    assert append_deliverable(MissionRecord(fleet="f", scenario=sc, speed=1.0, started=0.0), tmp_path)
    md = (tmp_path / "report.md").read_text()
    assert "Not built" not in md and "found on the inspected surface" in md
