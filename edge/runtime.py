"""Wiring of the edge process: which driver, which camera, and the camera's bus binding.

Kept out of :mod:`edge.board` so that the board's logic stays a thin shell over the driver,
and so that the ground station can rebuild the very same synthetic surface (and so its ground
truth) from the scenario with :func:`synthetic_surface`.
"""

from __future__ import annotations

import argparse
import logging
import math

import numpy as np

from protocol import keys
from protocol.bus import Bus
from protocol.imagery import pack_image
from protocol.links import IMAGERY
from protocol.messages import ImageMeta, Intrinsics
from protocol.rtp import RtpSender, ssrc_for

from .vehicle.driver import CaptureEvent, VehicleDriver

#: frames each camera keeps for retransmission of frames lost on the way
IMAGERY_CACHE_FRAMES = 32
#: seed of the synthetic surface: one wall for the whole fleet, whatever the UAV
SURFACE_SEED = 2024


def make_driver(args: argparse.Namespace, t0: float) -> VehicleDriver:
    if args.vehicle == "sim":
        from .vehicle.quadrotor import DisturbanceParams
        from .vehicle.sim import SimDriver, SimParams

        wind = DisturbanceParams.moderate() if args.wind == "moderate" else DisturbanceParams()
        return SimDriver(args.uav, params=SimParams(disturbance=wind), home=args.home, t0=t0,
                         seed=args.seed if args.seed is not None else args.uav)
    from .vehicle.mavlink import MavlinkDriver  # needs the "mavlink" extra

    return MavlinkDriver(args.uav, args.mavlink, home=args.home)


def synthetic_surface(scenario: dict, px_per_m: float | None = None, seed: int = SURFACE_SEED):
    """The inspected wall of the scenario as a textured, cracked :class:`SyntheticSurface`."""
    from .surface import DEFAULT_PX_PER_M, SyntheticSurface

    corners = np.asarray(scenario["surface"]["corners"], dtype=float)
    return SyntheticSurface.from_corners(corners, px_per_m=px_per_m or DEFAULT_PX_PER_M, seed=seed)


def camera_model(scenario: dict, frame_size: tuple[int, int]):
    """The scenario's camera delivering ``frame_size`` frames (the same field of view, fewer pixels)."""
    from .camera import CameraModel

    cam = scenario["camera"]
    return CameraModel(resolution=frame_size, sensor_mm=tuple(cam["sensor_mm"]), focal_mm=float(cam["focal_mm"]))


def camera_rotation(yaw: float) -> np.ndarray:
    """World-from-camera rotation of a gimbal-stabilised camera looking horizontally along ``yaw``.

    OpenCV camera axes: z forward (the optical axis), x right, y down.
    """
    c, s = math.cos(yaw), math.sin(yaw)
    z = np.array([c, s, 0.0])
    x = np.array([s, -c, 0.0])
    y = np.array([0.0, 0.0, -1.0])
    return np.column_stack([x, y, z])


class CameraLink:
    """Capture -> frame -> JPEG (off the control loop) -> imagery sample on the bus."""

    def __init__(self, bus: Bus, uav: int, source, model, surface=None, log: logging.Logger | None = None,
                 quality: int = 85):
        from .camera import FrameEncoder

        self.bus, self.uav, self.source, self.model, self.surface, self.log = bus, uav, source, model, surface, log
        self.sender = RtpSender(ssrc_for(uav, 0))
        # keep the last frames for retransmission to subscribers that ask (RTP NACK-like recovery)
        self.pub = bus.publisher(keys.camera(bus.fleet, uav), IMAGERY, cache=IMAGERY_CACHE_FRAMES)
        self.encoder = FrameEncoder(self._publish, capacity=4, quality=quality)
        self.sent = 0

    def range_to_surface(self, pos: np.ndarray, axis: np.ndarray) -> float | None:
        """Distance along the optical axis to the wall (what a rangefinder would measure)."""
        if self.surface is None:
            return None
        n = self.surface.normal
        along = float(np.dot(axis, n))
        if along >= -1e-6:
            return None
        return float(np.dot(self.surface.origin - pos, n)) / along

    def intrinsics(self, width: int, height: int) -> Intrinsics:
        fx, fy, cx, cy = self.model.scaled(width, height).intrinsics()
        return Intrinsics(width=width, height=height, fx=fx, fy=fy, cx=cx, cy=cy)

    def capture(self, ev: CaptureEvent, stamp: float) -> None:
        from .camera import CameraPose

        R = camera_rotation(ev.att[2])
        pose = CameraPose(position=np.asarray(ev.pos, dtype=float), rotation=R)
        frame = self.source.grab(pose, ev.t)
        if frame is None:
            if self.log:
                self.log.warning("capture %d: the camera gave no frame", ev.capture_id)
            return
        h, w = frame.image.shape[:2]
        rng = self.range_to_surface(pose.position, R[:, 2])
        meta = ImageMeta(uav=self.uav, capture_id=ev.capture_id, t=max(0.0, ev.t), stamp=stamp,
                         cam_pos=tuple(map(float, ev.pos)), cam_rot=tuple(map(float, R.ravel())),
                         intrinsics=self.intrinsics(w, h), range_m=rng if rng and rng <= 1000 else None)
        self.encoder.submit(frame.image, meta)

    def _publish(self, meta: ImageMeta, jpeg: bytes) -> None:
        self.pub.put_bytes(pack_image(self.sender, meta, jpeg, meta.stamp))
        self.sent += 1

    def close(self) -> None:
        self.encoder.close()
        self.source.close()


def make_camera(args: argparse.Namespace, bus: Bus, log: logging.Logger) -> CameraLink | None:
    if args.camera in ("", "none"):
        return None
    from .camera import make_source

    w, h = (int(v) for v in args.frame_size.lower().split("x"))
    from services.planner.scenario import load_scenario_document

    scenario = load_scenario_document(args.scenario)
    model = camera_model(scenario, (w, h))
    surface = synthetic_surface(scenario) if args.camera == "synthetic" else None
    source = make_source(args.camera, surface=surface, camera=model)
    return CameraLink(bus, args.uav, source, model, surface=surface, log=log)
