"""Camera geometry shared by the edge and the ground: the scenario's camera at a frame size, and the
orientation of a gimbal-stabilised camera (OpenCV axes)."""

from __future__ import annotations

import math

import numpy as np

from protocol.scenario import Scenario

from .optics import CameraModel


def camera_model(scenario: Scenario, frame_size: tuple[int, int]) -> CameraModel:
    """The scenario's camera delivering ``frame_size`` frames (the same field of view, fewer pixels)."""
    cam = scenario.camera
    return CameraModel(resolution=frame_size, sensor_mm=cam.sensor_mm, focal_mm=cam.focal_mm)


def camera_rotation(yaw: float) -> np.ndarray:
    """World-from-camera rotation of a gimbal-stabilised camera looking horizontally along ``yaw``.

    OpenCV camera axes: z forward (the optical axis), x right, y down.
    """
    c, s = math.cos(yaw), math.sin(yaw)
    z = np.array([c, s, 0.0])
    x = np.array([s, -c, 0.0])
    y = np.array([0.0, 0.0, -1.0])
    return np.column_stack([x, y, z])
