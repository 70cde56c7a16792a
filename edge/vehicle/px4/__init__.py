"""PX4's conventions, beside :mod:`edge.vehicle.apm` for ArduPilot's (pure: no socket).

- :mod:`.modes`  PX4's custom modes (``(sub_mode << 24) | (main_mode << 16)``), their names, the
  board's reading of a mode the edge did not command, HEARTBEAT base_mode, and the mode rules the
  sim autopilot applies when it presents itself as PX4;
- :mod:`.params` PX4's parameter names the project uses, their types, and the byte-wise encoding of
  integer parameters in PARAM_VALUE / PARAM_SET's float field;
- :mod:`.missions` PX4's mission numbering (item 0 is the first real item, no home item).

The driver's PX4 dialect (:class:`edge.vehicle.mavlink.dialect.Px4`) and the sim autopilot's PX4
persona (:mod:`edge.vehicle.mavsim.px4`) use them.
"""
