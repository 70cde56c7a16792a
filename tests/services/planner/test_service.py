"""The planner service over the real bus: plan requests answered, bad ones refused with a reason."""

import time

import msgpack

from protocol import codec, keys
from protocol.bus import Bus, BusConfig
from protocol.messages import ErrorReply, MissionPlan, PlanRequest
from services.planner.scenario import load_scenario

FLEET = "test"


def test_planner_answers_plan_requests_over_the_bus(group, gateway):
    svc = group.start("planner", ["planner", "--fleet", FLEET, "--multilink",
                                  *[a for e in gateway for a in ("--connect", e)]])
    assert svc.wait_ready(30), "\n".join(svc.lines)
    scenario = load_scenario()
    doc = scenario.model_dump(mode="json")
    with Bus(BusConfig(mode="client", connect=gateway, multilink=True), FLEET, "gcs") as gcs:
        deadline = time.monotonic() + 10
        while not gcs.alive(keys.rcu_alive(FLEET, "planner")) and time.monotonic() < deadline:
            time.sleep(0.1)
        reply = gcs.request(keys.planner(FLEET), PlanRequest(request_id=7, scenario=scenario, seed=1),
                             expect=MissionPlan, timeout=60)
        assert reply.ok, reply.error
        plan = reply.message
        assert plan.request_id == 7 and plan.collision_free
        assert {t.uav for t in plan.trajectories} == {1, 2, 3}
        assert plan.centroid_path[0] == tuple(doc["start"]) and plan.centroid_path[-1] == tuple(doc["goal"])

        # a bad scenario cannot be built here (it is typed), so send the bytes an outside node could
        bad = dict(doc, box={"lo": [0, 0, 0], "hi": [10, 10, "high"]})
        raw = msgpack.packb([codec.SCHEMA_VERSION, PlanRequest.TYPE, {"scenario": bad}])
        replies = list(gcs.session.get(keys.planner(FLEET), payload=raw, timeout=30))
        assert len(replies) == 1 and replies[0].err is not None
        reason = codec.decode(replies[0].err.payload.to_bytes(), ErrorReply).reason
        assert "box" in reason

        unknown = gcs.request(keys.planner(FLEET), PlanRequest(scenario=scenario, algorithm="magic", iterations=5),
                              expect=MissionPlan, timeout=30)
        assert not unknown.ok and "magic" in unknown.error


def test_oversized_and_overlong_plan_requests_are_refused_and_free_the_worker(group, gateway):
    """the schema's largest request (10,000 particles x 100,000 iterations) would hold the planner for
    hours and 200 waypoints took gigabytes; both are now refused before any work ("too large"). A request within
    the limits that outlasts the time budget (here 1 s) is answered "timeout" and the next request is served."""
    svc = group.start("planner", ["planner", "--fleet", FLEET, "--multilink", "--time-budget-s", "1",
                                  *[a for e in gateway for a in ("--connect", e)]])
    assert svc.wait_ready(30), "\n".join(svc.lines)
    doc = load_scenario().model_dump(mode="json")
    with Bus(BusConfig(mode="client", connect=gateway, multilink=True), FLEET, "gcs") as gcs:
        deadline = time.monotonic() + 10
        while not gcs.alive(keys.rcu_alive(FLEET, "planner")) and time.monotonic() < deadline:
            time.sleep(0.1)
        huge = gcs.request(keys.planner(FLEET), PlanRequest(scenario=doc, particles=10000, iterations=100000),
                           expect=MissionPlan, timeout=30)
        assert not huge.ok and "too large" in huge.error and "limit" in huge.error, huge.error
        wide = gcs.request(keys.planner(FLEET), PlanRequest(scenario=doc, particles=10000, waypoints=200,
                                                              iterations=1), expect=MissionPlan, timeout=30)
        assert not wide.ok and "too large" in wide.error and "elements" in wide.error, wide.error
        long = gcs.request(keys.planner(FLEET), PlanRequest(scenario=doc, particles=150, iterations=5000),
                           expect=MissionPlan, timeout=60)
        assert not long.ok and "time budget of 1 s ran out" in long.error, long.error
        small = gcs.request(keys.planner(FLEET), PlanRequest(scenario=doc, particles=20, iterations=10),
                            expect=MissionPlan, timeout=60)
        assert small.ok, small.error
    assert svc.alive()
