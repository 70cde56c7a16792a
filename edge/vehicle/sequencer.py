"""Mission sequencing shared by the vehicle drivers: what to fly when, with no vehicle underneath.

Design notes: docs/edge.md (edge/vehicle/sequencer.py).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Literal

from edge.vehicle.driver import check_vec3
from edge.vehicle.follower import Follower, Reference
from protocol.messages import Trajectory, Waypoint

__all__ = ["Mover", "MissionSequencer", "MIN_CLEARANCE"]

Vec3 = tuple[float, float, float]
ZERO: Vec3 = (0.0, 0.0, 0.0)
#: waypoints lower than this above the ground (the launch point's height) are refused, m
MIN_CLEARANCE = 0.5


class Mover:
    """A reference from ``start`` straight toward ``target`` (ENU m) at ``speed`` (m/s) from time ``t0``:
    ``start + u · min(v (t − t0), L)``, velocity ``u v`` until it arrives (transits here; takeoff, landing
    and return to launch in :class:`edge.vehicle.sim.SimDriver`).

    >>> m = Mover((0.0, 0.0, 0.0), (4.0, 0.0, 0.0), 2.0, 10.0)
    >>> m.at(11.0)
    ((2.0, 0.0, 0.0), (2.0, 0.0, 0.0), False)
    >>> m.at(13.0)
    ((4.0, 0.0, 0.0), (0.0, 0.0, 0.0), True)
    """

    __slots__ = ("start", "target", "speed", "t0", "_u", "_n")

    def __init__(self, start: Vec3, target: Vec3, speed: float, t0: float):
        if not (math.isfinite(speed) and speed > 0 and math.isfinite(t0)):
            raise ValueError("speed must be finite and > 0, t0 finite")
        d = (target[0] - start[0], target[1] - start[1], target[2] - start[2])
        n = math.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2)
        if not math.isfinite(n):
            raise ValueError("start and target must be finite")
        self.start = start
        self.target = target
        self.speed = speed
        self.t0 = t0
        self._u: Vec3 = (d[0] / n, d[1] / n, d[2] / n) if n > 1e-12 else ZERO
        self._n = n

    def at(self, t: float) -> tuple[Vec3, Vec3, bool]:
        """Reference position and velocity at time ``t``, and whether the target is reached."""
        start, u, n, v = self.start, self._u, self._n, self.speed
        s = t - self.t0
        if s < 0.0:
            return start, ZERO, n == 0.0
        s *= v
        if s >= n:
            return (start[0] + u[0] * n, start[1] + u[1] * n, start[2] + u[2] * n), ZERO, True
        return (start[0] + u[0] * s, start[1] + u[1] * s, start[2] + u[2] * s), (u[0] * v, u[1] * v, u[2] * v), False


class MissionSequencer:
    """The trajectory a driver flies: upload checks, start, pause/resume, offset, captures, progress.

    Waypoints must be ``MIN_CLEARANCE`` above ``ground_z``; ``start``/``resume`` first fly at
    ``transit_speed`` to a point farther than ``start_radius``, arriving within ``arrive_radius``; the
    formation offset is bounded by ``max_offset`` and slewed at ``offset_rate``. ``phase`` is "transit",
    "wait", "track", "transit_resume" or "" (no mission in flight).
    """

    def __init__(self, uav: int, ground_z: float = 0.0, *, transit_speed: float = 4.0, start_radius: float = 1.0,
                 arrive_radius: float = 0.3, max_offset: float = 3.0, offset_rate: float = 1.0,
                 interpolation: Literal["cubic", "linear"] = "cubic"):
        if not (isinstance(uav, int) and 1 <= uav <= 255):
            raise ValueError("uav must be an int in 1..255")
        if not math.isfinite(ground_z):
            raise ValueError("ground_z must be finite")
        for name, v in (("transit_speed", transit_speed), ("start_radius", start_radius),
                        ("arrive_radius", arrive_radius), ("offset_rate", offset_rate)):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be finite and > 0")
        if not (math.isfinite(max_offset) and max_offset >= 0):
            raise ValueError("max_offset must be finite and >= 0")
        if interpolation not in ("cubic", "linear"):
            raise ValueError("interpolation must be 'cubic' or 'linear'")
        self.uav = uav
        self.ground_z = float(ground_z)
        self.transit_speed = float(transit_speed)
        self.start_radius = float(start_radius)
        self.arrive_radius = float(arrive_radius)
        self.max_offset = float(max_offset)
        self.offset_rate = float(offset_rate)
        self.interpolation = interpolation
        self.follower: Follower | None = None
        self.phase = ""
        self.done = False
        self.captures = 0
        self.yaw = 0.0
        self.offset_cmd: Vec3 = ZERO
        self.offset: Vec3 = ZERO
        self._t_start = 0.0  # requested time of trajectory time 0
        self._origin = 0.0  # time of trajectory time 0 while tracking
        self._mover: Mover | None = None
        self._paused = ""  # the phase a pause interrupted ("" = no paused mission)
        self._tau_paused: float | None = None  # trajectory time since t_0 when paused while tracking
        self._resume_tau = 0.0  # the paused trajectory time a "transit_resume" flies back to
        self._leftover: list[Waypoint] = []  # captures due at the end, handed out by the next due()

    # ------------------------------------------------------------------ upload
    def check(self, traj: Trajectory) -> None:
        """ValueError unless ``traj`` is a Trajectory for this UAV with every waypoint above ground."""
        if not isinstance(traj, Trajectory):
            raise ValueError("upload needs a protocol.messages.Trajectory")
        if traj.uav != self.uav:
            raise ValueError(f"trajectory is for UAV {traj.uav}, this is UAV {self.uav}")
        gz = self.ground_z
        for i, w in enumerate(traj.waypoints):
            if w.pos[2] < gz + MIN_CLEARANCE:
                raise ValueError(f"waypoint {i} is below {MIN_CLEARANCE} m above the ground (z = {w.pos[2]:.2f} m)")

    def load(self, traj: Trajectory, check: Callable[[Trajectory], None] | None = None) -> Follower:
        """Validate and store a trajectory; clears the captures count, a finished or paused mission.

        ``check`` is a driver's own extra validation (e.g. speed limits), run after :meth:`check`
        and before anything changes; it raises ValueError to refuse.
        """
        self.check(traj)
        if check is not None:
            check(traj)
        f = Follower(traj, self.interpolation)
        self.follower = f
        self.captures = 0
        self.done = False
        self.phase = ""
        self._paused = ""
        self._tau_paused = None
        self._leftover = []
        return f

    # ------------------------------------------------------------------ start, pause, resume
    def check_start(self, t0: float | None = None) -> None:
        """ValueError if :meth:`start` would refuse (no trajectory, non-finite ``t0``)."""
        if self.follower is None:
            raise ValueError("no trajectory uploaded")
        if t0 is not None and not math.isfinite(t0):
            raise ValueError("t0 must be finite")

    def start(self, t: float, pos: Vec3, t0: float | None = None, ref: Vec3 | None = None) -> None:
        """Start the trajectory at time ``t`` from position ``pos``, its time 0 at ``t0`` (or ``t``).

        Farther than ``start_radius`` from the first waypoint the reference first flies there
        from ``ref`` (the driver's current reference, so that it does not jump; default ``pos``).
        """
        self.check_start(t0)
        f = self.follower
        assert f is not None
        self._t_start = t if t0 is None else float(t0)
        self._paused = ""
        self._tau_paused = None
        self._leftover = []
        self.done = False
        self.yaw = f.reference(f.t0)[3]
        if math.dist(pos, f.start) > self.start_radius:
            self.phase = "transit"
            self._mover = Mover(pos if ref is None else ref, f.start, self.transit_speed, t)
        else:
            self._wait_or_track(t, arrived=False)

    def _wait_or_track(self, now: float, arrived: bool) -> None:
        """At the first waypoint: wait for the start time, or track from it (or from the arrival)."""
        if now < self._t_start:
            self.phase = "wait"
        else:
            self.phase = "track"
            self._origin = now if arrived else self._t_start

    def pause(self, t: float) -> None:
        """Stop the mission in flight at time ``t``, remembering where (no-op when none is)."""
        phase = self.phase
        if phase == "":
            return
        if phase == "track":
            self._tau_paused = t - self._origin
        elif phase == "transit_resume":  # paused again before getting back on track
            self._tau_paused = self._resume_tau
        else:  # transit, wait: the trajectory has not started
            self._tau_paused = None
        self._paused = phase
        self.phase = ""

    @property
    def paused(self) -> bool:
        """A paused mission that :meth:`resume` can continue."""
        return self._paused != "" and self.follower is not None and not self.done

    def check_resume(self) -> None:
        """ValueError if there is no paused mission to resume."""
        if not self.paused:
            raise ValueError("no paused mission to resume")

    def resume(self, t: float, pos: Vec3, yaw: float) -> None:
        """Continue the paused mission at time ``t`` from ``pos``, from the paused trajectory time.

        Farther than ``start_radius`` from the paused point the reference first flies back there
        (heading ``yaw``, the one the vehicle held); a mission paused before tracking flies to
        the first waypoint again and keeps its requested start time.
        """
        self.check_resume()
        f = self.follower
        assert f is not None
        self.yaw = yaw
        self._paused = ""
        tau = self._tau_paused
        if tau is None:
            self.phase = "transit"
            self._mover = Mover(pos, f.start, self.transit_speed, t)
            return
        self._tau_paused = None
        ref = f.reference(tau + f.t0)[0]
        if math.dist(pos, ref) > self.start_radius:
            self.phase = "transit_resume"
            self._resume_tau = tau
            self._mover = Mover(pos, ref, self.transit_speed, t)
        else:
            self.phase = "track"
            self._origin = t - tau

    def cancel(self) -> None:
        """Drop the mission in flight and any paused one (landing, return to launch)."""
        self.phase = ""
        self._paused = ""
        self._tau_paused = None

    # ------------------------------------------------------------------ formation offset
    def set_offset(self, offset: Vec3) -> Vec3:
        """Command the formation offset (m); bounded to ``max_offset`` in norm. Returns the bounded one."""
        o = check_vec3(offset, "offset")
        n = math.sqrt(o[0] ** 2 + o[1] ** 2 + o[2] ** 2)
        m = self.max_offset
        if n > m:
            o = (o[0] * m / n, o[1] * m / n, o[2] * m / n)
        self.offset_cmd = o
        return o

    def _step_offset(self, dt: float) -> Vec3:
        o, c = self.offset, self.offset_cmd
        d = (c[0] - o[0], c[1] - o[1], c[2] - o[2])
        n = math.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2)
        step = self.offset_rate * dt if dt > 0.0 else 0.0
        if n <= step:
            self.offset = c
        else:
            s = step / n
            self.offset = (o[0] + d[0] * s, o[1] + d[1] * s, o[2] + d[2] * s)
        return self.offset

    # ------------------------------------------------------------------ reference, captures, progress
    def reference(self, t: float, pos: Vec3, dt: float) -> Reference:
        """The reference ``(pos, vel, acc, yaw)`` at time ``t`` (non-decreasing) for a vehicle at ``pos``,
        ``dt`` after the previous call; advances the phase. At the trajectory's end it sets :attr:`done`
        and holds the end point plus the offset. ValueError when no mission is in flight."""
        phase = self.phase
        if phase == "track":
            f = self.follower
            tau = t - self._origin + f.t0  # type: ignore[union-attr]
            if tau >= f.t_end:  # type: ignore[union-attr]
                return self._finish()
            p, v, a, yaw = f.reference(tau)  # type: ignore[union-attr]
            o = self.offset
            if o is not self.offset_cmd:
                o = self._step_offset(dt)
            return (p[0] + o[0], p[1] + o[1], p[2] + o[2]), v, a, yaw
        if phase == "wait":
            if t >= self._t_start:
                self.phase = "track"
                self._origin = self._t_start
                return self.reference(t, pos, dt)
            return self.follower.start, ZERO, ZERO, self.yaw  # type: ignore[union-attr]
        if phase == "transit" or phase == "transit_resume":
            p, v, arrived = self._mover.at(t)  # type: ignore[union-attr]
            if arrived and math.dist(pos, p) < self.arrive_radius:
                if phase == "transit":
                    self._wait_or_track(t, arrived=True)
                else:
                    self.phase = "track"
                    self._origin = t - self._resume_tau
                return self.reference(t, pos, dt)
            return p, v, ZERO, self.yaw
        raise ValueError("no mission in flight: start or resume it first")

    def _finish(self) -> Reference:
        f = self.follower
        assert f is not None
        self._leftover = f.due_captures(f.t_end)  # a capture exactly at the end not yet handed out
        self.done = True
        self.phase = ""
        self._paused = ""
        e, o = f.end, self.offset
        return (e[0] + o[0], e[1] + o[1], e[2] + o[2]), ZERO, ZERO, f.reference(f.t_end)[3]

    def due(self, t: float) -> list[Waypoint]:
        """Capture waypoints reached by time ``t`` and not handed out before (each once per upload).

        While tracking, those whose time is at most the trajectory time of ``t``; right after the
        end was reached, those left at the end. Counted in :attr:`captures`.
        """
        out = self._leftover
        if out:
            self._leftover = []
        elif self.phase == "track":
            f = self.follower
            out = f.due_captures(t - self._origin + f.t0)  # type: ignore[union-attr]
        else:
            return []
        self.captures += len(out)
        return out

    def tau(self, t: float) -> float | None:
        """Trajectory time at time ``t``: frozen while paused, the end once done; None before tracking."""
        f = self.follower
        if f is None:
            return None
        if self.done:
            return f.t_end
        if self._tau_paused is not None:
            return self._tau_paused + f.t0
        if self.phase == "track":
            return t - self._origin + f.t0
        return None

    def progress(self, t: float) -> tuple[int, float]:
        """``(wp_index, progress)`` at time ``t``: last waypoint passed (−1 before the first) and the
        fraction of the trajectory's duration flown, as in :class:`edge.vehicle.driver.DriverState`."""
        tau = self.tau(t)
        f = self.follower
        if f is None or tau is None:
            return -1, 0.0
        return f.segment(tau), f.progress(tau)
