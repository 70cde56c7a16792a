"""The ground control station's mission: plan, upload, take off, fly, image, land — over the bus.

Design notes: docs/ground-station.md (services/gcs/mission.py).
"""

from __future__ import annotations

import contextlib
import functools
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

from protocol import binding, keys, planauth
from protocol.budget import for_topic
from protocol.bus import Bus
from protocol.links import COMMAND, TELEMETRY
from protocol.messages import (
    Box,
    DefectReport,
    Event,
    EventKind,
    Heartbeat,
    Land,
    Level,
    LinkStats,
    MissionPlan,
    Mode,
    PlanRequest,
    Resume,
    SetFormation,
    Signed,
    Start,
    Takeoff,
    UploadTrajectory,
    VehicleState,
)
from protocol.scenario import FormationSpec, Scenario
from services.recording.record import (
    CommandRecord,
    DefectRx,
    EventRx,
    FaultRecord,
    Incident,
    LiveRecord,
    MissionRecord,
    StateRx,
    StatsRx,
    capture_name,
)
from services.recording.witness import FrameWitness

from .commands import CommandIds, RetryPolicy, not_sent, send, start_margin
from .evidence import corroboration_failures, has_evidence, held_captures, ledger, no_surface_reasons
from .supervision import SUPERVISE_PERIOD_S, Supervisor, mission_time
from .verdict import GOAL_SETTLE_S, goal_check, not_imaged_text, planned_captures, short_of_goal


def with_formation_size(scenario: Scenario, n: int, log=None) -> Scenario:
    """The scenario with one formation offset per UAV of the mission (P9).

    A scenario written for three UAVs flown with two or five gets the offsets of
    :func:`edge.geometry.formation.offsets_for`, so the planner plans a trajectory for every UAV present.
    """
    if len(scenario.formation.offsets) == n:
        return scenario
    from edge.geometry.formation import offsets_for

    new = [tuple(map(float, o)) for o in offsets_for(n)]
    if log:
        log.info("formation of %d UAVs: offsets %s", n, new)
    formation = FormationSpec(offsets=new, min_separation=scenario.formation.min_separation)
    return scenario.model_copy(update={"formation": formation})


#: failed defect reports logged while flying, one per capture, at most (the record keeps every one)
MAX_FAILED_TOLD = 50


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
    plan_settle_s: float = 10.0  # wall s other answers to the plan request are waited for after the first
    command_timeout_s: float = 2.0
    start_margin_s: float = 2.0  # least time between the start commands and the common start t0, wall s
    command_attempts: int = 4
    takeoff_timeout_s: float = 60.0  # simulated seconds
    ready_timeout_s: float = 120.0  # wall s every autopilot is waited for before takeoff (services/gcs/readiness.py)
    mission_margin: float = 1.5  # x planned duration, simulated
    land_timeout_s: float = 60.0  # simulated seconds
    report_wait_s: float = 5.0  # wall seconds to wait for the last defect reports
    lost_grace_s: float = 3.0  # wall s a token may stay away (own link up) before its UAV counts as lost
    lost_wait_s: float = 10.0  # wall s a lost UAV is still waited for after the others finished
    stall_limit_s: float = 120.0  # wall s the waits may be extended by while the fleet stands still
    resume_held: bool = True  # resume UAVs holding mid-mission (failsafe) once they are heard again
    particles: int | None = None
    iterations: int | None = None
    waypoints: int | None = None
    method: str | None = None  # the detector's detection method (the record's header, the findings name it)
    transport: dict[str, str] | None = None  # the session's protocol per link class (protocol.links.transports)


@dataclass(frozen=True)
class Snapshot:
    """The runner's live figures, copied at one instant (:meth:`MissionRunner.snapshot`)."""

    phase: str  # the latest phase begun ("-" before the first)
    states: dict[int, VehicleState]  # UAV -> its latest state
    ages_ms: list[float]  # age rx - stamp of the latest states received (any UAV), ms
    reports: int  # capture points with an ok defect report
    last_heard: dict[int, float]  # UAV -> wall time its latest state was received
    lost: dict[int, float]  # lost UAV -> wall time its token went away


class MissionRunner:
    def __init__(self, bus: Bus, scenario: Scenario, options: MissionOptions,
                 on_progress: Callable[[MissionRunner], None] | None = None, log=None,
                 abort: threading.Event | None = None, sink=None, signer=None, plan_verifier=None,
                 witness: FrameWitness | None = None):
        self.bus, self.opt, self.log = bus, options, log
        #: the capture frames this ground station received itself (the mission log's,
        #: services.recording.witness): a capture counts only on a report naming one of them; None: not checked
        self.witness = witness
        self.signer = signer  # protocol.signing.Signer: commands and heartbeats signed end to end
        #: protocol.signing.Verifier of the planner's key (protocol.planauth.plan_verifier); None: unsigned plans
        #: are taken (--insecure, --secure without a key set), still bound to the request and checked
        self.plan_verifier = plan_verifier
        self.abort = abort or threading.Event()
        scenario = with_formation_size(scenario, len(options.uavs), log)
        self.on_progress = on_progress
        self.scenario = scenario
        self.record = MissionRecord(fleet=bus.fleet, scenario=scenario, speed=options.speed, started=time.time(),
                                    method=options.method, transport=options.transport or {})
        #: every item goes through it: bounded in memory; the ground station's own entries also to ``sink``, the
        #: mission log's writer (services.recording.recorder), which logs the bus's samples itself
        self.recorder = LiveRecord(self.record, sink)
        self.reports: dict[tuple[int, int], DefectReport] = {}
        self._failed_told: set[tuple[int, int]] = set()  # captures whose failed report was logged (bounded)
        self._lock = threading.Lock()
        self._cmd_ids = CommandIds()
        self._retry = RetryPolicy(attempts=options.command_attempts, timeout_s=options.command_timeout_s)
        self._hb_stop = threading.Event()
        # the supervision policy (supervisor thread + Zenoh callbacks; under self._lock)
        self._sup = Supervisor(options.uavs, time.time(), lost_grace_s=options.lost_grace_s,
                               lost_wait_s=options.lost_wait_s, describe=self.mission_time)
        self._land_state: dict[int, tuple[bool, float]] = {}  # UAV -> (Land accepted, last try)
        self._in_mission = threading.Event()
        self._sup_stop = threading.Event()
        #: called (in order, on the runner's thread) when the flight is over, before the "done" phase; a text
        #: one returns is a failure of the mission, added after the mission's own verdict
        self.closing: list[Callable[[], str | None]] = []
        fleet = bus.fleet
        # per-source budgets (protocol.budget): a flood on one key is dropped and counted, never recorded
        bus.subscribe(keys.state(fleet, "*"), self._on_state, expect=VehicleState, link=TELEMETRY,
                      budget=for_topic("state"))
        bus.subscribe(keys.all_events(fleet), self._on_event, expect=Event, link=COMMAND, budget=for_topic("event"))
        bus.subscribe(keys.defects(fleet), self._on_defects, expect=DefectReport, link=COMMAND,
                      budget=for_topic("defects"))
        for key, table in ((keys.gateway_stats(fleet), "gateway_stats"),
                           (keys.rcu_instances(fleet, "detector", "stats"), "detector_stats")):
            bus.subscribe(key, functools.partial(self._on_stats, table), expect=LinkStats, link=TELEMETRY,
                          budget=for_topic("stats"))
        self._hb_pub = bus.publisher(keys.heartbeat(fleet), COMMAND)
        bus.watch_alive(keys.alive(fleet, "*"), self._on_alive)

    # -- recording (Zenoh callback threads: short)
    def _on_state(self, msg, sample) -> None:
        if not binding.matches(str(sample.key_expr), msg.uav):  # a node speaking for another: refused
            self.bus.counters.reject(str(sample.key_expr), binding.MISMATCH)
            return
        now = time.time()
        with self._lock:
            self.recorder.add("states", StateRx(rx=now, msg=msg))
            self._sup.on_state(msg, now)

    @property
    def latest(self) -> dict[int, VehicleState]:
        """UAV -> its latest state (the supervisor's; read it under ``self._lock`` or via :meth:`snapshot`)."""
        return self._sup.latest

    def _on_event(self, msg, sample) -> None:
        if not binding.matches(str(sample.key_expr), None, msg.source):
            self.bus.counters.reject(str(sample.key_expr), binding.MISMATCH)
            return
        with self._lock:
            self.recorder.add("events", EventRx(rx=time.time(), msg=msg))
        if self.log and msg.level != "info":
            self.log.warning("event from %s: %s %s", msg.source, msg.kind, msg.text)

    def _on_defects(self, msg, sample) -> None:
        tell = False
        with self._lock:
            self.recorder.add("defects", DefectRx(rx=time.time(), msg=msg))
            if has_evidence(msg):  # a capture counts only on a report that names its frame (evidence.py)
                self.reports[(msg.uav, msg.capture_id)] = msg
            elif not msg.ok and len(self._failed_told) < MAX_FAILED_TOLD and \
                    (msg.uav, msg.capture_id) not in self._failed_told:
                self._failed_told.add((msg.uav, msg.capture_id))
                tell = True
        if tell and self.log:  # while flying, so that a camera showing nothing can be seen to, not only at the end
            self.log.warning("capture %s not analysed: %s", capture_name(msg.uav, msg.capture_id), msg.error[:200])

    def _on_stats(self, table: str, msg, sample) -> None:
        if not binding.source_matches(str(sample.key_expr), msg.source):  # statistics only for their own node
            self.bus.counters.reject(str(sample.key_expr), binding.MISMATCH)
            return
        with self._lock:
            self.recorder.add(table, StatsRx(rx=time.time(), msg=msg))

    def _on_alive(self, key: str, alive: bool) -> None:
        try:
            uav = keys.parse(key).uav
        except ValueError:
            return
        if uav is None or uav not in self.opt.uavs:
            return
        with self._lock:
            self._note(*self._sup.on_token(uav, alive, time.time()))

    def _note(self, *incidents: Incident) -> None:
        """Record the supervisor's incidents (caller holds ``self._lock``)."""
        for inc in incidents:
            self.recorder.add("incidents", inc)
            if self.log:
                (self.log.info if inc.kind in ("token-back", "uav-back", "link-up", "resume") else self.log.warning)(
                    "%s: %s", inc.kind, inc.text)

    def note_fault(self, action: str, target: str, text: str = "") -> None:
        """Record a fault injected into the run (kill, restart, cut, restore, partition, heal).

        Called by the launcher's fault injector from its own thread; thread-safe.
        """
        with self._lock:
            self.recorder.add("faults", FaultRecord(at=time.time(), action=action, target=target, text=text))
        if self.log:
            self.log.warning("fault: %s %s %s", action, target, text)

    # -- steps
    def phase(self, name: str) -> None:
        self.record.phases[name] = time.time()
        if self.log:
            self.log.info("phase: %s", name)

    def wait_for(self, pred: Callable[[], bool], timeout_s: float, what: str) -> None:
        """Poll ``pred`` until true; the timeout is extended by the time the fleet stood still
        meanwhile (own link down, a UAV unheard or holding; see :meth:`supervise`), at most
        ``stall_limit_s``."""
        deadline = time.monotonic() + timeout_s
        stalled0 = self._sup.stalled_s
        while not pred():
            if self.abort.is_set():
                raise MissionFailed(f"aborted by the operator while waiting for {what}")
            extra = min(self._sup.stalled_s - stalled0, self.opt.stall_limit_s)
            if time.monotonic() > deadline + extra:
                raise MissionFailed(f"timed out after {timeout_s + extra:.0f} s waiting for {what}"
                                    + (f" ({extra:.0f} s of it added while the fleet stood still)" if extra >= 1 else ""))
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

    def wait_ready(self) -> None:
        """Wait until every UAV's autopilot is ready to fly; refuse naming each UAV and its reason after
        ``ready_timeout_s`` (:mod:`.readiness`)."""
        from .readiness import not_ready, refusal

        self.phase("readiness")
        t0, told = time.monotonic(), False
        while True:
            with self._lock:
                waiting = not_ready(dict(self.latest), self.opt.uavs)
            if not waiting:
                return
            if self.log and not told:
                told = True
                self.log.info("waiting for the autopilots: %s", "; ".join(f"UAV {u}: {w}" for u, w in waiting.items()))
            if self.abort.is_set():
                raise MissionFailed("aborted by the operator while waiting for the autopilots")
            if time.monotonic() - t0 > self.opt.ready_timeout_s:
                raise MissionFailed(refusal(waiting, time.monotonic() - t0))
            if self.on_progress:
                self.on_progress(self)
            time.sleep(0.2)

    def request_plan(self) -> MissionPlan:
        """Ask for the plan and take it only on the operator's authority (:mod:`protocol.planauth`,
        :func:`.preflight.scenario_problem`): every answer of the request is gathered; one without the
        planner's signature, the request's nonce or the scenario's digest is refused (an event says why),
        two different accepted answers refuse the plan, and the one plan left must stay inside the
        scenario. MissionFailed before anything is uploaded otherwise."""
        self.phase("planning")
        scenario = self.scenario
        req = PlanRequest(request_id=1, nonce=planauth.new_nonce(), scenario=scenario, algorithm=self.opt.algorithm,
                          seed=self.opt.seed, particles=self.opt.particles, iterations=self.opt.iterations,
                          waypoints=self.opt.waypoints)
        where = keys.planner(self.bus.fleet)
        digest = planauth.scenario_digest(scenario)

        def acceptable(answer) -> bool:  # only an answer that would be taken starts the settle window
            try:
                planauth.open_answer(answer, req, where, self.plan_verifier, digest)
            except planauth.PlanRefused:
                return False
            return True

        replies = self.bus.request_all(where, req, expect=(MissionPlan, Signed), timeout=self.opt.plan_timeout_s,
                                       settle_s=self.opt.plan_settle_s, settles=acceptable)
        answers = [r.message for r in replies if r.ok and r.message is not None]
        errors = [r.error for r in replies if not r.ok]
        self.record.plan_request_s = next((r.elapsed_s for r in replies if r.ok), replies[0].elapsed_s if replies else 0.0)
        try:
            choice = planauth.choose(answers, req, where, self.plan_verifier)
        except planauth.Conflict as exc:
            self.plan_event(EventKind.PLAN_CONFLICT, str(exc))
            raise MissionFailed(f"refused before takeoff: {exc}") from None
        for why in choice.refused:
            self.plan_event(EventKind.PLAN_REFUSED, why)
        if choice.plan is None:
            why = "; ".join(choice.refused + errors) or f"no reply from {where} (nobody listening)"
            raise MissionFailed(f"the planner did not deliver a plan: {why}")
        plan = choice.plan
        missing = set(self.opt.uavs) - {t.uav for t in plan.trajectories}
        if missing:
            raise MissionFailed(f"the plan has no trajectory for UAV(s) {sorted(missing)}")
        from .preflight import (  # before any upload: all fit, or nobody flies
            plan_problem,
            scenario_box,
            scenario_problem,
        )

        problem = scenario_problem(plan, scenario, self.opt.uavs)
        if problem:
            self.plan_event(EventKind.PLAN_REFUSED, f"the plan leaves the scenario: {problem}")
            self.record.plan = plan
            raise MissionFailed(f"refused before takeoff: the plan leaves the scenario: {problem}")
        problem = plan_problem(plan, scenario.formation.offsets, scenario_box(scenario))
        if problem:
            self.record.plan = plan
            raise MissionFailed(f"refused before takeoff: {problem}")
        self.record.plan = plan
        return plan

    def plan_event(self, kind: EventKind, text: str) -> None:
        """Record the ground station's own warning about a plan answer (the report's events)."""
        ev = Event(source="gcs", stamp=time.time(), kind=kind, level=Level.WARNING, text=text[:2000])
        with self._lock:
            self.recorder.add("events", EventRx(rx=time.time(), msg=ev), own=True)  # not on the bus
        if self.log:
            self.log.warning("%s: %s", kind, text)

    def command(self, make: Callable[[int], Any]) -> CommandRecord:
        """Send one command with retries and back-off (:func:`services.gcs.commands.send`); a
        refusal is final (not retried).

        A command for a lost UAV is not sent; it is recorded as failed ("not sent: ...") so that no
        command disappears without a trace.
        """
        cmd = make(self._cmd_ids.next())
        lost = self.lost()
        if cmd.uav in lost:
            rec = not_sent(cmd, f"UAV {cmd.uav} is lost (no liveliness token since "
                                f"{self.mission_time(lost[cmd.uav])})")
        else:
            rec = send(self.bus, cmd, self._retry, signer=self.signer)
        with self._lock:
            self.recorder.add("commands", rec)
        return rec

    def command_all(self, make: Callable[[int, int], object], what: str, parallel: bool = False) -> None:
        """The command to every UAV, one after another or (``parallel``) all at once; MissionFailed
        naming the first UAV that did not acknowledge or refused it."""
        def one(uav: int) -> CommandRecord:
            return self.command(lambda cid: make(uav, cid))

        if parallel:
            with ThreadPoolExecutor(max_workers=len(self.opt.uavs), thread_name_prefix="cmd") as pool:
                records = list(pool.map(one, self.opt.uavs))
        else:
            records = []
            for uav in self.opt.uavs:
                records.append(one(uav))
                if not (records[-1].ok and records[-1].accepted):
                    break
        for uav, rec in zip(self.opt.uavs, records):
            if not rec.ok:
                raise MissionFailed(f"UAV {uav} did not acknowledge {what} after {rec.attempts} tries: {rec.reason}")
            if not rec.accepted:
                raise MissionFailed(f"UAV {uav} refused {what}: {rec.reason}")

    def start_margin_s(self) -> float:
        """How far ahead the common start time ``t0`` is set (:func:`services.gcs.commands.start_margin`:
        twice the slowest acknowledgement so far, at least ``start_margin_s``, at most 30 s)."""
        with self._lock:
            commands = list(self.record.commands)
        return start_margin(commands, self.opt.start_margin_s)

    def transit_s(self, plan: MissionPlan) -> float:
        """Wall seconds the farthest UAV needs to reach its first waypoint (:func:`.preflight.transit_margin_s`)."""
        from .preflight import transit_margin_s

        with self._lock:
            here = {u: s.pos for u, s in self.latest.items()}
        return transit_margin_s(here, plan, self.opt.speed)

    def _beat(self, seq: int) -> None:
        """Publish one heartbeat, signed when the runner has a signer (only a verified one holds off a failsafe)."""
        hb = Heartbeat(source="gcs", seq=seq, stamp=time.time())
        self._hb_pub.put(hb if self.signer is None else self.signer.sign(hb, self._hb_pub.key))

    def heartbeat(self) -> None:
        period = 1.0 / self.opt.heartbeat_hz
        seq = 0
        while not self._hb_stop.wait(period):
            self._beat(seq)
            seq += 1
            self.record.heartbeats_sent = seq

    def sim_timeout(self, sim_s: float) -> float:
        return sim_s / self.opt.speed + 10.0

    def modes(self) -> dict[int, Mode]:
        with self._lock:
            return {u: s.mode for u, s in self.latest.items()}

    def run(self) -> MissionRecord:
        hb = threading.Thread(target=self.heartbeat, name="heartbeat", daemon=True)
        sup = threading.Thread(target=self.supervise, name="supervisor", daemon=True)
        sup.start()
        try:
            self.wait_alive()
            plan = self.request_plan()
            hb.start()
            self.phase("upload")
            traj = {t.uav: t for t in plan.trajectories}
            fence = self.fence()  # the scenario's box: never the plan's own geofence
            self.command_all(lambda u, cid: UploadTrajectory(uav=u, cmd_id=cid, trajectory=traj[u],
                                                             geofence=fence), "its trajectory upload")
            offsets = dict(zip(self.opt.uavs, self.scenario.formation.offsets))
            self.command_all(lambda u, cid: SetFormation(uav=u, cmd_id=cid, offsets=offsets), "the formation")
            self.wait_ready()
            self.phase("takeoff")
            self.command_all(lambda u, cid: Takeoff(uav=u, cmd_id=cid, altitude=self.takeoff_altitude(u)), "takeoff")
            self.wait_for(lambda: self.fleet_done(lambda u, s: s is not None and s.mode == Mode.HOLD),
                          self.sim_timeout(self.opt.takeoff_timeout_s), "every UAV to reach takeoff altitude")
            self.phase("mission")
            t0 = time.time() + self.start_margin_s() + self.transit_s(plan)
            self.command_all(lambda u, cid: Start(uav=u, cmd_id=cid, t0_stamp=t0), "start", parallel=True)
            with self._lock:
                self._sup.on_started(self.opt.uavs, time.time())
            self._in_mission.set()
            duration = max(t.waypoints[-1].t for t in plan.trajectories)
            self.wait_for(lambda: self.mission_done(), self.sim_timeout(duration * self.opt.mission_margin + 60.0),
                          "every UAV to finish its trajectory")
            with contextlib.suppress(MissionFailed):  # one that fell behind its clock gets there before the landing
                self.wait_for(lambda: not self.short_of_goal(plan), GOAL_SETTLE_S / self.opt.speed + 1.0,
                              "every UAV at its goal")
            self._in_mission.clear()
            self.phase("reports")
            with contextlib.suppress(MissionFailed):  # judge() names the captures that were not imaged
                self.wait_for(lambda: not self.missing_captures(), self.opt.report_wait_s, "the last defect reports")
        except MissionFailed as exc:
            self.record.failures.append(str(exc))
        finally:
            self._in_mission.clear()
            try:
                self.phase("landing")
                self.wait_for(self._land_step, self.sim_timeout(self.opt.land_timeout_s), "every UAV to land")
            except MissionFailed as exc:
                self.record.failures.append(str(exc))
            self._hb_stop.set()
            self._sup_stop.set()
            for t in (hb, sup):
                if t.is_alive():
                    t.join(2.0)
            late: list[str | None] = []
            for hook in self.closing:
                try:
                    late.append(hook())
                except Exception:  # the mission's end goes on: its record is finished below
                    if self.log:
                        self.log.exception("closing hook failed")
            self.record.ended = time.time()
            self.record.rejected = self.bus.counters.snapshot()["rejected"]
            self.phase("done")
        self.judge(late=[f for f in late if f])
        return self.record

    def snapshot(self, recent: int = 60) -> Snapshot:
        """The live figures (for a progress display, from any thread): ``recent`` latest state ages."""
        with self._lock:
            phases = dict(self.record.phases)
            return Snapshot(phase=max(phases, key=phases.get) if phases else "-", states=dict(self.latest),
                            ages_ms=[1000 * (s.rx - s.msg.stamp) for s in self.record.states[-recent:]],
                            reports=len(self.reports), last_heard=dict(self._sup.rx), lost=dict(self._sup.lost))

    # -- faults: liveliness, the own link, failsafe holds
    def lost(self) -> dict[int, float]:
        """Lost UAVs -> wall time their token went away."""
        with self._lock:
            return dict(self._sup.lost)

    def last_heard(self) -> dict[int, float]:
        """UAV -> wall time its latest state was received."""
        with self._lock:
            return dict(self._sup.rx)

    def mission_time(self, wall: float) -> str:
        """``wall`` as "mission t=12.3 s" (from the mission phase's start), or "t=… s" from the start."""
        return mission_time(wall, self.record.phases, self.record.started)

    def supervise(self) -> None:
        """Supervisor thread: one :meth:`Supervisor.tick` every ``SUPERVISE_PERIOD_S`` (own link, lost
        UAVs, stall time and, in the mission phase, failsafe holds), then the Resumes it decided."""
        last = time.monotonic()
        while not self._sup_stop.wait(SUPERVISE_PERIOD_S):
            now_m = time.monotonic()
            dt, last = now_m - last, now_m
            try:
                up = bool(self.bus.routers() or self.bus.peers())
                with self._lock:
                    d = self._sup.tick(time.time(), dt, up, resume=self._in_mission.is_set() and self.opt.resume_held)
                    self._note(*d.incidents)
                for u in d.resume:
                    # a board resumes only after a heartbeat newer than its failsafe (edge.failsafe): one goes just
                    # ahead of the Resume, on the same reliable link
                    self._beat(self.record.heartbeats_sent)
                    rec = self.command(lambda cid: Resume(uav=u, cmd_id=cid))  # called at once, in this turn
                    with self._lock:
                        self._note(self._sup.on_resumed(u, rec, time.time()))
            except Exception:  # the supervisor must outlive a bug in one pass (and say so)
                if self.log:
                    self.log.exception("supervisor pass failed")

    def fleet_done(self, finished: Callable[[int, VehicleState | None], bool]) -> bool:
        """Every UAV still counted (not lost) is ``finished``; lost ones are waited for ``lost_wait_s``
        after they went away, unless every UAV is lost (then until the wait's own timeout)."""
        with self._lock:
            return self._sup.fleet_done(finished, time.time())

    def _land_step(self) -> bool:
        """Send Land to every armed UAV not yet landing (retried every 2 s while unacknowledged;
        lost UAVs get a failed "not sent" record once); True when every UAV still counted is down."""
        now = time.time()
        for u in self.opt.uavs:
            with self._lock:
                s, lost = self.latest.get(u), u in self._sup.lost
            if s is None or not s.armed or s.mode == Mode.LAND:
                continue
            tried = self._land_state.get(u)  # (accepted, when)
            if tried is not None and (lost or tried[0] or now - tried[1] < 2.0):
                continue
            rec = self.command(lambda cid: Land(uav=u, cmd_id=cid))  # called at once, in this turn
            self._land_state[u] = (rec.ok and rec.accepted, time.time())
        with self._lock:
            return all(not s.armed for u, s in self.latest.items() if u in self.opt.uavs and u not in self._sup.lost)

    def fence(self) -> Box:
        """The geofence the edges get: the operator's scenario box (:func:`.preflight.scenario_box`)."""
        from .preflight import scenario_box

        return scenario_box(self.scenario)

    def takeoff_altitude(self, uav: int) -> float:
        plan = self.record.plan
        if plan is None:
            raise MissionFailed("no plan to take off on")
        first = next(t for t in plan.trajectories if t.uav == uav).waypoints[0].pos
        home_z = self.latest[uav].pos[2] if uav in self.latest else 0.0
        return max(2.0, min(first[2] - home_z, self.fence().hi[2] - home_z - 1.0))

    def short_of_goal(self, plan: MissionPlan) -> list[int]:
        """The UAVs holding at their trajectory's end but not yet at its goal (:func:`.verdict.short_of_goal`)."""
        with self._lock:
            latest = dict(self.latest)
        return short_of_goal(latest, plan.trajectories)

    def mission_done(self) -> bool:
        """Every UAV still counted finished its trajectory (or came down on its own: not waited for)."""
        return self.fleet_done(lambda u, s: s is not None and ((s.progress >= 1.0 and s.mode != Mode.MISSION)
                                                                or not s.armed))

    def planned_captures(self) -> set[tuple[int, int]]:
        plan = self.record.plan
        return set() if plan is None else planned_captures(plan.trajectories)

    def missing_captures(self, include_lost: bool = False, imaged: set[tuple[int, int]] | None = None
                         ) -> set[tuple[int, int]]:
        """Planned capture points without a report (``imaged``: those imaged; default: every evidenced report's),
        of the lost UAVs too with ``include_lost``."""
        with self._lock:
            missing = self.planned_captures() - (set(self.reports) if imaged is None else imaged)
            lost = set(self._sup.lost)
        return missing if include_lost else {c for c in missing if c[0] not in lost}

    def judge(self, late: Sequence[str] = ()) -> None:
        """The verdict: the failures so far, then (when there were none) each UAV's goal and the captures,
        then ``late``, failures of the run found at its end (a fault it never injected); success if none."""
        rec = self.record
        clean = not rec.failures
        planned, lost = self.planned_captures(), self.lost()
        held, no_surface = None, {}
        if self.witness is not None:  # a capture counts on a frame this ground station holds (evidence.py)
            with self._lock:
                reports = [d.msg for d in rec.defects]
            held = held_captures(reports, self.witness)
            no_surface = no_surface_reasons(reports, self.witness)
            rec.held_captures = sorted(held)
        missed_any = self.missing_captures(include_lost=True, imaged=held)
        for u, gone in sorted(lost.items()):
            mine = {c for c in planned if c[0] == u}
            rec.failures.append(f"UAV {u} lost at {self.mission_time(gone)} (no liveliness token since); "
                                f"its {len(mine & missed_any)} of {len(mine)} capture points not imaged")
        if rec.plan is not None and clean:
            for t in rec.plan.trajectories:
                if t.uav in lost:
                    continue
                goal = t.waypoints[-1].pos
                check = goal_check((s.msg for s in rec.states if s.msg.uav == t.uav), t)  # services.gcs.verdict
                if check is None or not (check.completed and check.reached):
                    rec.failures.append(f"UAV {t.uav} did not reach its goal {tuple(round(v, 1) for v in goal)}")
            from .capture_pose import CAPTURE_TOLERANCE_M, capture_errors, far_text  # frames off their points

            errs = capture_errors(rec.plan.trajectories, (s.msg for s in rec.states), (d.msg for d in rec.defects))
            far = {k: d for k, d in errs.items() if d > CAPTURE_TOLERANCE_M}
            if errs and self.log:
                ds = sorted(errs.values())
                self.log.info("capture positions: %d frames placed, error median %.2f m, max %.2f m (tolerance %g m)",
                              len(ds), ds[len(ds) // 2], ds[-1], CAPTURE_TOLERANCE_M)
            if far:
                rec.failures.append(far_text(far))
            missing = self.missing_captures(imaged=held)
            if missing:
                rec.failures.append(not_imaged_text(missing, len(self.planned_captures()),
                                                    (d.msg for d in rec.defects), reasons=no_surface))
        rec.imagery = ledger(self.opt.uavs, (s.msg for s in rec.states), (d.msg for d in rec.defects),
                             (s.msg for s in rec.detector_stats), self.witness)
        rec.failures += corroboration_failures(rec.imagery)
        rec.failures += late
        rec.success = not rec.failures
