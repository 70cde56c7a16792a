"""services.gcs.resilience: the report's "Faults and recovery" figures on a hand-made record.

The record (mission phase from wall time 1000): UAV 1 sends states at 10 Hz throughout; UAV 2
stops at t=5 (killed: token gone at 5.5, counted lost at 8.6, never back); the gateway is killed
at t=10 and restarted at t=13, UAV 1's states resume at t=13.5 (a 3.5 s blackout, 0.5 s after
the restart); UAV 1's failsafe fired at t=15 with its event lost, its failsafe-cleared event
says so, and the ground station resumed it at t=17; the Land for UAV 2 was recorded not sent.
"""

from __future__ import annotations

import pytest

from protocol.messages import Event, Level, Mode, VehicleState
from services.gcs.figures import summarise
from services.gcs.markdown import _faults_markdown
from services.gcs.report import write_report
from services.gcs.resilience import fault_figures, reception_gaps
from services.recording.record import CommandRecord, EventRx, FaultRecord, Incident, MissionRecord, StateRx

M = 1000.0  # wall time of the mission phase


def state(uav: int, t: float) -> StateRx:
    return StateRx(rx=M + t, msg=VehicleState(uav=uav, seq=int(t * 10), stamp=M + t, t=t, pos=(0, 0, 5),
                                              vel=(0, 0, 0), att=(0, 0, 0), rates=(0, 0, 0), mode=Mode.MISSION,
                                              armed=True))


def event(uav: int, t: float, kind: str, **data) -> EventRx:
    return EventRx(rx=M + t + 0.01, msg=Event(source=f"uav/{uav}", stamp=M + t, kind=kind, level=Level.INFO,
                                               data=data))


@pytest.fixture
def record() -> MissionRecord:
    ts1 = [round(0.1 * i, 1) for i in range(101)] + [round(13.5 + 0.1 * i, 1) for i in range(66)]
    states = [state(1, t) for t in ts1] + [state(2, round(0.1 * i, 1)) for i in range(51)]
    return MissionRecord(
        fleet="f", speed=8.0, started=M - 20, ended=M + 22, phases={"mission": M},
        states=states,
        events=[event(1, 5.6, "neighbour-lost", neighbour=2), event(1, 17.0, "failsafe-cleared", since=M + 15.0,
                                                                   held_s=2.0)],
        commands=[CommandRecord(uav=1, kind="start", cmd_id=1, ok=True, accepted=True, elapsed_s=0.01),
                  CommandRecord(uav=1, kind="resume", cmd_id=2, ok=True, accepted=True, elapsed_s=0.01),
                  CommandRecord(uav=2, kind="land", cmd_id=3, ok=False, accepted=False, attempts=0, elapsed_s=0.0,
                                reason="not sent: UAV 2 is lost")],
        faults=[FaultRecord(at=M + 5.0, action="kill", target="uav2", text="5s kill uav2"),
                FaultRecord(at=M + 10.0, action="kill", target="gateway", text="10s kill gateway for 3s"),
                FaultRecord(at=M + 13.0, action="restart", target="gateway", text="up")],
        incidents=[Incident(at=M + 5.5, kind="token-gone", uav=2), Incident(at=M + 8.6, kind="uav-lost", uav=2),
                   Incident(at=M + 10.1, kind="link-down"), Incident(at=M + 13.4, kind="link-up"),
                   Incident(at=M + 16.0, kind="hold-seen", uav=1), Incident(at=M + 17.0, kind="resume", uav=1)],
    )


def test_reception_gaps():
    assert reception_gaps([]) == (0.0, None, [])
    best, end, gaps = reception_gaps([0.0, 0.1, 2.1, 2.2, 2.5], 1.0)
    assert best == pytest.approx(2.0) and end == 2.1 and gaps == [(0.1, 2.1)]


def test_fault_figures_by_hand(record):
    f = fault_figures(record)
    assert f["origin"] == "mission phase start"
    assert [(x["t_s"], x["action"]) for x in f["faults"]] == [(5.0, "kill"), (10.0, "kill"), (13.0, "restart")]
    assert f["uavs_lost"] == [{"uav": 2, "gone_s": 5.5, "lost_s": 8.6, "back_s": None}]
    assert f["still_lost"] == [2]
    assert f["gcs_link"] == [{"down_s": 10.1, "up_s": 13.4}]
    (seen,) = f["seen_again"]
    # UAV 1 is heard again at 13.5: 0.5 s after the restart, 3.5 s after the kill; UAV 2 never
    assert seen["fleet_seen_s"] == pytest.approx(13.5) and seen["fleet_s"] == pytest.approx(0.5)
    assert seen["blackout_s"] == pytest.approx(3.5) and seen["never"] == [2]
    assert f["reception"][1]["max_gap_s"] == pytest.approx(3.5) and f["reception"][1]["max_gap_ended_s"] == 13.5
    assert f["reception"][1]["gaps"] == [[10.0, 13.5]] and f["reception"][2]["last_rx_s"] == 5.0
    # the failsafe's own event was lost: its time comes from the cleared event; resume 2 s after it
    assert f["failsafes"] == [{"uav": 1, "t_s": 15.0, "rx_s": None, "action": None, "silent_s": None}]
    (res,) = f["resumes"]
    assert res["uav"] == 1 and res["ok"] and res["after_failsafe_s"] == pytest.approx(2.0)
    assert f["skynet"] == [{"t_s": 5.6, "uav": 1, "kind": "neighbour-lost", "neighbour": 2}]
    assert f["commands"]["sent"] == 3 and f["commands"]["acknowledged"] == 2
    assert [c["cmd_id"] for c in f["commands"]["failed"]] == [3]


@pytest.mark.slow
def test_report_has_the_faults_section(record, tmp_path):
    s = write_report(record, tmp_path)
    assert s.faults["still_lost"] == [2]
    md = (tmp_path / "report.md").read_text()
    section = md[md.index("## Faults and recovery"):md.index("## Events")]
    for text in ("kill", "gateway", "fleet seen again at 13.50 s", "3.50 s of blackout", "never heard again: UAV 2",
                 "Lost at the end", "resume", "not sent: UAV 2 is lost", "neighbour-lost"):
        assert text in section, text


def test_a_quiet_run_says_so():
    rec = MissionRecord(fleet="f", speed=1.0, started=M)
    f = summarise(rec).faults
    assert f["faults"] == [] and f["uavs_lost"] == [] and f["commands"]["failed"] == []
    assert f["origin"] == "record start"


def test_supervisor_restarts_and_start_failures_are_listed_apart_from_injected_faults(record):
    from services.gcs.markdown import _faults_markdown

    noted = [FaultRecord(at=M + 2.0, action="supervisor-restart", target="video",
                         text="exited with code 2; restarted by the supervisor (run 2)"),
             FaultRecord(at=M + 4.0, action="start-failed", target="video", text="exited 3 times without coming up")]
    rec = record.model_copy(update={"faults": [*record.faults, *noted]})
    f = fault_figures(rec)
    assert [x["action"] for x in f["faults"]] == ["kill", "kill", "restart"]  # only what was injected
    assert [(x["action"], x["target"]) for x in f["supervision"]] == [("supervisor-restart", "video"),
                                                                       ("start-failed", "video")]
    assert [x["target"] for x in f["seen_again"]] == ["gateway"]  # no recovery line for the supervisor's restart
    md = "\n".join(_faults_markdown(f))
    injected, supervisor = md.split("The launcher's supervisor (not injected faults):")
    assert "video" not in injected and "did not start" in supervisor and "restarted" in supervisor
    # a run with nothing injected and only the supervisor's restart is not "quiet"
    only = MissionRecord(fleet="f", speed=8.0, started=M - 20, ended=M + 22, phases={"mission": M}, faults=noted)
    md = "\n".join(_faults_markdown(fault_figures(only)))
    assert "No fault injected." in md and "did not start" in md


def test_a_restart_the_fleet_was_heard_through_claims_no_blackout():
    """The planner killed at 5 s and restarted at 8 s while both UAVs were heard every 0.1 s: no blackout, and no
    "seen again" time taken from the restart (the report said "3.31 s of blackout" after a planner restart)."""
    rec = MissionRecord(fleet="f", speed=4.0, started=M - 5, ended=M + 20, phases={"mission": M},
                        states=[state(u, round(0.1 * i, 1)) for u in (1, 2) for i in range(150)],
                        faults=[FaultRecord(at=M + 5.0, action="kill", target="planner", text="5s kill planner for 3s"),
                                FaultRecord(at=M + 8.0, action="restart", target="planner", text="up")])
    (seen,) = fault_figures(rec)["seen_again"]
    assert seen["heard_throughout"] == [1, 2] and seen["never"] == [] and seen["uavs_s"] == {}
    assert seen["blackout_s"] == 0.0 and seen["fleet_seen_s"] is None
    md = "\n".join(_faults_markdown(fault_figures(rec)))
    assert "the fleet was heard throughout" in md and "of blackout" not in md
