"""The UAV's IoT board: one process per UAV, a Zenoh peer of SkyNet connected to the gateway.

Design notes: docs/edge.md (edge/board.py).
"""

from __future__ import annotations

import argparse
import functools
import logging
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from protocol import keys
from protocol.budget import for_topic
from protocol.bus import Bus, Publisher, config_from_args, setup_logging, stop_event_on_signals
from protocol.checks import xyz
from protocol.links import COMMAND, TELEMETRY
from protocol.messages import (
    COMMAND_TYPES,
    Box,
    CommandAck,
    Event,
    EventKind,
    Heartbeat,
    Hold,
    Land,
    Level,
    Message,
    Mode,
    Resume,
    ReturnToLaunch,
    SetFormation,
    Signed,
    Start,
    Takeoff,
    Trajectory,
    UploadTrajectory,
    VehicleState,
)
from protocol.readiness import notify_ready
from protocol.signing import TrustError

from .failsafe import FailsafeOptions, FailsafePolicy
from .geometry import formation
from .geometry.neighbourhood import FORMATION_SIZE
from .geometry.neighbourhood import neighbours as neighbourhood_of
from .geometry.validate import narrowed_fence, validate_command
from .trust import Gate, command_id
from .vehicle.follower import Follower

if TYPE_CHECKING:
    from .config import EdgeConfig


logger = logging.getLogger("skynet.edge.board")

@dataclass
class Neighbour:
    pos: tuple[float, float, float]
    ref: tuple[float, float, float] | None  # its planned position, when it flies a mission
    tau: float | None  # its trajectory time
    stamp: float  # wall time of reception
    sent: float  # its publication stamp (not after reception): what the state's age counts from


@dataclass
class BoardOptions:
    uav: int
    rate_hz: float = 20.0
    stale_s: float = 1.0
    failsafe: FailsafeOptions = field(default_factory=FailsafeOptions)  # link and battery failsafes (edge.failsafe)
    geofence: Box | None = None
    max_speed: float = 12.0
    formation_gain: float = 0.8
    formation_size: int = FORMATION_SIZE  # the SkyNet neighbourhood: UAVs of the same formation
    offsets: dict[int, tuple[float, float, float]] = field(
        default_factory=lambda: {i + 1: xyz(o) for i, o in enumerate(formation.DEFAULT_OFFSETS)})


class Unpublished:
    """Where a board's messages go between two sessions: counted, then dropped."""

    def __init__(self) -> None:
        self.dropped = 0

    def put(self, msg: Message) -> int:
        self.dropped += 1
        return 0


class Board:
    """The board's logic, bound to a bus and a driver; :meth:`tick` is one control-loop pass."""

    def __init__(self, bus: Bus, driver, clock, options: BoardOptions, camera=None, log=None, gate: Gate | None = None):
        self.driver, self.clock, self.opt, self.camera = driver, clock, options, camera
        # signed commands and heartbeats, bodies bound to keys (edge.trust); no verifier = --insecure
        self.gate = gate or Gate(bus.fleet, options.uav, None)
        self.log = log
        self.uav = options.uav
        self.lock = threading.RLock()
        self.neighbours: dict[int, Neighbour] = {}
        self.stale: set[int] = set()  # formation members whose state went stale (event sent)
        self.seq = 0
        self.last_heartbeat: float | None = None
        self._pilot_modes_seen = 0  # the driver's external_modes already reported
        self.failsafe = FailsafePolicy(options.failsafe)
        self.trajectory: Trajectory | None = None
        self.follower: Follower | None = None
        # only the formation's states: the cost per edge does not grow with the fleet
        self.neighbourhood = frozenset(neighbourhood_of(self.uav, options.formation_size))
        self._between = Unpublished()
        self.state_pub: Publisher | Unpublished
        self.event_pub: Publisher | Unpublished
        self.bind(bus)

    def detach(self) -> None:
        """Before the board's session closes: until :meth:`bind` gives it the next one, its states and events
        are counted (:attr:`dropped`) and dropped, never put on a closed session."""
        self.state_pub = self.event_pub = self._between

    @property
    def dropped(self) -> int:
        """States and events the board made between two sessions."""
        return self._between.dropped

    def bind(self, bus: Bus) -> None:
        """Declare the board's publishers, subscriptions, command queryable and liveliness token on ``bus``;
        again on a session the edge reopened (a narrower ACL), the board's state going on."""
        self.bus = bus
        fleet = bus.fleet
        self.state_pub = bus.publisher(keys.state(fleet, self.uav), TELEMETRY)
        self.event_pub = bus.publisher(keys.event(fleet, self.uav), COMMAND)
        for j in sorted(self.neighbourhood):
            bus.subscribe(keys.state(fleet, j), functools.partial(self._on_state, j), expect=VehicleState, link=TELEMETRY,
                          budget=for_topic("state"))
        bus.subscribe(keys.heartbeat(fleet), self._on_heartbeat, expect=(Heartbeat, Signed), link=COMMAND,
                      budget=for_topic("heartbeat"))
        bus.serve(keys.cmd(fleet, self.uav), self.handle_command, expect=(*COMMAND_TYPES, Signed))
        bus.token(keys.alive(fleet, self.uav))
        bus.watch_alive(keys.alive(fleet, "*"), self._on_alive)

    # -- inputs (Zenoh callback threads)
    def _on_state(self, uav: int, msg: Message, sample) -> None:
        """A state on UAV ``uav``'s key (one subscription per formation neighbour)."""
        assert isinstance(msg, VehicleState)
        if not self.gate.body_matches(uav, msg):
            self._refused("body.mismatch", f"a state saying UAV {msg.uav} on {sample.key_expr}")
            return
        if msg.uav in self.neighbourhood:
            rx = time.time()
            # a stamp from a clock ahead of ours reads as no transit time; one far behind makes the state
            # stale, so formation keeping falls back to the planned slot (hosts' clocks: GPS/NTP)
            self.neighbours[msg.uav] = Neighbour(msg.pos, msg.ref, msg.tau, rx, min(msg.stamp, rx))

    def _on_alive(self, key: str, alive: bool) -> None:
        uav = keys.parse(key).uav
        if uav not in self.neighbourhood:  # itself, or a UAV of another formation
            return
        if alive:
            self.event(EventKind.NEIGHBOUR_UP, f"UAV {uav} joined SkyNet", neighbour=uav)
        else:
            self.neighbours.pop(uav, None)
            self.stale.discard(uav)
            self.event(EventKind.NEIGHBOUR_LOST, f"UAV {uav} left SkyNet (liveliness lost)", Level.WARNING, neighbour=uav)

    def _on_heartbeat(self, msg: Message, sample) -> None:
        refused = self.gate.heartbeat(msg)
        if refused is not None:  # only a verified heartbeat resets the failsafe timer
            self._refused(f"heartbeat.{refused.reason.value}", f"heartbeat refused: {refused}")
            return
        self.last_heartbeat = time.time()

    def _refused(self, what: str, text: str) -> None:
        """A rate-limited ``trust-refused`` event (edge.trust counts every refusal)."""
        n = self.gate.report(what)
        if n:
            self.event(EventKind.TRUST_REFUSED, text, Level.WARNING, what=what, count=n)

    def event(self, kind: EventKind, text: str, level: Level = Level.INFO, **data) -> None:
        msg = Event(source=f"uav/{self.uav}", stamp=time.time(), kind=kind, level=level, text=text, data=data)
        try:
            self.event_pub.put(msg)
        except Exception as exc:  # a callback of a session closing under it (the edge reopening): dropped, counted
            self._between.dropped += 1
            logger.debug("event %s not sent: %s", kind, exc)
        if self.log:
            self.log.info("event %s: %s", kind, text)

    # -- commands
    def handle_command(self, cmd: Message) -> CommandAck:
        signed = isinstance(cmd, Signed)
        try:
            cmd = self.gate.command(cmd)  # before anything else
        except TrustError as exc:
            self._refused(f"command.{exc.reason.value}", f"command refused: {exc}")
            return CommandAck(uav=self.uav, cmd_id=command_id(cmd), accepted=False, reason=f"trust: {exc}")
        reason = validate_command(cmd, self.uav, self.opt.geofence, self.opt.max_speed)
        if reason:
            return self._ack(cmd, False, reason)
        try:
            with self.lock:
                self._apply(cmd, signed)
        except ValueError as exc:
            return self._ack(cmd, False, str(exc))
        return self._ack(cmd, True, "")

    def _ack(self, cmd, accepted: bool, reason: str) -> CommandAck:
        if not accepted:
            self.event(EventKind.COMMAND_REJECTED, f"{cmd.kind} #{cmd.cmd_id}: {reason}", Level.WARNING)
        return CommandAck(uav=self.uav, cmd_id=cmd.cmd_id, accepted=accepted, reason=reason)

    def _apply(self, cmd: Message, signed: bool = False) -> None:
        d = self.driver
        if isinstance(cmd, UploadTrajectory):
            fence = self.opt.geofence
            if cmd.geofence is not None and signed:  # a signed mission's fence narrows the board's, never widens it
                fence = narrowed_fence(self.opt.geofence, cmd.geofence)
            d.upload(cmd.trajectory)
            self.trajectory, self.follower = cmd.trajectory, Follower(cmd.trajectory)
            if fence is not self.opt.geofence:
                if fence is not None and self.opt.geofence is not None and fence != self.opt.geofence:
                    self.event(EventKind.GEOFENCE_NARROWED, f"geofence {tuple(fence.lo)}..{tuple(fence.hi)}")
                self.opt.geofence = fence  # never an unsigned uploader's
        elif isinstance(cmd, Takeoff):
            d.takeoff(cmd.altitude)
        elif isinstance(cmd, Start):
            t0 = None if cmd.t0_stamp is None else self.clock.sim_of(cmd.t0_stamp)
            d.start(t0)
        elif isinstance(cmd, Land):
            d.land()
        elif isinstance(cmd, Hold):
            d.hold()
        elif isinstance(cmd, Resume):
            now = time.time()
            refusal = self.failsafe.may_resume(now, self.last_heartbeat)
            if refusal:
                raise ValueError(refusal)
            if self.failsafe.active:
                # the "failsafe" event may have been lost with the link that caused it: this one
                # says again when it began, for the report's failsafe -> resume time
                since = self.failsafe.resumed() or now
                self.event(EventKind.FAILSAFE_CLEARED, f"resumed by command after {now - since:.1f} s of failsafe",
                           since=round(since, 3), held_s=round(now - since, 3))
            d.resume()
        elif isinstance(cmd, ReturnToLaunch):
            d.return_to_launch()
        elif isinstance(cmd, SetFormation):
            self.opt.offsets = {int(k): xyz(v) for k, v in cmd.offsets.items()}

    # -- the control loop
    def tick(self) -> VehicleState:
        now_wall = time.time()
        with self.lock:
            captures = self.driver.step(self.clock.now())
            st = self.driver.state()
            plan: dict = self._keep_formation(st, now_wall) if st.mode == Mode.MISSION and self.follower else {}
            self._check_failsafe(st, now_wall)
        for ev in captures:
            if self.camera is not None:
                self.camera.capture(ev, now_wall)
        self._report_pilot_modes()
        fresh = self._watch_staleness(now_wall)
        readiness = getattr(self.driver, "readiness", None)  # an autopilot's readiness (MAVLink drivers)
        if readiness is not None:
            plan = {**plan, "autopilot": readiness()}
        msg = st.to_message(self.uav, self.seq, now_wall).model_copy(update={"neighbours": fresh, **plan})
        if self.camera is not None:  # live preview: rate-limited, best-effort, encoded off this loop
            self.camera.preview(msg.pos, msg.att, msg.t, now_wall)
        self.seq += 1
        self.state_pub.put(msg)
        return msg

    def _report_pilot_modes(self) -> None:
        """An event for each autopilot mode the edge did not command (a pilot taking over, as in the paper;
        the MAVLink driver's ``external_modes``): the driver has stopped commanding until resumed."""
        modes = getattr(self.driver, "external_modes", None)
        if modes is None or len(modes) <= self._pilot_modes_seen:
            return
        for mode in list(modes[self._pilot_modes_seen:]):
            self.event(EventKind.PILOT_MODE, f"the autopilot is in {mode}, a mode the edge did not command: it stops "
                       "commanding until resumed", Level.WARNING, mode=mode)
        self._pilot_modes_seen = len(modes)

    def _watch_staleness(self, now_wall: float) -> int:
        """Events when a formation member's state goes stale or fresh again; the number of fresh ones."""
        fresh = 0
        for j, n in list(self.neighbours.items()):
            age = now_wall - n.stamp
            if age <= self.opt.stale_s:
                fresh += 1
                if j in self.stale:
                    self.stale.discard(j)
                    self.event(EventKind.NEIGHBOUR_FRESH, f"UAV {j}'s state heard again over SkyNet", neighbour=j)
            elif j not in self.stale and j in self.opt.offsets:
                self.stale.add(j)
                self.event(EventKind.NEIGHBOUR_STALE, f"UAV {j}'s state is {age:.1f} s old: formation keeping without it",
                           Level.WARNING, neighbour=j, age_s=round(age, 3))
        return fresh

    def _keep_formation(self, st, now_wall: float) -> dict:
        """Correct the own reference from the errors the neighbours share (P8, see
        :func:`edge.geometry.formation.neighbour_correction`); returns the own plan to share."""
        if st.wp_index < 0:  # still flying to the first waypoint or waiting there: nothing to keep
            self.driver.set_reference_offset((0.0, 0.0, 0.0))
            return {}
        fol = self.follower
        if fol is None:
            return {}
        tau = fol.t0 + st.progress * fol.duration
        pos, vel, _, _ = fol.reference(tau)
        members = self.opt.offsets  # the formation set by SetFormation (P9): other UAVs do not count
        # the age from publication, link delay included: the neighbour's tau is that old (P8 correction)
        neigh = {j: (n.pos, n.ref, n.tau, now_wall - n.sent) for j, n in list(self.neighbours.items())
                 if n.ref is not None and n.tau is not None and j in members}
        corr = formation.neighbour_correction(tau, vel, neigh, stale_after_s=self.opt.stale_s,
                                              gain=self.opt.formation_gain, clock_rate=self.clock.speed)
        self.driver.set_reference_offset(tuple(map(float, corr)))
        return {"ref": tuple(map(float, pos)), "tau": max(0.0, float(tau))}

    def _check_failsafe(self, st, now_wall: float) -> None:
        """Apply the failsafe policy's decision (or the retry of a failed one): a vehicle that does not take
        the action is never reported as having taken it (:meth:`edge.failsafe.FailsafePolicy.failed`)."""
        flying = st.armed and st.mode in (Mode.TAKEOFF, Mode.HOLD, Mode.MISSION)
        decision = self.failsafe.step(now_wall, self.last_heartbeat, flying, st.battery,
                                      returning=st.armed and st.mode == Mode.RTL)
        if decision is None:
            decision = self.failsafe.retry(now_wall, airborne=st.armed and st.mode != Mode.LANDED)
        if decision is None:
            return
        data: dict = {"action": decision.action, "reason": decision.reason, "battery": round(float(st.battery), 3)}
        if self.last_heartbeat is not None:
            data["silent_s"] = round(now_wall - self.last_heartbeat, 3)
        try:
            {"hold": self.driver.hold, "land": self.driver.land, "rtl": self.driver.return_to_launch}[decision.action]()
        except Exception as exc:  # a refusal or a lost vehicle link (VehicleLinkError is a ValueError)
            error = (str(exc) or type(exc).__name__)[:200]
            failure = self.failsafe.failed(decision.action, error, now_wall)
            (logger.warning if isinstance(exc, ValueError) else logger.exception)(
                "uav %d failsafe %s: %s", self.uav, decision.kind, failure.text)
            self.event(decision.kind, f"{decision.text}; {failure.text}", Level.ERROR, **data, ok=False,
                       failed=decision.action, error=error, next_action=failure.next_action,
                       attempts=failure.attempts)
            return
        retries = self.failsafe.done()
        if retries:
            data["attempts"] = retries + 1
        self.event(decision.kind, decision.text, Level.WARNING, **data, ok=True)


def yield_cpu(n: int) -> tuple[int, int | None]:
    """Lower this process's CPU priority by ``n``: its nice value (``nice(2)``) and, where the kernel groups
    the processes of a session for scheduling (``CONFIG_SCHED_AUTOGROUP``, ``sched(7)`` "The autogroup
    feature"), its autogroup's nice too: there a process's nice only orders it against its own session,
    and the launcher starts every service in a session of its own, so without the autogroup's value the
    edges would still share the CPU equally with the services. The autogroup is the whole session's, so it
    is set only when this process leads its session (as the launcher starts it), never for a shell that
    ran ``skynet edge --nice``. Returns (nice, autogroup nice, or None where it was left alone or there
    are no autogroups)."""
    nice = os.nice(n)
    if os.getsid(0) != os.getpid():
        return nice, None
    try:
        with open("/proc/self/autogroup", "w") as f:
            f.write(str(n))
        with open("/proc/self/autogroup") as f:
            group = int(f.read().split("nice")[1])
    except (OSError, ValueError, IndexError):
        group = None
    return nice, group


def build_parser() -> argparse.ArgumentParser:
    """``skynet edge``'s command line: the options of :class:`edge.config.EdgeConfig`."""
    from protocol.cliconfig import add_options

    from .config import EdgeConfig

    return add_options(argparse.ArgumentParser(prog="skynet edge", description=__doc__.split("\n\n")[0]), EdgeConfig)


def main(argv: list[str] | None = None) -> int:
    """``skynet edge``: parse the command line, then :func:`run` the board."""
    from protocol.cliconfig import from_namespace

    from .config import EdgeConfig

    parser = build_parser()
    return run(from_namespace(EdgeConfig, parser.parse_args(argv), parser))


def run(config: EdgeConfig) -> int:
    """One UAV's board from its configuration, until SIGINT/SIGTERM. With a key set, the board's session is
    reopened when the certificates it admits change beside it (``skynet keys revoke``), so that a revoked
    node's sessions at this edge's listener end; the board keeps ticking meanwhile (docs/security.md)."""
    log = setup_logging(f"uav{config.uav}")
    if config.nice:
        yield_cpu(config.nice)
    from .camera_service import make_camera
    from .clock import SimClock
    from .trust import secure_setup
    from .vehicle.factory import make_driver

    clock = SimClock(epoch=config.epoch if config.epoch is not None else time.time(), speed=config.speed)
    driver = make_driver(config, t0=clock.now())
    stop = stop_event_on_signals()
    opts = BoardOptions(uav=config.uav, rate_hz=config.rate, stale_s=config.stale, failsafe=config.failsafe(),
                        geofence=config.geofence, formation_gain=config.formation_gain,
                        formation_size=config.formation_size)
    gate, admission = secure_setup(config, log)
    watch = admission.watch if admission is not None else None
    if watch is not None:  # a change is logged where it is taken (below)
        log.info("mutual TLS as uav%d, ACL by certificate for %s", config.uav, ", ".join(watch.current))

    def open_bus() -> Bus:
        acl = admission.access_control() if admission is not None else None
        return Bus(config_from_args(config, role=f"uav{config.uav}", access_control=acl), fleet=config.fleet,
                   name=f"uav{config.uav}")

    loop = ControlLoop(config.rate, stop, log)
    board: Board | None = None
    camera = None
    try:
        bus: Bus | None = open_bus()  # the first session: a failure ends the edge with its reason
        while bus is not None:
            with bus:
                if board is None:
                    camera = make_camera(config, bus, log)
                    board = Board(bus, driver, clock, opts, camera=camera, log=log, gate=gate)
                    log.info("board up: uav %d, %s driver, camera %s, speed x%g", config.uav, config.vehicle,
                             config.camera, config.speed)
                    notify_ready("edge", f"uav{config.uav}")
                else:
                    board.bind(bus)
                    if camera is not None:
                        camera.attach(bus)
                changed = loop.run(board, watch)
                if changed is None:
                    log.info("shutting down")
                    if camera is not None:
                        camera.close()
                        camera = None
                    break
                log.warning("key set changed (admitted now: %s); reopening the session so that a revoked "
                            "node's sessions end", ", ".join(changed) or "none")
                board.detach()  # before the session closes: what the board says meanwhile is counted, dropped
                if camera is not None:
                    camera.detach()
            dropped = board.dropped
            bus = loop.reopen(board, open_bus)
            if bus is not None:
                log.info("session reopened: %d states and events made between the two sessions were dropped",
                         board.dropped - dropped)
    finally:
        if camera is not None:
            camera.close()
        driver.close()
    return 0


class ControlLoop:
    """The board's ticks at ``rate`` Hz until ``stop``, until the key set's admitted certificates change, or while
    its next session opens."""

    #: seconds between attempts to reopen a session that did not open
    RETRY_S = 0.5

    def __init__(self, rate: float, stop: threading.Event, log: logging.Logger):
        self.period, self.stop, self.log = 1.0 / rate, stop, log
        self.tick_errors = 0

    def run(self, board: Board, watch=None, until: Callable[[], bool] | None = None) -> list[str] | None:
        """Tick until stopped or ``until()`` (None), or until ``watch`` (:class:`protocol.keyset.AdmissionWatch`)
        takes a change (the names admitted now)."""
        next_t = time.monotonic()
        while not self.stop.is_set() and not (until is not None and until()):
            try:
                board.tick()
            except Exception:  # nothing a neighbour or the link sends may end the board: counted, logged once
                self.tick_errors += 1
                if self.tick_errors == 1:
                    self.log.exception("board tick failed (further failures are only counted)")
            if watch is not None:
                changed = watch()
                if changed is not None:
                    return changed
            next_t += self.period
            delay = next_t - time.monotonic()
            if delay < -1.0:  # fell far behind (suspended?): do not try to catch up in a burst
                next_t = time.monotonic()
            self.stop.wait(max(0.0, delay))
        return None

    def reopen(self, board: Board, open_bus: Callable[[], Bus]) -> Bus | None:
        """The next session, opened on a thread while the board keeps ticking (vehicle, failsafe checks,
        captures), and tried again every :data:`RETRY_S` until it opens: without a session no heartbeat
        arrives, so the link failsafe decides what the vehicle does. None when stopped meanwhile."""
        failures = 0
        while not self.stop.is_set():
            pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="reopen")
            opening = pool.submit(open_bus)
            pool.shutdown(wait=False)
            self.run(board, until=opening.done)
            if self.stop.is_set():
                opening.add_done_callback(_close_opened)
                return None
            try:
                bus = opening.result()
            except Exception as exc:  # the old listener not released yet, a key set mid-edit, ...
                failures += 1
                if failures == 1:
                    self.log.warning("session did not reopen (%s); trying again every %g s, the board flying on",
                                     str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__,
                                     self.RETRY_S)
                deadline = time.monotonic() + self.RETRY_S
                self.run(board, until=lambda: time.monotonic() >= deadline)
                continue
            if failures:
                self.log.info("session reopened after %d failed attempt(s)", failures)
            return bus
        return None


def _close_opened(opening: Future) -> None:
    """A session that opened after the edge was told to stop."""
    if opening.exception() is None:
        opening.result().close()


if __name__ == "__main__":
    raise SystemExit(main())
