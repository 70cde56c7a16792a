"""services.planner.limits: work checked before planning, a time budget while planning."""


import pytest

from services.planner.limits import MAX_CELLS, MAX_WORK, Deadline, TimeBudgetExceeded, TooLarge, check_budget, work_of
from services.planner.mission import plan_mission
from services.planner.scenario import load_scenario


def test_the_papers_budget_is_far_inside_the_limits_and_the_schemas_largest_is_not():
    cells, work = work_of(3, 10, 150, 300, 10)
    assert cells == 49_500 and work == 14_850_000
    assert 20 * work < MAX_WORK and 20 * cells < MAX_CELLS
    check_budget(3, 10, 150, 300, 10)
    with pytest.raises(TooLarge, match="units of work"):
        check_budget(3, 10, 10_000, 100_000, 10)
    with pytest.raises(TooLarge, match="elements"):
        check_budget(3, 10, 10_000, 1, 200)


def test_too_large_is_refused_before_any_work():
    sc = load_scenario()
    with pytest.raises(TooLarge):
        plan_mission(sc, particles=10_000, iterations=100_000, waypoints=200)


def test_deadline_ends_the_optimiser():
    sc = load_scenario()
    with pytest.raises(TimeBudgetExceeded, match="time budget of 0.2 s"):
        plan_mission(sc, particles=150, iterations=10_000, time_budget_s=0.2)
    with pytest.raises(ValueError):
        Deadline(lambda x: x, 0)


@pytest.mark.slow
def test_anytime_answers_with_the_best_collision_free_path_when_the_budget_runs_out():
    """a fleet's edges starve the planner; with ``anytime`` it plans the best path it had."""
    sc = load_scenario()
    plan = plan_mission(sc, particles=150, iterations=10_000, time_budget_s=5.0, anytime=True)
    assert 1 < len(plan.convergence) < 10_001  # stopped by the budget, not by the iterations
    assert plan.collision_free and len(plan.trajectories) == 3 and len(plan.captures) == 26
    assert plan.convergence[-1] == pytest.approx(plan.cost)
    try:  # within a few milliseconds: the first swarm only, collision free or refused as without anytime
        quick = plan_mission(sc, particles=150, iterations=10_000, time_budget_s=0.05, anytime=True)
    except TimeBudgetExceeded as exc:
        assert "not collision free" in str(exc) or "ran out" in str(exc)
    else:
        assert quick.collision_free
