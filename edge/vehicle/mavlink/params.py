"""The parameter protocol (https://mavlink.io/en/services/parameter.html) and the dialect's naming schemes.

Design notes: docs/hardware-mavlink.md (edge/vehicle/mavlink/params.py).
"""

from __future__ import annotations

import logging
import math
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as M

from edge.vehicle.px4.params import encode

from .commands import CommandAwaiter, VehicleLinkError, await_reply
from .dialect import Dialect
from .handlers import Telemetry
from .link import Link

__all__ = ["ParamClient"]

log = logging.getLogger("skynet.mavlink")


class ParamClient:
    """The driver's parameter calls (a mixin of :class:`.driver.MavlinkDriver`: its link, telemetry, dialect)."""

    uav: int
    tel: Telemetry
    link: Link
    commands: CommandAwaiter
    #: the autopilot's parameter naming scheme (the dialect's ``schemes``); None until learnt
    param_scheme: str | None = None

    def _link_error(self) -> VehicleLinkError | None:
        raise NotImplementedError

    @property
    def dialect(self) -> Dialect:
        """The autopilot family (the driver's: given, or from the HEARTBEAT)."""
        raise NotImplementedError

    def _param_exchange(self, name: str, send: Any, timeout_s: float, retries: int) -> float | None:
        """Send ``send`` (a PARAM_REQUEST_READ or PARAM_SET) until a PARAM_VALUE of ``name`` or a PARAM_ERROR for it
        arrives after it: the value, or None for PARAM_ERROR (the parameter does not exist)."""
        if len(name) > 16 or not name.isascii():
            raise ValueError(f"bad parameter name {name!r}")
        err = self._link_error()
        if err is not None:
            raise err
        tel, rx0 = self.tel, [0]

        def ask(_: int) -> None:
            with tel.cv:
                rx0[0] = tel.rx
            self.link.send(send)

        def reply() -> tuple[float | None] | None:
            got = tel.param_rx.get(name)
            if got is not None and got[1] > rx0[0]:
                return (got[0],)
            return (None,) if tel.param_err.get(name, -1) > rx0[0] else None

        with self.commands.lock:
            answer = await_reply(tel.cv, ask, reply, timeout_s, retries)
        if answer is not None:
            return answer[0]
        raise VehicleLinkError(f"no answer from the autopilot for parameter {name} "
                               f"({timeout_s:g} s x {retries + 1} attempts)")

    def read_param(self, name: str, timeout_s: float = 1.0, retries: int = 2) -> float | None:
        """PARAM_REQUEST_READ by name: the value as the autopilot stores it, or None when it answers PARAM_ERROR
        (no such parameter); :class:`VehicleLinkError` without an answer."""
        raw = name.encode("ascii", "replace")
        msg = M.MAVLink_param_request_read_message(self.tel.sysid or 0, self.tel.compid, raw, -1)
        return self._param_exchange(name, msg, timeout_s, retries)

    def set_param(self, name: str, value: float, param_type: int = M.MAV_PARAM_TYPE_REAL32,
                  timeout_s: float = 1.0, retries: int = 2) -> float:
        """PARAM_SET and wait for the echoed PARAM_VALUE (ArduPilot's ints travel as float values). Raises
        ValueError when the parameter does not exist or the autopilot kept another value (refused)."""
        value = float(value)
        if not math.isfinite(value):
            raise ValueError(f"parameter {name}: value must be finite")
        raw = name.encode("ascii", "replace")
        wire = value
        if self.dialect.param_bitcast and param_type != M.MAV_PARAM_TYPE_REAL32:
            wire = encode(round(value), param_type)  # PX4: an integer's bytes in the float field
        msg = M.MAVLink_param_set_message(self.tel.sysid or 0, self.tel.compid, raw, wire, param_type)
        got = self._param_exchange(name, msg, timeout_s, retries)
        if got is None:
            raise ValueError(f"parameter {name} does not exist on the autopilot")
        if not math.isclose(got, value, rel_tol=1e-6, abs_tol=1e-6):
            raise ValueError(f"parameter {name}: the autopilot kept {got:g} instead of {value:g}")
        return got

    def learn_param_scheme(self, timeout_s: float = 1.0) -> str:
        """The autopilot's parameter naming scheme, learnt once: read the newest scheme's waypoint speed (4.7's
        WP_SPD); a value means that scheme; PARAM_ERROR (or silence, as firmware before PARAM_ERROR) means
        trying the older one (4.6's WPNAV_SPEED)."""
        if self.param_scheme is not None:
            return self.param_scheme
        schemes = self.dialect.schemes
        scheme = None
        for candidate in reversed(schemes):
            try:
                value = self.read_param(self.dialect.param_name("wp_speed", candidate), timeout_s=timeout_s, retries=1)
            except VehicleLinkError:
                if candidate == schemes[0]:
                    raise
                continue
            if value is not None:
                scheme = candidate
                break
        if scheme is None:
            raise ValueError("the autopilot has neither WP_SPD nor WPNAV_SPEED: unknown parameter scheme")
        self.param_scheme = scheme
        log.info("UAV %d: autopilot parameters in %s %s's naming scheme", self.uav, self.dialect.name, scheme)
        return scheme

    def _spelling(self, key: str) -> tuple[str, str, float]:
        """(name, scheme of that name, current raw value) of renamed parameter ``key``: the learnt scheme's
        name, else the other scheme's (firmware mid-way through the renames, e.g. 4.7.0 kept SYSID_THISMAV)."""
        first, d = self.learn_param_scheme(), self.dialect
        for scheme in (first, *(x for x in d.schemes if x != first)):
            name = d.param_name(key, scheme)
            raw = self.read_param(name)
            if raw is not None:
                return name, scheme, raw
        raise ValueError(f"the autopilot has no parameter {' or '.join(d.param_name(key, x) for x in d.schemes)}")

    def read_param_si(self, key: str) -> float:
        """Renamed parameter ``key`` (:data:`.apm.params.RENAMED`, e.g. "wp_speed") in SI units (m, m/s)."""
        _, scheme, raw = self._spelling(key)
        return self.dialect.from_raw(key, raw, scheme)

    def set_param_si(self, key: str, si: float) -> float:
        """Set renamed parameter ``key`` from a value in SI units, in the autopilot's name and unit; the value
        stored, in SI units."""
        name, scheme, _ = self._spelling(key)
        d = self.dialect
        raw = d.to_raw(key, si, scheme)
        ptype = d.param_type(key, scheme)
        if ptype != M.MAV_PARAM_TYPE_REAL32:
            raw = float(round(raw))
        return d.from_raw(key, self.set_param(name, raw, ptype), scheme)

    def set_waypoint_speed(self, speed: float) -> float:
        """The autopilot's default waypoint speed (WPNAV_SPEED cm/s in 4.6, WP_SPD m/s in 4.7), m/s."""
        if not (math.isfinite(speed) and speed > 0):
            raise ValueError("waypoint speed must be finite and > 0")
        return self.set_param_si("wp_speed", speed)
