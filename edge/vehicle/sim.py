"""The built-in simulated vehicle: quadrotor plant + PID position loop + ATSM attitude loop.

Design notes: docs/edge.md (edge/vehicle/sim.py).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from edge.vehicle.angles import wrap_angle
from edge.vehicle.atsm import ATSM, ATSMGains, TwistingController
from edge.vehicle.driver import CaptureEvent, DriverState, VehicleDriver, check_vec3
from edge.vehicle.follower import Reference
from edge.vehicle.pid import PIDGains, PositionPID
from edge.vehicle.quadrotor import DisturbanceParams, QuadParams, Quadrotor, euler_rates_from_body_rates
from edge.vehicle.sequencer import ZERO, MissionSequencer, Mover
from protocol.messages import Mode, Trajectory

__all__ = ["SimParams", "SimDriver"]

Vec3 = tuple[float, float, float]

_GROUNDED = (Mode.IDLE, Mode.LANDED)
#: longest flight one step() call may simulate, s (guards against a clock/driver time mismatch)
MAX_STEP_S = 3600.0
_AIRBORNE = (Mode.TAKEOFF, Mode.HOLD, Mode.MISSION, Mode.LAND, Mode.RTL)


@dataclass(frozen=True)
class SimParams:
    """Everything that configures a simulated vehicle: plant (3DR Solo class), disturbance (default none),
    PID and ATSM gains, ``controller`` ("atsm" (P13)-(P17) or "twisting"), ``model_mismatch`` (the
    controllers' mass and inertia = plant × this), speeds (m/s), ``rtl_altitude`` above launch, the
    sequencer's radii and offset bounds (:class:`edge.vehicle.sequencer.MissionSequencer`),
    ``endurance_s`` (hover time on a full battery; drain ∝ thrust / hover thrust) and ``interpolation``."""

    quad: QuadParams = field(default_factory=QuadParams)
    disturbance: DisturbanceParams = field(default_factory=DisturbanceParams)
    pid: PIDGains = field(default_factory=PIDGains)
    atsm: ATSMGains = field(default_factory=ATSMGains)
    controller: Literal["atsm", "twisting"] = "atsm"
    model_mismatch: float = 1.0
    takeoff_speed: float = 1.5
    land_speed: float = 0.7
    transit_speed: float = 4.0
    rtl_altitude: float = 10.0
    start_radius: float = 1.0
    arrive_radius: float = 0.3
    max_offset: float = 3.0
    offset_rate: float = 1.0
    endurance_s: float = 1200.0
    interpolation: Literal["cubic", "linear"] = "cubic"

    def __post_init__(self) -> None:
        if self.controller not in ("atsm", "twisting"):
            raise ValueError("controller must be 'atsm' or 'twisting'")
        for k in ("model_mismatch", "takeoff_speed", "land_speed", "transit_speed", "rtl_altitude",
                  "start_radius", "arrive_radius", "offset_rate", "endurance_s"):
            v = getattr(self, k)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{k} must be finite and > 0")
        if not (math.isfinite(self.max_offset) and self.max_offset >= 0):
            raise ValueError("max_offset must be finite and >= 0")


class SimDriver(VehicleDriver):
    """A simulated UAV behind the driver interface: launch point ``home`` (ENU m, z the ground), physics
    and control at ``physics_hz`` (>= 100), disturbance seeded by ``seed``, clock ``t0`` and heading ``yaw``."""

    def __init__(self, uav: int, params: SimParams = SimParams(), seed: int = 0, home: Vec3 = (0.0, 0.0, 0.0),
                 physics_hz: int = 200, t0: float = 0.0, yaw: float = 0.0):
        if not (isinstance(uav, int) and 1 <= uav <= 255):
            raise ValueError("uav must be an int in 1..255")
        if not (isinstance(physics_hz, int) and 100 <= physics_hz <= 10000):
            raise ValueError("physics_hz must be an int in 100..10000")
        if not (math.isfinite(t0) and math.isfinite(yaw)):
            raise ValueError("t0 and yaw must be finite")
        self.uav = uav
        self.params = params
        self.home = check_vec3(home, "home")
        self.dt = 1.0 / physics_hz
        self._t_base = float(t0)
        self._k = 0
        P = params.quad
        self.quad = Quadrotor(P, self.dt, params.disturbance, np.random.default_rng(seed),
                              pos=self.home, yaw=yaw, ground_z=self.home[2])
        mm = params.model_mismatch
        self.pid = PositionPID(P.mass * mm, params.pid, self.dt, (P.drag_xy * mm, P.drag_z * mm), P.thrust_max)
        ctl = ATSM if params.controller == "atsm" else TwistingController
        self.attitude = ctl((P.ixx * mm, P.iyy * mm, P.izz * mm), params.atsm, self.dt)
        self.mode = Mode.IDLE
        self.armed = False
        self.battery = 1.0
        self._closed = False
        self._events: list[CaptureEvent] = []
        #: the trajectory, its start/pause/resume, the formation offset and the captures
        self.mission = MissionSequencer(
            uav, self.home[2], transit_speed=params.transit_speed, start_radius=params.start_radius,
            arrive_radius=params.arrive_radius, max_offset=params.max_offset, offset_rate=params.offset_rate,
            interpolation=params.interpolation)
        self._rtl_leg = ""  # RTL: "climb" -> "return" (then LAND)
        self._rtl_z = self.home[2] + params.rtl_altitude
        # takeoff / land / RTL reference: from a start point toward a target at constant speed
        self._mv = Mover(self.home, self.home, params.takeoff_speed, self.t)
        self._hold_pos: Vec3 = self.home
        self._yaw_ref = float(yaw)
        self._external: Callable[[float], Reference] | None = None
        self._hover_inv = 1.0 / P.hover_thrust
        self._drain = self.dt / params.endurance_s
        #: last reference position (for inspection/tests)
        self.ref_pos: Vec3 = self.home

    # ------------------------------------------------------------------ time
    @property
    def t(self) -> float:
        """Current simulation time, s."""
        return self._t_base + self._k * self.dt

    @property
    def _phase(self) -> str:
        """The mission's phase (:attr:`MissionSequencer.phase`: transit, wait, track, transit_resume)."""
        return self.mission.phase

    # ------------------------------------------------------------------ state
    def state(self) -> DriverState:
        q = self.quad.s
        wp, prog = self.mission.progress(self.t)
        return DriverState(t=self.t, pos=(q[0], q[1], q[2]), vel=(q[3], q[4], q[5]), att=(q[6], q[7], wrap_angle(q[8])),
                           rates=(q[9], q[10], q[11]), mode=self.mode, armed=self.armed, battery=self.battery,
                           wp_index=wp, progress=prog, captures=self.mission.captures)

    # ------------------------------------------------------------------ commands
    def _check_open(self) -> None:
        if self._closed:
            raise ValueError("driver is closed")

    def _require(self, allowed: tuple[Mode, ...], what: str) -> None:
        self._check_open()
        if self.mode not in allowed:
            names = ", ".join(m.value for m in allowed)
            raise ValueError(f"cannot {what} in mode {self.mode.value} (allowed in: {names})")

    def _go(self, target: Vec3, speed: float, start: Vec3) -> None:
        self._mv = Mover(start, target, speed, self.t)

    def _here(self) -> Vec3:
        s = self.quad.s
        return (s[0], s[1], s[2])

    def upload(self, traj: Trajectory) -> None:
        self._require((Mode.IDLE, Mode.LANDED, Mode.TAKEOFF, Mode.HOLD), "upload a trajectory")
        self.mission.load(traj, check=self._check_speeds)

    def _check_speeds(self, traj: Trajectory) -> None:
        """ValueError if a segment needs more than the position loop's speed limits."""
        G = self.params.pid
        wps = traj.waypoints
        for i, (a, b) in enumerate(zip(wps, wps[1:])):
            dt = b.t - a.t
            h = math.hypot(b.pos[0] - a.pos[0], b.pos[1] - a.pos[1]) / dt
            vz = (b.pos[2] - a.pos[2]) / dt
            if h > G.max_speed_xy or vz > G.max_speed_up or -vz > G.max_speed_down:
                raise ValueError(
                    f"segment {i}->{i + 1} needs {h:.1f} m/s horizontal, {vz:.1f} m/s vertical: "
                    f"beyond the limits {G.max_speed_xy}/{G.max_speed_up}/{G.max_speed_down} m/s"
                )

    def takeoff(self, altitude: float) -> None:
        self._require(_GROUNDED, "take off")
        altitude = float(altitude)
        if not (math.isfinite(altitude) and 0.5 <= altitude <= 500.0):
            raise ValueError("takeoff altitude must be in [0.5, 500] m")
        here = self._here()
        self.pid.reset()
        self.attitude.reset()
        self.armed = True
        self.mode = Mode.TAKEOFF
        self._external = None
        self._yaw_ref = self.quad.s[8]
        self.ref_pos = here
        self._go((here[0], here[1], self.home[2] + altitude), self.params.takeoff_speed, here)

    def start(self, t0: float | None = None) -> None:
        self._require((Mode.HOLD,), "start a mission")
        m = self.mission
        m.start(self.t, self._here(), t0, ref=self.ref_pos)  # the transit leaves from the hold reference
        self.mode = Mode.MISSION
        self._external = None
        self._yaw_ref = m.yaw

    def hold(self) -> None:
        self._require(_AIRBORNE, "hold")
        if self.mode == Mode.HOLD:
            return
        if self.mode == Mode.MISSION:
            self.mission.pause(self.t)
        self._hold_here()

    def _hold_here(self) -> None:
        self.mode = Mode.HOLD
        self._external = None
        self._hold_pos = self._here()
        self._yaw_ref = self.quad.s[8]
        self.ref_pos = self._hold_pos

    def resume(self) -> None:
        self._require((Mode.HOLD,), "resume")
        self.mission.resume(self.t, self._here(), self._yaw_ref)
        self.mode = Mode.MISSION
        self._external = None

    def land(self) -> None:
        self._require((Mode.TAKEOFF, Mode.HOLD, Mode.MISSION, Mode.RTL, Mode.LAND), "land")
        if self.mode == Mode.LAND:
            return
        self._start_landing()

    def _start_landing(self) -> None:
        self.mode = Mode.LAND
        self._external = None
        self.mission.cancel()
        here = self._here()
        start = (here[0], here[1], self.ref_pos[2] if self.ref_pos[2] < here[2] else here[2])
        self._go((here[0], here[1], self.home[2] - 2.0), self.params.land_speed, start)

    def return_to_launch(self, altitude: float | None = None) -> None:
        """Climb to ``max(here, altitude)`` above launch (default ``rtl_altitude``), fly home, land."""
        self._require(_AIRBORNE, "return to launch")
        if self.mode == Mode.RTL:
            return
        if altitude is not None and not (math.isfinite(altitude) and altitude >= 0):
            raise ValueError(f"return altitude must be finite and >= 0 m, got {altitude!r}")
        self.mode = Mode.RTL
        self._external = None
        self.mission.cancel()
        here = self._here()
        self._rtl_z = max(here[2], self.home[2] + (self.params.rtl_altitude if altitude is None else altitude))
        self._rtl_leg = "climb"
        self._yaw_ref = self.quad.s[8]
        self._go((here[0], here[1], self._rtl_z), self.params.takeoff_speed, here)

    def set_reference_offset(self, offset: Vec3) -> None:
        self._check_open()
        self.mission.set_offset(offset)

    def set_external_reference(self, source: Callable[[float], Reference] | None) -> None:
        """While in HOLD, fly ``source(t)`` (position, velocity, acceleration, yaw) instead of the held point.

        The hook for a guided target from outside (:mod:`edge.vehicle.mavsim` follows MAVLink
        position targets with it). None goes back to the held point; every command that changes
        the mode (takeoff, start, resume, hold from another mode, land, return to launch) drops it.
        """
        self._check_open()
        if source is not None and not callable(source):
            raise ValueError("the external reference must be callable (t -> (pos, vel, acc, yaw)) or None")
        self._external = source

    def close(self) -> None:
        self._closed = True

    # ------------------------------------------------------------------ simulation
    def step(self, until_t: float) -> list[CaptureEvent]:
        self._check_open()
        until_t = float(until_t)
        if not math.isfinite(until_t):
            raise ValueError("until_t must be finite")
        n = int(math.floor((until_t - self._t_base) / self.dt + 1e-9)) - self._k
        self._events = []
        if n <= 0:
            return []
        if self.mode in _GROUNDED:
            self._k += n  # at rest on the ground: nothing moves
            return []
        if n * self.dt > MAX_STEP_S:
            raise ValueError(
                f"step of {n * self.dt:.0f} s of flight in one call exceeds {MAX_STEP_S:.0f} s "
                f"(sim time is {self.t:.3f} s: was the driver created with the clock's t0?)"
            )
        self._run(n)
        return self._events

    def _reference(self, t: float) -> Reference:
        """Position, velocity, acceleration and yaw references for the current mode at time t."""
        mode = self.mode
        if mode == Mode.HOLD:
            ext = self._external
            if ext is not None:
                return ext(t)
            return self._hold_pos, ZERO, ZERO, self._yaw_ref
        if mode == Mode.MISSION:
            m = self.mission
            q = self.quad.s
            r = m.reference(t, (q[0], q[1], q[2]), self.dt)
            if m.done:
                self._finish_mission(r)
            return r
        if mode == Mode.TAKEOFF:
            p, v, done = self._mv.at(t)
            if done and abs(self.quad.s[2] - p[2]) < 0.15 and abs(self.quad.s[5]) < 0.3:
                self.mode = Mode.HOLD
                self._hold_pos = p
                return p, ZERO, ZERO, self._yaw_ref
            return p, v, ZERO, self._yaw_ref
        if mode == Mode.LAND:
            p, v, _ = self._mv.at(t)
            return p, v, ZERO, self._yaw_ref
        if mode == Mode.RTL:
            p, v, done = self._mv.at(t)
            if done and math.dist(self._here(), p) < max(self.params.arrive_radius, 0.5):
                if self._rtl_leg == "climb":
                    self._rtl_leg = "return"
                    self._go((self.home[0], self.home[1], self._rtl_z), self.params.transit_speed, p)
                else:
                    self._start_landing()
                return self._reference(t)
            return p, v, ZERO, self._yaw_ref
        return self._here(), ZERO, ZERO, self._yaw_ref

    def _finish_mission(self, end: Reference) -> None:
        """The trajectory ended: fire what is left at the end, hold at the end point (+ offset)."""
        due = self.mission.due(self.t)  # a capture exactly at the end not yet fired (rounding)
        if due:
            self._fire(due, self.t)
        self.mode = Mode.HOLD
        self._hold_pos = end[0]
        self._yaw_ref = end[3]

    def _run(self, n: int) -> None:
        quad, pid, att_ctl, mission = self.quad, self.pid, self.attitude, self.mission
        dt = self.dt
        hover_inv, drain = self._hover_inv, self._drain
        for i in range(n):
            t = self._t_base + self._k * dt
            p_ref, v_ref, a_ref, yaw_ref = self._reference(t)
            self.ref_pos = p_ref
            s = quad.s
            att = (s[6], s[7], s[8])
            rates = (s[9], s[10], s[11])
            roll_d, pitch_d, yaw_d, thrust = pid.update((s[0], s[1], s[2]), (s[3], s[4], s[5]), att,
                                                        p_ref, v_ref, a_ref, yaw_ref)
            u = att_ctl.update(att, euler_rates_from_body_rates(att, rates), rates, (roll_d, pitch_d, yaw_d))
            quad.step(thrust, u[0], u[1], u[2])
            self._k += 1
            self.battery = max(0.0, self.battery - quad.thrust * hover_inv * drain)
            mode = self.mode
            if mode == Mode.LAND and quad.on_ground:
                self.mode = Mode.LANDED
                self.armed = False
                quad.rest_on_ground()
                self.ref_pos = self._here()
                self._k += n - 1 - i  # the rest of this call needs no physics
                return
            if mode == Mode.MISSION:
                due = mission.due(t + dt)
                if due:
                    self._fire(due, t + dt)

    def _fire(self, due: list, t: float) -> None:
        s = self.quad.s
        for w in due:
            self._events.append(CaptureEvent(w.capture_id, t, (s[0], s[1], s[2]), (s[6], s[7], wrap_angle(s[8]))))
