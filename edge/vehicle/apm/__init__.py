"""Pure cores of the simulated ArduCopter (:mod:`edge.vehicle.mavsim` is their socket shell).

Design notes: docs/hardware-mavlink.md (edge/vehicle/apm/__init__.py).
"""
