"""``skynet sim-autopilot``: the sim autopilot's one command line (:mod:`edge.vehicle.mavsim.cli`)."""

from edge.vehicle.mavsim.cli import build_parser, connection_for, main

__all__ = ["build_parser", "main", "connection_for"]

if __name__ == "__main__":
    raise SystemExit(main())
