"""Capture frames of a synthetic wall at the planned shots, without the bus (pure).

Design notes: docs/report.md (services/inspection/captures.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from edge.geometry.camera import camera_model, camera_rotation
from edge.geometry.optics import CameraPose
from edge.world.camera import SyntheticSource
from edge.world.surface import SyntheticSurface, textured_background
from edge.world.wall import synthetic_surface
from protocol.imagecodec import decode_image, encode_jpeg
from protocol.messages import ImageMeta, Intrinsics
from protocol.scenario import Scenario
from services.planner.task import formation_pass

__all__ = ["Capture", "capture_meta", "synthetic_captures"]


@dataclass(frozen=True)
class Capture:
    """One capture: its metadata, the JPEG bytes as sent, and the rendered truth mask."""

    meta: ImageMeta
    jpeg: bytes
    truth: np.ndarray  # uint8 0/255, frame pixels


def capture_meta(uav: int, capture_id: int, pos: np.ndarray, rot: np.ndarray, size: tuple[int, int],
                 fx: float, fy: float, cx: float, cy: float, range_m: float | None) -> ImageMeta:
    """The :class:`ImageMeta` of a frame (what :class:`edge.camera_service.CameraLink` sends)."""
    return ImageMeta(uav=uav, capture_id=capture_id, t=0.0, stamp=0.0, cam_pos=tuple(map(float, pos)),
                     cam_rot=tuple(map(float, np.asarray(rot).ravel())),
                     intrinsics=Intrinsics(width=size[0], height=size[1], fx=fx, fy=fy, cx=cx, cy=cy),
                     range_m=range_m)


def synthetic_captures(scenario: Scenario, surface: SyntheticSurface, frame_size: tuple[int, int] = (640, 480),
                       jitter_m: float = 0.0, jitter_yaw_rad: float = 0.0, seed: int = 0,
                       quality: int = 85) -> list[Capture]:
    """Render every planned shot of ``scenario`` on ``surface`` (JPEG ``quality`` as the edges send).

    ``jitter_m`` / ``jitter_yaw_rad`` perturb each pose (normal, that standard deviation), as the
    formation's tracking error does in flight; the metadata carries the perturbed (true) pose.
    """
    ip = formation_pass(scenario)
    if ip is None:
        raise ValueError("the scenario has no surface to inspect")
    model = camera_model(scenario, frame_size)
    src = SyntheticSource(surface, model)
    fx, fy, cx, cy = model.intrinsics()
    rng = np.random.default_rng(seed)
    out = []
    n = surface.normal
    for k, (pos, look, uav) in enumerate(zip(ip.positions, ip.look, ip.uav)):
        p = np.asarray(pos, float) + (rng.normal(0.0, jitter_m, 3) if jitter_m > 0 else 0.0)
        yaw = float(np.arctan2(look[1], look[0])) + (float(rng.normal(0.0, jitter_yaw_rad)) if jitter_yaw_rad else 0.0)
        R = camera_rotation(yaw)
        img, gt = src.render(CameraPose(position=p, rotation=R))
        along = float(R[:, 2] @ n)
        rng_m = float((surface.origin - p) @ n) / along if along < -1e-6 else None
        meta = capture_meta(int(uav) + 1, k + 1, p, R, frame_size, fx, fy, cx, cy, rng_m)
        out.append(Capture(meta=meta, jpeg=encode_jpeg(img, quality), truth=gt))
    return out


def decode(c: Capture) -> np.ndarray:
    """The grey frame of a capture (as the detector decodes it: :func:`protocol.imagecodec.decode_image`)."""
    return decode_image(c.jpeg, grey=True)


def known_crack_wall(sc: Scenario) -> tuple[SyntheticSurface, list[tuple[float, float, float, float]]]:
    """The scenario's wall with 14 straight cracks of known length and width (rectangles 2..6 texture
    pixels wide, 1..2.5 m long, at six angles) on the synthetic texture: ``(surface, truth)``, each truth
    ``(u, v, length_m, width_px)`` (the width the drawn rectangle's pixel area over its length). The
    measurements' test and bench/inspection.py score against it."""
    ref = synthetic_surface(sc, seed=1)
    h, w = ref.shape_px
    ppm = ref.px_per_m
    tex = textured_background((h, w), np.random.default_rng(3)).astype(np.float32)
    mask = np.zeros((h, w), np.uint8)
    truth: list[tuple[float, float, float, float]] = []
    for i, u in enumerate(np.arange(2.0, 48.0, 3.5)):
        wpx, length = (2, 3, 4, 5, 6)[i % 5], (1.0, 1.5, 2.0, 2.5)[i % 4]
        v = 1.5 + 3.0 * ((i // 2) % 2)
        one = np.zeros_like(mask)
        box = cv2.boxPoints(((u * ppm, (ref.height_m - v) * ppm), (length * ppm, wpx), -(0, 20, 35, 60, 90, 130)[i % 6]))
        cv2.fillConvexPoly(one, np.round(box * 16).astype(np.int32), 255, cv2.LINE_8, 4)
        mask |= one
        truth.append((float(u), v, length, float(np.count_nonzero(one) / (length * ppm) / ppm)))
    tex[mask > 0] *= 0.55
    surf = SyntheticSurface(ref.origin, ref.u_axis, ref.v_axis, ref.width_m, ref.height_m, ppm,
                            texture=np.clip(tex, 0, 255).astype(np.uint8), mask=mask)
    return surf, truth
