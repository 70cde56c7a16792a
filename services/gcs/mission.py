"""The ground control station's mission: plan, upload, take off, fly, image, land — over the bus.

:class:`MissionRunner` is a Zenoh client of the gateway. It records everything into a
:class:`~services.gcs.record.MissionRecord` (the input of the report) and returns it with
``success`` set only when every UAV reached the goal and every capture point was imaged; any
step that cannot complete (a UAV that never appears, refuses its upload, a planner that does
not answer, a timeout) ends the mission with a failure that says why, never a hang.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass
from typing import Callable

from protocol import keys
from protocol.bus import Bus
from protocol.links import COMMAND, TELEMETRY
from protocol.messages import (
    CommandAck, DefectReport, Event, Heartbeat, Land, LinkStats, MissionPlan, Mode, PlanRequest, SetFormation, Start, Takeoff,
    UploadTrajectory, VehicleState,
)

from .record import GOAL_RADIUS_M, CommandRecord, DefectRx, EventRx, FaultRecord, MissionRecord, StateRx, StatsRx



def with_formation_size(scenario: dict, n: int, log=None) -> dict:
    """The scenario with one formation offset per UAV of the mission (P9).

    A scenario written for three UAVs flown with two or five gets the offsets of
    :func:`edge.formation.offsets_for`, so the planner plans a trajectory for every UAV present.
    """
    offsets = scenario.get("formation", {}).get("offsets")
    if offsets is not None and len(offsets) == n:
        return scenario
    from edge.formation import offsets_for

    new = [list(map(float, o)) for o in offsets_for(n)]
    if log:
        log.info("formation of %d UAVs: offsets %s", n, new)
    return {**scenario, "formation": {**scenario.get("formation", {}), "offsets": new}}


class MissionFailed(Exception):
    """A step of the mission could not complete; the message says which and why."""


@dataclass
class MissionOptions:
    uavs: tuple[int, ...] = (1, 2, 3)
    algorithm: str = "theta-pso"
    seed: int = 0
    speed: float = 1.0
    heartbeat_hz: float = 2.0
    appear_timeout_s: float = 30.0
    plan_timeout_s: float = 120.0
    command_timeout_s: float = 2.0
    command_attempts: int = 4
    takeoff_timeout_s: float = 60.0  # simulated seconds
    mission_margin: float = 1.5  # x planned duration, simulated
    land_timeout_s: float = 60.0  # simulated seconds
    report_wait_s: float = 5.0  # wall seconds to wait for the last defect reports
    particles: int | None = None
    iterations: int | None = None
    waypoints: int | None = None


class MissionRunner:
    def __init__(self, bus: Bus, scenario: dict, options: MissionOptions,
                 on_progress: Callable[["MissionRunner"], None] | None = None, log=None,
                 abort: threading.Event | None = None):
        self.bus, self.opt, self.log = bus, options, log
        self.abort = abort or threading.Event()
        scenario = with_formation_size(scenario, len(options.uavs), log)
        self.on_progress = on_progress
        self.record = MissionRecord(fleet=bus.fleet, scenario=scenario, speed=options.speed, started=time.time())
        self.latest: dict[int, VehicleState] = {}
        self.reports: dict[tuple[int, int], DefectReport] = {}
        self._lock = threading.Lock()
        self._cmd_id = 0
        self._hb_stop = threading.Event()
        fleet = bus.fleet
        bus.subscribe(keys.state(fleet, "*"), self._on_state, expect=VehicleState, link=TELEMETRY)
        bus.subscribe(keys.all_events(fleet), self._on_event, expect=Event, link=COMMAND)
        bus.subscribe(keys.defects(fleet), self._on_defects, expect=DefectReport, link=COMMAND)
        bus.subscribe(keys.gateway_stats(fleet), self._on_gw_stats, expect=LinkStats, link=TELEMETRY)
        bus.subscribe(keys.rcu_stats(fleet, "detector"), self._on_det_stats, expect=LinkStats, link=TELEMETRY)
        self._hb_pub = bus.publisher(keys.heartbeat(fleet), COMMAND)

    # -- recording (Zenoh callback threads: short)
    def _on_state(self, msg, sample) -> None:
        with self._lock:
            self.record.states.append(StateRx(rx=time.time(), msg=msg))
            self.latest[msg.uav] = msg

    def _on_event(self, msg, sample) -> None:
        with self._lock:
            self.record.events.append(EventRx(rx=time.time(), msg=msg))
        if self.log and msg.level != "info":
            self.log.warning("event from %s: %s %s", msg.source, msg.kind, msg.text)

    def _on_defects(self, msg, sample) -> None:
        with self._lock:
            self.record.defects.append(DefectRx(rx=time.time(), msg=msg))
            if msg.ok:
                self.reports[(msg.uav, msg.capture_id)] = msg

    def _on_gw_stats(self, msg, sample) -> None:
        with self._lock:
            self.record.gateway_stats.append(StatsRx(rx=time.time(), msg=msg))

    def _on_det_stats(self, msg, sample) -> None:
        with self._lock:
            self.record.detector_stats.append(StatsRx(rx=time.time(), msg=msg))

    def note_fault(self, action: str, target: str, text: str = "") -> None:
        """Record a fault injected into the run (kill, restart, cut, restore, partition, heal).

        Called by the launcher's fault injector from its own thread; thread-safe.
        """
        with self._lock:
            self.record.faults.append(FaultRecord(at=time.time(), action=action, target=target, text=text))
        if self.log:
            self.log.warning("fault: %s %s %s", action, target, text)

    # -- steps
    def phase(self, name: str) -> None:
        self.record.phases[name] = time.time()
        if self.log:
            self.log.info("phase: %s", name)

    def wait_for(self, pred: Callable[[], bool], timeout_s: float, what: str) -> None:
        deadline = time.monotonic() + timeout_s
        while not pred():
            if self.abort.is_set():
                raise MissionFailed(f"aborted by the operator while waiting for {what}")
            if time.monotonic() > deadline:
                raise MissionFailed(f"timed out after {timeout_s:.0f} s waiting for {what}")
            if self.on_progress:
                self.on_progress(self)
            time.sleep(0.1)

    def wait_alive(self) -> None:
        self.phase("discovery")
        want = {keys.alive(self.bus.fleet, u): u for u in self.opt.uavs}
        planner = keys.rcu_alive(self.bus.fleet, "planner")
        deadline = time.monotonic() + self.opt.appear_timeout_s
        while True:
            alive = set(self.bus.alive(keys.fleet_all(self.bus.fleet), timeout=1.0))
            missing = [u for k, u in want.items() if k not in alive]
            if not missing and planner in alive:
                return
            if self.abort.is_set():
                raise MissionFailed("aborted by the operator during discovery")
            if time.monotonic() > deadline:
                who = [f"UAV {u}" for u in missing] + ([] if planner in alive else ["the planner"])
                raise MissionFailed(f"{', '.join(who)} never appeared (no liveliness token within "
                                    f"{self.opt.appear_timeout_s:.0f} s)")
            time.sleep(0.2)

    def request_plan(self) -> MissionPlan:
        self.phase("planning")
        req = PlanRequest(request_id=1, scenario=self.record.scenario, algorithm=self.opt.algorithm,
                          seed=self.opt.seed, particles=self.opt.particles, iterations=self.opt.iterations,
                          waypoints=self.opt.waypoints)
        reply = self.bus.request(keys.planner(self.bus.fleet), req, expect=MissionPlan,
                                 timeout=self.opt.plan_timeout_s)
        self.record.plan_request_s = reply.elapsed_s
        if not reply.ok:
            raise MissionFailed(f"the planner did not deliver a plan: {reply.error}")
        plan = reply.message
        assert isinstance(plan, MissionPlan)
        missing = set(self.opt.uavs) - {t.uav for t in plan.trajectories}
        if missing:
            raise MissionFailed(f"the plan has no trajectory for UAV(s) {sorted(missing)}")
        self.record.plan = plan
        return plan

    def command(self, make: Callable[[int], object]) -> CommandRecord:
        """Send one command with retries and back-off; a refusal is final (not retried)."""
        self._cmd_id += 1
        cmd = make(self._cmd_id)
        t0 = time.monotonic()
        acks, reason = [], ""
        backoff = 0.25
        for attempt in range(1, self.opt.command_attempts + 1):
            reply = self.bus.request(keys.cmd(self.bus.fleet, cmd.uav), cmd, expect=CommandAck,
                                     timeout=self.opt.command_timeout_s)
            if reply.ok:
                acks.append(reply.elapsed_s)
                ack = reply.message
                rec = CommandRecord(uav=cmd.uav, kind=cmd.kind, cmd_id=cmd.cmd_id, ok=True, accepted=ack.accepted,
                                    reason=ack.reason, attempts=attempt, elapsed_s=time.monotonic() - t0, ack_s=acks)
                self.record.commands.append(rec)
                return rec
            reason = reply.error
            time.sleep(backoff)
            backoff *= 2
        rec = CommandRecord(uav=cmd.uav, kind=cmd.kind, cmd_id=cmd.cmd_id, ok=False, accepted=False, reason=reason,
                            attempts=self.opt.command_attempts, elapsed_s=time.monotonic() - t0, ack_s=acks)
        self.record.commands.append(rec)
        return rec

    def command_all(self, make: Callable[[int, int], object], what: str) -> None:
        for uav in self.opt.uavs:
            rec = self.command(lambda cid, u=uav: make(u, cid))
            if not rec.ok:
                raise MissionFailed(f"UAV {uav} did not acknowledge {what} after {rec.attempts} tries: {rec.reason}")
            if not rec.accepted:
                raise MissionFailed(f"UAV {uav} refused {what}: {rec.reason}")

    def heartbeat(self) -> None:
        period = 1.0 / self.opt.heartbeat_hz
        seq = 0
        while not self._hb_stop.wait(period):
            self._hb_pub.put(Heartbeat(source="gcs", seq=seq, stamp=time.time()))
            seq += 1
            self.record.heartbeats_sent = seq

    def sim_timeout(self, sim_s: float) -> float:
        return sim_s / self.opt.speed + 10.0

    def modes(self) -> dict[int, Mode]:
        with self._lock:
            return {u: s.mode for u, s in self.latest.items()}

    def run(self) -> MissionRecord:
        hb = threading.Thread(target=self.heartbeat, name="heartbeat", daemon=True)
        try:
            self.wait_alive()
            plan = self.request_plan()
            hb.start()
            self.phase("upload")
            traj = {t.uav: t for t in plan.trajectories}
            self.command_all(lambda u, cid: UploadTrajectory(uav=u, cmd_id=cid, trajectory=traj[u],
                                                             geofence=plan.geofence), "its trajectory upload")
            offsets = {u: tuple(map(float, o)) for u, o in zip(self.opt.uavs, self.record.scenario["formation"]["offsets"])}
            self.command_all(lambda u, cid: SetFormation(uav=u, cmd_id=cid, offsets=offsets), "the formation")
            self.phase("takeoff")
            self.command_all(lambda u, cid: Takeoff(uav=u, cmd_id=cid, altitude=self.takeoff_altitude(u)), "takeoff")
            self.wait_for(lambda: all(self.modes().get(u) == Mode.HOLD for u in self.opt.uavs),
                          self.sim_timeout(self.opt.takeoff_timeout_s), "every UAV to reach takeoff altitude")
            self.phase("mission")
            t0 = time.time() + 1.0
            self.command_all(lambda u, cid: Start(uav=u, cmd_id=cid, t0_stamp=t0), "start")
            duration = max(t.waypoints[-1].t for t in plan.trajectories)
            self.wait_for(lambda: self.mission_done(), self.sim_timeout(duration * self.opt.mission_margin + 60.0),
                          "every UAV to finish its trajectory")
            self.phase("reports")
            try:
                self.wait_for(lambda: not self.missing_captures(), self.opt.report_wait_s, "the last defect reports")
            except MissionFailed:
                pass  # judge() names the captures that were not imaged
        except MissionFailed as exc:
            self.record.failures.append(str(exc))
        finally:
            try:
                self.phase("landing")
                for uav in self.opt.uavs:
                    if uav in self.latest and self.latest[uav].armed:
                        self.command(lambda cid, u=uav: Land(uav=u, cmd_id=cid))
                self.wait_for(lambda: all(not s.armed for u, s in self.latest.items() if u in self.opt.uavs),
                              self.sim_timeout(self.opt.land_timeout_s), "every UAV to land")
            except MissionFailed as exc:
                self.record.failures.append(str(exc))
            self._hb_stop.set()
            if hb.is_alive():
                hb.join(2.0)
            self.record.ended = time.time()
            self.phase("done")
        self.judge()
        return self.record

    def takeoff_altitude(self, uav: int) -> float:
        plan = self.record.plan
        first = next(t for t in plan.trajectories if t.uav == uav).waypoints[0].pos
        home_z = self.latest[uav].pos[2] if uav in self.latest else 0.0
        return max(2.0, min(first[2] - home_z, plan.geofence.hi[2] - home_z - 1.0))

    def mission_done(self) -> bool:
        with self._lock:
            latest = {u: self.latest.get(u) for u in self.opt.uavs}
        return all(s is not None and s.progress >= 1.0 and s.mode != Mode.MISSION for s in latest.values())

    def planned_captures(self) -> set[tuple[int, int]]:
        plan = self.record.plan
        if plan is None:
            return set()
        return {(t.uav, w.capture_id) for t in plan.trajectories for w in t.waypoints if w.capture_id is not None}

    def missing_captures(self) -> set[tuple[int, int]]:
        with self._lock:
            return self.planned_captures() - set(self.reports)

    def judge(self) -> None:
        rec = self.record
        if rec.plan is not None and not rec.failures:
            for t in rec.plan.trajectories:
                goal = t.waypoints[-1].pos
                flown = [s.msg for s in rec.states if s.msg.uav == t.uav and s.msg.mode in (Mode.MISSION, Mode.HOLD)
                         and s.msg.progress >= 1.0]
                if not flown or math.dist(flown[-1].pos, goal) > GOAL_RADIUS_M:
                    rec.failures.append(f"UAV {t.uav} did not reach its goal {tuple(round(v, 1) for v in goal)}")
            missing = self.missing_captures()
            if missing:
                rec.failures.append(f"{len(missing)} of {len(self.planned_captures())} capture points were not imaged: "
                                    f"{sorted(missing)[:10]}")
        rec.success = not rec.failures
