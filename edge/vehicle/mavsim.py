"""A MAVLink vehicle endpoint backed by the simulated quadcopter (an ArduCopter stand-in).

ArduPilot SITL cannot be fetched here, so :class:`MavlinkSimVehicle` answers the MAVLink subset
that :class:`edge.vehicle.mavlink.MavlinkDriver` speaks, as an ArduCopter would, with the
project's :class:`edge.vehicle.sim.SimDriver` (6-DoF plant (P10)-(P12), PID position loop, ATSM
attitude loop (P13)-(P17)) flying underneath. It runs in a thread (tests) or as a process::

    python -m edge.vehicle.mavsim --connection udpout:127.0.0.1:14550 --uav 1 --speed 5

What it does (MAVLink 2, system id = ``uav``, component 1, ``MAV_AUTOPILOT_ARDUPILOTMEGA``):

- sends HEARTBEAT at 1 Hz (custom mode, armed flag), LOCAL_POSITION_NED and ATTITUDE at
  ``telemetry_hz`` (20 Hz) and SYS_STATUS at 2 Hz, on the wall clock; MAV_CMD_SET_MESSAGE_INTERVAL
  changes those rates. Frames as in :mod:`edge.vehicle.mavlink` (NED about ``home``, FRD body).
- answers every COMMAND_LONG addressed to it with a COMMAND_ACK:

  =======================  ==================================================================
  DO_SET_MODE (and the     STABILIZE 0 (on the ground), GUIDED 4, LOITER 5, BRAKE 17 (hold where
  SET_MODE message)        it is), LAND 9, RTL 6 (airborne only); others MAV_RESULT_FAILED
  COMPONENT_ARM_DISARM     arms in STABILIZE / GUIDED / LOITER unless ``refuse_arming`` (then a
                           "PreArm:" STATUSTEXT and MAV_RESULT_FAILED); disarms on the ground
                           only (or with the 21196 force code)
  NAV_TAKEOFF              GUIDED, armed, on the ground: climbs to param7 m above home
  NAV_LAND                 LAND mode; NAV_RETURN_TO_LAUNCH: RTL mode
  DO_DIGICAM_CONTROL       param5 = 1 records a shot (:attr:`shots`, the param6 id)
  SET_MESSAGE_INTERVAL     LOCAL_POSITION_NED, ATTITUDE, SYS_STATUS
  anything else            MAV_RESULT_UNSUPPORTED
  =======================  ==================================================================

- in GUIDED, airborne, follows SET_POSITION_TARGET_LOCAL_NED (``MAV_FRAME_LOCAL_NED``) as
  ArduCopter's guided position/velocity/acceleration controller does: the target moves on with
  its velocity and acceleration (p + v·Δt + a·Δt²/2) until 3 s pass without a new one, then the
  feed-forward is dropped and the last position held; a velocity-only target starts from the
  current position; an ignored yaw keeps the current heading. A target during the takeoff climb
  ends the climb. Other frames are ignored.
- disarms on the ground after LAND/RTL, and 10 s after arming without a takeoff (DISARM_DELAY).
- :meth:`MavlinkSimVehicle.pilot_mode` flips the mode as the pilot's remote control would (the
  paper's emergency take-over), to test that the driver reports it and stops streaming.

Hook into the simulator: a guided target is a :class:`GuidedTarget` handed to
:meth:`SimDriver.set_external_reference`, which the simulated vehicle flies while in HOLD; the rest
of SimDriver (dynamics, control, takeoff, land, RTL) is used as is, and any of its mode-changing
commands drops the target.
"""

from __future__ import annotations

import argparse
import math
import queue
import signal
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any

from edge.clock import SimClock
from edge.vehicle.driver import check_vec3
from edge.vehicle.follower import Reference
from edge.vehicle.mavlink import CopterMode, open_connection, wrap
from edge.vehicle.quadrotor import DisturbanceParams
from edge.vehicle.sim import SimDriver, SimParams
from protocol.messages import Mode

from pymavlink.dialects.v20 import ardupilotmega as M

__all__ = ["GuidedTarget", "MavlinkSimVehicle", "GUIDED_TIMEOUT_S", "main"]

Vec3 = tuple[float, float, float]

#: a guided velocity target older than this is dropped (ArduCopter's guided pos/vel timeout), s
GUIDED_TIMEOUT_S = 3.0
#: ArduCopter's DISARM_DELAY: armed on the ground this long without a takeoff -> disarm, s
DISARM_DELAY_S = 10.0
#: ArduPilot's "force" code in param2 of COMPONENT_ARM_DISARM
FORCE_CODE = 21196
_SUPPORTED_MODES = {CopterMode.STABILIZE, CopterMode.GUIDED, CopterMode.LOITER, CopterMode.BRAKE,
                    CopterMode.LAND, CopterMode.RTL}
_ARMABLE = {CopterMode.STABILIZE, CopterMode.GUIDED, CopterMode.LOITER}
_ON_GROUND = (Mode.IDLE, Mode.LANDED)
_STREAMS = ("LOCAL_POSITION_NED", "ATTITUDE", "SYS_STATUS")
_STREAM_IDS = {M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: "LOCAL_POSITION_NED", M.MAVLINK_MSG_ID_ATTITUDE: "ATTITUDE",
               M.MAVLINK_MSG_ID_SYS_STATUS: "SYS_STATUS"}
_ZERO: Vec3 = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class GuidedTarget:
    """A guided position target, as ArduCopter's guided position/velocity/acceleration controller flies it.

    Position ``p``, velocity ``v``, acceleration ``a`` (ENU m, m/s, m/s²) and yaw (rad), set at
    sim time ``t_set``. Called at time t it moves on by constant-acceleration kinematics for
    ``k = t − t_set``: ``p + v k + a k²/2``, velocity ``v + a k`` and acceleration ``a`` as
    feed-forward, until ``k`` reaches GUIDED_TIMEOUT_S; then the position stays and the
    feed-forward is dropped. Handed to :meth:`SimDriver.set_external_reference`.
    """

    pos: Vec3
    vel: Vec3
    acc: Vec3
    yaw: float
    t_set: float

    def __call__(self, t: float) -> Reference:
        p, v, a = self.pos, self.vel, self.acc
        age = t - self.t_set
        k = min(max(age, 0.0), GUIDED_TIMEOUT_S)
        h = 0.5 * k * k
        pos = (p[0] + v[0] * k + a[0] * h, p[1] + v[1] * k + a[1] * h, p[2] + v[2] * k + a[2] * h)
        if age >= GUIDED_TIMEOUT_S:
            return pos, _ZERO, _ZERO, self.yaw
        return pos, (v[0] + a[0] * k, v[1] + a[1] * k, v[2] + a[2] * k), a, self.yaw


class MavlinkSimVehicle:
    """A simulated ArduCopter on a MAVLink connection.

    Parameters
    ----------
    connection : str
        pymavlink connection string (``udpout:host:port`` to reach a driver listening with udpin).
    uav : int
        UAV id = MAVLink system id.
    home : (x, y, z)
        Launch point, ENU m (the LOCAL_POSITION_NED origin).
    speed : float
        Simulation speed factor (simulated seconds per wall second).
    epoch : float or None
        Wall-clock UNIX time of simulated time 0 (share it with the board's clock); None = now.
    params : SimParams
        The simulated vehicle.
    seed : int
        Disturbance seed.
    telemetry_hz : float
        LOCAL_POSITION_NED and ATTITUDE rate, Hz (wall clock).
    refuse_arming : bool
        Refuse COMPONENT_ARM_DISARM(1) with a PreArm STATUSTEXT (can be changed at any time).
    """

    def __init__(
        self,
        connection: str,
        uav: int,
        home: Vec3 = (0.0, 0.0, 0.0),
        speed: float = 1.0,
        *,
        epoch: float | None = None,
        params: SimParams = SimParams(),
        seed: int = 0,
        telemetry_hz: float = 20.0,
        refuse_arming: bool = False,
    ):
        if not (isinstance(uav, int) and 1 <= uav <= 255):
            raise ValueError("uav must be an int in 1..255")
        if not (isinstance(telemetry_hz, (int, float)) and math.isfinite(telemetry_hz) and 0 < telemetry_hz <= 100):
            raise ValueError("telemetry_hz must be in (0, 100]")
        self.uav = uav
        self.home = check_vec3(home, "home")
        self.clock = SimClock(epoch=epoch, speed=speed)
        self.sim = SimDriver(uav, params=params, seed=seed, home=self.home, t0=self.clock.now())
        self._t_boot = self.clock.now()
        self._conn = open_connection(connection, uav, M.MAV_COMP_ID_AUTOPILOT1)
        self.connection = connection
        self.custom_mode = CopterMode.STABILIZE
        self.armed = False
        self.refuse_arming = bool(refuse_arming)
        self.prearm_text = "PreArm: arming refused by the simulator (refuse_arming)"
        self._armed_at = 0.0
        self._default_hz = {"LOCAL_POSITION_NED": float(telemetry_hz), "ATTITUDE": float(telemetry_hz),
                            "SYS_STATUS": 2.0}
        self.stream_hz = dict(self._default_hz)
        self._last_sent = {k: -math.inf for k in ("HEARTBEAT", *_STREAMS)}
        #: camera shots commanded (DO_DIGICAM_CONTROL param6 ids), commands answered (command, result)
        self.shots: list[int] = []
        self.commands: list[tuple[int, int]] = []
        self.targets_received = 0
        self.gcs_heartbeats = 0
        self.errors: list[str] = []
        self._pilot: queue.SimpleQueue[int] = queue.SimpleQueue()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closed = False

    # ------------------------------------------------------------------ running
    def start(self) -> "MavlinkSimVehicle":
        """Run in a daemon thread (stop with :meth:`close`)."""
        if self._thread is None:
            self._thread = threading.Thread(target=self.run, name=f"mavsim-uav{self.uav}", daemon=True)
            self._thread.start()
        return self

    def run(self, stop: threading.Event | None = None) -> None:
        """Serve until :meth:`close` (or ``stop`` is set)."""
        while not self._stop.is_set() and not (stop is not None and stop.is_set()):
            self.poll()
            self._conn.select(0.005)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        try:
            self._conn.close()
        except OSError:
            pass

    def __enter__(self) -> "MavlinkSimVehicle":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def pilot_mode(self, mode: int) -> None:
        """Flip the mode as the pilot's remote control would (thread-safe; applied at the next poll)."""
        self._pilot.put(int(mode))

    def poll(self) -> None:
        """One pass: handle the pending messages, advance the simulation to now, send due telemetry."""
        while not self._pilot.empty():
            if self._set_mode(self._pilot.get()) != M.MAV_RESULT_ACCEPTED:
                self.errors.append("pilot mode change refused")
            self.send_heartbeat()  # show the new mode now, not at the next 1 Hz heartbeat
        for _ in range(200):
            try:
                msg = self._conn.recv_msg()
            except Exception as exc:  # a malformed datagram must not stop the vehicle
                self.errors.append(f"receive: {exc}")
                break
            if msg is None:
                break
            self._handle(msg)
        try:
            self.sim.step(self.clock.now())
        except ValueError as exc:
            self.errors.append(f"step: {exc}")
        self._after_step()
        self._send_telemetry(time.monotonic())

    def _after_step(self) -> None:
        sim = self.sim
        if self.armed and sim.mode == Mode.LANDED:
            self.armed = False  # ArduCopter disarms once landed
        if self.armed and sim.mode == Mode.IDLE and self.sim.t - self._armed_at > DISARM_DELAY_S:
            self.armed = False

    # ------------------------------------------------------------------ output
    def _boot_ms(self) -> int:
        return int(max(0.0, self.clock.now() - self._t_boot) * 1000) & 0xFFFFFFFF

    def _send(self, name: str, *args: Any, **kw: Any) -> None:
        try:
            getattr(self._conn.mav, name)(*args, **kw)
        except OSError as exc:
            self.errors.append(f"send {name}: {exc}")

    def _send_telemetry(self, now: float) -> None:
        last = self._last_sent
        if now - last["HEARTBEAT"] >= 1.0:
            last["HEARTBEAT"] = now
            self.send_heartbeat()
        st = None
        for name in _STREAMS:
            hz = self.stream_hz[name]
            if hz <= 0 or now - last[name] < 1.0 / hz:
                continue
            last[name] = now
            st = st or self.sim.state()
            ms = self._boot_ms()
            h = self.home
            if name == "LOCAL_POSITION_NED":
                p, v = st.pos, st.vel
                self._send("local_position_ned_send", ms, p[1] - h[1], p[0] - h[0], -(p[2] - h[2]),
                           v[1], v[0], -v[2])
            elif name == "ATTITUDE":
                r, q = st.att, st.rates
                self._send("attitude_send", ms, r[0], -r[1], wrap(math.pi / 2 - r[2]), q[0], -q[1], -q[2])
            else:
                sensors = (M.MAV_SYS_STATUS_SENSOR_3D_GYRO | M.MAV_SYS_STATUS_SENSOR_3D_ACCEL
                           | M.MAV_SYS_STATUS_SENSOR_GPS)
                pct = int(round(100 * min(1.0, max(0.0, st.battery))))
                self._send("sys_status_send", sensors, sensors, sensors, 100, int(15000 + 1800 * st.battery), -1,
                           pct, 0, 0, 0, 0, 0, 0)

    def send_heartbeat(self) -> None:
        base = (M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | M.MAV_MODE_FLAG_STABILIZE_ENABLED
                | M.MAV_MODE_FLAG_GUIDED_ENABLED | (M.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0))
        status = M.MAV_STATE_ACTIVE if self.armed else M.MAV_STATE_STANDBY
        self._send("heartbeat_send", M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_ARDUPILOTMEGA, base,
                   int(self.custom_mode), status)

    def _text(self, severity: int, text: str) -> None:
        self._send("statustext_send", severity, text.encode()[:50])

    # ------------------------------------------------------------------ input
    def _for_me(self, msg: Any) -> bool:
        return msg.target_system in (0, self.uav)

    def _handle(self, msg: Any) -> None:
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            if msg.type == M.MAV_TYPE_GCS:
                self.gcs_heartbeats += 1
        elif kind == "COMMAND_LONG" and self._for_me(msg):
            result = self._command(msg)
            self.commands.append((int(msg.command), result))
            self._send("command_ack_send", msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())
        elif kind == "SET_MODE" and msg.target_system == self.uav:
            ok = msg.base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            result = self._set_mode(msg.custom_mode) if ok else M.MAV_RESULT_UNSUPPORTED
            self._send("command_ack_send", M.MAVLINK_MSG_ID_SET_MODE, result, 0, 0, msg.get_srcSystem(),
                       msg.get_srcComponent())
        elif kind == "SET_POSITION_TARGET_LOCAL_NED" and self._for_me(msg):
            self._position_target(msg)

    def _command(self, msg: Any) -> int:
        c = msg.command
        if c == M.MAV_CMD_DO_SET_MODE:
            if not int(msg.param1) & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                return M.MAV_RESULT_UNSUPPORTED
            return self._set_mode(msg.param2)
        if c == M.MAV_CMD_COMPONENT_ARM_DISARM:
            return self._arm(msg.param1 > 0.5, int(msg.param2) == FORCE_CODE)
        if c == M.MAV_CMD_NAV_TAKEOFF:
            return self._takeoff(msg.param7)
        if c == M.MAV_CMD_NAV_LAND:
            return self._set_mode(CopterMode.LAND)
        if c == M.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return self._set_mode(CopterMode.RTL)
        if c == M.MAV_CMD_DO_DIGICAM_CONTROL:
            if msg.param5 == 1:
                self.shots.append(int(msg.param6))
            return M.MAV_RESULT_ACCEPTED
        if c == M.MAV_CMD_SET_MESSAGE_INTERVAL:
            name = _STREAM_IDS.get(int(msg.param1))
            if name is None:
                return M.MAV_RESULT_DENIED
            us = msg.param2
            self.stream_hz[name] = (self._default_hz[name] if us == 0 else 0.0 if us < 0
                                    else min(50.0, 1e6 / us))
            return M.MAV_RESULT_ACCEPTED
        return M.MAV_RESULT_UNSUPPORTED

    @property
    def airborne(self) -> bool:
        return self.sim.mode not in _ON_GROUND

    def _hold_here(self) -> None:
        sim = self.sim
        if sim.mode != Mode.HOLD:
            sim.hold()  # from TAKEOFF, MISSION, LAND, RTL: hold where it is (drops a guided target)
        else:
            s = sim.state()
            sim.set_external_reference(GuidedTarget(s.pos, _ZERO, _ZERO, s.att[2], sim.t))

    def _set_mode(self, mode: float) -> int:
        try:
            m = CopterMode(int(mode))
        except ValueError:
            m = None
        if m is None or m not in _SUPPORTED_MODES or mode != int(mode):
            self._text(M.MAV_SEVERITY_WARNING, f"Mode change to {mode:g} failed: not supported")
            return M.MAV_RESULT_FAILED
        sim = self.sim
        try:
            if self.airborne:
                if m == CopterMode.STABILIZE:
                    self._text(M.MAV_SEVERITY_WARNING, "Mode change to STABILIZE failed: not simulated in flight")
                    return M.MAV_RESULT_FAILED
                if m in (CopterMode.GUIDED, CopterMode.LOITER, CopterMode.BRAKE):
                    if m != self.custom_mode or m != CopterMode.GUIDED:
                        self._hold_here()
                elif m == CopterMode.LAND:
                    sim.land()
                elif m == CopterMode.RTL:
                    sim.return_to_launch()
            elif m == CopterMode.RTL:
                self._text(M.MAV_SEVERITY_WARNING, "Mode change to RTL failed: not armed/flying")
                return M.MAV_RESULT_FAILED
        except ValueError as exc:
            self._text(M.MAV_SEVERITY_WARNING, f"Mode change failed: {exc}")
            return M.MAV_RESULT_FAILED
        self.custom_mode = m
        return M.MAV_RESULT_ACCEPTED

    def _arm(self, arm: bool, force: bool) -> int:
        if not arm:
            if self.airborne and not force:
                self._text(M.MAV_SEVERITY_WARNING, "Disarm: vehicle is flying")
                return M.MAV_RESULT_FAILED
            self.armed = False
            return M.MAV_RESULT_ACCEPTED
        if self.armed:
            return M.MAV_RESULT_ACCEPTED
        if self.refuse_arming:
            self._text(M.MAV_SEVERITY_CRITICAL, self.prearm_text)
            return M.MAV_RESULT_FAILED
        if self.custom_mode not in _ARMABLE:
            self._text(M.MAV_SEVERITY_CRITICAL, f"Arm: mode {self.custom_mode.name} not armable")
            return M.MAV_RESULT_FAILED
        self.armed = True
        self._armed_at = self.sim.t
        return M.MAV_RESULT_ACCEPTED

    def _takeoff(self, altitude: float) -> int:
        if self.custom_mode != CopterMode.GUIDED or not self.armed or self.airborne:
            self._text(M.MAV_SEVERITY_WARNING, "Takeoff: needs GUIDED, armed, on the ground")
            return M.MAV_RESULT_FAILED
        try:
            self.sim.takeoff(altitude)
        except ValueError as exc:
            self._text(M.MAV_SEVERITY_WARNING, f"Takeoff: {exc}"[:50])
            return M.MAV_RESULT_FAILED
        return M.MAV_RESULT_ACCEPTED

    def _position_target(self, msg: Any) -> None:
        sim = self.sim
        if (msg.coordinate_frame != M.MAV_FRAME_LOCAL_NED or self.custom_mode != CopterMode.GUIDED
                or not self.armed or sim.mode not in (Mode.HOLD, Mode.TAKEOFF)):
            return
        mask = msg.type_mask
        use_pos = (mask & 0b111) != 0b111
        use_vel = (mask & 0b111000) != 0b111000
        use_acc = (mask & 0b111000000) != 0b111000000 and not mask & M.POSITION_TARGET_TYPEMASK_FORCE_SET
        if not (use_pos or use_vel):
            return
        vals = (msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz, msg.afx, msg.afy, msg.afz, msg.yaw)
        if not all(math.isfinite(v) for v in vals):
            return
        if sim.mode == Mode.TAKEOFF:
            sim.hold()  # a target ends the takeoff climb
        s = sim.state()
        h = self.home
        pos = (h[0] + msg.y, h[1] + msg.x, h[2] - msg.z) if use_pos else s.pos
        vel = (msg.vy, msg.vx, -msg.vz) if use_vel else _ZERO
        acc = (msg.afy, msg.afx, -msg.afz) if use_acc else _ZERO
        yaw = s.att[2] if mask & M.POSITION_TARGET_TYPEMASK_YAW_IGNORE else wrap(math.pi / 2 - msg.yaw)
        sim.set_external_reference(GuidedTarget(pos, vel, acc, yaw, sim.t))
        self.targets_received += 1


# ---------------------------------------------------------------------------------- process
def _vec(text: str) -> Vec3:
    try:
        return check_vec3([float(x) for x in text.split(",")], "home")
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected x,y,z ({exc})") from None


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m edge.vehicle.mavsim", description=__doc__.split("\n\n")[0])
    p.add_argument("--connection", default="udpout:127.0.0.1:14550", help="pymavlink connection string")
    p.add_argument("--uav", type=int, required=True, help="UAV id = MAVLink system id")
    p.add_argument("--home", type=_vec, default=(0.0, 0.0, 0.0), help="launch point x,y,z (ENU m)")
    p.add_argument("--speed", type=float, default=1.0, help="simulation speed factor")
    p.add_argument("--epoch", type=float, default=None, help="wall-clock UNIX time of sim time 0")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--wind", choices=["calm", "moderate"], default="calm")
    p.add_argument("--telemetry-hz", type=float, default=20.0)
    p.add_argument("--refuse-arming", action="store_true", help="fail every arming request (PreArm)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    wind = DisturbanceParams.moderate() if args.wind == "moderate" else DisturbanceParams()
    try:
        vehicle = MavlinkSimVehicle(args.connection, args.uav, home=args.home, speed=args.speed, epoch=args.epoch,
                                    params=SimParams(disturbance=wind), seed=args.seed,
                                    telemetry_hz=args.telemetry_hz, refuse_arming=args.refuse_arming)
    except ValueError as exc:
        print(f"mavsim: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    print(f"mavsim up: uav {args.uav} on {args.connection}, speed x{args.speed:g}", flush=True)
    try:
        vehicle.run(stop)
    finally:
        vehicle.close()
    print("mavsim stopped", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
