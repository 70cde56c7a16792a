"""The ground control station's mission: plan, upload, take off, fly, image, land — over the bus.

:class:`MissionRunner` is a Zenoh client of the gateway. It records everything into a
:class:`~services.gcs.record.MissionRecord` (the input of the report) and returns it with
``success`` set only when every UAV reached the goal and every capture point was imaged; any
step that cannot complete (a UAV that never appears, refuses its upload, a planner that does
not answer, a timeout) ends the mission with a failure that says why, never a hang.

Faults (issue 7). A supervisor thread watches, for the whole mission:

* the UAVs' liveliness tokens: a token that goes away is recorded at once (``token-gone``); a UAV
  whose token stays away longer than ``lost_grace_s`` while the ground station's own link is up
  is *lost* (``uav-lost``): the waits stop waiting for it (a lost UAV is still waited for
  ``lost_wait_s`` after the others finish, in case it comes back), it is not sent commands (a
  failed command record says so), and the mission ends with a failure naming it and the capture
  points it did not image; the others finish and land. A lost UAV whose token comes back is
  noted (``uav-back``) and counted again. A gateway restart takes every token away at once but
  also the ground station's own link, so nobody is declared lost unless it stays away after the
  link is back (the grace is counted from the later of the two);
* the ground station's own link to the gateway (``link-down``/``link-up``; Zenoh's client
  reconnects by itself, :class:`protocol.bus.BusConfig` ``reconnect_max_s``);
* failsafe holds: during the mission phase a UAV in HOLD before the end of its trajectory holds
  because of its failsafe (the ground station never commands a hold): once its state is heard
  again (the link is back) it gets a ``Resume`` — each UAV as soon as possible, not the fleet at
  once, since the others kept flying and the board's formation keeping on trajectory time closes
  the lag. The waits are extended by the time the fleet stood still, up to ``stall_limit_s``.

Heartbeats continue throughout. Every command ends in the record acknowledged or failed.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

from protocol import keys
from protocol.budget import for_topic
from protocol.bus import Bus
from protocol.links import COMMAND, TELEMETRY
from protocol.scenario import FormationSpec, Scenario
from protocol.messages import (
    CommandAck,
    DefectReport,
    Event,
    Heartbeat,
    Land,
    LinkStats,
    MissionPlan,
    Mode,
    PlanRequest,
    Resume,
    SetFormation,
    Start,
    Takeoff,
    UploadTrajectory,
    VehicleState,
)

from .evidence import corroboration_failures, has_evidence, ledger
from .record import (
    GOAL_RADIUS_M,
    CommandRecord,
    DefectRx,
    EventRx,
    FaultRecord,
    Incident,
    MissionRecord,
    Recorder,
    StateRx,
    StatsRx,
)

#: How often the supervisor looks at liveliness, the own link and failsafe holds, s.
SUPERVISE_PERIOD_S = 0.2
#: A UAV's state counts as heard "now" when received within this many wall seconds.
FRESH_STATE_S = 1.0



def with_formation_size(scenario: Scenario, n: int, log=None) -> Scenario:
    """The scenario with one formation offset per UAV of the mission (P9).

    A scenario written for three UAVs flown with two or five gets the offsets of
    :func:`edge.formation.offsets_for`, so the planner plans a trajectory for every UAV present.
    """
    if len(scenario.formation.offsets) == n:
        return scenario
    from edge.formation import offsets_for

    new = [tuple(map(float, o)) for o in offsets_for(n)]
    if log:
        log.info("formation of %d UAVs: offsets %s", n, new)
    formation = FormationSpec(offsets=new, min_separation=scenario.formation.min_separation)
    return scenario.model_copy(update={"formation": formation})


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
    start_margin_s: float = 2.0  # least time between the start commands and the common start t0, wall s
    command_attempts: int = 4
    takeoff_timeout_s: float = 60.0  # simulated seconds
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


class MissionRunner:
    def __init__(self, bus: Bus, scenario: Scenario, options: MissionOptions,
                 on_progress: Callable[[MissionRunner], None] | None = None, log=None,
                 abort: threading.Event | None = None, journal=None):
        self.bus, self.opt, self.log = bus, options, log
        self.abort = abort or threading.Event()
        scenario = with_formation_size(scenario, len(options.uavs), log)
        self.on_progress = on_progress
        self.record = MissionRecord(fleet=bus.fleet, scenario=scenario, speed=options.speed, started=time.time())
        #: every item goes through it: bounded in memory, streamed to ``journal`` (record.Recorder)
        self.recorder = Recorder(self.record, journal, log)
        self.latest: dict[int, VehicleState] = {}
        self.reports: dict[tuple[int, int], DefectReport] = {}
        self._lock = threading.Lock()
        self._cmd_lock = threading.Lock()
        self._cmd_id = 0
        self._hb_stop = threading.Event()
        # fault tracking (supervisor thread + liveliness callback; under self._lock)
        self._gone: dict[int, float] = {}  # UAV -> wall time its token went away
        self._lost: dict[int, float] = {}  # UAV -> wall time it was declared lost
        self._link_up_since: float | None = time.time()  # None while the own link is down
        self._started: dict[int, float] = {}  # UAV -> wall time its Start was acknowledged
        self._held: dict[int, float] = {}  # UAV -> wall time a mid-mission hold was first seen
        self._resume_after: dict[int, float] = {}  # UAV -> no resume before this wall time
        self._rx: dict[int, float] = {}  # UAV -> wall time of its latest state
        self._stalled_s = 0.0
        self._land_state: dict[int, tuple[bool, float]] = {}  # UAV -> (Land accepted, last try)
        self._in_mission = threading.Event()
        self._sup_stop = threading.Event()
        fleet = bus.fleet
        # per-source budgets (protocol.budget): a flood on one key is dropped and counted, never recorded
        bus.subscribe(keys.state(fleet, "*"), self._on_state, expect=VehicleState, link=TELEMETRY,
                      budget=for_topic("state"))
        bus.subscribe(keys.all_events(fleet), self._on_event, expect=Event, link=COMMAND, budget=for_topic("event"))
        bus.subscribe(keys.defects(fleet), self._on_defects, expect=DefectReport, link=COMMAND,
                      budget=for_topic("defects"))
        bus.subscribe(keys.gateway_stats(fleet), self._on_gw_stats, expect=LinkStats, link=TELEMETRY,
                      budget=for_topic("stats"))
        bus.subscribe(keys.rcu_stats(fleet, "detector"), self._on_det_stats, expect=LinkStats, link=TELEMETRY,
                      budget=for_topic("stats"))
        self._hb_pub = bus.publisher(keys.heartbeat(fleet), COMMAND)
        bus.watch_alive(keys.alive(fleet, "*"), self._on_alive)

    # -- recording (Zenoh callback threads: short)
    def _on_state(self, msg, sample) -> None:
        now = time.time()
        with self._lock:
            self.recorder.add("states", StateRx(rx=now, msg=msg))
            self.latest[msg.uav] = msg
            self._rx[msg.uav] = now

    def _on_event(self, msg, sample) -> None:
        with self._lock:
            self.recorder.add("events", EventRx(rx=time.time(), msg=msg))
        if self.log and msg.level != "info":
            self.log.warning("event from %s: %s %s", msg.source, msg.kind, msg.text)

    def _on_defects(self, msg, sample) -> None:
        with self._lock:
            self.recorder.add("defects", DefectRx(rx=time.time(), msg=msg))
            if has_evidence(msg):  # a capture counts only on a report that names its frame (evidence.py)
                self.reports[(msg.uav, msg.capture_id)] = msg

    def _on_gw_stats(self, msg, sample) -> None:
        with self._lock:
            self.recorder.add("gateway_stats", StatsRx(rx=time.time(), msg=msg))

    def _on_det_stats(self, msg, sample) -> None:
        with self._lock:
            self.recorder.add("detector_stats", StatsRx(rx=time.time(), msg=msg))

    def _on_alive(self, key: str, alive: bool) -> None:
        try:
            uav = keys.parse(key).uav
        except ValueError:
            return
        if uav is None or uav not in self.opt.uavs:
            return
        now = time.time()
        with self._lock:
            if alive:
                gone = self._gone.pop(uav, None)
                if gone is not None:
                    self._incident("token-back", uav, f"UAV {uav}'s liveliness token is back after {now - gone:.1f} s",
                                   now)
                lost = self._lost.pop(uav, None)
                if lost is not None:
                    self._incident("uav-back", uav, f"UAV {uav} is back (lost for {now - lost:.1f} s)", now)
            elif uav not in self._gone:
                self._gone[uav] = now
                self._incident("token-gone", uav, f"UAV {uav}'s liveliness token went away", now)

    def _incident(self, kind: str, uav: int | None, text: str, at: float | None = None) -> None:
        """Record an incident (caller holds ``self._lock``)."""
        self.recorder.add("incidents", Incident(at=time.time() if at is None else at, kind=kind, uav=uav, text=text))
        if self.log:
            (self.log.info if kind in ("token-back", "uav-back", "link-up", "resume") else self.log.warning)(
                "%s: %s", kind, text)

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
        stalled0 = self._stalled_s
        while not pred():
            if self.abort.is_set():
                raise MissionFailed(f"aborted by the operator while waiting for {what}")
            extra = min(self._stalled_s - stalled0, self.opt.stall_limit_s)
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
        """Send one command with retries and back-off; a refusal is final (not retried).

        A command for a lost UAV is not sent; it is recorded as failed ("not sent: ...") so that no
        command disappears without a trace.
        """
        with self._cmd_lock:
            self._cmd_id += 1
            cmd = make(self._cmd_id)
        lost = self.lost()
        if cmd.uav in lost:
            rec = CommandRecord(uav=cmd.uav, kind=cmd.kind, cmd_id=cmd.cmd_id, ok=False, accepted=False,
                                reason=f"not sent: UAV {cmd.uav} is lost (no liveliness token since "
                                       f"{self.mission_time(lost[cmd.uav])})",
                                attempts=0, elapsed_s=0.0)
            with self._lock:
                self.recorder.add("commands", rec)
            return rec
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
                with self._lock:
                    self.recorder.add("commands", rec)
                return rec
            reason = reply.error
            time.sleep(backoff)
            backoff *= 2
        rec = CommandRecord(uav=cmd.uav, kind=cmd.kind, cmd_id=cmd.cmd_id, ok=False, accepted=False, reason=reason,
                            attempts=self.opt.command_attempts, elapsed_s=time.monotonic() - t0, ack_s=acks)
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
        """How far ahead the common start time ``t0`` is set. The Start commands go out to all UAVs
        at once, and each must arrive before ``t0`` or that UAV begins behind the others (and
        formation keeping pulls them back toward it): twice the slowest acknowledgement so far, at
        least ``start_margin_s`` (2 s), at most 30 s. (With 200 ms on every link a round trip takes
        0.8 s; sent one after another with 1 s of margin, UAV 3 began 7 s of trajectory late.)"""
        acks = [a for c in self.record.commands for a in c.ack_s]
        slowest = max(acks, default=0.0)
        return min(30.0, max(self.opt.start_margin_s, 2.0 * slowest))

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
        sup = threading.Thread(target=self.supervise, name="supervisor", daemon=True)
        sup.start()
        try:
            self.wait_alive()
            plan = self.request_plan()
            hb.start()
            self.phase("upload")
            traj = {t.uav: t for t in plan.trajectories}
            self.command_all(lambda u, cid: UploadTrajectory(uav=u, cmd_id=cid, trajectory=traj[u],
                                                             geofence=plan.geofence), "its trajectory upload")
            offsets = dict(zip(self.opt.uavs, self.record.scenario.formation.offsets))
            self.command_all(lambda u, cid: SetFormation(uav=u, cmd_id=cid, offsets=offsets), "the formation")
            self.phase("takeoff")
            self.command_all(lambda u, cid: Takeoff(uav=u, cmd_id=cid, altitude=self.takeoff_altitude(u)), "takeoff")
            self.wait_for(lambda: self.fleet_done(lambda u, s: s is not None and s.mode == Mode.HOLD),
                          self.sim_timeout(self.opt.takeoff_timeout_s), "every UAV to reach takeoff altitude")
            self.phase("mission")
            t0 = time.time() + self.start_margin_s()
            self.command_all(lambda u, cid: Start(uav=u, cmd_id=cid, t0_stamp=t0), "start", parallel=True)
            with self._lock:
                self._started.update({u: time.time() for u in self.opt.uavs})
            self._in_mission.set()
            duration = max(t.waypoints[-1].t for t in plan.trajectories)
            self.wait_for(lambda: self.mission_done(), self.sim_timeout(duration * self.opt.mission_margin + 60.0),
                          "every UAV to finish its trajectory")
            self._in_mission.clear()
            self.phase("reports")
            try:
                self.wait_for(lambda: not self.missing_captures(), self.opt.report_wait_s, "the last defect reports")
            except MissionFailed:
                pass  # judge() names the captures that were not imaged
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
            self.record.ended = time.time()
            self.record.rejected = self.bus.counters.snapshot()["rejected"]
            self.phase("done")
        self.judge()
        self.recorder.close()  # the journal's footer: plan, verdict, counters
        return self.record

    # -- faults: liveliness, the own link, failsafe holds
    def lost(self) -> dict[int, float]:
        """Lost UAVs -> wall time their token went away."""
        with self._lock:
            return dict(self._lost)

    def last_heard(self) -> dict[int, float]:
        """UAV -> wall time its latest state was received."""
        with self._lock:
            return dict(self._rx)

    def mission_time(self, wall: float) -> str:
        """``wall`` as "mission t=12.3 s" (from the mission phase's start), or "t=… s" from the start."""
        m = self.record.phases.get("mission")
        return f"mission t={wall - m:.1f} s" if m is not None else f"t={wall - self.record.started:.1f} s"

    def supervise(self) -> None:
        """Supervisor thread: own link, lost UAVs, stall time and (mission phase) failsafe resumes."""
        last = time.monotonic()
        while not self._sup_stop.wait(SUPERVISE_PERIOD_S):
            now_m = time.monotonic()
            dt, last = now_m - last, now_m
            try:
                self._check_link()
                self._confirm_losses()
                if self._standing_still():
                    self._stalled_s += dt
                if self._in_mission.is_set() and self.opt.resume_held:
                    self._resume_held()
            except Exception:  # the supervisor must outlive a bug in one pass (and say so)
                if self.log:
                    self.log.exception("supervisor pass failed")

    def _check_link(self) -> None:
        up = bool(self.bus.routers() or self.bus.peers())
        now = time.time()
        with self._lock:
            if up and self._link_up_since is None:
                self._link_up_since = now
                self._incident("link-up", None, "the ground station reached the gateway again", now)
            elif not up and self._link_up_since is not None:
                self._link_up_since = None
                self._incident("link-down", None, "the ground station lost its link to the gateway", now)

    def _confirm_losses(self) -> None:
        now = time.time()
        with self._lock:
            if self._link_up_since is None:
                return
            for u, gone in self._gone.items():
                if u not in self._lost and now - max(gone, self._link_up_since) > self.opt.lost_grace_s:
                    self._lost[u] = gone
                    self._incident("uav-lost", u, f"UAV {u} lost: no liveliness token since {self.mission_time(gone)} "
                                                  f"({now - gone:.1f} s) while the ground station's link is up", now)

    def _standing_still(self) -> bool:
        """True while the mission cannot progress for a fault: own link down, or a UAV still counted
        (not lost) unheard for a while or holding mid-mission."""
        now = time.time()
        with self._lock:
            if self._link_up_since is None:
                return True
            active = [u for u in self.opt.uavs if u not in self._lost]
            if not active:
                return True
            for u in active:
                rx = self._rx.get(u)
                if rx is not None and now - rx > FRESH_STATE_S:
                    return True
                if u in self._held:
                    return True
        return False

    def _resume_held(self) -> None:
        """Resume each UAV holding mid-mission (its failsafe) once its state is heard again."""
        for u in self.opt.uavs:
            now = time.time()
            with self._lock:
                s, rx, started = self.latest.get(u), self._rx.get(u), self._started.get(u)
                if u in self._lost or s is None or rx is None or started is None or rx < started + 0.5:
                    continue
                held = s.armed and s.mode == Mode.HOLD and s.progress < 1.0
                if not held:
                    self._held.pop(u, None)
                    continue
                if u not in self._held:
                    self._held[u] = now
                    self._incident("hold-seen", u, f"UAV {u} holds mid-mission at {s.progress:.0%} of its trajectory "
                                                   f"(its failsafe; the ground station did not command it)", now)
                ready = (now - rx <= FRESH_STATE_S and self._link_up_since is not None
                         and now >= self._resume_after.get(u, 0.0))
                held_since = self._held[u]
            if not ready:
                continue
            # a board resumes only after a heartbeat newer than its failsafe (edge.failsafe): one goes just
            # ahead of the Resume, on the same reliable link
            self._hb_pub.put(Heartbeat(source="gcs", seq=self.record.heartbeats_sent, stamp=time.time()))
            rec = self.command(lambda cid, uav=u: Resume(uav=uav, cmd_id=cid))
            with self._lock:
                if rec.ok and rec.accepted:
                    self._resume_after[u] = time.time() + 1.0
                    self._incident("resume", u, f"UAV {u} resumed, {time.time() - held_since:.1f} s after its hold "
                                                f"was seen ({rec.attempts} tries)")
                else:  # refused for want of a fresh heartbeat: the next one is at most 1 / heartbeat_hz away
                    self._resume_after[u] = time.time() + (0.5 if "heartbeat" in (rec.reason or "") else 2.0)
                    self._incident("resume-failed", u, f"UAV {u} not resumed: "
                                                       f"{rec.reason or 'refused'} ({rec.attempts} tries)")

    def fleet_done(self, finished: Callable[[int, VehicleState | None], bool]) -> bool:
        """Every UAV still counted (not lost) is ``finished``; lost ones are waited for ``lost_wait_s``
        after they went away, unless every UAV is lost (then until the wait's own timeout)."""
        with self._lock:
            latest = {u: self.latest.get(u) for u in self.opt.uavs}
            lost = dict(self._lost)
        active = [u for u in self.opt.uavs if u not in lost]
        if not active or not all(finished(u, latest[u]) for u in active):
            return False
        return not lost or time.time() - max(lost.values()) > self.opt.lost_wait_s

    def _land_step(self) -> bool:
        """Send Land to every armed UAV not yet landing (retried every 2 s while unacknowledged;
        lost UAVs get a failed "not sent" record once); True when every UAV still counted is down."""
        now = time.time()
        for u in self.opt.uavs:
            with self._lock:
                s, lost = self.latest.get(u), u in self._lost
            if s is None or not s.armed or s.mode == Mode.LAND:
                continue
            tried = self._land_state.get(u)  # (accepted, when)
            if tried is not None and (lost or tried[0] or now - tried[1] < 2.0):
                continue
            rec = self.command(lambda cid, uav=u: Land(uav=uav, cmd_id=cid))
            self._land_state[u] = (rec.ok and rec.accepted, time.time())
        with self._lock:
            return all(not s.armed for u, s in self.latest.items() if u in self.opt.uavs and u not in self._lost)

    def takeoff_altitude(self, uav: int) -> float:
        plan = self.record.plan
        first = next(t for t in plan.trajectories if t.uav == uav).waypoints[0].pos
        home_z = self.latest[uav].pos[2] if uav in self.latest else 0.0
        return max(2.0, min(first[2] - home_z, plan.geofence.hi[2] - home_z - 1.0))

    def mission_done(self) -> bool:
        """Every UAV still counted finished its trajectory (or came down on its own: not waited for)."""
        return self.fleet_done(lambda u, s: s is not None and ((s.progress >= 1.0 and s.mode != Mode.MISSION)
                                                                or not s.armed))

    def planned_captures(self) -> set[tuple[int, int]]:
        plan = self.record.plan
        if plan is None:
            return set()
        return {(t.uav, w.capture_id) for t in plan.trajectories for w in t.waypoints if w.capture_id is not None}

    def missing_captures(self, include_lost: bool = False) -> set[tuple[int, int]]:
        """Planned capture points without a report (of the lost UAVs too with ``include_lost``)."""
        with self._lock:
            missing = self.planned_captures() - set(self.reports)
            lost = set(self._lost)
        return missing if include_lost else {c for c in missing if c[0] not in lost}

    def judge(self) -> None:
        rec = self.record
        clean = not rec.failures
        planned, lost = self.planned_captures(), self.lost()
        missed_any = self.missing_captures(include_lost=True)
        for u, gone in sorted(lost.items()):
            mine = {c for c in planned if c[0] == u}
            rec.failures.append(f"UAV {u} lost at {self.mission_time(gone)} (no liveliness token since); "
                                f"its {len(mine & missed_any)} of {len(mine)} capture points not imaged")
        if rec.plan is not None and clean:
            for t in rec.plan.trajectories:
                if t.uav in lost:
                    continue
                goal = t.waypoints[-1].pos
                flown = [s.msg for s in rec.states if s.msg.uav == t.uav and s.msg.mode in (Mode.MISSION, Mode.HOLD)
                         and s.msg.progress >= 1.0]
                if not flown or math.dist(flown[-1].pos, goal) > GOAL_RADIUS_M:
                    rec.failures.append(f"UAV {t.uav} did not reach its goal {tuple(round(v, 1) for v in goal)}")
            missing = self.missing_captures()
            if missing:
                rec.failures.append(f"{len(missing)} of {len(self.planned_captures())} capture points were not imaged: "
                                    f"{sorted(missing)[:10]}")
        rec.imagery = ledger(self.opt.uavs, (s.msg for s in rec.states), (d.msg for d in rec.defects),
                             (s.msg for s in rec.detector_stats))
        rec.failures += corroboration_failures(rec.imagery)
        rec.success = not rec.failures
