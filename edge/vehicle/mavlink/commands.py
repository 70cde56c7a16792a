"""One command sent and its COMMAND_ACK awaited (the MAVLink command protocol,
https://mavlink.io/en/services/command.html).

Design notes: docs/hardware-mavlink.md (edge/vehicle/mavlink/commands.py).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as M

from .handlers import Telemetry

__all__ = ["VehicleLinkError", "CommandRefused", "CommandAwaiter", "await_reply", "result_name", "command_name"]

#: sends one attempt: (command, confirmation, param1..7, frame or None for COMMAND_LONG)
Sender = Callable[[int, int, tuple[float, ...], "int | None"], None]


class VehicleLinkError(ValueError):
    """No (recent) HEARTBEAT from the autopilot, or no answer: the vehicle cannot be commanded."""


def result_name(result: int) -> str:
    """``MAV_RESULT_*`` name of a COMMAND_ACK result."""
    e = M.enums["MAV_RESULT"].get(int(result))
    return e.name if e is not None else f"MAV_RESULT {int(result)}"


def command_name(command: int) -> str:
    """``MAV_CMD_*`` name of a command id (or ``MAVLINK_MSG_ID_<n>`` for a message acked as a command)."""
    e = M.enums["MAV_CMD"].get(int(command))
    return e.name if e is not None else f"MAVLINK_MSG_ID_{int(command)}"


class CommandRefused(VehicleLinkError):
    """The autopilot answered a command with a MAV_RESULT other than ACCEPTED."""

    def __init__(self, what: str, command: int, result: int, texts: tuple[str, ...] = ()):
        self.what, self.command, self.result, self.texts = what, int(command), int(result), texts
        why = f" ({'; '.join(texts)})" if texts else ""
        super().__init__(f"{what} refused by the autopilot: {result_name(result)} to {command_name(command)}{why}")


#: a ``reply`` answer that restarts the attempt's timeout (MAV_RESULT_IN_PROGRESS)
MORE = object()


def await_reply(cv: threading.Condition, send: Callable[[int], None], reply: Callable[[], Any],
                timeout_s: float, retries: int) -> Any:
    """``send(attempt)`` until ``reply()`` (asked under ``cv`` at every wake-up) returns something but None,
    ``timeout_s`` per attempt and ``retries`` resends; None when every attempt timed out."""
    for attempt in range(retries + 1):
        send(attempt)
        deadline = time.monotonic() + timeout_s
        with cv:
            while True:
                got = reply()
                if got is MORE:
                    deadline = time.monotonic() + timeout_s
                elif got is not None:
                    return got
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                cv.wait(left)
    return None


class CommandAwaiter:
    """Sends commands through ``send`` and matches the COMMAND_ACKs the handlers store in ``tel.acks``.

    ``lock`` holds one command (or a sequence of them, e.g. a mode switch) in flight at a time.
    """

    def __init__(self, tel: Telemetry, send: Sender, timeout_s: float, retries: int):
        self.tel, self._send = tel, send
        self.timeout_s, self.retries = float(timeout_s), int(retries)
        self.lock = threading.RLock()

    def call(self, command: int, params: tuple[float, ...], what: str, frame: int | None = None) -> int:
        """Send ``command`` (param1..7, missing ones 0) until its COMMAND_ACK; the ack's receive index."""
        tel, p = self.tel, tuple(float(x) for x in params) + (0.0,) * (7 - len(params))

        def send(attempt: int) -> None:
            with tel.cv:
                tel.acks.pop(command, None)
            self._send(command, attempt, p, frame)

        def reply() -> Any:
            a = tel.acks.pop(command, None)
            return MORE if a is not None and a[0] == M.MAV_RESULT_IN_PROGRESS else a

        with self.lock:
            sent_mono = time.monotonic()
            got = await_reply(tel.cv, send, reply, self.timeout_s, self.retries)
        if got is None:
            raise VehicleLinkError(f"{what}: no COMMAND_ACK to {command_name(command)} within "
                                   f"{self.timeout_s:g} s x {self.retries + 1} attempts")
        if got[0] != M.MAV_RESULT_ACCEPTED:
            with tel.lock:
                texts = tuple(t for m, _, t in tel.texts if m >= sent_mono - 1.0)
            raise CommandRefused(what, command, got[0], texts)
        return got[1]
