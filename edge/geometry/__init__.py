"""Geometry shared by the UAV and the ground: formations, optics, neighbourhoods, geodetic frames,
the waypoint-mission builder, ArduPilot mission-item conventions and the board's geometric checks.

Pure modules over :mod:`protocol` (numpy, pymap3d): no bus, no OpenCV, nothing else of :mod:`edge`,
so that the ground services import them without loading the UAV's process (the import contracts
in ``pyproject.toml``, checked by ``tests/test_layers.py``).
"""
