"""AUTO flight (``MavlinkParams(flight="auto")``, ``skynet edge --flight auto``): the paper's way.

Design notes: docs/hardware-mavlink.md (edge/vehicle/mavlink/auto.py).
"""

from __future__ import annotations

import logging
import math
import time
from concurrent.futures import CancelledError, ThreadPoolExecutor
from typing import TYPE_CHECKING, Any

from pymavlink.dialects.v20 import ardupilotmega as M

from edge.geometry import ardupilot_items as AI
from edge.vehicle.auto_flight import AutoMissionPlan, autopilot_mission, resume_item, speed_correction
from edge.vehicle.px4.missions import without_home
from protocol.messages import Trajectory

from .commands import CommandRefused, VehicleLinkError, await_reply
from .guided import Target
from .phase import Phase
from .progress import MissionProgress, autopilot_window, bounded

if TYPE_CHECKING:
    from .driver import MavlinkDriver

__all__ = ["AutoFlight"]

log = logging.getLogger("skynet.mavlink")


class AutoFlight:
    """The AUTO strategy of one driver (its lock guards ``switching``, ``pending`` and the end state)."""

    def __init__(self, drv: MavlinkDriver):
        self.drv = drv
        self.plan: AutoMissionPlan | None = None
        self._traj: Trajectory | None = None
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"mavlink-uav{drv.uav}-auto")
        self.switching = False
        self.pending: set[int] = set()  # autopilot modes accepted while a mode switch is in flight
        self._end_switch = False  # the AUTO mission ended: back to GUIDED to hold there
        self._end_mono = 0.0  # when the trajectory's clock ran out in AUTO
        self._speed_sent: tuple[float, float] | None = None  # (speed, monotonic) of the last DO_CHANGE_SPEED
        self._fractions: tuple[float, ...] = ()  # per trajectory waypoint: its fraction of the duration
        self.from_seq: int | None = None  # the item AUTO was last entered at (None: not flown since the start)
        #: per capture point of the trajectory: (capture id, ENU position, the NAV item it follows); fired ids
        self._captures: tuple[tuple[int, tuple[float, float, float], int], ...] = ()
        self._fired: set[int] = set()
        self._progress_seen: tuple[int, int, float] = (-1, -1, 0.0)  # (current, reached, monotonic of change)
        #: DO_CHANGE_SPEED corrections sent; mode switches to AUTO that failed (with why)
        self.speed_commands = 0
        self.errors: list[str] = []

    # ------------------------------------------------------------------ upload (on the worker, the caller waits)
    def prepare(self, traj: Trajectory | None) -> None:
        """Upload the trajectory as a waypoint mission unless the autopilot already has it."""
        if traj is None:
            raise ValueError("no trajectory uploaded")
        self.from_seq = None
        if self._traj is traj and self.plan is not None:
            return
        try:
            self._worker.submit(self._upload_plan, traj).result()
        except (CancelledError, RuntimeError) as exc:  # the driver was closed meanwhile
            raise ValueError("driver is closed") from exc

    def _upload_plan(self, traj: Trajectory) -> None:
        drv = self.drv
        plan = autopilot_mission(traj, drv.home, self._wait_home())
        if not drv.dialect.home_item:
            plan = without_home(plan)  # PX4: item 0 is the first real item
        with drv.tel.lock:
            drv.tel.mission_total = -1
        self._upload(plan.items)
        if not drv.dialect.home_item:
            self._await_mission_total(len(plan.items))
        self._default_speed(plan.items)
        times = [w.t for w in traj.waypoints]
        span = times[-1] - times[0]
        with drv.tel.lock:
            drv.tel.reached_seq = drv.tel.current_seq = -1
            drv.tel.mission_count = len(plan.items)
            self._fractions = tuple((t - times[0]) / span if span > 0 else 1.0 for t in times)
            self._captures = _capture_points(traj, plan)
            self._fired = set()
        self.plan, self._traj = plan, traj
        log.info("UAV %d: trajectory uploaded to the autopilot as a mission of %d items (%d waypoints, %d captures)",
                 drv.uav, len(plan.items), len(set(plan.waypoint_seq)), len(plan.capture_seq))

    def _await_mission_total(self, n: int, timeout_s: float = 3.0) -> None:
        """PX4 may refuse or ignore a mission started right after its upload: wait until MISSION_CURRENT reports
        the new mission (``total`` == its item count), at most ``timeout_s`` (then a warning)."""
        tel = self.drv.tel
        deadline = time.monotonic() + timeout_s
        with tel.cv:
            while tel.mission_total != n:
                left = deadline - time.monotonic()
                if left <= 0:
                    log.warning("UAV %d: MISSION_CURRENT does not report the %d uploaded items yet (total %d)",
                                self.drv.uav, n, tel.mission_total)
                    return
                tel.cv.wait(min(left, 0.1))

    def _wait_home(self, timeout_s: float = 5.0) -> tuple[float, float, float]:
        """The autopilot's HOME_POSITION (asked for with MAV_CMD_REQUEST_MESSAGE until it comes)."""
        tel = self.drv.tel
        ask = M.MAVLink_command_long_message(tel.sysid, tel.compid, M.MAV_CMD_REQUEST_MESSAGE, 0,
                                             M.MAVLINK_MSG_ID_HOME_POSITION, 0, 0, 0, 0, 0, 0)
        home = await_reply(tel.cv, lambda _: self.drv.link.send(ask), lambda: tel.home_lla, 1.0, int(timeout_s) - 1)
        if home is None:
            raise VehicleLinkError(f"no HOME_POSITION from the autopilot in {timeout_s:g} s")
        return home

    def _upload(self, items: tuple, timeout_s: float = 1.0, retries: int = 5) -> None:
        """The MAVLink mission protocol's upload (https://mavlink.io/en/services/mission.html):
        MISSION_COUNT, then MISSION_ITEM_INT for each MISSION_REQUEST(_INT), until MISSION_ACK."""
        drv, tel, n = self.drv, self.drv.tel, len(items)
        count = M.MAVLink_mission_count_message(tel.sysid, tel.compid, n, M.MAV_MISSION_TYPE_MISSION)
        with drv.commands.lock:
            with tel.cv:
                tel.mission_rx.clear()
            drv.link.send(count)
            tries, deadline = 0, time.monotonic() + timeout_s
            while True:
                with tel.cv:
                    while not tel.mission_rx and time.monotonic() < deadline:
                        tel.cv.wait(max(0.0, deadline - time.monotonic()))
                    msg = tel.mission_rx.popleft() if tel.mission_rx else None
                if msg is None:
                    tries += 1
                    if tries > retries:
                        raise VehicleLinkError(f"mission upload: no answer from the autopilot after {tries} tries")
                    drv.link.send(count)
                    deadline = time.monotonic() + timeout_s
                    continue
                if msg.get_type() == "MISSION_ACK":
                    if msg.type != M.MAV_MISSION_ACCEPTED:
                        e = M.enums["MAV_MISSION_RESULT"].get(int(msg.type))
                        raise ValueError(f"mission upload refused by the autopilot: {e.name if e else msg.type}")
                    return
                seq = int(msg.seq)
                if 0 <= seq < n:
                    it = items[seq]
                    drv.link.send(M.MAVLink_mission_item_int_message(
                        tel.sysid, tel.compid, seq, it.frame, it.command, int(seq == 0), 1, it.param1, it.param2,
                        it.param3, it.param4, it.x, it.y, it.z, M.MAV_MISSION_TYPE_MISSION))
                deadline = time.monotonic() + timeout_s

    def _default_speed(self, items: tuple) -> None:
        """Make the plan's first leg speed the autopilot's waypoint speed too: ArduCopter starts (and re-enters)
        AUTO at WPNAV_SPEED / WP_SPD until the next DO_CHANGE_SPEED item. Best effort: a warning if refused."""
        drv = self.drv
        speed = next((it.param2 for it in items if it.command == AI.MAV_CMD_DO_CHANGE_SPEED
                      and math.isfinite(it.param2) and it.param2 > 0), None)
        if speed is None:
            return
        try:
            got = drv.set_waypoint_speed(min(float(speed), 20.0))
        except ValueError as exc:
            log.warning("UAV %d: the autopilot's waypoint speed was not set: %s", drv.uav, exc)
            return
        scheme = drv.param_scheme or drv.dialect.schemes[0]
        log.info("UAV %d: waypoint speed %.2f m/s set as %s (%s %s parameter names)", drv.uav, got,
                 drv.dialect.param_name("wp_speed", scheme), drv.dialect.name, drv.param_scheme)

    # ------------------------------------------------------------------ mode switches (under the driver's lock)
    def enter(self, t: float) -> None:
        """Tracking began in GUIDED: switch to AUTO from the item after the last waypoint passed."""
        if self.plan is not None and not self.switching:
            wp, _ = self.drv.mission.progress(t)
            self.switch(self.drv.dialect.auto, resume_item(self.plan, wp), Phase.MISSION)

    def ended(self) -> None:
        """The trajectory's clock ran out in AUTO: the autopilot flies on (the edge's mode stays MISSION) until it
        finished (:meth:`finished`); then the driver holds in the guided mode."""
        if not self._end_switch:
            self._end_switch, self._end_mono = True, time.monotonic()
            self.pending = {int(self.drv.dialect.auto)}

    def hold_tick(self) -> None:
        """In HOLD: the switch back to GUIDED once the AUTO mission finished."""
        if self._end_switch and not self.switching and self._finished():
            self._end_switch = False
            self.switch(self.drv.dialect.guided, None, Phase.HOLD)

    def finished(self) -> bool:
        """The autopilot reached the mission's last waypoint (its capture items ran), or its mission progress
        has not moved for ``auto_end_wait_s`` since the trajectory's clock ran out (it stopped short)."""
        return self._finished()

    def _finished(self) -> bool:
        plan, tel = self.plan, self.drv.tel
        last = max(plan.waypoint_seq) if plan is not None and plan.waypoint_seq else -1
        if tel.reached_seq >= last:
            return True
        now = time.monotonic()
        cur, reached, since = self._progress_seen
        if (tel.current_seq, tel.reached_seq) != (cur, reached):
            self._progress_seen = (tel.current_seq, tel.reached_seq, now)
            since = now
        return now - max(since, self._end_mono) > self.drv.params.auto_end_wait_s

    def switch(self, mode: int, seq: int | None, expect: Phase) -> None:
        """Queue DO_SET_MISSION_CURRENT (``seq``) and DO_SET_MODE ``mode`` on the worker while the driver stays
        in phase ``expect``; the guided and AUTO modes are both accepted meanwhile."""
        if self.switching:
            return
        self.switching = True
        self.pending = {int(self.drv.dialect.auto), int(self.drv.dialect.guided)}
        try:
            self._worker.submit(self._switch, mode, seq, expect)
        except RuntimeError:  # closed meanwhile
            self.switching, self.pending = False, set()

    def _switch(self, mode: int, seq: int | None, expect: Phase) -> None:
        drv = self.drv
        name = drv.dialect.mode_name(mode)
        try:
            with drv.commands.lock:
                with drv.tel.lock:
                    if drv.phase is not expect:
                        return  # a command (hold, land, ...) came first
                if seq is not None:
                    try:
                        drv.command(M.MAV_CMD_DO_SET_MISSION_CURRENT, (float(seq),), "set the mission item")
                    except CommandRefused as exc:  # before ArduPilot 4.4: the MISSION_SET_CURRENT message
                        if exc.result != M.MAV_RESULT_UNSUPPORTED:
                            raise
                        drv.link.send(M.MAVLink_mission_set_current_message(drv.tel.sysid, drv.tel.compid, seq))
                drv.set_mode(mode)
                with drv.tel.lock:
                    if drv.phase is expect and mode == drv.dialect.auto:
                        drv.phase = Phase.AUTO
                        self._speed_sent = None
                        self.from_seq = seq if seq is not None else max(0, drv.tel.current_seq)
                log.info("UAV %d: flying %s%s", drv.uav, name,
                         f" from mission item {seq}" if seq is not None else " (the AUTO mission ended: hold)")
        except ValueError as exc:
            self.errors.append(str(exc))  # AUTO refused: the mission goes on in GUIDED
            log.warning("UAV %d: mode switch to %s failed: %s", drv.uav, name, exc)
        finally:
            with drv.tel.lock:
                self.switching = False
                self.pending = set()

    # ------------------------------------------------------------------ progress (under the driver's lock)
    def progress(self) -> MissionProgress | None:
        """The autopilot's mission progress since AUTO was entered (None before, or without a plan). A
        MISSION_CURRENT older than the entry (below its item) does not count."""
        plan, tel = self.plan, self.drv.tel
        if plan is None or self.from_seq is None or len(self._fractions) != len(plan.waypoint_seq):
            return None
        current = max(tel.current_seq, self.from_seq)
        lo, hi = autopilot_window(plan.waypoint_seq, self._fractions, tel.reached_seq, current)
        return MissionProgress(current, tel.reached_seq, lo, hi)

    def follow(self, wp: int, progress: float) -> tuple[int, float]:
        """The edge's ``(wp_index, progress)`` from its clock's, kept where the autopilot's progress allows."""
        p = self.progress()
        return (wp, progress) if p is None else bounded(progress, (p.lo, p.hi), self._fractions)

    # ------------------------------------------------------------------ captures in AUTO (under the driver's lock)
    def captures_due(self, pos: tuple[float, float, float]) -> list[int]:
        """The capture ids to fire now: those whose capture point the vehicle is within ``capture_radius`` of, or
        whose waypoint the autopilot reported reached (MISSION_ITEM_REACHED), each once; not the edge's clock."""
        radius, reached = self.drv.params.capture_radius, self.drv.tel.reached_seq
        out = []
        for cid, p, nav in self._captures:
            if cid in self._fired:
                continue
            if reached >= nav or math.dist(pos, p) <= radius:
                self._fired.add(cid)
                out.append(cid)
        return out

    # ------------------------------------------------------------------ formation keeping in AUTO
    def speed_message(self, target: Target) -> Any | None:
        """One AUTO tick: the formation-keeping DO_CHANGE_SPEED to send (fire and forget), or None."""
        p, v, _, _ = target
        if v is None:
            return None
        speed = speed_correction(self.drv.tel.pos, p, v, gain=self.drv.params.auto_speed_gain)
        if speed is None:
            return None
        now, last = time.monotonic(), self._speed_sent
        if last is not None and now - last[1] < self.drv.params.auto_speed_period_s and abs(speed - last[0]) < 0.5:
            return None
        self._speed_sent = (speed, now)
        self.speed_commands += 1
        tel = self.drv.tel
        return M.MAVLink_command_long_message(tel.sysid, tel.compid, M.MAV_CMD_DO_CHANGE_SPEED, 0,
                                             *AI.speed_params(min(speed, 20.0)))

    def close(self) -> None:
        self._worker.shutdown(wait=False, cancel_futures=True)


def _capture_points(traj: Trajectory, plan: AutoMissionPlan) -> tuple[tuple[int, tuple[float, float, float], int], ...]:
    """(capture id, ENU point, the NAV_WAYPOINT item before its DO_DIGICAM_CONTROL) per capture waypoint."""
    out = []
    for i, w in enumerate(traj.waypoints):
        cid = getattr(w, "capture_id", None)
        if cid is None or cid not in plan.capture_seq:
            continue
        seq = plan.capture_seq[cid]
        nav = max((s for s in plan.waypoint_seq if s < seq), default=plan.waypoint_seq[min(i, len(plan.waypoint_seq) - 1)])
        out.append((int(cid), (float(w.pos[0]), float(w.pos[1]), float(w.pos[2])), nav))
    return tuple(out)
