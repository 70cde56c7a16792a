"""edge.failsafe: escalation after a hold, battery failsafe, resume only after a fresh heartbeat."""

import pytest

from edge.failsafe import FailsafeOptions, FailsafePolicy


def test_hold_then_escalate_to_rtl_after_the_configured_time():
    p = FailsafePolicy(FailsafeOptions(timeout_s=5, escalate_after_s=20, escalate_action="rtl"))
    assert p.step(4.0, last_heartbeat=0.0, flying=True, battery=1.0) is None
    d = p.step(5.5, 0.0, True, 1.0)
    assert d.action == "hold" and d.kind == "failsafe"
    assert p.step(20.0, 0.0, True, 1.0) is None  # holding
    d = p.step(25.5, 0.0, True, 1.0)
    assert d.action == "rtl" and d.kind == "failsafe-escalated"
    assert p.step(100.0, 0.0, True, 1.0) is None  # once


def test_escalation_can_land_or_be_off():
    p = FailsafePolicy(FailsafeOptions(escalate_after_s=0, escalate_action="land"))
    assert p.step(6, 0, True, 1.0).action == "hold"
    assert p.step(6.1, 0, True, 1.0).action == "land"
    p = FailsafePolicy(FailsafeOptions(escalate_action="none"))
    p.step(6, 0, True, 1.0)
    assert p.step(1e6, 0, True, 1.0) is None


def test_resume_needs_a_heartbeat_newer_than_the_failsafe():
    """After a gateway freeze the Resume overtook the first heartbeat and the UAV failed safe again at once."""
    p = FailsafePolicy()
    p.step(6.0, 0.0, True, 1.0)
    assert "no fresh" in p.may_resume(7.0, last_heartbeat=0.0)
    assert p.may_resume(7.0, last_heartbeat=6.8) is None
    assert p.resumed() == 6.0 and not p.active
    assert p.step(7.1, 6.8, True, 1.0) is None  # no second failsafe


def test_low_battery_returns_critical_lands_and_resume_is_refused():
    p = FailsafePolicy(FailsafeOptions(battery_low=0.2, battery_critical=0.1))
    assert p.step(0, 0, True, 0.5) is None
    d = p.step(1, 1, True, 0.19)
    assert (d.action, d.reason) == ("rtl", "battery")
    assert p.step(2, 2, True, 0.18) is None
    assert p.step(3, 3, True, 0.09).action == "land"
    assert "battery" in p.may_resume(4, 4)
    # a GCS failsafe while landing never steps back to hold
    assert p.step(100, 3, True, 0.09) is None


def test_not_flying_or_never_heard_is_no_failsafe_and_bad_options_refused():
    p = FailsafePolicy()
    assert p.step(100, 0, False, 1.0) is None and p.step(100, None, True, 1.0) is None
    for bad in [dict(action="dance"), dict(escalate_action="hold"), dict(timeout_s=0),
                dict(battery_low=0.1, battery_critical=0.2)]:
        with pytest.raises(ValueError):
            FailsafeOptions(**bad)


def test_a_uav_returning_home_is_not_stopped_by_a_lost_ground_station_but_lands_on_a_critical_battery():
    p = FailsafePolicy()
    assert p.step(100, 0, flying=False, battery=0.5, returning=True) is None  # RTL commanded: no hold
    assert p.step(101, 0, False, 0.15, returning=True) is None  # low battery: it is already returning
    assert p.step(102, 0, False, 0.05, returning=True).action == "land"


def test_a_failed_action_is_retried_after_the_retry_period_and_rtl_falls_back_to_land():
    p = FailsafePolicy(FailsafeOptions(retry_s=2.0))
    d = p.step(0.0, 0.0, True, 0.15)  # low battery: rtl
    assert d.action == "rtl"
    f = p.failed("rtl", "denied", 0.0)
    assert (f.next_action, f.attempts, f.retry_at) == ("land", 1, 2.0) and "trying land instead" in f.text
    assert p.retry(1.9, airborne=True) is None
    d = p.retry(2.0, airborne=True)
    assert (d.action, d.kind, d.reason) == ("land", "failsafe-retry", "retry")
    assert p.retry(10.0, airborne=True) is None  # handed out once
    f = p.failed("land", "no ack", 2.0)
    assert (f.next_action, f.attempts) == ("land", 2)
    assert p.step(3.0, 0.0, True, 0.15) is None  # the retry is not superseded by a milder order
    assert p.retry(4.0, airborne=True).action == "land"
    assert p.done() == 2 and p.failures == 0 and p.pending is None


def test_a_pending_retry_ends_on_the_ground_or_with_a_resume():
    p = FailsafePolicy()
    p.step(6.0, 0.0, True, 1.0)
    p.failed("hold", "link lost", 6.0)
    assert p.retry(100.0, airborne=False) is None and p.pending is None
    p.failed("hold", "link lost", 6.0)
    p.resumed()
    assert p.pending is None and p.retry(100.0, airborne=True) is None
    with pytest.raises(ValueError):
        FailsafeOptions(retry_s=0)
