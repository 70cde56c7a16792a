"""The planner RCU service: answers plan requests on ``skynet/<fleet>/rcu/planner/plan``.

Design notes: docs/planner.md (services/planner/service.py).
"""

from __future__ import annotations

import argparse
import time

from protocol import keys, planauth
from protocol.bus import Bus, Rejected, config_from_args, setup_logging, stop_event_on_signals
from protocol.cliconfig import add_options, from_namespace
from protocol.messages import Message, MissionPlan, PlanRequest
from protocol.readiness import notify_ready

from .config import PlannerConfig
from .limits import TIME_BUDGET_S, TimeBudgetExceeded, TooLarge
from .mission import plan_mission


def answer(request: PlanRequest, time_budget_s: float | None = TIME_BUDGET_S, anytime: bool = False) -> MissionPlan:
    """The plan for one request; :class:`Rejected` (with the reason) when it cannot be planned, is over
    the limits (``too-large``, before any work) or runs out of its time budget (``timeout``).

    The scenario was validated when the request was decoded (it is typed on the wire): a bad one
    never reaches here, its reply names the field.
    """
    try:
        plan = plan_mission(request.scenario, algorithm=request.algorithm, seed=request.seed, particles=request.particles,
                            iterations=request.iterations, waypoints=request.waypoints, time_budget_s=time_budget_s,
                            anytime=anytime)
    except TooLarge as exc:
        raise Rejected(str(exc), code="too-large") from None
    except TimeBudgetExceeded as exc:
        raise Rejected(str(exc), code="timeout") from None
    except ValueError as exc:
        raise Rejected(f"cannot plan: {exc}", code="infeasible") from None
    return planauth.bind(plan, request)


def build_parser() -> argparse.ArgumentParser:
    """``skynet planner``'s command line: the options of :class:`PlannerConfig`."""
    return add_options(argparse.ArgumentParser(prog="skynet planner", description=__doc__.split("\n\n")[0]),
                       PlannerConfig)


def main(argv: list[str] | None = None) -> int:
    """``skynet planner``: parse the command line, then :func:`run` the service."""
    parser = build_parser()
    return run(from_namespace(PlannerConfig, parser.parse_args(argv), parser))


def run(args: PlannerConfig) -> int:
    """The planner RCU from its configuration, until SIGINT/SIGTERM."""
    log = setup_logging("planner")
    stop = stop_event_on_signals()
    signer = None
    if args.keys:  # the ground station takes only plans signed with this key
        from protocol.keyset import KeySet

        signer = KeySet(args.keys, "planner").signer()
    else:
        log.warning("INSECURE: plans go unsigned (no --keys)")
    with Bus(config_from_args(args, role="planner"), fleet=args.fleet, name="planner") as bus:
        where = keys.planner(args.fleet)

        def handle(req: PlanRequest) -> Message:
            t0 = time.perf_counter()
            try:
                plan = answer(req, args.time_budget, args.anytime)
            except Rejected as exc:
                log.warning("plan request %d refused: %s", req.request_id, exc.reason)
                raise
            log.info("plan %d: %s seed %d cost %.2f collision-free %s in %.2f s", req.request_id, plan.algorithm,
                     plan.seed, plan.cost, plan.collision_free, time.perf_counter() - t0)
            return plan if signer is None else signer.sign(plan, where)

        bus.serve(where, handle, expect=PlanRequest, ring=4)
        bus.token(keys.rcu_alive(args.fleet, "planner"))
        log.info("planner up")
        notify_ready("planner")
        stop.wait()
        log.info("shutting down")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
