"""The driver's phase: what it last commanded the vehicle to do, and how a HEARTBEAT overrules it.

Design notes: docs/hardware-mavlink.md (edge/vehicle/mavlink/phase.py).
"""

from __future__ import annotations

from enum import Enum
from typing import NamedTuple

from protocol.messages import Mode

__all__ = ["Phase", "GROUNDED", "Overrule", "overrule"]


class Phase(str, Enum):
    """The driver's phase (its value is the board's mode name where they coincide)."""

    IDLE = "idle"
    LANDED = "landed"
    TAKEOFF = "takeoff"
    HOLD = "hold"
    MISSION = "mission"  # the trajectory streamed in the guided mode (and the transit in AUTO flight)
    AUTO = "auto"  # the uploaded mission flown by the autopilot
    LAND = "land"
    RTL = "rtl"
    EXTERNAL = "external"  # a mode the driver did not command

    @property
    def mode(self) -> Mode | None:
        """The board's mode of this phase (None for EXTERNAL: the autopilot's mode decides)."""
        if self is Phase.EXTERNAL:
            return None
        return Mode.MISSION if self is Phase.AUTO else Mode(self.value)


GROUNDED = frozenset({Phase.IDLE, Phase.LANDED})


class Overrule(NamedTuple):
    phase: Phase
    pause: bool  # the mission pauses
    noticed: bool  # a mode the driver did not command (logged, listed in ``external_modes``)


def overrule(phase: Phase, *, armed: bool, expected: bool, guided: bool) -> Overrule:
    """The phase after a HEARTBEAT newer than the last accepted command.

    ``expected``: its mode is the phase's own (or one a mode switch in flight may show);
    ``guided``: its mode is the dialect's guided mode (the driver holds there).
    """
    if not armed:
        return Overrule(phase, False, False) if phase in GROUNDED else Overrule(Phase.LANDED, True, False)
    if phase in GROUNDED:
        return Overrule(Phase.EXTERNAL, False, False)  # armed by someone else
    if phase is Phase.EXTERNAL:
        return Overrule(Phase.HOLD if guided else phase, False, False)
    if expected:
        return Overrule(phase, False, False)
    return Overrule(Phase.HOLD if guided else Phase.EXTERNAL, True, True)
