"""The sim autopilot's one command line: ``skynet sim-autopilot`` = ``python -m edge.vehicle.mavsim``.

Design notes: docs/hardware-mavlink.md (edge/vehicle/mavsim/cli.py).
"""

from __future__ import annotations

import argparse
import sys

from edge.vehicle.apm.params import DEFAULT_SCHEME, SCHEMES
from edge.vehicle.driver import check_vec3
from edge.vehicle.quadrotor import DisturbanceParams
from edge.vehicle.sim import SimParams
from protocol.cliconfig import show_defaults
from protocol.signals import stop_event_on_signals

from .px4 import Px4SimVehicle
from .vehicle import DEFAULT_ORIGIN, MavlinkSimVehicle, Vec3

__all__ = ["build_parser", "main", "connection_for", "DEFAULT_ORIGIN"]


def connection_for(template: str, uav: int, port_base: int) -> str:
    """The connection string of autopilot ``uav`` (``{port}`` -> port_base + uav − 1, ``{uav}`` -> uav)."""
    port = port_base + uav - 1
    if not 1 <= port <= 65535:
        raise ValueError(f"uav {uav}: port {port} is out of range")
    return template.replace("{port}", str(port)).replace("{uav}", str(uav))


def _vec(text: str) -> Vec3:
    try:
        return check_vec3([float(x) for x in text.split(",")], "vector")
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected three comma-separated numbers ({exc})") from None


def _param(text: str) -> tuple[str, float]:
    name, _, value = text.partition("=")
    try:
        return name.strip().upper(), float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}") from None


def _hostport(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    try:
        if host and 1 <= int(port) <= 65535:
            return host, int(port)
    except ValueError:
        pass
    raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")


def build_parser(prog: str = "skynet sim-autopilot") -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    p.add_argument("--uav", type=int, action="append", required=True, help="system id (repeatable)")
    p.add_argument("--connection", default="udpout:127.0.0.1:{port}",
                   help="pymavlink connection string (udpout:HOST:PORT reaches a GCS listening there); "
                        "{port} and {uav} are substituted")
    p.add_argument("--port-base", type=int, default=14550, help="{port} of uav 1 (uav N: base + N - 1)")
    p.add_argument("--home", type=_vec, action="append", default=[], help="launch point x,y,z per uav (ENU m)")
    p.add_argument("--origin", type=_vec, default=DEFAULT_ORIGIN, help="geodetic origin lat,lon,alt of the ENU frame")
    p.add_argument("--speed", type=float, default=1.0, help="simulation speed factor")
    p.add_argument("--epoch", type=float, default=None, help="wall-clock UNIX time of sim time 0 (share the board's)")
    p.add_argument("--seed", type=int, default=0, help="disturbance seed (uav N: seed + N)")
    p.add_argument("--wind", choices=["calm", "moderate"], default="calm")
    p.add_argument("--telemetry-hz", type=float, default=20.0, help="position and attitude rate with --stream-all")
    p.add_argument("--refuse-arming", action="store_true", help="fail every arming request (PreArm)")
    p.add_argument("--mavlink-key", default=None, help="MAVLink 2 signing key: 64 hex digits or a passphrase")
    p.add_argument("--param", type=_param, action="append", default=[], metavar="NAME=VALUE",
                   help="initial parameter value (repeatable), e.g. FS_GCS_ENABLE=1")
    p.add_argument("--boot-scale", type=float, default=1.0,
                   help="start-up times as a fraction of ArduCopter's (1: BOOT 2 s, home 20 s, armable 24 s, "
                        "GUIDED/AUTO 42 s; 0: ready at once)")
    p.add_argument("--stream-all", action="store_true",
                   help="stream telemetry unasked (ArduCopter sends only HEARTBEAT until a ground station asks)")
    p.add_argument("--firmware-version", choices=SCHEMES, default=DEFAULT_SCHEME,
                   help="parameter names and units of this ArduCopter version: 4.6 (stable 4.5/4.6: SYSID_THISMAV, "
                        "WPNAV_SPEED cm/s, RTL_ALT cm, LAND_SPEED, ARMING_CHECK) or 4.7 (4.7+: MAV_SYSID, WP_SPD m/s, "
                        "RTL_ALT_M m, LAND_SPD_MS, ARMING_SKIPCHK, WP_RADIUS_M, MAV_GCS_SYSID)")
    p.add_argument("--legacy-mission-request", action="store_true",
                   help="ask for uploaded mission items with MISSION_REQUEST (as ArduCopter's firmware may) "
                        "instead of MISSION_REQUEST_INT")
    p.add_argument("--firmware", choices=["arducopter", "px4"], default="arducopter",
                   help="the firmware to present: ArduCopter (the default) or PX4 (HEARTBEAT autopilot 12, PX4's "
                        "custom modes, OFFBOARD, missions without a home item, PX4's parameter names; "
                        "--firmware-version, --stream-all and --legacy-mission-request then do not apply)")
    p.add_argument("--remote", type=_hostport, default=None, metavar="HOST:PORT",
                   help="--firmware px4 with a udpin --connection: send to HOST:PORT until a ground station's packet "
                        "arrives, then to it (PX4's SITL: udpin:0.0.0.0:18570 with 127.0.0.1:14550)")
    p.add_argument("--rc-centred", action="store_true",
                   help="a pilot's RC transmitter is on with its sticks centred: LOITER holds position and altitude "
                        "(without RC input, the default, LOITER descends at the throttle-down rate as ArduCopter does)")
    return show_defaults(p)


def main(argv: list[str] | None = None, prog: str = "skynet sim-autopilot") -> int:
    args = build_parser(prog).parse_args(argv)
    if len(set(args.uav)) != len(args.uav):
        print("sim-autopilot: every --uav must be a distinct system id", file=sys.stderr)
        return 2
    if args.remote is not None and args.firmware != "px4":
        print("sim-autopilot: --remote applies to --firmware px4", file=sys.stderr)
        return 2
    if args.home and len(args.home) != len(args.uav):
        print("sim-autopilot: give one --home per --uav (or none)", file=sys.stderr)
        return 2
    wind = DisturbanceParams.moderate() if args.wind == "moderate" else DisturbanceParams()
    vehicles: list[MavlinkSimVehicle] = []
    try:
        for k, uav in enumerate(args.uav):
            conn = connection_for(args.connection, uav, args.port_base)
            px4 = {"remote": args.remote} if args.firmware == "px4" else {}
            cls = Px4SimVehicle if args.firmware == "px4" else MavlinkSimVehicle
            vehicles.append(cls(conn, uav, **px4, home=args.home[k] if args.home else (0.0, 0.0, 0.0),
                                              speed=args.speed, epoch=args.epoch, params=SimParams(disturbance=wind),
                                              seed=args.seed + uav, telemetry_hz=args.telemetry_hz,
                                              refuse_arming=args.refuse_arming, origin=args.origin,
                                              mavlink_key=args.mavlink_key, param_overrides=dict(args.param),
                                              boot_scale=args.boot_scale, stream_all=args.stream_all,
                                              firmware=args.firmware_version,
                                              legacy_mission_request=args.legacy_mission_request,
                                              rc_centred=args.rc_centred))
            print(f"sim-autopilot: uav {uav} (system id {uav}) as {args.firmware} on {conn}, speed x{args.speed:g}",
                  flush=True)
    except ValueError as exc:
        for v in vehicles:
            v.close()
        print(f"sim-autopilot: {exc}", file=sys.stderr)
        return 2
    stop = stop_event_on_signals()
    for v in vehicles:
        v.start()
    try:
        stop.wait()
    finally:
        for v in vehicles:
            v.close()
    print("sim-autopilot stopped", flush=True)
    return 0
