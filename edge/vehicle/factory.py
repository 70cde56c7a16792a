"""The vehicle driver an edge's configuration asks for: the built-in simulation or a MAVLink autopilot."""

from __future__ import annotations

from ..config import PREVIEW_SIZE, EdgeConfig
from .driver import VehicleDriver
from .quadrotor import DisturbanceParams
from .sim import SimDriver, SimParams


def make_driver(config: EdgeConfig, t0: float) -> VehicleDriver:
    """``--vehicle sim`` (seeded by ``--seed``, else the UAV id) or ``mavlink`` (needs the "mavlink" extra)."""
    if config.vehicle == "sim":
        wind = DisturbanceParams.moderate() if config.wind == "moderate" else DisturbanceParams()
        endurance = {} if config.endurance is None else {"endurance_s": config.endurance}
        return SimDriver(config.uav, params=SimParams(disturbance=wind, **endurance), home=config.home, t0=t0,
                         seed=config.seed if config.seed is not None else config.uav)
    from .mavlink import MavlinkDriver, MavlinkParams

    video = None
    if config.mavlink_video is not None:  # the preview as skynet video sends it (UAV 1: base)
        from .mav_camera import VideoStreamSpec, stream_port

        video = VideoStreamSpec(stream_port(config.mavlink_video, config.uav), *PREVIEW_SIZE,
                                framerate=config.preview_hz)
    origin = None
    if config.home_from_autopilot:  # the mission frame's geodetic origin: the scenario's
        from protocol.scenario import load_scenario

        o = load_scenario(config.scenario).origin
        origin = (o.lat, o.lon, o.alt)
    return MavlinkDriver(config.uav, config.mavlink, home=config.home, signing_key=config.mavlink_key,
                         gcs_endpoint=config.mavlink_gcs, gcs_video=video, params=MavlinkParams(flight=config.flight),
                         home_origin=origin, clock_rate=config.speed)
