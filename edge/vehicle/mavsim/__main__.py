"""``python -m edge.vehicle.mavsim``: the same command line as ``skynet sim-autopilot``."""

from .cli import main

raise SystemExit(main(prog="python -m edge.vehicle.mavsim"))
