"""``skynet plan``: plan offline, compare the algorithms (Table I), benchmark.

Design notes: docs/planner.md (services/planner/cli.py).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from protocol.cliconfig import show_defaults

__all__ = ["main"]


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", default=None, help="scenario TOML (default: the monorail bridge)")


def build_parser() -> argparse.ArgumentParser:
    """``skynet plan mission|compare|bench``, one subparser each."""
    from .mission import ALGORITHMS

    parser = argparse.ArgumentParser(prog="skynet plan", description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True, metavar="mission|compare|bench")
    ap = commands.add_parser("mission", help="plan a formation inspection mission and export it")
    _common(ap)
    ap.add_argument("--algorithm", default="theta-pso", choices=sorted(ALGORITHMS))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--particles", type=int, default=None)
    ap.add_argument("--iterations", type=int, default=None)
    ap.add_argument("--waypoints", type=int, default=None)
    ap.add_argument("--out", default="out/plan", help="directory for the mission files")
    ap = commands.add_parser("compare", help="Table I: GA, TLBO, PSO, θ-PSO")
    _common(ap)
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--particles", type=int, default=150)
    ap.add_argument("--iterations", type=int, default=300)
    ap.add_argument("--waypoints", type=int, default=10)
    ap.add_argument("--out", default="out/compare")
    ap = commands.add_parser("bench", help="planner benchmark (paper's setting)")
    _common(ap)
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--out", default="bench/results/plan.json")
    return show_defaults(parser)


def _plan(a: argparse.Namespace) -> int:
    from .export import write_mission
    from .mission import plan_mission
    from .scenario import load_scenario

    sc = load_scenario(a.scenario)
    plan = plan_mission(sc, a.algorithm, a.seed, a.particles, a.iterations, a.waypoints)
    files = write_mission(plan, a.out, sc.surface.corners if sc.surface is not None else None)
    dur = max(tr.waypoints[-1].t for tr in plan.trajectories)
    print(f"scenario {sc.name}: {plan.algorithm} seed {plan.seed}, cost {plan.cost:.2f}, "
          f"{'collision-free' if plan.collision_free else 'COLLISION'}, planned in {plan.planning_time_s:.2f} s")
    print(f"  {len(plan.trajectories)} UAVs, {len(plan.captures)} captures, stand-off {plan.standoff_m:.2f} m, "
          f"flight {dur:.1f} s")
    for f in files:
        print(f"  wrote {f}")
    return 0 if plan.collision_free else 1


def _compare(a: argparse.Namespace) -> int:
    from .compare import compare, convergence_plot, format_table
    from .scenario import load_scenario

    res = compare(load_scenario(a.scenario), a.seeds, a.particles, a.iterations, a.waypoints)
    print(format_table(res))
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "compare.json").write_text(json.dumps(res, indent=1))
    print(f"wrote {convergence_plot(res, out / 'convergence.png')} and {out / 'compare.json'}")
    return 0


def _bench(a: argparse.Namespace) -> int:
    from .compare import bench, format_table
    from .scenario import load_scenario

    res = bench(load_scenario(a.scenario), seeds=a.seeds, out=a.out)
    print(format_table(res["compare"]))
    print(f"theta-pso {res['theta_pso_s']:.3f} s per plan (150 particles, 10 waypoints, 300 iterations)")
    if res.get("pyswarms_s") is not None:
        print(f"pyswarms GlobalBestPSO {res['pyswarms_s']:.3f} s, ratio {res['pyswarms_over_theta_pso']:.2f}x")
    print(f"wrote {a.out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    a = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    try:
        return {"mission": _plan, "compare": _compare, "bench": _bench}[a.command](a)
    except ValueError as exc:
        print(f"skynet plan: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
