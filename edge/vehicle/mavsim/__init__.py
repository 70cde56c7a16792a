"""The sim autopilot: a MAVLink 2 vehicle that behaves like ArduCopter, flown by the project's simulation.

:class:`MavlinkSimVehicle` stands in for ArduCopter towards real ground stations (QGroundControl, Mission
Planner, MAVProxy, MAVSDK) and towards :class:`edge.vehicle.mavlink.MavlinkDriver`, with
:class:`edge.vehicle.sim.SimDriver` ((P10)-(P17)) flying underneath. The rules live in pure modules
(:mod:`edge.vehicle.apm`); this package is the socket shell, split as the driver is: :mod:`.vehicle` (the link,
the message-type handler table, the model glue), :mod:`.commands` (the MAV_CMD handler table), :mod:`.telemetry`
(what it sends) and :mod:`.cli` (one command line: ``skynet sim-autopilot`` = ``python -m edge.vehicle.mavsim``).
It promises ArduCopter's answers, message by message, and says where it differs: docs/hardware-mavlink.md,
"The sim autopilot, message by message".
"""

from .cli import DEFAULT_ORIGIN, build_parser, main
from .commands import GUIDED_TIMEOUT_S, GuidedTarget
from .vehicle import MavlinkSimVehicle

__all__ = ["GuidedTarget", "MavlinkSimVehicle", "GUIDED_TIMEOUT_S", "DEFAULT_ORIGIN", "build_parser", "main"]
