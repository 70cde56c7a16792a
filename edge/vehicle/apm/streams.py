"""The telemetry scheduler: which message is due when, as ArduPilot's stream rates work.

Design notes: docs/hardware-mavlink.md (edge/vehicle/apm/streams.py).
"""

from __future__ import annotations

import math

__all__ = ["StreamScheduler", "DEFAULT_RATES", "ARDUCOPTER_RATES", "STREAM_GROUPS", "MAX_RATE_HZ"]

MAX_RATE_HZ = 50.0

#: message name -> default rate, Hz (HOME_POSITION at 0.5 Hz, as MAVSDK asks ArduPilot for it anyway)
DEFAULT_RATES: dict[str, float] = {
    "HEARTBEAT": 1.0,
    "SYS_STATUS": 2.0,
    "GPS_RAW_INT": 2.0,
    "GLOBAL_POSITION_INT": 20.0,
    "LOCAL_POSITION_NED": 20.0,
    "ATTITUDE": 20.0,
    "VFR_HUD": 4.0,
    "BATTERY_STATUS": 1.0,
    "EXTENDED_SYS_STATE": 2.0,
    "HOME_POSITION": 0.5,
    "MISSION_CURRENT": 1.0,
    "EKF_STATUS_REPORT": 1.0,
}

#: what ArduCopter sends before anyone asks: HEARTBEAT only
ARDUCOPTER_RATES: dict[str, float] = {"HEARTBEAT": 1.0}

#: MAV_DATA_STREAM id -> the messages of ArduCopter's group
STREAM_GROUPS: dict[int, tuple[str, ...]] = {
    2: ("SYS_STATUS", "GPS_RAW_INT", "MISSION_CURRENT"),
    6: ("GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"),
    10: ("ATTITUDE",),
    11: ("VFR_HUD",),
    12: ("BATTERY_STATUS", "EXTENDED_SYS_STATE", "EKF_STATUS_REPORT"),
}
STREAM_GROUPS[0] = tuple(n for g in (2, 6, 10, 11, 12) for n in STREAM_GROUPS[g])


class StreamScheduler:
    """Rates per message and the time each was last sent: ``ids`` maps the names the vehicle can produce to
    MAVLink ids, ``defaults`` to default rates in Hz (missing: 0, on request only)."""

    def __init__(self, ids: dict[str, int], defaults: dict[str, float] | None = None):
        d = DEFAULT_RATES if defaults is None else defaults
        self.ids = dict(ids)
        self.names = {v: k for k, v in self.ids.items()}
        self.defaults = {n: float(d.get(n, 0.0)) for n in self.ids}
        self.rate = dict(self.defaults)
        self._last = {n: -math.inf for n in self.ids}

    def due(self, now: float) -> list[str]:
        """The messages due at wall time ``now`` (each marked sent)."""
        out = []
        for n, hz in self.rate.items():
            if hz > 0 and now - self._last[n] >= 1.0 / hz:
                self._last[n] = now
                out.append(n)
        return out

    def set_interval(self, msg_id: float, interval_us: float) -> bool:
        """SET_MESSAGE_INTERVAL; False for a message this vehicle does not produce or a bad interval."""
        if not (math.isfinite(msg_id) and math.isfinite(interval_us)):
            return False
        name = self.names.get(int(msg_id))
        if name is None or msg_id != int(msg_id):
            return False
        if interval_us == 0:
            self.rate[name] = self.defaults[name]
        elif interval_us < 0:
            self.rate[name] = 0.0
        else:
            self.rate[name] = min(MAX_RATE_HZ, 1e6 / interval_us)
        self._last[name] = -math.inf
        return True

    def interval_us(self, msg_id: float) -> int | None:
        """GET_MESSAGE_INTERVAL: −1 when off, None for a message this vehicle does not produce."""
        name = self.names.get(int(msg_id)) if math.isfinite(msg_id) else None
        if name is None:
            return None
        hz = self.rate[name]
        return -1 if hz <= 0 else int(round(1e6 / hz))

    def request_data_stream(self, stream_id: int, rate_hz: int, start_stop: int) -> bool:
        """REQUEST_DATA_STREAM: set every message of a group to ``rate_hz`` (0 or stop: off)."""
        group = STREAM_GROUPS.get(int(stream_id))
        if group is None:
            return False
        hz = min(MAX_RATE_HZ, float(rate_hz)) if start_stop and rate_hz > 0 else 0.0
        for n in group:
            if n in self.rate:
                self.rate[n] = hz
        return True
