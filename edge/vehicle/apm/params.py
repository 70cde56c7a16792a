"""ArduCopter's parameter table (a subset) and the MAVLink parameter protocol.

Design notes: docs/hardware-mavlink.md (edge/vehicle/apm/params.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["MAV_PARAM_TYPE_INT8", "MAV_PARAM_TYPE_INT16", "MAV_PARAM_TYPE_INT32", "MAV_PARAM_TYPE_REAL32",
           "MAV_PARAM_ERROR_DOES_NOT_EXIST",
           "ParamSpec", "ParamTable", "COPTER_PARAMS", "SCHEMES", "DEFAULT_SCHEME", "Renamed", "RENAMED",
           "copter_params", "param_name", "param_type", "to_raw", "from_raw", "scheme_of_version", "flight_sw_version"]

MAV_PARAM_TYPE_INT8 = 2
MAV_PARAM_TYPE_INT16 = 4
MAV_PARAM_TYPE_INT32 = 6
MAV_PARAM_TYPE_REAL32 = 9
MAV_PARAM_ERROR_DOES_NOT_EXIST = 1

Out = tuple[str, dict]


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: name (at most 16 characters), default, range and MAV_PARAM_TYPE."""

    name: str
    default: float
    lo: float
    hi: float
    type: int = MAV_PARAM_TYPE_REAL32

    @property
    def integer(self) -> bool:
        return self.type != MAV_PARAM_TYPE_REAL32


I8, I16, I32, F = MAV_PARAM_TYPE_INT8, MAV_PARAM_TYPE_INT16, MAV_PARAM_TYPE_INT32, MAV_PARAM_TYPE_REAL32
COPTER_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("ARMING_CHECK", 1, 0, 0x7FFFFFFF, I32),
    ParamSpec("DISARM_DELAY", 10, 0, 127, I8),
    ParamSpec("FENCE_ACTION", 1, 0, 7, I8),
    ParamSpec("FENCE_ALT_MAX", 100.0, 10.0, 1000.0, F),
    ParamSpec("FENCE_ENABLE", 0, 0, 1, I8),
    ParamSpec("FENCE_MARGIN", 2.0, 1.0, 10.0, F),
    ParamSpec("FENCE_RADIUS", 300.0, 30.0, 10000.0, F),
    ParamSpec("FENCE_TYPE", 7, 0, 15, I8),
    ParamSpec("FS_GCS_ENABLE", 0, 0, 7, I8),
    ParamSpec("FS_GCS_TIMEOUT", 5.0, 2.0, 120.0, F),
    ParamSpec("LAND_SPEED", 50, 30, 200, I16),
    ParamSpec("RTL_ALT", 1500, 200, 300000, I32),
    ParamSpec("SYSID_MYGCS", 255, 1, 255, I16),
    ParamSpec("SYSID_THISMAV", 1, 1, 255, I16),
    ParamSpec("WPNAV_RADIUS", 200.0, 5.0, 1000.0, F),
    ParamSpec("WPNAV_SPEED", 1000.0, 10.0, 2000.0, F),
    ParamSpec("WPNAV_SPEED_DN", 150.0, 10.0, 500.0, F),
    ParamSpec("WPNAV_SPEED_UP", 250.0, 10.0, 1000.0, F),
)


#: the naming schemes: "4.6" (ArduCopter 4.5 and 4.6, stable) and "4.7" (4.7 and later)
SCHEMES = ("4.6", "4.7")
DEFAULT_SCHEME = "4.6"


@dataclass(frozen=True)
class Renamed:
    """A parameter renamed in 4.7: its key, its 4.6 name and 4.7 spec; ``scale`` is SI units per 4.6 unit
    (0.01 for cm -> m); None for a value that is not converted but re-meant (ARMING_SKIPCHK)."""

    key: str
    old: str
    new: ParamSpec
    scale: float | None = 1.0


RENAMED: tuple[Renamed, ...] = (
    Renamed("sysid", "SYSID_THISMAV", ParamSpec("MAV_SYSID", 1, 1, 255, I16)),
    Renamed("wp_speed", "WPNAV_SPEED", ParamSpec("WP_SPD", 10.0, 0.1, 20.0, F), 0.01),
    Renamed("rtl_alt", "RTL_ALT", ParamSpec("RTL_ALT_M", 15.0, 2.0, 3000.0, F), 0.01),
    Renamed("land_speed", "LAND_SPEED", ParamSpec("LAND_SPD_MS", 0.5, 0.3, 2.0, F), 0.01),
    Renamed("arming_skip", "ARMING_CHECK", ParamSpec("ARMING_SKIPCHK", 0, 0, 0x7FFFFFFF, I32), None),
    Renamed("gcs_sysid", "SYSID_MYGCS", ParamSpec("MAV_GCS_SYSID", 255, 1, 255, I16)),
    Renamed("wp_radius", "WPNAV_RADIUS", ParamSpec("WP_RADIUS_M", 2.0, 0.05, 10.0, F), 0.01),
    Renamed("wp_speed_up", "WPNAV_SPEED_UP", ParamSpec("WP_SPD_UP", 2.5, 0.1, 10.0, F), 0.01),
    Renamed("wp_speed_dn", "WPNAV_SPEED_DN", ParamSpec("WP_SPD_DN", 1.5, 0.1, 5.0, F), 0.01),
)
_RENAMED = {r.key: r for r in RENAMED}


def _check_scheme(scheme: str) -> str:
    if scheme not in SCHEMES:
        raise ValueError(f"unknown firmware parameter scheme {scheme!r} (one of {', '.join(SCHEMES)})")
    return scheme


def copter_params(scheme: str = DEFAULT_SCHEME) -> tuple[ParamSpec, ...]:
    """The parameter table of a scheme: 4.6's, or 4.7's with :data:`RENAMED` swapped in."""
    if _check_scheme(scheme) == "4.6":
        return COPTER_PARAMS
    old = {r.old: r.new for r in RENAMED}
    return tuple(old.get(s.name, s) for s in COPTER_PARAMS)


def param_name(key: str, scheme: str) -> str:
    """The name of renamed parameter ``key`` (:data:`RENAMED`) in ``scheme``."""
    r = _RENAMED[key]
    return r.old if _check_scheme(scheme) == "4.6" else r.new.name


def param_type(key: str, scheme: str) -> int:
    """The MAV_PARAM_TYPE of renamed parameter ``key`` in ``scheme``."""
    name = param_name(key, scheme)
    return next(s.type for s in copter_params(scheme) if s.name == name)


def to_raw(key: str, si: float, scheme: str) -> float:
    """A value in SI units (m, m/s) as stored in the scheme's parameter (cm, cm/s in 4.6)."""
    r = _RENAMED[key]
    if r.scale is None:
        raise ValueError(f"{key} has no unit conversion")
    return float(si) / r.scale if _check_scheme(scheme) == "4.6" else float(si)


def from_raw(key: str, raw: float, scheme: str) -> float:
    """The scheme's stored value of ``key`` in SI units."""
    r = _RENAMED[key]
    if r.scale is None:
        raise ValueError(f"{key} has no unit conversion")
    return float(raw) * r.scale if _check_scheme(scheme) == "4.6" else float(raw)


def flight_sw_version(scheme: str) -> int:
    """AUTOPILOT_VERSION's ``flight_sw_version`` of the scheme's firmware (major<<24 | minor<<16 | patch<<8 |
    FIRMWARE_VERSION_TYPE_OFFICIAL 255): 4.6.0 or 4.7.0."""
    minor = 6 if _check_scheme(scheme) == "4.6" else 7
    return (4 << 24) | (minor << 16) | 255


def scheme_of_version(version: int) -> str:
    """The naming scheme of firmware ``flight_sw_version`` (4.7 and later: "4.7"; earlier: "4.6")."""
    major, minor = (int(version) >> 24) & 0xFF, (int(version) >> 16) & 0xFF
    return "4.7" if (major, minor) >= (4, 7) else "4.6"


def _name(raw: object) -> str:
    if isinstance(raw, (bytes, bytearray)):
        raw = bytes(raw).split(b"\0", 1)[0].decode("ascii", "replace")
    return str(raw).split("\0", 1)[0].strip()


class ParamTable:
    """The vehicle's parameters: values by name, in a fixed index order (sorted by name, as ArduPilot lists)."""

    def __init__(self, specs: tuple[ParamSpec, ...] | None = None, *, scheme: str = DEFAULT_SCHEME, **overrides: float):
        self.scheme = _check_scheme(scheme)
        specs = copter_params(scheme) if specs is None else specs
        self.specs = tuple(sorted(specs, key=lambda s: s.name))
        self._by_name = {s.name: s for s in self.specs}
        self.values = {s.name: float(s.default) for s in self.specs}
        self.rejected = 0
        for k, v in overrides.items():
            if not self.set(k, v):
                raise ValueError(f"bad value {v!r} for parameter {k}")

    def __getitem__(self, name: str) -> float:
        return self.values[name]

    def name(self, key: str) -> str:
        """This table's name of renamed parameter ``key`` (e.g. "wp_speed": WPNAV_SPEED or WP_SPD)."""
        return param_name(key, self.scheme)

    def si(self, key: str) -> float:
        """Renamed parameter ``key``'s value in SI units (m, m/s) whatever the scheme."""
        return from_raw(key, self.values[self.name(key)], self.scheme)

    def set(self, name: str, value: float) -> bool:
        """Store ``value``; False (and counted) when the name is unknown or the value is out of its range."""
        spec = self._by_name.get(name)
        ok = spec is not None and isinstance(value, (int, float)) and math.isfinite(value)
        if ok and spec.integer:
            ok = float(value) == round(value)
        if ok and not (spec.lo <= value <= spec.hi):
            ok = False
        if not ok:
            self.rejected += 1
            return False
        self.values[name] = float(value)
        return True

    def _value(self, i: int) -> Out:
        s = self.specs[i]
        return ("param_value", dict(param_id=s.name.encode(), param_value=self.values[s.name], param_type=s.type,
                                    param_count=len(self.specs), param_index=i))

    def request_list(self) -> list[Out]:
        """PARAM_REQUEST_LIST: every PARAM_VALUE."""
        return [self._value(i) for i in range(len(self.specs))]

    @staticmethod
    def _error(param_id: object, param_index: int, requester: tuple[int, int] | None) -> list[Out]:
        if requester is None:
            return []
        raw = param_id if isinstance(param_id, (bytes, bytearray)) else str(param_id).encode("ascii", "replace")
        return [("param_error", dict(target_system=requester[0], target_component=requester[1],
                                     param_id=bytes(raw)[:16], param_index=int(param_index),
                                     error=MAV_PARAM_ERROR_DOES_NOT_EXIST))]

    def request_read(self, param_id: object, param_index: int, requester: tuple[int, int] | None = None) -> list[Out]:
        """PARAM_REQUEST_READ: one PARAM_VALUE; for an unknown parameter PARAM_ERROR to ``requester``
        (system, component), or nothing without one."""
        if param_index >= 0:
            if param_index < len(self.specs):
                return [self._value(param_index)]
            return self._error(param_id, max(-1, min(param_index, 32767)), requester)
        name = _name(param_id)
        if name not in self._by_name:
            return self._error(param_id, -1, requester)
        return [self._value(self.specs.index(self._by_name[name]))]

    def param_set(self, param_id: object, value: float, requester: tuple[int, int] | None = None) -> list[Out]:
        """PARAM_SET: store when valid; answer the (new or unchanged) value; PARAM_ERROR (or nothing
        without a ``requester``) for an unknown name."""
        name = _name(param_id)
        if name not in self._by_name:
            self.rejected += 1
            return self._error(param_id, -1, requester)
        self.set(name, value)
        return self.request_read(name, -1)
