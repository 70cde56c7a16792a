"""The mission runner's steps (services.gcs.mission.MissionRunner) on the in-memory bus (protocol.membus): edges
twinned by queryables that acknowledge commands and publish the state a command leads to. No processes, no
planner: the plan is set as the planner would have answered it. The whole mission over real processes:
tests/services/gcs/test_mission.py."""

from __future__ import annotations

import pytest

from protocol import keys
from protocol.links import TELEMETRY
from protocol.membus import MemBus, MemNetwork
from protocol.messages import (
    COMMAND_TYPES,
    Box,
    CommandAck,
    Heartbeat,
    Land,
    MissionPlan,
    Mode,
    SetFormation,
    Start,
    Takeoff,
    Trajectory,
    UploadTrajectory,
    VehicleState,
    Waypoint,
)
from protocol.scenario import load_scenario
from services.gcs.mission import MissionFailed, MissionOptions, MissionRunner

FLEET = "steps"
UAVS = (1, 2)
HOME = {1: (20.0, 20.0, 0.0), 2: (24.0, 20.0, 0.0)}


def trajectory(uav: int) -> Trajectory:
    x, y, _ = HOME[uav]
    return Trajectory(uav=uav, waypoints=[Waypoint(t=0.0, pos=(x, y, 10.0)), Waypoint(t=10.0, pos=(x + 20, y, 10.0))])


class EdgeTwin:
    """One UAV's board as the ground station sees it: a token, a command queryable, states."""

    def __init__(self, net: MemNetwork, uav: int, refuse: str | None = None, answer=None) -> None:
        self.uav, self.refuse, self.answer = uav, refuse, answer
        self.bus = MemBus(net, FLEET, f"uav{uav}")
        self.got: list[str] = []
        self.state = VehicleState(uav=uav, seq=0, t=0.0, stamp=1.0, pos=HOME[uav], vel=(0, 0, 0), att=(0, 0, 0),
                                  rates=(0, 0, 0), mode=Mode.IDLE)
        self.pub = self.bus.publisher(keys.state(FLEET, uav), TELEMETRY)
        self.bus.serve(keys.cmd(FLEET, uav), self.on_command, expect=COMMAND_TYPES)
        self.bus.token(keys.alive(FLEET, uav))
        self.publish()

    def publish(self, **update) -> None:
        import time

        self.state = self.state.model_copy(update={**update, "seq": self.state.seq + 1, "stamp": time.time()})
        self.pub.put(self.state)

    def on_command(self, cmd):
        self.got.append(cmd.kind)
        if self.answer is not None:
            return self.answer
        if cmd.kind == self.refuse:
            return CommandAck(uav=self.uav, cmd_id=cmd.cmd_id, accepted=False, reason=f"no {cmd.kind} today")
        if isinstance(cmd, Takeoff):
            self.publish(armed=True, mode=Mode.HOLD, pos=(*HOME[self.uav][:2], cmd.altitude))
        elif isinstance(cmd, Start):
            goal = trajectory(self.uav).waypoints[-1].pos
            self.publish(mode=Mode.HOLD, progress=1.0, wp_index=1, pos=goal, t=10.0)
        elif isinstance(cmd, Land):
            self.publish(mode=Mode.LANDED, armed=False)
        else:
            self.publish()  # its telemetry goes on
        return CommandAck(uav=self.uav, cmd_id=cmd.cmd_id, accepted=True)


@pytest.fixture
def net():
    return MemNetwork()


def runner_on(net: MemNetwork) -> MissionRunner:
    bus = MemBus(net, FLEET, "gcs")
    bus.token(keys.rcu_alive(FLEET, "planner"))  # the planner is there (its answer is set below)
    r = MissionRunner(bus, load_scenario(), MissionOptions(uavs=UAVS, speed=4.0, command_attempts=2,
                                                           command_timeout_s=0.2, appear_timeout_s=1.0,
                                                           ready_timeout_s=1.0))
    r.record.plan = MissionPlan(algorithm="test", seed=0, cost=1.0, collision_free=True,
                                centroid_path=[(22.0, 20.0, 10.0), (42.0, 20.0, 10.0)],
                                trajectories=[trajectory(u) for u in UAVS],
                                geofence=Box(lo=(0.0, 0.0, 0.0), hi=(100.0, 100.0, 40.0)), origin=(0.0, 0.0, 0.0))
    return r


def fly(r: MissionRunner) -> None:
    """The steps of MissionRunner.run after the plan: upload, formation, takeoff, start, complete, land."""
    traj = {t.uav: t for t in r.record.plan.trajectories}
    r.wait_alive()
    r.command_all(lambda u, c: UploadTrajectory(uav=u, cmd_id=c, trajectory=traj[u], geofence=r.fence()), "upload")
    r.command_all(lambda u, c: SetFormation(uav=u, cmd_id=c, offsets={1: (0, 0, 0), 2: (4, 0, 0)}), "the formation")
    r.wait_ready()
    r.command_all(lambda u, c: Takeoff(uav=u, cmd_id=c, altitude=r.takeoff_altitude(u)), "takeoff")
    r.wait_for(lambda: r.fleet_done(lambda u, s: s is not None and s.mode == Mode.HOLD), 1.0, "takeoff altitude")
    r.command_all(lambda u, c: Start(uav=u, cmd_id=c, t0_stamp=None), "start", parallel=True)
    r.wait_for(r.mission_done, 1.0, "the trajectories")
    r.wait_for(r._land_step, 1.0, "every UAV to land")


def test_takeoff_upload_and_completion_with_acknowledged_commands(net):
    edges = {u: EdgeTwin(net, u) for u in UAVS}
    r = runner_on(net)
    fly(r)
    r.judge()
    assert r.record.failures == []
    for e in edges.values():
        assert e.got == ["upload", "formation", "takeoff", "start", "land"]
    assert all(c.ok and c.accepted and c.attempts == 1 for c in r.record.commands)
    assert len(r.record.commands) == 5 * len(UAVS)
    assert {s.msg.mode for s in r.record.states} >= {Mode.IDLE, Mode.HOLD, Mode.LANDED}


def test_a_failure_found_at_the_end_fails_a_mission_that_flew_well(net):
    """A fault the run was asked for and never injected (the mission ended first) is found after the flight:
    the verdict is a failure, and the goal checks still ran (they come first)."""
    late = "never injected, the mission ended first: 40s cut uplinks for 2s"
    for u in UAVS:
        EdgeTwin(net, u)
    r = runner_on(net)
    fly(r)
    r.judge(late=[late])
    assert not r.record.success and r.record.failures == [late]  # it alone: the flight was good
    net2 = MemNetwork()
    short, _ = EdgeTwin(net2, 1), EdgeTwin(net2, 2)
    r = runner_on(net2)
    fly(r)
    short.publish(mode=Mode.HOLD, progress=1.0, pos=(0.0, 0.0, 10.0))  # it ended far from its goal
    r.judge(late=[late])
    assert not r.record.success and r.record.failures[-1] == late
    assert any("did not reach its goal" in f for f in r.record.failures), r.record.failures


def test_a_refused_takeoff_ends_the_mission_before_any_start(net):
    edges = {1: EdgeTwin(net, 1), 2: EdgeTwin(net, 2, refuse="takeoff")}
    r = runner_on(net)
    with pytest.raises(MissionFailed, match="UAV 2 refused takeoff: no takeoff today"):
        fly(r)
    assert "start" not in edges[1].got and edges[2].got == ["upload", "formation", "takeoff"]


def test_an_answer_that_is_not_an_acknowledgement_is_retried_then_fails(net):
    EdgeTwin(net, 1)
    EdgeTwin(net, 2, answer=Heartbeat(seq=1, stamp=1.0))  # a reply of the wrong type: not an ack
    r = runner_on(net)
    with pytest.raises(MissionFailed, match="UAV 2 did not acknowledge upload after 2 tries"):
        fly(r)
    rec = [c for c in r.record.commands if c.uav == 2]
    assert len(rec) == 1 and not rec[0].ok and rec[0].attempts == 2


def test_a_uav_that_never_appears_fails_discovery_naming_it(net):
    EdgeTwin(net, 1)
    r = runner_on(net)
    with pytest.raises(MissionFailed, match="UAV 2 never appeared"):
        r.wait_alive()
