"""The fleet view's documents (services.web.view): what the page is told, bounded."""

from __future__ import annotations

import math

from protocol.messages import Defect, DefectReport, Event, Mode, VehicleState
from protocol.scenario import load_scenario
from services.web import view as view_mod
from services.web.view import FleetView
from tests.conftest import wait_until


def state(uav: int, seq: int, pos, ref=None, mode=Mode.MISSION) -> VehicleState:
    return VehicleState(uav=uav, seq=seq, t=seq * 0.05, stamp=1000.0 + seq * 0.05, pos=pos, vel=(0, 0, 0),
                        att=(0, 0, 0), rates=(0, 0, 0), mode=mode, battery=0.8, ref=ref, tau=1.0 if ref else None)


class Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


def test_snapshot_positions_health_age_and_formation_error() -> None:
    clock = Clock()
    v = FleetView(load_scenario(), fleet="f", clock=clock)
    for k in range(40):  # 2 s of 20 Hz telemetry from UAV 1, 1 m from its slot
        clock.t = 1000.0 + k * 0.05
        v.on_state(state(1, k, (10.0 + k * 0.1, 5.0, 20.0), ref=(10.0 + k * 0.1, 6.0, 20.0)))
    v.on_state(state(2, 0, (0.0, 0.0, 0.0), ref=(0.0, 0.0, 3.0)), rx=clock.t - 2.0)  # heard once, long ago
    clock.t += 0.5
    s = v.snapshot()
    u1, u2 = s["uavs"]["1"], s["uavs"]["2"]
    assert u1["pos"] == [13.9, 5.0, 20.0] and u1["mode"] == "mission" and u1["battery"] == 0.8
    assert u1["age_s"] == 0.5 and u2["age_s"] == 2.5
    assert 14 <= u1["rate_hz"] <= 16 and u2["rate_hz"] == 0.0  # 30 of the 40 states inside the last 2 s
    assert u1["health"] == round(u1["rate_hz"] / 20, 2)
    assert s["formation_error_m"] == round(math.sqrt((1 + 9) / 2), 3)
    # the flown path is decimated (one point per 0.5 m): 3.9 m flown -> 8 points, not 40
    assert 7 <= len(u1["trail"]) <= 9


def test_static_scenario_defects_events_and_bounds(monkeypatch) -> None:
    v = FleetView(load_scenario(), fleet="f")
    st = v.static()
    assert st["box"]["hi"] == [101.0, 141.0, 40.0] and len(st["obstacles"]) == 10 and len(st["wall"]) == 4
    d = Defect(area_px=10, bbox=(1, 2, 3, 4), centroid_px=(2.0, 3.0), contrast=5.0, pos=(60.0, 50.0, 28.0))
    v.on_defects(DefectReport(uav=2, capture_id=3, stamp_capture=1.0, stamp_report=2.0, method="it+",
                              defects=[d, d.model_copy(update={"pos": None})]))
    for k in range(view_mod.EVENTS + 20):
        v.on_event(Event(source="gcs", stamp=float(k), kind="phase", text=f"p{k}"))
    s = v.snapshot()
    assert s["detections"] == 1 and s["reports"] == 1 and s["defects"][0]["pos"] == [60.0, 50.0, 28.0]
    assert s["defect_count"] is None  # the deduplicated count is the report's (set_inspection), not the detections
    assert len(s["events"]) == view_mod.SENT_EVENTS and s["events"][-1]["text"] == f"p{view_mod.EVENTS + 19}"
    assert len(v._events) == view_mod.EVENTS  # bounded
    v.on_preview(3, b"\xff\xd8jpeg")
    assert v.snapshot()["uavs"]["3"]["preview"] == 1 and v.preview(3) == b"\xff\xd8jpeg" and v.preview(9) is None


def test_timeline_has_phases_captures_defect_reports_and_warnings() -> None:
    clock = Clock()
    v = FleetView(load_scenario(), fleet="f", clock=clock)
    v.note(999.0, "gcs", "phase", "mission")
    v.on_state(state(1, 0, (1.0, 2.0, 3.0)))
    v.on_state(state(1, 1, (1.0, 2.0, 3.0)).model_copy(update={"captures": 1}))
    v.on_state(state(1, 2, (1.0, 2.0, 3.0)).model_copy(update={"captures": 3}))  # two captures between states
    v.on_state(state(1, 3, (1.0, 2.0, 3.0)).model_copy(update={"captures": 3}))  # none new
    v.on_state(state(1, 4, (1.0, 2.0, 3.0), mode=Mode.LAND).model_copy(update={"captures": 3}))
    d = Defect(area_px=10, bbox=(1, 2, 3, 4), centroid_px=(2.0, 3.0), contrast=5.0, pos=(60.0, 50.0, 28.0))
    v.on_defects(DefectReport(uav=1, capture_id=2, stamp_capture=1001.0, stamp_report=1001.5, method="it+",
                              defects=[d, d]))
    v.on_defects(DefectReport(uav=1, capture_id=3, stamp_capture=1002.0, stamp_report=1002.5, method="it+",
                              defects=[]))  # nothing found: nothing to say
    v.on_defects(DefectReport(uav=1, capture_id=4, stamp_capture=1003.0, stamp_report=1003.5, method="it+",
                              defects=[], ok=False))
    v.on_event(Event(source="uav/2", stamp=1004.0, kind="neighbour-lost", text="UAV 3 left", level="warning"))
    ev = [(e["kind"], e["text"], e["level"]) for e in v.snapshot()["events"]]
    assert ev == [("phase", "mission", "info"), ("capture", "capture 1", "info"), ("capture", "captures 2-3", "info"),
                  ("mode", "mission -> land", "info"), ("defect-report", "capture 2: 2 detection(s)", "info"),
                  ("defect-report", "capture 4: no result", "warning"),
                  ("neighbour-lost", "UAV 3 left", "warning")]
    assert v.snapshot()["detections"] == 2


def test_the_deduplicated_count_is_the_inspections() -> None:
    v = FleetView(load_scenario(), fleet="f")
    v.set_inspection(19, 60)
    s = v.snapshot()
    assert s["defect_count"] == 19 and s["inspection"] == {"defects": 19, "frames": 60}


def test_source_live_replay_or_both() -> None:
    clock = Clock()
    v = FleetView(load_scenario(), fleet="f", clock=clock)
    assert v.snapshot()["source"] is None  # nothing heard
    v.on_state(state(1, 0, (0.0, 0.0, 0.0)))
    assert v.snapshot()["source"] == "live"
    v.on_event(Event(source="uav/1", stamp=1.0, kind="k", text="t"), replayed=True)
    assert v.snapshot()["source"] == "live+replay"
    clock.t += view_mod.SOURCE_WINDOW_S + 1
    v.on_state(state(1, 1, (0.0, 0.0, 0.0)), replayed=True)
    assert v.snapshot()["source"] == "replay"
    clock.t += view_mod.SOURCE_WINDOW_S + 1
    assert v.snapshot()["source"] is None  # silent: neither
    # a fleet named as skynet replay names its fleet is a replay, marked or not
    r = FleetView(load_scenario(), fleet="demo" + view_mod.REPLAY_FLEET_SUFFIX, clock=clock)
    r.on_state(state(1, 0, (0.0, 0.0, 0.0)))
    assert r.snapshot()["source"] == "replay"


def test_follow_runner_puts_the_ground_stations_phases_failures_incidents_and_faults_on_the_timeline() -> None:
    import threading
    import types

    from services.recording.record import FaultRecord, Incident, MissionRecord
    from services.web.service import follow_runner

    rec = MissionRecord(fleet="f", speed=1.0, started=1000.0)
    runner = types.SimpleNamespace(record=rec)
    v = FleetView(load_scenario(), fleet="f")
    stop = threading.Event()
    rec.phases.update(discovery=1000.0, planning=1001.0)
    t = follow_runner(v, runner, stop)
    try:
        assert wait_until(lambda: len(v.snapshot()["events"]) == 2, 10)
        rec.incidents.append(Incident(at=1002.0, kind="uav-lost", uav=2, text="UAV 2 unheard for 3.0 s"))
        rec.faults.append(FaultRecord(at=1003.0, action="kill", target="uav2"))
        rec.failures.append("UAV 2 did not land")
        rec.phases["done"] = 1004.0
        t.join(10)
        assert not t.is_alive()  # "done": nothing more to follow
    finally:
        stop.set()
    ev = [(e["source"], e["kind"], e["text"], e["level"]) for e in v.snapshot()["events"]]
    assert ev[:5] == [("gcs", "phase", "discovery", "info"), ("gcs", "phase", "planning", "info"),
                      ("uav/2", "uav-lost", "UAV 2 unheard for 3.0 s", "warning"), ("faults", "kill", "uav2", "warning"),
                      ("gcs", "phase", "done", "info")]
    assert ev[5] == ("gcs", "failure", "UAV 2 did not land", "warning")  # the time it was seen (now)
