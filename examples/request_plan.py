"""Request a plan from the planner and print each UAV's waypoint count and the plan's check against the scenario.

As the ground station does before a mission (services/gcs/mission.py): the request carries the
scenario and a fresh nonce; every answer must be signed by the planner's key of the key set and
bound to the request (protocol/planauth.py), and the plan must stay inside the operator's scenario
(services/gcs/preflight.py). Beside `skynet up`::

    python examples/request_plan.py                 # the default scenario, three UAVs
    python examples/request_plan.py --uavs 5 --seed 3

Exit status 0 for a plan that passes the check, 1 otherwise.
"""

from __future__ import annotations

import argparse
import sys

from protocol import keys, planauth
from protocol.cliconfig import add_options
from protocol.messages import MissionPlan, PlanRequest, Signed
from protocol.scenario import load_scenario
from protocol.textsafe import printable
from services.attach import AttachOptions, open_bus
from services.gcs.mission import with_formation_size
from services.gcs.preflight import scenario_problem

ROLE = "gcs"  # the identity that may query the planner


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_options(parser, AttachOptions)
    parser.add_argument("--scenario", default=None, metavar="FILE", help="(default: the paper's monorail bridge)")
    parser.add_argument("--uavs", type=int, default=3, help="UAVs 1..N in the formation (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=0, help="the planner's seed (default: %(default)s)")
    parser.add_argument("--timeout-s", dest="timeout", type=float, default=60.0, help="wait for the plan, s (default: %(default)s)")
    args = parser.parse_args(argv)
    try:
        scenario = with_formation_size(load_scenario(args.scenario), args.uavs)
        with open_bus(args, ROLE, sys.argv[1:] if argv is None else argv, name="request-plan") as bus:
            verifier = planauth.plan_verifier(planauth.planner_public_key(args.keys)) if args.keys else None
            req = PlanRequest(request_id=1, nonce=planauth.new_nonce(), scenario=scenario, seed=args.seed)
            where = keys.planner(args.fleet)
            replies = bus.request_all(where, req, expect=(MissionPlan, Signed), timeout=args.timeout, settle_s=1.0)
        choice = planauth.choose([r.message for r in replies if r.ok and r.message], req, where, verifier)
    except (ValueError, OSError) as exc:  # cannot attach, a bad scenario, two planners disagreeing: one line
        parser.exit(1, f"{parser.prog}: error: {exc}\n")
    except KeyboardInterrupt:
        return 1
    for why in choice.refused + [r.error for r in replies if not r.ok]:
        print(printable(why))
    plan = choice.plan
    if plan is None:
        print(f"no plan from {where}" + ("" if replies else " (nobody answered)"))
        return 1
    print(f"plan {printable(plan.algorithm)} seed {plan.seed}: cost {plan.cost:.2f}, {len(plan.captures)} capture "
          f"points, planned in {plan.planning_time_s:.1f} s, signature {'verified' if verifier else 'NOT checked (no key set)'}")
    for traj in plan.trajectories:
        print(f"uav {traj.uav}: {len(traj.waypoints)} waypoints")
    problem = scenario_problem(plan, scenario, range(1, args.uavs + 1))
    print(f"check against the scenario: {printable(problem) if problem else 'ok'}")
    return 1 if problem else 0


if __name__ == "__main__":
    sys.exit(main())
