"""The planner's library entry point: scenario -> mission plan (the paper's Sections 2-4).

Design notes: docs/planner.md (services/planner/mission.py).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from protocol.messages import Box, MissionPlan

from .cost import Cost, PathProblem, path_collision_free
from .ga import ga
from .limits import Deadline, TimeBudgetExceeded, check_budget
from .optimiser import OptResult
from .pso import pso
from .scenario import Scenario, validate_scenario
from .theta_pso import theta_pso
from .tlbo import tlbo
from .trajectory import FormationTrajectories, build_trajectories

__all__ = ["ALGORITHMS", "optimise", "plan_mission", "plan_details"]

#: algorithm name -> optimiser(cost, x0, iterations, rng) -> OptResult
ALGORITHMS: dict[str, Callable[..., OptResult]] = {"theta-pso": theta_pso, "pso": pso, "ga": ga, "tlbo": tlbo}


def _int(name: str, value: Any, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not lo <= value <= hi:
        raise ValueError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}")
    return int(value)


def optimise(scenario: Scenario, algorithm: str = "theta-pso", seed: int = 0, particles: int | None = None,
             iterations: int | None = None, waypoints: int | None = None, init: str | None = None,
             time_budget_s: float | None = None, anytime: bool = False) -> tuple[PathProblem, OptResult]:
    """Optimise the centroid path only; returns the problem and the optimiser's result.

    All algorithms start from the same initial population for the same seed
    (:meth:`PathProblem.initial_population`) and get the same budget of evaluations. With
    ``anytime``, a run that outlives ``time_budget_s`` returns the best path it had evaluated
    (fewer iterations than asked: ``history`` says how many) instead of raising
    :class:`~services.planner.limits.TimeBudgetExceeded`.
    """
    if algorithm not in ALGORITHMS:
        raise ValueError(f"unknown algorithm {algorithm!r}; choose one of {sorted(ALGORITHMS)}")
    sp = scenario.planner
    P = _int("particles", sp.particles if particles is None else particles, 2, 10000)
    I = _int("iterations", sp.iterations if iterations is None else iterations, 1, 100000)
    n = _int("waypoints", sp.waypoints if waypoints is None else waypoints, 1, 200)
    s = _int("seed", seed, 0, 2**63 - 1)
    # before any work: a request over the limits is refused at once (services.planner.limits)
    check_budget(scenario.offsets.shape[0], scenario.cylinders().shape[0], P, I, n)
    problem = PathProblem.from_scenario(scenario, n)
    x0 = problem.initial_population(P, np.random.default_rng([s, 0]), init or sp.init, sp.corridor_width)
    cost = Cost(problem) if time_budget_s is None else Deadline(Cost(problem), time_budget_s)
    t0 = time.perf_counter()
    try:
        result = ALGORITHMS[algorithm](cost, x0, I, np.random.default_rng([s, 1]))
    except TimeBudgetExceeded:
        if not anytime or not isinstance(cost, Deadline) or cost.best_x is None:
            raise
        result = OptResult(algorithm=algorithm, x=cost.best_x, cost=cost.best_cost, history=np.asarray(cost.history),
                           evaluations=cost.evaluations, wall_time_s=time.perf_counter() - t0)
    return problem, result


def plan_details(scenario: Scenario | dict[str, Any], algorithm: str = "theta-pso", seed: int = 0,
                 particles: int | None = None, iterations: int | None = None, waypoints: int | None = None,
                 request_id: int = 0, time_budget_s: float | None = None,
                 anytime: bool = False) -> tuple[MissionPlan, FormationTrajectories, OptResult]:
    """:func:`plan_mission` plus the dense trajectories and the optimiser's result.

    With ``anytime`` (:func:`optimise`), the best path found when the time budget ran out is
    planned only if it is collision free; otherwise the budget's exception is raised as without it.
    """
    t0 = time.perf_counter()
    sc = validate_scenario(scenario)
    problem, res = optimise(sc, algorithm, seed, particles, iterations, waypoints, time_budget_s=time_budget_s,
                            anytime=anytime)
    V = problem.assemble(res.x[None])[0]
    ft = build_trajectories(sc, V, problem.inspection)
    free = ft.min_clearance >= 0 and path_collision_free(V, sc)
    asked = _int("iterations", sc.planner.iterations if iterations is None else iterations, 1, 100000)
    if anytime and len(res.history) < asked + 1 and not free:
        raise TimeBudgetExceeded(f"the plan's time budget of {time_budget_s:g} s ran out after {res.evaluations:,} "
                                 "evaluations, and the best path so far is not collision free")
    plan = MissionPlan(request_id=request_id, algorithm=algorithm, seed=seed, cost=res.cost, collision_free=bool(free),
                       centroid_path=[tuple(p) for p in V.tolist()], trajectories=ft.trajectories, captures=ft.captures,
                       convergence=res.history.tolist(), planning_time_s=time.perf_counter() - t0,
                       geofence=Box(lo=sc.box.lo, hi=sc.box.hi), origin=(sc.origin.lat, sc.origin.lon, sc.origin.alt),
                       standoff_m=problem.inspection.standoff if problem.inspection is not None else 0.0)
    return plan, ft, res


def plan_mission(scenario: Scenario | dict[str, Any], algorithm: str = "theta-pso", seed: int = 0,
                 particles: int | None = None, iterations: int | None = None, waypoints: int | None = None,
                 time_budget_s: float | None = None, anytime: bool = False) -> MissionPlan:
    """Plan a formation inspection mission from a scenario (or its document) with ``algorithm``
    ("theta-pso", "pso", "ga", "tlbo"), the same ``seed`` giving the same plan; the budget defaults to the
    scenario's ``[planner]`` section (the paper's 150 / 300 / 10). ``collision_free`` is an exact dense check
    of every UAV's trajectory. ValueError for a malformed scenario (naming the field), an unknown algorithm,
    a bad budget, or a surface the formation cannot image in one pass."""
    return plan_details(scenario, algorithm, seed, particles, iterations, waypoints,
                        time_budget_s=time_budget_s, anytime=anytime)[0]
