"""The vehicle driver interface that the edge's board service talks to.

Design notes: docs/edge.md (edge/vehicle/driver.py).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

from protocol.messages import Mode, Trajectory, VehicleState

__all__ = ["DriverState", "CaptureEvent", "VehicleDriver", "shutter_position", "MAX_DEAD_RECKON_S"]

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class DriverState:
    """Snapshot of the vehicle: mission time ``t`` (s), ENU ``pos``/``vel``, ZYX ``att`` (yaw in (−π, π]),
    body ``rates`` (P10), ``mode``, ``armed``, ``battery`` (0..1), ``wp_index`` (last waypoint passed, −1
    before), ``progress`` (fraction of the trajectory flown) and ``captures`` fired since the upload."""

    t: float
    pos: Vec3
    vel: Vec3
    att: Vec3
    rates: Vec3
    mode: Mode
    armed: bool
    battery: float
    wp_index: int
    progress: float
    captures: int

    def to_message(self, uav: int, seq: int, stamp: float) -> VehicleState:
        """The wire message (protocol.messages.VehicleState) for this snapshot."""
        return VehicleState(uav=uav, seq=seq, t=max(0.0, self.t), stamp=stamp, pos=self.pos, vel=self.vel, att=self.att,
                            rates=self.rates, mode=self.mode, armed=self.armed,
                            battery=min(1.0, max(0.0, self.battery)), wp_index=self.wp_index, progress=self.progress,
                            captures=self.captures)


@dataclass(frozen=True)
class CaptureEvent:
    """The follower passed a waypoint with a capture id: take the picture now (time, ENU position and
    attitude of the vehicle then)."""

    capture_id: int
    t: float
    pos: Vec3
    att: Vec3


#: the longest a position report is carried forward to the shutter (wall seconds): an older one is a link
#: problem, not an age to extrapolate over
MAX_DEAD_RECKON_S = 0.25


def shutter_position(pos: Vec3, vel: Vec3, age_s: float) -> Vec3:
    """Where the vehicle is at the shutter, from a position report ``age_s`` mission seconds old: the report
    dead-reckoned at its own velocity, ``pos + vel * age_s`` (``pos`` for a bad or negative age).

    >>> shutter_position((1.0, 2.0, 3.0), (2.0, 0.0, -1.0), 0.05)
    (1.1, 2.0, 2.95)
    """
    if not (math.isfinite(age_s) and age_s > 0.0):
        return pos
    return (pos[0] + vel[0] * age_s, pos[1] + vel[1] * age_s, pos[2] + vel[2] * age_s)


def check_vec3(v: object, name: str) -> Vec3:
    """Three finite floats, or a ValueError naming ``name``."""
    try:
        out = tuple(float(x) for x in v)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be 3 numbers") from None
    if len(out) != 3 or not all(math.isfinite(x) for x in out):
        raise ValueError(f"{name} must be 3 finite numbers")
    return out  # type: ignore[return-value]


class VehicleDriver(ABC):
    """What the board needs from a vehicle (simulated or real)."""

    @abstractmethod
    def state(self) -> DriverState:
        """Current snapshot."""

    @abstractmethod
    def upload(self, traj: Trajectory) -> None:
        """Store the trajectory to follow (ValueError if unusable or not allowed now)."""

    @abstractmethod
    def takeoff(self, altitude: float) -> None:
        """Arm and climb to ``altitude`` metres above the launch point, then HOLD."""

    @abstractmethod
    def start(self, t0: float | None = None) -> None:
        """Follow the uploaded trajectory, its time 0 at sim time ``t0`` (or now).

        If the vehicle is far from the first waypoint it first flies there; the trajectory
        clock then starts at the later of ``t0`` and the arrival. Started at the first waypoint
        with ``t0`` in the past, the trajectory is already running (the vehicle catches up, and
        capture points already passed fire at once). Capture points fire once per upload.
        """

    @abstractmethod
    def land(self) -> None:
        """Descend where the vehicle is and disarm on the ground."""

    @abstractmethod
    def hold(self) -> None:
        """Stop and hold the current position (pausing a mission)."""

    @abstractmethod
    def resume(self) -> None:
        """Continue a mission paused by :meth:`hold`."""

    @abstractmethod
    def return_to_launch(self) -> None:
        """Fly back above the launch point and land."""

    @abstractmethod
    def set_reference_offset(self, offset: Vec3) -> None:
        """Formation correction (m) added to the trajectory reference; bounded by the driver."""

    @abstractmethod
    def step(self, until_t: float) -> list[CaptureEvent]:
        """Advance to sim time ``until_t``; the capture events that fired meanwhile."""

    @abstractmethod
    def close(self) -> None:
        """Release the vehicle (connections, threads)."""
