"""Algorithm comparison reproducing Table I, the convergence plot, and the planner benchmark.

Design notes: docs/planner.md (services/planner/compare.py).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from .cost import Cost, PathProblem, path_collision_free
from .mission import ALGORITHMS
from .scenario import Scenario
from .theta_pso import theta_pso

__all__ = ["compare", "format_table", "convergence_plot", "cost_call_times", "bench"]


def compare(scenario: Scenario, seeds: int = 20, particles: int = 150, iterations: int = 300, waypoints: int = 10,
            algorithms: tuple[str, ...] = ("ga", "tlbo", "pso", "theta-pso"),
            init: str | None = None) -> dict[str, Any]:
    """Run every algorithm over ``seeds`` seeds; returns ``{"rows": {...}, "histories": {...}}``."""
    if int(seeds) != seeds or seeds < 1:
        raise ValueError(f"seeds must be a positive integer, got {seeds!r}")
    for a in algorithms:
        if a not in ALGORITHMS:
            raise ValueError(f"unknown algorithm {a!r}")
    problem = PathProblem.from_scenario(scenario, waypoints)
    sp = scenario.planner
    runs: dict[str, list[tuple[float, float, int, float, bool]]] = {a: [] for a in algorithms}
    hist: dict[str, list[np.ndarray]] = {a: [] for a in algorithms}
    for seed in range(int(seeds)):
        x0 = problem.initial_population(particles, np.random.default_rng([seed, 0]), init or sp.init, sp.corridor_width)
        for a in algorithms:
            res = ALGORITHMS[a](Cost(problem), x0, iterations, np.random.default_rng([seed, 1]))
            free = path_collision_free(problem.assemble(res.x[None])[0], scenario)
            runs[a].append((res.initial_cost, res.cost, res.convergence_iteration(), res.wall_time_s, free))
            hist[a].append(res.history)
    rows = {}
    for a, r in runs.items():
        arr = np.array([x[:4] for x in r], float)
        rows[a] = {"initial_cost": float(np.mean(arr[:, 0])), "final_mean": float(np.mean(arr[:, 1])),
                   "final_std": float(np.std(arr[:, 1])), "final_median": float(np.median(arr[:, 1])),
                   "final_best": float(np.min(arr[:, 1])), "convergence_iteration": float(np.mean(arr[:, 2])),
                   "wall_time_s": float(np.mean(arr[:, 3])), "collision_free": float(np.mean([x[4] for x in r]))}
    return {"scenario": scenario.name, "seeds": int(seeds), "particles": particles, "iterations": iterations,
            "waypoints": waypoints, "evaluations": particles * (iterations + 1), "rows": rows,
            "histories": {a: np.mean(h, axis=0).tolist() for a, h in hist.items()}}


def format_table(result: dict[str, Any]) -> str:
    """Table I as plain text."""
    head = (f"{'algorithm':<10} {'initial':>8} {'mean':>8} {'std':>6} {'median':>8} {'best':>8} "
            f"{'conv.it':>7} {'time s':>7} {'no-coll':>7}")
    lines = [head, "-" * len(head)]
    for a, r in result["rows"].items():
        lines.append(
            f"{a:<10} {r['initial_cost']:8.2f} {r['final_mean']:8.2f} {r['final_std']:6.2f} "
            f"{r['final_median']:8.2f} {r['final_best']:8.2f} {r['convergence_iteration']:7.1f} "
            f"{r['wall_time_s']:7.3f} {100 * r['collision_free']:6.0f}%"
        )
    return "\n".join(lines)


def convergence_plot(result: dict[str, Any], path: str | Path) -> Path:
    """PNG of the mean best cost against iteration for every algorithm (matplotlib, Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=120)
    for a, h in result["histories"].items():
        ax.plot(np.arange(len(h)), h, label=a)
    finals = [r["final_mean"] for r in result["rows"].values()]
    ax.set_ylim(min(finals) * 0.98, max(h[min(10, len(h) - 1)] for h in result["histories"].values()) * 1.05)
    ax.set_xlabel("iteration (particles evaluations)")
    ax.set_ylabel(f"mean best cost over {result['seeds']} seeds")
    ax.set_title("Convergence comparison")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(p)
    plt.close(fig)
    return p


def cost_call_times(problem: PathProblem, particles: int = 150, calls: int = 100) -> dict[str, float]:
    """Median time (ms) of one :class:`Cost` call on swarms in different places.

    ``corridor``: the shared initial population; ``box``: uniform over the box; ``clear``: every
    waypoint in the box's south-west corner, away from every obstacle and the wall. Equal times
    show that the cost's work does not depend on where the swarm is.
    """
    rng = np.random.default_rng(0)
    swarms = {"corridor": problem.initial_population(particles, rng),
              "box": problem.initial_population(particles, rng, "box"),
              "clear": np.tile(problem.lo + [5.0, 5.0, 20.0], (particles, problem.n_free))}
    cost = Cost(problem)
    for X in swarms.values():  # warm up (buffers, caches, clock)
        for _ in range(10):
            cost(X)
    ts: dict[str, list[float]] = {name: [] for name in swarms}
    for _ in range(calls):  # interleaved, so drifts in machine load hit every swarm alike
        for name, X in swarms.items():
            t = time.perf_counter()
            cost(X)
            ts[name].append(time.perf_counter() - t)
    return {name: 1e3 * float(np.median(t)) for name, t in ts.items()}


def bench(scenario: Scenario, seeds: int = 20, particles: int = 150, iterations: int = 300, waypoints: int = 10,
          repeats: int = 7, out: str | Path | None = None) -> dict[str, Any]:
    """θ-PSO timing against pyswarms' GlobalBestPSO (same cost and budget), plus :func:`compare`.

    Medians over ``repeats`` alternating pairs (docs/planner.md, services/planner/compare.py);
    ``pyswarms_over_theta_pso`` > 1: θ-PSO is faster. Writes JSON to ``out`` if given; without pyswarms (optional)
    the ratio is omitted.
    """
    problem = PathProblem.from_scenario(scenario, waypoints)
    x0 = problem.initial_population(particles, np.random.default_rng([0, 0]))
    budget = particles * (iterations + 1)

    def timed(run: Any) -> tuple[float, float, int]:
        cost = Cost(problem)
        t, c = time.perf_counter(), time.process_time()
        run(cost)
        return time.perf_counter() - t, time.process_time() - c, cost.evaluations

    try:
        import logging

        import pyswarms as ps

        logging.getLogger("pyswarms").setLevel(logging.ERROR)
        bounds = (np.tile(problem.lo, waypoints), np.tile(problem.hi, waypoints))
    except ImportError:
        ps = None
    theta: list[tuple[float, float, int]] = []
    swarm: list[tuple[float, float, int]] = []
    for r in range(repeats):
        theta.append(timed(lambda c: theta_pso(c, x0, iterations, np.random.default_rng([r, 1]))))
        if ps is not None:
            np.random.seed(r)
            opt = ps.single.GlobalBestPSO(particles, problem.dim, {"c1": 2.0, "c2": 2.0, "w": 0.65},
                                          bounds=bounds, init_pos=x0.copy())
            swarm.append(timed(lambda c: opt.optimize(c, iters=iterations + 1, verbose=False)))
    th = np.array(theta)
    out_doc: dict[str, Any] = {"budget_evaluations": budget, "repeats": repeats,
                               "theta_pso_s": float(np.median(th[:, 0])), "theta_pso_cpu_s": float(np.median(th[:, 1])),
                               "theta_pso_runs_s": th[:, 0].tolist(), "theta_pso_evaluations": int(th[0, 2]),
                               "pyswarms_s": None}
    if swarm:
        sw = np.array(swarm)
        out_doc.update({"pyswarms_s": float(np.median(sw[:, 0])), "pyswarms_cpu_s": float(np.median(sw[:, 1])),
                        "pyswarms_runs_s": sw[:, 0].tolist(), "pyswarms_evaluations": int(sw[0, 2]),
                        "pyswarms_over_theta_pso": float(np.median(sw[:, 0]) / np.median(th[:, 0])),
                        "pyswarms_over_theta_pso_cpu": float(np.median(sw[:, 1]) / np.median(th[:, 1]))})
    out_doc["cost_call_ms"] = cost_call_times(problem, particles)
    out_doc["compare"] = compare(scenario, seeds, particles, iterations, waypoints)
    if out is not None:
        p = Path(out)
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(json.dumps(out_doc, indent=1))
    return out_doc
