"""The built-in simulated vehicle: quadrotor plant + PID position loop + ATSM attitude loop.

:class:`SimDriver` implements :class:`edge.vehicle.driver.VehicleDriver` on top of

- :class:`edge.vehicle.quadrotor.Quadrotor` — 6-DoF dynamics (P10)-(P12), RK4 at ``physics_hz``;
- :class:`edge.vehicle.pid.PositionPID` — the autopilot's position loop (PAPER.md Section 5);
- :class:`edge.vehicle.atsm.ATSM` — the attitude loop (P13)-(P17) (or the fixed-gain twisting
  baseline, ``SimParams.controller = "twisting"``);
- :class:`edge.vehicle.follower.Follower` — the uploaded trajectory (P9) and its capture points.

Control runs at the physics rate. Simulated time advances only in :meth:`SimDriver.step`, so the
same driver runs in real time (the board steps it to the shared clock, :mod:`edge.clock`) or as
fast as the CPU allows (tests, benchmarks).

Reference generation per mode (our choices; the paper leaves the autopilot's modes implicit):
TAKEOFF climbs vertically at ``takeoff_speed``; LAND descends at ``land_speed`` where the
vehicle is; HOLD holds the position where it was commanded; MISSION first flies straight to the
first waypoint at ``transit_speed`` when farther than ``start_radius`` from it, waits there for
the trajectory's start time, then tracks the trajectory (plus the bounded, rate-limited formation
offset); RTL climbs to ``max(altitude, rtl_altitude)`` above launch, flies above the launch point
and lands.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from edge.vehicle.atsm import ATSM, ATSMGains, TwistingController, wrap_angle
from edge.vehicle.driver import CaptureEvent, DriverState, VehicleDriver, check_vec3
from edge.vehicle.follower import Follower
from edge.vehicle.pid import PIDGains, PositionPID
from edge.vehicle.quadrotor import DisturbanceParams, Quadrotor, QuadParams, euler_rates_from_body_rates
from protocol.messages import Mode, Trajectory

__all__ = ["SimParams", "SimDriver"]

Vec3 = tuple[float, float, float]

_GROUNDED = (Mode.IDLE, Mode.LANDED)
#: longest flight one step() call may simulate, s (guards against a clock/driver time mismatch)
MAX_STEP_S = 3600.0
_AIRBORNE = (Mode.TAKEOFF, Mode.HOLD, Mode.MISSION, Mode.LAND, Mode.RTL)


@dataclass(frozen=True)
class SimParams:
    """Everything that configures a simulated vehicle.

    Attributes
    ----------
    quad : plant parameters (3DR Solo class).
    disturbance : torque disturbance and wind (default: none).
    pid, atsm : controller gains.
    controller : "atsm" (P13)-(P17) or "twisting" (fixed gain).
    model_mismatch : the controllers' model of mass and inertia = plant value × this factor.
    takeoff_speed, land_speed, transit_speed : m/s.
    rtl_altitude : minimum return altitude above launch, m.
    start_radius : ``start`` flies to the first waypoint first when farther than this, m.
    arrive_radius : a go-to target counts as reached within this distance, m.
    max_offset : bound on the formation offset's norm, m.
    offset_rate : the applied offset moves toward the commanded one at most this fast, m/s.
    endurance_s : hover time on a full battery, s (battery drains ∝ thrust / hover thrust).
    interpolation : trajectory interpolation, "cubic" or "linear".
    """

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
    """A simulated UAV behind the driver interface.

    Parameters
    ----------
    uav : int
        UAV id (trajectories for another id are refused).
    params : SimParams
    seed : int
        Seed of the disturbance generator (numpy.random.default_rng).
    home : (x, y, z)
        Launch point, ENU m; z is the ground height there.
    physics_hz : int
        Physics and control rate, Hz (>= 100).
    t0 : float
        Simulation time at construction, s.
    yaw : float
        Initial heading, rad.
    """

    def __init__(
        self,
        uav: int,
        params: SimParams = SimParams(),
        seed: int = 0,
        home: Vec3 = (0.0, 0.0, 0.0),
        physics_hz: int = 200,
        t0: float = 0.0,
        yaw: float = 0.0,
    ):
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
        self._follower: Follower | None = None
        self._events: list[CaptureEvent] = []
        self._captures = 0
        # mission bookkeeping
        self._phase = ""  # MISSION: "transit" -> "wait" -> "track"
        self._t_start = 0.0  # requested sim time of trajectory time 0
        self._origin = 0.0  # sim time of trajectory time 0 while tracking
        self._tau_paused: float | None = None  # trajectory time when paused by hold()
        self._paused_phase = ""
        self._resume_tau = 0.0
        self._mission_done = False
        self._rtl_z = self.home[2] + params.rtl_altitude
        # go-to "mover": reference moving from a start point toward a target at constant speed
        self._mv = (self.home, (0.0, 0.0, 0.0), 0.0, 0.0, 0.0)  # start, dir, length, t_start, speed
        self._hold_pos: Vec3 = self.home
        self._yaw_ref = float(yaw)
        # formation offset: commanded and applied (rate-limited)
        self._offset_cmd: Vec3 = (0.0, 0.0, 0.0)
        self._offset: Vec3 = (0.0, 0.0, 0.0)
        self._hover_inv = 1.0 / P.hover_thrust
        self._drain = self.dt / params.endurance_s
        #: last reference position (for inspection/tests)
        self.ref_pos: Vec3 = self.home

    # ------------------------------------------------------------------ time
    @property
    def t(self) -> float:
        """Current simulation time, s."""
        return self._t_base + self._k * self.dt

    # ------------------------------------------------------------------ state
    def _tau(self) -> float | None:
        """Trajectory time now (None when no mission has started)."""
        f = self._follower
        if f is None:
            return None
        if self._mission_done:
            return f.t_end
        if self._tau_paused is not None:
            return self._tau_paused + f.t0
        if self.mode == Mode.MISSION and self._phase == "track":
            return self.t - self._origin + f.t0
        return None

    def state(self) -> DriverState:
        q = self.quad.s
        tau = self._tau()
        f = self._follower
        if f is None or tau is None:
            wp, prog = -1, 0.0
        else:
            wp, prog = f.segment(tau), f.progress(tau)
        return DriverState(
            t=self.t, pos=(q[0], q[1], q[2]), vel=(q[3], q[4], q[5]),
            att=(q[6], q[7], wrap_angle(q[8])), rates=(q[9], q[10], q[11]),
            mode=self.mode, armed=self.armed, battery=self.battery,
            wp_index=wp, progress=prog, captures=self._captures,
        )

    # ------------------------------------------------------------------ commands
    def _check_open(self) -> None:
        if self._closed:
            raise ValueError("driver is closed")

    def _require(self, allowed: tuple[Mode, ...], what: str) -> None:
        self._check_open()
        if self.mode not in allowed:
            names = ", ".join(m.value for m in allowed)
            raise ValueError(f"cannot {what} in mode {self.mode.value} (allowed in: {names})")

    def _go(self, target: Vec3, speed: float, start: Vec3 | None = None) -> None:
        start = self.ref_pos if start is None else start
        d = (target[0] - start[0], target[1] - start[1], target[2] - start[2])
        n = math.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2)
        u = (d[0] / n, d[1] / n, d[2] / n) if n > 1e-12 else (0.0, 0.0, 0.0)
        self._mv = (start, u, n, self.t, speed)

    def _mover(self, t: float) -> tuple[Vec3, Vec3, bool]:
        start, u, n, ts, v = self._mv
        s = v * (t - ts)
        if s >= n:
            return (start[0] + u[0] * n, start[1] + u[1] * n, start[2] + u[2] * n), (0.0, 0.0, 0.0), True
        return (start[0] + u[0] * s, start[1] + u[1] * s, start[2] + u[2] * s), (u[0] * v, u[1] * v, u[2] * v), False

    def _here(self) -> Vec3:
        s = self.quad.s
        return (s[0], s[1], s[2])

    def upload(self, traj: Trajectory) -> None:
        self._require((Mode.IDLE, Mode.LANDED, Mode.TAKEOFF, Mode.HOLD), "upload a trajectory")
        if not isinstance(traj, Trajectory):
            raise ValueError("upload needs a protocol.messages.Trajectory")
        if traj.uav != self.uav:
            raise ValueError(f"trajectory is for UAV {traj.uav}, this is UAV {self.uav}")
        gz = self.home[2]
        for i, w in enumerate(traj.waypoints):
            if w.pos[2] < gz + 0.5:
                raise ValueError(f"waypoint {i} is below 0.5 m above the ground (z = {w.pos[2]:.2f} m)")
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
        self._follower = Follower(traj, self.params.interpolation)
        self._captures = 0
        self._mission_done = False
        self._tau_paused = None
        self._paused_phase = ""
        self._phase = ""

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
        self._yaw_ref = self.quad.s[8]
        self.ref_pos = here
        self._go((here[0], here[1], self.home[2] + altitude), self.params.takeoff_speed, here)

    def start(self, t0: float | None = None) -> None:
        self._require((Mode.HOLD,), "start a mission")
        if self._follower is None:
            raise ValueError("no trajectory uploaded")
        if t0 is not None and not math.isfinite(t0):
            raise ValueError("t0 must be finite")
        f = self._follower
        self._t_start = self.t if t0 is None else float(t0)
        self._tau_paused = None
        self._mission_done = False
        self.mode = Mode.MISSION
        here = self._here()
        first = f.start
        self._yaw_ref = f.reference(f.t0)[3]
        if math.dist(here, first) > self.params.start_radius:
            self._phase = "transit"
            self._go(first, self.params.transit_speed, self.ref_pos)
        else:
            self._begin_wait_or_track()

    def _begin_wait_or_track(self, t: float | None = None) -> None:
        """At the first waypoint: wait for the start time, or track from it.

        After a transit (``t`` given, the arrival time) the trajectory clock starts at the later
        of the requested start and the arrival; when started at the first waypoint, at the
        requested start even if that is in the past (the vehicle catches up).
        """
        now = self.t if t is None else t
        if now < self._t_start:
            self._phase = "wait"
        else:
            self._phase = "track"
            self._origin = self._t_start if t is None else now

    def hold(self) -> None:
        self._require(_AIRBORNE, "hold")
        if self.mode == Mode.HOLD:
            return
        if self.mode == Mode.MISSION:
            if self._phase == "track":
                self._tau_paused = self.t - self._origin
            elif self._phase == "transit_resume":  # paused again before getting back on track
                self._tau_paused = self._resume_tau
            self._paused_phase = self._phase
        elif self.mode in (Mode.LAND, Mode.RTL):
            self._tau_paused = None
        self._hold_here()

    def _hold_here(self) -> None:
        self.mode = Mode.HOLD
        self._hold_pos = self._here()
        self._yaw_ref = self.quad.s[8]
        self.ref_pos = self._hold_pos

    def resume(self) -> None:
        self._require((Mode.HOLD,), "resume")
        if self._follower is None or self._mission_done or self._paused_phase == "":
            raise ValueError("no paused mission to resume")
        f = self._follower
        self.mode = Mode.MISSION
        if self._tau_paused is not None:
            tau = self._tau_paused
            self._tau_paused = None
            # continue from the paused trajectory time: fly back to that point first if needed
            self._t_start = self.t - tau
            ref = f.reference(tau + f.t0)[0]
            if math.dist(self._here(), ref) > self.params.start_radius:
                self._phase = "transit_resume"
                self._resume_tau = tau
                self._go(ref, self.params.transit_speed, self._here())
            else:
                self._phase = "track"
                self._origin = self.t - tau
        else:
            self._phase = "transit"
            self._go(f.start, self.params.transit_speed, self._here())
        self._paused_phase = ""

    def land(self) -> None:
        self._require((Mode.TAKEOFF, Mode.HOLD, Mode.MISSION, Mode.RTL, Mode.LAND), "land")
        if self.mode == Mode.LAND:
            return
        self._start_landing()

    def _start_landing(self) -> None:
        self.mode = Mode.LAND
        self._tau_paused = None
        self._paused_phase = ""
        here = self._here()
        start = (here[0], here[1], self.ref_pos[2] if self.ref_pos[2] < here[2] else here[2])
        self._go((here[0], here[1], self.home[2] - 2.0), self.params.land_speed, start)

    def return_to_launch(self) -> None:
        self._require(_AIRBORNE, "return to launch")
        if self.mode == Mode.RTL:
            return
        self.mode = Mode.RTL
        self._tau_paused = None
        self._paused_phase = ""
        here = self._here()
        self._rtl_z = max(here[2], self.home[2] + self.params.rtl_altitude)
        self._phase = "rtl_climb"
        self._yaw_ref = self.quad.s[8]
        self._go((here[0], here[1], self._rtl_z), self.params.takeoff_speed, here)

    def set_reference_offset(self, offset: Vec3) -> None:
        self._check_open()
        o = check_vec3(offset, "offset")
        n = math.sqrt(o[0] ** 2 + o[1] ** 2 + o[2] ** 2)
        m = self.params.max_offset
        if n > m:
            o = (o[0] * m / n, o[1] * m / n, o[2] * m / n)
        self._offset_cmd = o

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

    def _reference(self, t: float) -> tuple[Vec3, Vec3, Vec3, float]:
        """Position, velocity, acceleration and yaw references for the current mode at time t."""
        zero = (0.0, 0.0, 0.0)
        mode = self.mode
        if mode == Mode.HOLD:
            return self._hold_pos, zero, zero, self._yaw_ref
        if mode == Mode.MISSION:
            phase = self._phase
            if phase == "track":
                f = self._follower
                tau = t - self._origin + f.t0
                if tau >= f.t_end:
                    self._finish_mission()
                    return self._hold_pos, zero, zero, self._yaw_ref
                p, v, a, yaw = f.reference(tau)
                o = self._rate_limit_offset()
                return (p[0] + o[0], p[1] + o[1], p[2] + o[2]), v, a, yaw
            if phase == "wait":
                f = self._follower
                if t >= self._t_start:
                    self._phase = "track"
                    self._origin = self._t_start
                    return self._reference(t)
                return f.start, zero, zero, self._yaw_ref
            # transit / transit_resume
            p, v, done = self._mover(t)
            if done and math.dist(self._here(), p) < self.params.arrive_radius:
                if phase == "transit":
                    self._begin_wait_or_track(t)
                else:
                    self._phase = "track"
                    self._origin = t - self._resume_tau
                return self._reference(t)
            return p, v, zero, self._yaw_ref
        if mode == Mode.TAKEOFF:
            p, v, done = self._mover(t)
            if done and abs(self.quad.s[2] - p[2]) < 0.15 and abs(self.quad.s[5]) < 0.3:
                self.mode = Mode.HOLD
                self._hold_pos = p
                return p, zero, zero, self._yaw_ref
            return p, v, zero, self._yaw_ref
        if mode == Mode.LAND:
            p, v, _ = self._mover(t)
            return p, v, zero, self._yaw_ref
        if mode == Mode.RTL:
            p, v, done = self._mover(t)
            if done and math.dist(self._here(), p) < max(self.params.arrive_radius, 0.5):
                if self._phase == "rtl_climb":
                    self._phase = "rtl_return"
                    self._go((self.home[0], self.home[1], self._rtl_z), self.params.transit_speed, p)
                else:
                    self._start_landing()
                return self._reference(t)
            return p, v, zero, self._yaw_ref
        return self._here(), zero, zero, self._yaw_ref

    def _finish_mission(self) -> None:
        f = self._follower
        due = f.due_captures(f.t_end)  # a capture exactly at the end not yet fired (rounding)
        if due:
            self._fire(due, self.t)
        end = f.end
        o = self._offset
        self._mission_done = True
        self._phase = ""
        self._paused_phase = ""
        self.mode = Mode.HOLD
        self._hold_pos = (end[0] + o[0], end[1] + o[1], end[2] + o[2])
        self._yaw_ref = f.reference(f.t_end)[3]

    def _rate_limit_offset(self) -> Vec3:
        o, c = self._offset, self._offset_cmd
        if o is c:
            return o
        d = (c[0] - o[0], c[1] - o[1], c[2] - o[2])
        n = math.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2)
        step = self.params.offset_rate * self.dt
        if n <= step:
            self._offset = c
        else:
            s = step / n
            self._offset = (o[0] + d[0] * s, o[1] + d[1] * s, o[2] + d[2] * s)
        return self._offset

    def _run(self, n: int) -> None:
        quad, pid, att_ctl = self.quad, self.pid, self.attitude
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
            if mode == Mode.MISSION and self._phase == "track":
                f = self._follower
                due = f.due_captures(t + dt - self._origin + f.t0)
                if due:
                    self._fire(due, t + dt)

    def _fire(self, due: list, t: float) -> None:
        s = self.quad.s
        for w in due:
            self._events.append(CaptureEvent(w.capture_id, t, (s[0], s[1], s[2]), (s[6], s[7], wrap_angle(s[8]))))
            self._captures += 1
