"""The launcher's restart policy: back-off doubling to a cap, reset after a good run."""

import pytest

from services.orchestration.restart import Backoff, RestartTracker


def test_backoff_doubles_up_to_its_cap():
    b = Backoff(initial_s=0.5, factor=2.0, max_s=30.0)
    assert [b.delay(n) for n in range(1, 9)] == [0.5, 1, 2, 4, 8, 16, 30, 30]
    assert b.delay(10_000) == 30.0  # no overflow after a long crash loop
    with pytest.raises(ValueError):
        b.delay(0)
    with pytest.raises(ValueError):
        Backoff(initial_s=0)


def test_quick_failures_back_off_and_a_good_run_resets():
    t = RestartTracker(Backoff(initial_s=1.0, max_s=8.0, reset_after_s=10.0))
    p = t.exited("planner", now=100.0, ran_s=0.2, code=2)
    assert (p.due, p.failures) == (101.0, 1)
    assert t.exited("planner", now=100.5, ran_s=0.2, code=2) is p  # scheduled once while pending
    assert t.due(100.9) == [] and t.pending("planner")
    assert [x.name for x in t.due(101.0)] == ["planner"] and not t.pending("planner")
    assert t.exited("planner", 102.0, 0.5, 1).due == 104.0  # second quick failure: 2 s
    t.due(1e9)
    assert t.exited("planner", 110.0, 3.0, 1).due == 114.0  # third: 4 s
    t.due(1e9)
    p = t.exited("planner", 200.0, ran_s=60.0, code=-9)  # it ran a minute: back to the first delay
    assert (p.due, p.failures) == (201.0, 1)
    assert t.failures("detector") == 0
