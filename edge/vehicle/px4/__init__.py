"""PX4's conventions, beside :mod:`edge.vehicle.apm` for ArduPilot's (pure: no socket).

Design notes: docs/hardware-mavlink.md (edge/vehicle/px4/__init__.py).
"""
