"""A mosaic of the inspected surface from posed frames: each frame warped onto the surface plane.

Design notes: docs/report.md (services/inspection/mosaic.py).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from protocol.messages import ImageMeta
from protocol.scenario import surface_frame

__all__ = ["Plane", "Mosaic", "PosedFrame", "build_mosaic", "canvas_homography", "frame_gsd", "plane_from_frames"]


@dataclass(frozen=True)
class Plane:
    """A rectangle of the world: ``origin + u u_axis + v v_axis``, ``0 <= u <= width_m``, ``0 <= v <= height_m``."""

    origin: NDArray[np.float64]
    u_axis: NDArray[np.float64]
    v_axis: NDArray[np.float64]
    width_m: float
    height_m: float

    @classmethod
    def from_corners(cls, corners: ArrayLike) -> Plane:
        """From the corners p0, p1, p2, p3 (p0-p1 the bottom edge, p3 above p0), ENU metres."""
        p0, u, v = surface_frame(corners)  # the one surface frame (protocol.scenario); ValueError when degenerate
        c = np.asarray(corners, float)
        return cls(p0.copy(), u, v, float((c[1] - p0) @ u), float((c[3] - p0) @ v))

    @property
    def normal(self) -> NDArray[np.float64]:
        return np.cross(self.u_axis, self.v_axis)

    @property
    def corners(self) -> NDArray[np.float64]:
        u, v = self.u_axis * self.width_m, self.v_axis * self.height_m
        return np.array([self.origin, self.origin + u, self.origin + u + v, self.origin + v])

    def to_world(self, uv: ArrayLike) -> NDArray[np.float64]:
        a = np.asarray(uv, float)
        return self.origin + a[..., :1] * self.u_axis + a[..., 1:2] * self.v_axis

    def to_uv(self, points: ArrayLike) -> NDArray[np.float64]:
        d = np.asarray(points, float) - self.origin
        return np.stack([d @ self.u_axis, d @ self.v_axis], axis=-1)


@dataclass(frozen=True)
class PosedFrame:
    """A grey frame with its pose and intrinsics (and optionally its defect mask)."""

    meta: ImageMeta
    grey: NDArray[np.uint8]
    mask: NDArray[np.uint8] | None = None


@dataclass
class Mosaic:
    """The surface seen by the frames: ``image`` (grey, 0 where no frame saw it), ``mask`` (defects),
    ``owner`` (index of the frame each pixel comes from, -1 for none), at ``m_per_px``."""

    plane: Plane
    m_per_px: float
    image: NDArray[np.uint8]
    mask: NDArray[np.uint8]
    owner: NDArray[np.int32]
    seconds: float = 0.0
    frames_used: int = 0
    skipped: list[str] = field(default_factory=list)

    @property
    def coverage(self) -> float:
        """Share of the surface seen by at least one frame."""
        return float(np.count_nonzero(self.owner >= 0)) / self.owner.size

    def pixel_to_uv(self, xy: ArrayLike) -> NDArray[np.float64]:
        a = np.asarray(xy, float)
        s = self.m_per_px
        return np.stack([(a[..., 0] + 0.5) * s, self.plane.height_m - (a[..., 1] + 0.5) * s], axis=-1)


def _meta_arrays(meta: ImageMeta) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    k = meta.intrinsics
    K = np.array([[k.fx, 0.0, k.cx], [0.0, k.fy, k.cy], [0.0, 0.0, 1.0]])
    return K, np.asarray(meta.cam_rot, float).reshape(3, 3), np.asarray(meta.cam_pos, float)


def canvas_homography(meta: ImageMeta, plane: Plane, m_per_px: float) -> NDArray[np.float64] | None:
    """Canvas pixel -> frame pixel homography ``K R^T (A − C e3^T)``; None if the camera is behind the plane."""
    K, R, C = _meta_arrays(meta)
    if float((C - plane.origin) @ plane.normal) <= 1e-9:
        return None
    s = m_per_px
    A = np.column_stack([plane.u_axis * s, -plane.v_axis * s,
                         plane.origin + plane.v_axis * (plane.height_m - 0.5 * s) + plane.u_axis * 0.5 * s])
    return K @ (R.T @ (A - np.outer(C, [0.0, 0.0, 1.0])))


def frame_gsd(meta: ImageMeta) -> float | None:
    """Metres per pixel at the frame centre, ``range / f`` (the inverse of (P2)); None without a range."""
    if meta.range_m is None:
        return None
    k = meta.intrinsics
    return meta.range_m / (0.5 * (k.fx + k.fy))


def plane_gsd(meta: ImageMeta, plane: Plane) -> float | None:
    """Metres per pixel at the frame centre where its optical axis meets ``plane`` (a camera without a rangefinder
    over a surface the scenario gives), as :func:`frame_gsd`; None when the axis does not meet it in front."""
    k, (_, R, C) = meta.intrinsics, _meta_arrays(meta)
    along = float(R[:, 2] @ plane.normal)
    d = float((plane.origin - C) @ plane.normal) / along if abs(along) > 1e-6 else -1.0
    return d / (0.5 * (k.fx + k.fy)) if 0.0 < d <= 1000.0 else None


def plane_from_frames(metas: Sequence[ImageMeta], margin_m: float = 0.0) -> Plane:
    """A plane for frames without a known surface: through the points where the optical axes meet
    the surface at the frames' ranges, facing the mean viewing direction, ``u`` horizontal, ``v``
    up (a wall; for a deck looking down, ``v`` is north), bounded by the frames' footprints."""
    pts, axes, feet = [], [], []
    for m in metas:
        if m.range_m is None:
            continue
        K, R, C = _meta_arrays(m)
        z = R[:, 2]
        pts.append(C + m.range_m * z)
        axes.append(z)
        w, h = m.intrinsics.width, m.intrinsics.height
        rays = np.linalg.inv(K) @ np.array([[-0.5, -0.5, 1], [w - 0.5, -0.5, 1], [w - 0.5, h - 0.5, 1], [-0.5, h - 0.5, 1]]).T
        feet.append((C, R, rays))
    if not pts:
        raise ValueError("no frame has a range: give the surface corners")
    n = -np.mean(axes, axis=0)
    n /= np.linalg.norm(n)
    p = np.mean(pts, axis=0)
    up = np.array([0.0, 0.0, 1.0])
    if abs(n @ up) > 0.9:  # looking down: v north
        u = np.cross(np.array([0.0, 1.0, 0.0]), n)
    else:
        u = np.cross(up, n)
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    corners = []
    for C, R, rays in feet:
        d = R @ rays
        lam = ((p - C) @ n) / (n @ d)
        corners.append((C[:, None] + d * lam).T)
    uv = (np.concatenate(corners) - p) @ np.column_stack([u, v])
    lo, hi = uv.min(0) - margin_m, uv.max(0) + margin_m
    origin = p + lo[0] * u + lo[1] * v
    return Plane(origin, u, v, float(hi[0] - lo[0]), float(hi[1] - lo[1]))


def _centre_weight(w: int, h: int) -> NDArray[np.float32]:
    """1 at the image centre falling to 0 at its border (Chebyshev distance, normalised per axis)."""
    x = 1.0 - np.abs((np.arange(w, dtype=np.float32) + 0.5) / w * 2.0 - 1.0)
    y = 1.0 - np.abs((np.arange(h, dtype=np.float32) + 0.5) / h * 2.0 - 1.0)
    return np.minimum(y[:, None], x[None, :]) + np.float32(1e-3)


MAX_CANVAS_PX = 80_000_000


def build_mosaic(frames: Sequence[PosedFrame], plane: Plane, m_per_px: float | None = None) -> Mosaic:
    """Warp every frame onto ``plane`` (docs/report.md) at ``m_per_px``, by default the frames' median ground
    sampling distance (their own resolution: nothing lost or invented)."""
    import time

    t0 = time.perf_counter()
    if m_per_px is None:
        g = [x for x in (frame_gsd(f.meta) or plane_gsd(f.meta, plane) for f in frames) if x]
        if not g:
            raise ValueError("no frame has a range nor looks at the surface: give m_per_px")
        m_per_px = float(np.median(g))
    if not (math.isfinite(m_per_px) and m_per_px > 0):
        raise ValueError(f"m_per_px must be finite and > 0, got {m_per_px!r}")
    W = max(1, int(math.ceil(plane.width_m / m_per_px)))
    H = max(1, int(math.ceil(plane.height_m / m_per_px)))
    if W * H > MAX_CANVAS_PX:
        raise ValueError(f"mosaic of {W} x {H} px exceeds {MAX_CANVAS_PX / 1e6:.0f} MP: raise m_per_px")
    image = np.zeros((H, W), np.uint8)
    mask = np.zeros((H, W), np.uint8)
    owner = np.full((H, W), -1, np.int32)
    best = np.zeros((H, W), np.float32)
    skipped: list[str] = []
    used = 0
    for i, f in enumerate(frames):
        Hc = canvas_homography(f.meta, plane, m_per_px)
        if Hc is None:
            skipped.append(f"frame {i}: camera behind the surface")
            continue
        h, w = f.grey.shape[:2]
        # the frame's footprint on the canvas: its corners through the inverse homography
        try:
            Hi = np.linalg.inv(Hc)
        except np.linalg.LinAlgError:
            skipped.append(f"frame {i}: degenerate pose")
            continue
        q = np.array([[-0.5, -0.5, 1], [w - 0.5, -0.5, 1], [w - 0.5, h - 0.5, 1], [-0.5, h - 0.5, 1]]) @ Hi.T
        if np.any(q[:, 2] <= 0):
            skipped.append(f"frame {i}: sees beyond the horizon of the surface")
            continue
        c = q[:, :2] / q[:, 2:3]
        x0, y0 = np.floor(np.clip(c.min(0), 0, [W, H])).astype(int)
        x1, y1 = np.ceil(np.clip(c.max(0), 0, [W, H])).astype(int)
        if x1 <= x0 or y1 <= y0:
            skipped.append(f"frame {i}: off the surface")
            continue
        T = np.array([[1.0, 0.0, x0], [0.0, 1.0, y0], [0.0, 0.0, 1.0]])
        Hr = Hc @ T
        size = (int(x1 - x0), int(y1 - y0))
        flags = cv2.WARP_INVERSE_MAP
        img = cv2.warpPerspective(f.grey, Hr, size, flags=flags | cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        wt = cv2.warpPerspective(_centre_weight(w, h), Hr, size, flags=flags | cv2.INTER_LINEAR,
                                 borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        roi = (slice(y0, y1), slice(x0, x1))
        take = wt > best[roi]
        if not take.any():
            continue
        used += 1
        best[roi][take] = wt[take]
        image[roi][take] = img[take]
        owner[roi][take] = i
        fm = f.mask if f.mask is not None else None
        if fm is not None:
            mw = cv2.warpPerspective(fm, Hr, size, flags=flags | cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT)
            mask[roi][take] = mw[take]
        else:
            mask[roi][take] = 0
    return Mosaic(plane=plane, m_per_px=m_per_px, image=image, mask=mask, owner=owner,
                  seconds=time.perf_counter() - t0, frames_used=used, skipped=skipped)
