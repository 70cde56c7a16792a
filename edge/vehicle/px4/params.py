"""PX4's parameters the project uses, and PX4's byte-wise encoding of integer parameters.

Design notes: docs/hardware-mavlink.md (edge/vehicle/px4/params.py).
"""

from __future__ import annotations

import math
import struct

from edge.vehicle.apm.params import MAV_PARAM_TYPE_INT32, MAV_PARAM_TYPE_REAL32, ParamSpec, ParamTable, _name

__all__ = ["PX4_PARAMS", "SCHEME", "SCHEMES", "KEYS", "param_name", "param_type", "to_raw", "from_raw", "encode",
           "decode", "Px4ParamTable", "NAV_DLL_ACT_RETURN"]

I32, F = MAV_PARAM_TYPE_INT32, MAV_PARAM_TYPE_REAL32
SCHEME = "px4"
SCHEMES = (SCHEME,)
#: NAV_DLL_ACT: Return on data-link loss (the paper's failsafe: fly home when the ground link is lost)
NAV_DLL_ACT_RETURN = 2

PX4_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("MAV_SYS_ID", 1, 1, 250, I32),
    ParamSpec("NAV_DLL_ACT", 0, 0, 6, I32),
    ParamSpec("COM_DL_LOSS_T", 10, 5, 300, I32),
    ParamSpec("COM_OBL_RC_ACT", 0, 0, 7, I32),
    ParamSpec("COM_OF_LOSS_T", 1.0, 0.0, 60.0, F),
    ParamSpec("COM_DISARM_PRFLT", 10.0, -1.0, 20.0, F),
    ParamSpec("COM_DISARM_LAND", 2.0, -1.0, 20.0, F),
    ParamSpec("MPC_XY_CRUISE", 5.0, 0.5, 20.0, F),  # metadata says 3 m/s at least; the firmware stores less
    ParamSpec("MPC_LAND_SPEED", 0.7, 0.6, 3.0, F),
    ParamSpec("MIS_TAKEOFF_ALT", 2.5, 0.0, 100.0, F),
    ParamSpec("NAV_ACC_RAD", 2.0, 0.05, 200.0, F),  # a multicopter's (rc.mc_defaults); 10 m in the generic table
    ParamSpec("RTL_RETURN_ALT", 60.0, 0.0, 150.0, F),
    ParamSpec("RTL_DESCEND_ALT", 30.0, 2.0, 100.0, F),
)
#: the driver's parameter keys -> PX4's names
KEYS = {"sysid": "MAV_SYS_ID", "wp_speed": "MPC_XY_CRUISE", "rtl_alt": "RTL_RETURN_ALT",
        "land_speed": "MPC_LAND_SPEED", "wp_radius": "NAV_ACC_RAD", "link_loss_action": "NAV_DLL_ACT",
        "takeoff_alt": "MIS_TAKEOFF_ALT"}
_SPEC = {s.name: s for s in PX4_PARAMS}


def _check(scheme: str) -> None:
    if scheme != SCHEME:
        raise ValueError(f"unknown PX4 parameter scheme {scheme!r} (only {SCHEME!r})")


def param_name(key: str, scheme: str = SCHEME) -> str:
    """PX4's name of the driver's parameter ``key``."""
    _check(scheme)
    return KEYS[key]


def param_type(key: str, scheme: str = SCHEME) -> int:
    """The MAV_PARAM_TYPE of ``key``'s PX4 parameter."""
    return _SPEC[param_name(key, scheme)].type


def to_raw(key: str, si: float, scheme: str = SCHEME) -> float:
    """PX4's parameters are in SI units: the value as is."""
    _check(scheme)
    return float(si)


def from_raw(key: str, raw: float, scheme: str = SCHEME) -> float:
    _check(scheme)
    return float(raw)


def encode(value: float, param_type: int) -> float:
    """The float field carrying ``value`` of type ``param_type`` byte-wise (INT32's bytes as a float32)."""
    if param_type == MAV_PARAM_TYPE_REAL32:
        return float(value)
    return struct.unpack("<f", struct.pack("<i", int(value)))[0]


def decode(raw: float, param_type: int) -> float:
    """The value carried byte-wise in PARAM_VALUE / PARAM_SET's float field (NaN when it cannot be one)."""
    if param_type == MAV_PARAM_TYPE_REAL32:
        return float(raw)
    try:
        return float(struct.unpack("<i", struct.pack("<f", raw))[0])
    except (OverflowError, struct.error):
        return math.nan


class Px4ParamTable(ParamTable):
    """The sim autopilot's PX4 parameters (:data:`PX4_PARAMS`), integers sent and read byte-wise."""

    def __init__(self, **overrides: float):
        super().__init__(PX4_PARAMS, **overrides)
        self.scheme = SCHEME

    def name(self, key: str) -> str:
        return param_name(key)

    def si(self, key: str) -> float:
        return self.values[param_name(key)]

    def _value(self, i: int):  # noqa: ANN202 - the base class's (name, fields) pair
        kind, fields = super()._value(i)
        fields["param_value"] = encode(fields["param_value"], fields["param_type"])
        return kind, fields

    def param_set(self, param_id: object, value: float, requester: tuple[int, int] | None = None,
                  param_type: int = MAV_PARAM_TYPE_REAL32) -> list:
        """PARAM_SET with the value decoded by its declared type (an integer parameter's bytes)."""
        spec = _SPEC.get(_name(param_id))
        if spec is not None and spec.integer:
            value = decode(value, spec.type) if param_type != MAV_PARAM_TYPE_REAL32 else math.nan
        return super().param_set(param_id, value, requester)
