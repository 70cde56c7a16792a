"""The sim autopilot: a MAVLink 2 vehicle that behaves like ArduCopter, flown by the project's simulation.

Design notes: docs/hardware-mavlink.md (edge/vehicle/mavsim/__init__.py).
"""

from .cli import DEFAULT_ORIGIN, build_parser, main
from .commands import GUIDED_TIMEOUT_S, GuidedTarget
from .vehicle import MavlinkSimVehicle

__all__ = ["GuidedTarget", "MavlinkSimVehicle", "GUIDED_TIMEOUT_S", "DEFAULT_ORIGIN", "build_parser", "main"]
