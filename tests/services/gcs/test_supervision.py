"""services.gcs.supervision: the supervision policy as a function of time and events, without processes.

Every wall time is given to the supervisor, so each case below is a timeline written out: what
the ground station observed and when, and what the supervisor decided.
"""

from __future__ import annotations

import pytest

import services.gcs.supervision
from protocol.messages import Mode, VehicleState
from services.gcs.supervision import FRESH_STATE_S, RESUME_PAUSE_FAILED_S, RESUME_PAUSE_OK_S, START_SETTLE_S, Supervisor
from services.recording.record import INCIDENT_KINDS, CommandRecord

UAVS = (1, 2, 3)


def state(uav: int, mode: Mode = Mode.MISSION, progress: float = 0.4, armed: bool = True) -> VehicleState:
    return VehicleState(uav=uav, seq=0, t=0.0, stamp=0.0, pos=(0, 0, 10), vel=(0, 0, 0), att=(0, 0, 0),
                        rates=(0, 0, 0), mode=mode, armed=armed, wp_index=3, progress=progress)


def kinds(incidents) -> list[tuple[str, int | None]]:
    return [(i.kind, i.uav) for i in incidents]


def heard(sup: Supervisor, now: float, **modes) -> None:
    """Every UAV heard at ``now`` (MISSION unless given, e.g. ``u2=Mode.HOLD``)."""
    for u in sup.uavs:
        sup.on_state(state(u, modes.get(f"u{u}", Mode.MISSION)), now)


def ack(ok: bool = True, accepted: bool = True) -> CommandRecord:
    return CommandRecord(uav=2, kind="resume", cmd_id=1, ok=ok, accepted=accepted, reason="" if ok else "timeout",
                         attempts=1 if ok else 4, elapsed_s=0.1)


def test_a_token_gone_longer_than_the_grace_is_a_lost_uav():
    sup = Supervisor(UAVS, now=0.0, lost_grace_s=3.0)
    assert kinds(sup.on_token(2, False, 10.0)) == [("token-gone", 2)]
    assert sup.on_token(2, False, 10.5) == []  # told twice: recorded once
    assert sup.on_token(9, False, 10.5) == []  # not a UAV of the mission
    assert kinds(sup.tick(12.9, 0.2, link_up=True, resume=False).incidents) == []
    d = sup.tick(13.1, 0.2, link_up=True, resume=False)
    assert kinds(d.incidents) == [("uav-lost", 2)] and sup.lost == {2: 10.0}
    assert "3.1 s" in d.incidents[0].text and d.incidents[0].at == 13.1
    assert sup.tick(20.0, 0.2, link_up=True, resume=False).incidents == []  # declared once
    # it comes back: noted and counted again
    assert kinds(sup.on_token(2, True, 30.0)) == [("token-back", 2), ("uav-back", 2)] and sup.lost == {}
    assert all(i.kind in INCIDENT_KINDS for i in sup.on_token(2, False, 31.0))


def test_nobody_is_lost_while_the_own_link_is_down_and_the_grace_counts_from_its_return():
    sup = Supervisor(UAVS, now=0.0, lost_grace_s=3.0)
    assert kinds(sup.tick(5.0, 0.2, link_up=False, resume=False).incidents) == [("link-down", None)]
    for u in UAVS:  # a gateway restart: every token goes at once
        sup.on_token(u, False, 5.1)
    assert sup.tick(20.0, 0.2, link_up=False, resume=False).incidents == []
    assert kinds(sup.tick(21.0, 0.2, link_up=True, resume=False).incidents) == [("link-up", None)]
    assert sup.tick(23.9, 0.2, link_up=True, resume=False).incidents == []  # 2.9 s after the link came back
    sup.on_token(1, True, 24.0)
    sup.on_token(2, True, 24.0)
    d = sup.tick(24.1, 0.2, link_up=True, resume=False)
    assert kinds(d.incidents) == [("uav-lost", 3)] and set(sup.lost) == {3}


def test_standing_still_adds_up_the_time():
    sup = Supervisor(UAVS, now=0.0)
    heard(sup, 0.0)
    assert not sup.tick(0.5, 0.5, link_up=True, resume=False).standing_still and sup.stalled_s == 0.0
    # UAV 3 unheard for longer than a fresh state
    for u in (1, 2):
        sup.on_state(state(u), 1.5)
    assert sup.tick(0.5 + FRESH_STATE_S + 0.1, 0.6, link_up=True, resume=False).standing_still
    assert sup.stalled_s == pytest.approx(0.6)
    # the own link down
    heard(sup, 2.0)
    assert sup.tick(2.2, 0.2, link_up=False, resume=False).standing_still
    assert sup.stalled_s == pytest.approx(0.8)
    heard(sup, 2.4)
    assert not sup.tick(2.4, 0.2, link_up=True, resume=False).standing_still
    # every UAV lost: nothing can progress
    lone = Supervisor((1,), now=0.0, lost_grace_s=1.0)
    lone.on_token(1, False, 1.0)
    assert lone.tick(2.5, 0.3, link_up=True, resume=False).standing_still and lone.stalled_s == pytest.approx(0.3)


def test_a_failsafe_hold_is_resumed_once_heard_again():
    sup = Supervisor(UAVS, now=0.0)
    sup.on_started(UAVS, 10.0)
    # holding right after the start (states from before it settled): not looked at
    heard(sup, 10.0 + START_SETTLE_S / 2, u2=Mode.HOLD)
    assert sup.tick(10.3, 0.2, link_up=True, resume=True).resume == []
    # outside the mission phase: not looked at either
    heard(sup, 20.0, u2=Mode.HOLD)
    assert sup.tick(20.1, 0.2, link_up=True, resume=False).resume == [] and sup.held == {}
    d = sup.tick(20.1, 0.2, link_up=True, resume=True)
    assert kinds(d.incidents) == [("hold-seen", 2)] and d.resume == [2] and "40%" in d.incidents[0].text
    assert sup.standing_still(20.2)  # a UAV holding mid-mission: the fleet stands still
    inc = sup.on_resumed(2, ack(), 20.5)
    assert inc.kind == "resume" and "0.4 s after its hold was seen" in inc.text
    # still holding just after: not resumed again before the pause
    heard(sup, 20.6, u2=Mode.HOLD)
    assert sup.tick(20.6, 0.2, link_up=True, resume=True).resume == []
    assert sup.tick(20.5 + RESUME_PAUSE_OK_S, 0.2, link_up=True, resume=True).resume == [2]  # no second hold-seen
    # flying again: the hold is over
    heard(sup, 21.8)
    assert sup.tick(21.8, 0.2, link_up=True, resume=True).resume == [] and sup.held == {}


def test_a_hold_is_not_resumed_while_unheard_or_the_link_is_down_and_a_failed_resume_waits_longer():
    sup = Supervisor(UAVS, now=0.0)
    sup.on_started(UAVS, 0.0)
    heard(sup, 5.0, u1=Mode.HOLD)
    d = sup.tick(5.0 + FRESH_STATE_S + 0.5, 0.2, link_up=True, resume=True)  # its state is stale
    assert kinds(d.incidents) == [("hold-seen", 1)] and d.resume == []
    heard(sup, 7.0, u1=Mode.HOLD)
    assert sup.tick(7.0, 0.2, link_up=False, resume=True).resume == []
    assert sup.tick(7.1, 0.2, link_up=True, resume=True).resume == [1]
    inc = sup.on_resumed(1, ack(ok=False), 8.0)
    assert inc.kind == "resume-failed" and "timeout (4 tries)" in inc.text
    heard(sup, 8.5, u1=Mode.HOLD)
    assert sup.tick(8.0 + RESUME_PAUSE_FAILED_S - 0.1, 0.2, link_up=True, resume=True).resume == []
    heard(sup, 10.0, u1=Mode.HOLD)
    assert sup.tick(10.0, 0.2, link_up=True, resume=True).resume == [1]
    # the end of the trajectory (progress 1), a landed UAV and a lost one are not failsafe holds
    for s in (state(1, Mode.HOLD, progress=1.0), state(1, Mode.HOLD, armed=False)):
        sup.on_state(s, 11.0)
        assert sup.tick(11.0, 0.2, link_up=True, resume=True).resume == []
    sup.on_state(state(3, Mode.HOLD), 11.0)
    sup.lost[3] = 9.0
    assert 3 not in sup.tick(11.0, 0.2, link_up=True, resume=True).resume


def test_the_fleet_is_done_when_every_counted_uav_finished_and_a_lost_one_had_its_wait():
    sup = Supervisor(UAVS, now=0.0, lost_grace_s=1.0, lost_wait_s=10.0)

    def done(u, s):
        return s is not None and s.progress >= 1.0

    for u in UAVS:
        sup.on_state(state(u, progress=1.0 if u < 3 else 0.5), 1.0)
    assert not sup.fleet_done(done, 2.0)
    sup.on_token(3, False, 3.0)
    sup.tick(4.5, 0.2, link_up=True, resume=False)  # lost
    assert not sup.fleet_done(done, 12.9)  # still waited for, in case it comes back
    assert sup.fleet_done(done, 13.1)
    everyone = Supervisor((1,), now=0.0, lost_grace_s=1.0, lost_wait_s=0.0)
    everyone.on_token(1, False, 0.0)
    everyone.tick(2.0, 0.2, link_up=True, resume=False)
    assert not everyone.fleet_done(lambda u, s: True, 100.0)  # every UAV lost: never done


def test_incident_times_are_told_on_the_mission_clock():
    sup = Supervisor(UAVS, now=0.0, lost_grace_s=1.0,
                     describe=lambda wall: services.gcs.supervision.mission_time(wall, {"mission": 100.0}, 90.0))
    sup.on_token(1, False, 112.0)
    (inc,) = sup.tick(113.5, 0.2, link_up=True, resume=False).incidents
    assert "since mission t=12.0 s" in inc.text
