"""The camera's optics: the pinhole model with the paper's task-assessment geometry, and poses.

Design notes: docs/edge.md (edge/geometry/optics.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from protocol.checks import positive as _positive

__all__ = ["CameraModel", "CameraPose", "overlap_spacing"]


def overlap_spacing(a_fov: float, overlap: float) -> float:
    """(P3) the largest spacing between neighbouring shots, ``g = (1 - o_p) a_fov``, metres."""
    a = _positive("a_fov", a_fov)
    o = float(overlap)
    if not (math.isfinite(o) and 0.0 <= o < 1.0):
        raise ValueError(f"overlap must lie in [0, 1), got {overlap!r}")
    return (1.0 - o) * a


# ============================================================================ camera model
@dataclass(frozen=True)
class CameraModel:
    """Pinhole camera: delivered frame ``(width, height)`` (px), sensor ``(s_w, s_h)`` and focal length ``f``
    (mm). The defaults are the paper's camera as the planner reads it (docs/planner.md): 34.4 mm
    35 mm-equivalent on 36 mm x 27 mm, delivering 640 x 480 frames (the stills' field of view)."""

    resolution: tuple[int, int] = (640, 480)
    sensor_mm: tuple[float, float] = (36.0, 27.0)
    focal_mm: float = 34.4

    def __post_init__(self) -> None:
        try:
            w, h = self.resolution
            sw, sh = self.sensor_mm
        except (TypeError, ValueError):
            raise ValueError("resolution and sensor_mm must be (width, height) pairs") from None
        if not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 1 for v in (w, h)):
            raise ValueError(f"resolution must be two positive integers, got {self.resolution!r}")
        object.__setattr__(self, "resolution", (int(w), int(h)))
        object.__setattr__(self, "sensor_mm", (_positive("sensor width", sw), _positive("sensor height", sh)))
        object.__setattr__(self, "focal_mm", _positive("focal_mm", self.focal_mm))

    # ------------------------------------------------------------------ intrinsics
    def intrinsics(self) -> tuple[float, float, float, float]:
        """``(fx, fy, cx, cy)`` in pixels: ``f W / s_w``, ``f H / s_h``, ``(W - 1) / 2``, ``(H - 1) / 2``."""
        w, h = self.resolution
        return (self.focal_mm * w / self.sensor_mm[0], self.focal_mm * h / self.sensor_mm[1],
                (w - 1) / 2.0, (h - 1) / 2.0)

    def K(self) -> NDArray[np.float64]:
        """The 3 x 3 intrinsic matrix."""
        fx, fy, cx, cy = self.intrinsics()
        return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])

    @property
    def fov_rad(self) -> tuple[float, float]:
        """Full horizontal and vertical field of view, radians: ``2 atan(s / 2f)``."""
        return (2 * math.atan(self.sensor_mm[0] / (2 * self.focal_mm)),
                2 * math.atan(self.sensor_mm[1] / (2 * self.focal_mm)))

    def scaled(self, width: int, height: int) -> CameraModel:
        """The same optics delivering ``width x height`` frames."""
        return CameraModel((int(width), int(height)), self.sensor_mm, self.focal_mm)

    # ------------------------------------------------------------------ task assessment (P1)-(P3)
    def footprint(self, distance_m: float) -> tuple[float, float]:
        """Footprint (width, height), metres, of a square-on shot from ``distance_m``: ``d s_s / f``.

        The inverse of (P2).
        """
        d = _positive("distance_m", distance_m)
        return d * self.sensor_mm[0] / self.focal_mm, d * self.sensor_mm[1] / self.focal_mm

    def gsd(self, distance_m: float) -> tuple[float, float]:
        """Ground sample distance (metres per pixel of the delivered frame) at ``distance_m``."""
        a_w, a_h = self.footprint(distance_m)
        return a_w / self.resolution[0], a_h / self.resolution[1]

    def feature_footprint(self, smallest_feature_m: float) -> tuple[float, float]:
        """(P1) ``a_fov = 1/2 r_c s_f`` per axis, metres: two frame pixels per smallest feature."""
        s_f = _positive("smallest_feature_m", smallest_feature_m)
        return 0.5 * self.resolution[0] * s_f, 0.5 * self.resolution[1] * s_f

    def standoff(self, smallest_feature_m: float) -> float:
        """(P2) ``d_f = a_fov f / s_s``, metres; the smaller of the two axes (resolves ``s_f`` on both)."""
        a_w, a_h = self.feature_footprint(smallest_feature_m)
        return min(a_w * self.focal_mm / self.sensor_mm[0], a_h * self.focal_mm / self.sensor_mm[1])

    def spacing(self, distance_m: float, overlap: float) -> tuple[float, float]:
        """(P3) ``g = (1 - o_p) a_fov`` per axis, metres, for shots from ``distance_m``."""
        a_w, a_h = self.footprint(distance_m)
        return overlap_spacing(a_w, overlap), overlap_spacing(a_h, overlap)

    @classmethod
    def of(cls, camera: Any) -> CameraModel:
        """The model of a scenario's camera (:class:`protocol.scenario.Camera`), at its own resolution."""
        return cls(tuple(camera.resolution), tuple(camera.sensor_mm), camera.focal_mm)

    def project(self, points: ArrayLike, pose: CameraPose) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Project world points (..., 3) into the frame: pixel coordinates (..., 2) and depth (...,).

        Points with depth <= 0 are behind the camera; their pixel coordinates mean nothing.
        """
        pc = pose.world_to_camera(points)
        z = pc[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uvw = pc @ self.K().T
            px = uvw[..., :2] / uvw[..., 2:3]
        return px, z


# ============================================================================ pose
@dataclass(frozen=True)
class CameraPose:
    """Where the camera is and where it looks: centre ``C`` (ENU m) and the world-from-camera rotation ``R``
    (a proper rotation to 1e-6) whose columns are the OpenCV camera axes (x right, y down, z forward) in ENU."""

    position: NDArray[np.float64]
    rotation: NDArray[np.float64]

    def __post_init__(self) -> None:
        p = np.asarray(self.position, dtype=np.float64).reshape(-1)
        R = np.asarray(self.rotation, dtype=np.float64)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ValueError(f"position must be a finite 3-vector, got {self.position!r}")
        if R.shape != (3, 3) or not np.all(np.isfinite(R)):
            raise ValueError("rotation must be a finite 3 x 3 matrix")
        if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise ValueError("rotation must be a proper rotation matrix (orthonormal, det +1)")
        object.__setattr__(self, "position", p)
        object.__setattr__(self, "rotation", R)

    @classmethod
    def looking(cls, position: ArrayLike, yaw: float, pitch: float = 0.0, roll: float = 0.0) -> CameraPose:
        """A gimbal camera looking along heading ``yaw``, tilted down by ``pitch``, rolled by ``roll``.

        ``yaw`` is the heading of the optical axis in the ENU plane, radians counter-clockwise from
        east (the ψ of (P7)); ``pitch`` tilts the optical axis *down* (gimbal tilt: ``pi/2`` looks
        straight down); ``roll`` turns the camera about its optical axis, positive turning the
        image's x axis towards its y axis. At ``(0, 0, 0)`` the camera looks east, x points south,
        y down.
        """
        for name, a in (("yaw", yaw), ("pitch", pitch), ("roll", roll)):
            if not math.isfinite(a):
                raise ValueError(f"{name} must be finite, got {a!r}")
        c, s = math.cos(yaw), math.sin(yaw)
        cp, sp = math.cos(pitch), math.sin(pitch)
        z = np.array([c * cp, s * cp, -sp])
        x = np.array([s, -c, 0.0])
        y = np.cross(z, x)
        cr, sr = math.cos(roll), math.sin(roll)
        x, y = cr * x + sr * y, -sr * x + cr * y
        return cls(np.asarray(position, dtype=float), np.column_stack([x, y, z]))

    @classmethod
    def facing(cls, target: ArrayLike, normal: ArrayLike, distance: float,
               up: ArrayLike = (0.0, 0.0, 1.0)) -> CameraPose:
        """The camera ``distance`` metres out along ``normal`` from ``target``, looking back at it.

        The image's y axis points as nearly as possible along ``-up`` (world up is image up); when
        the optical axis is parallel to ``up`` (looking straight down or up), north is image up.
        For a :class:`~edge.world.surface.SyntheticSurface` ``s``, ``facing(point, s.normal, d)`` is the
        square-on shot the task assessment (P1)-(P3) assumes.
        """
        t = np.asarray(target, dtype=float)
        n = np.asarray(normal, dtype=float)
        u = np.asarray(up, dtype=float)
        if t.shape != (3,) or n.shape != (3,) or u.shape != (3,) or not np.all(np.isfinite(np.r_[t, n, u])):
            raise ValueError("target, normal and up must be finite 3-vectors")
        if np.linalg.norm(n) < 1e-12 or np.linalg.norm(u) < 1e-12:
            raise ValueError("normal and up must be non-zero")
        d = _positive("distance", distance)
        z = -n / np.linalg.norm(n)
        x = np.cross(z, u)
        if np.linalg.norm(x) < 1e-9 * np.linalg.norm(u):
            x = np.cross(z, [0.0, 1.0, 0.0])
        x /= np.linalg.norm(x)
        return cls(t - d * z, np.column_stack([x, np.cross(z, x), z]))

    @property
    def optical_axis(self) -> NDArray[np.float64]:
        """Unit optical axis (camera z) in ENU."""
        return self.rotation[:, 2]

    def world_to_camera(self, points: ArrayLike) -> NDArray[np.float64]:
        """World points (..., 3) in the camera frame: ``R^T (X - C)``."""
        X = np.asarray(points, dtype=float)
        if X.ndim == 0 or X.shape[-1] != 3:
            raise ValueError(f"points must have shape (..., 3), got {X.shape}")
        return (X - self.position) @ self.rotation
