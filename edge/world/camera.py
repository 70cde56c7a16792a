"""The synthetic camera: the view of a :class:`~edge.world.surface.SyntheticSurface` from a camera pose.

Design notes: docs/edge.md (edge/world/camera.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.geometry.optics import CameraModel, CameraPose
from edge.world.surface import SyntheticSurface

__all__ = ["Frame", "FrameSource", "SyntheticSource", "upsample_factor"]


# ============================================================================ frames and sources
@dataclass
class Frame:
    """One captured frame: a ``uint8`` grey or BGR image, its capture time ``t`` (the caller's clock), the
    pose given to :meth:`FrameSource.grab`, its ground-truth ``mask`` (255 on cracks) when known, the
    source's counter ``seq`` from 0 and its origin ``name`` (empty for the synthetic source)."""

    image: NDArray[np.uint8]
    t: float
    pose: CameraPose | None = None
    mask: NDArray[np.uint8] | None = None
    seq: int = 0
    name: str = ""


@runtime_checkable
class FrameSource(Protocol):
    """What the edge needs of a camera: a frame at each capture point, and a way to stop."""

    def grab(self, pose: CameraPose | None, t: float) -> Frame | None:
        """The frame seen from ``pose`` at time ``t``; None when there is none (end of a stream)."""
        ...

    def close(self) -> None:
        """Release the device; further grabs may fail."""
        ...


def upsample_factor(texels_per_px: float, frame_size: tuple[int, int], limit: float = 0.5) -> int:
    """The reduction 2^k at which :class:`SyntheticSource` warps a magnified view (``texels_per_px``
    texture pixels per frame pixel) before resizing it: the largest with at most ``limit`` texture
    pixels per reduced pixel and a reduced frame of at least 16 pixels a side (docs/edge.md)."""
    if not (math.isfinite(texels_per_px) and texels_per_px > 0):
        raise ValueError(f"texture pixels per frame pixel must be finite and > 0, got {texels_per_px!r}")
    if not (math.isfinite(limit) and limit > 0):
        raise ValueError(f"limit must be finite and > 0, got {limit!r}")
    f = 1
    while texels_per_px * f * 2 <= limit and min(frame_size) // (f * 2) >= 16:
        f *= 2
    return f


class SyntheticSource:
    """The view of a :class:`~edge.world.surface.SyntheticSurface` from the camera pose, by the homography
    ``H = K R^T (A - C e3^T)``; the rendering rules and options are in docs/edge.md (edge/world/camera.py)."""

    #: frame pixels of texture, at most, before a coarser texture level is used
    MINIFY_LIMIT = 2.0
    #: with ``upsample``: texture pixels per reduced frame pixel, at most (0.5: two pixels per texel)
    MAGNIFY_LIMIT = 0.5

    def __init__(self, surface: SyntheticSurface, camera: CameraModel, sky: int = 200, noise_sigma: float = 0.0,
                 seed: int | None = None, *, mask: bool = True, upsample: bool = False) -> None:
        if not isinstance(surface, SyntheticSurface):
            raise ValueError(f"surface must be a SyntheticSurface, got {type(surface).__name__}")
        if not isinstance(camera, CameraModel):
            raise ValueError(f"camera must be a CameraModel, got {type(camera).__name__}")
        if not 0 <= int(sky) <= 255:
            raise ValueError(f"sky must be a grey level 0..255, got {sky!r}")
        if not (math.isfinite(noise_sigma) and noise_sigma >= 0):
            raise ValueError(f"noise_sigma must be finite and >= 0, got {noise_sigma!r}")
        self.surface, self.camera, self.sky = surface, camera, int(sky)
        self.noise_sigma = float(noise_sigma)
        self.with_mask, self.upsample = bool(mask), bool(upsample)
        self._rng = np.random.default_rng(seed)
        self._A = surface.pixel_to_world_matrix()
        self._levels: dict[int, tuple[NDArray[np.uint8], NDArray[np.uint8]]] = {0: (surface.texture, surface.mask)}
        self._seq = 0

    # ------------------------------------------------------------------ geometry
    def homography(self, pose: CameraPose) -> NDArray[np.float64] | None:
        """Texture pixel -> frame pixel homography, or None when the camera is not in front of the
        surface (behind its plane or on it)."""
        R, C = pose.rotation, pose.position
        if float(np.dot(C - self.surface.origin, self.surface.normal)) <= 1e-9:
            return None
        return self.camera.K() @ (R.T @ (self._A - np.outer(C, [0.0, 0.0, 1.0])))

    def _visible_polygon(self, pose: CameraPose) -> NDArray[np.float64] | None:
        """The frame region (convex polygon, pixel coordinates) whose rays meet the plane in front.

        A ray ``d = R K^-1 p`` meets the plane ahead iff ``n . d < 0`` (the camera is in front):
        a half-plane of the image, clipped here against the frame rectangle (Sutherland-Hodgman
        with one edge). None when no pixel sees the plane.
        """
        w, h = self.camera.resolution
        line = self.surface.normal @ pose.rotation @ np.linalg.inv(self.camera.K())  # n . d(p)
        rect = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
        # keep a margin from the horizon, where the plane is infinitely far away
        margin = 1e-6 * float(np.abs(line).sum())
        val = rect @ line[:2] + line[2] + margin
        if np.all(val < 0):
            return rect
        if np.all(val >= 0):
            return None
        out = []
        for i in range(4):
            a, b, va, vb = rect[i], rect[(i + 1) % 4], val[i], val[(i + 1) % 4]
            if va < 0:
                out.append(a)
            if (va < 0) != (vb < 0):
                out.append(a + (b - a) * (va / (va - vb)))
        return np.array(out) if len(out) >= 3 else None

    def _level(self, level: int) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
        if level not in self._levels:
            f = 1 << level
            tex, mask = self.surface.texture, self.surface.mask
            h, w = (tex.shape[0] // f) * f, (tex.shape[1] // f) * f
            size = (max(1, w // f), max(1, h // f))
            t = cv2.resize(tex[: max(h, f), : max(w, f)], size, interpolation=cv2.INTER_AREA)
            m = cv2.resize(mask[: max(h, f), : max(w, f)], size, interpolation=cv2.INTER_AREA)
            self._levels[level] = (np.asarray(t, np.uint8), np.where(m > 0, 255, 0).astype(np.uint8))
        return self._levels[level]

    # ------------------------------------------------------------------ rendering
    def render(self, pose: CameraPose) -> tuple[NDArray[np.uint8], NDArray[np.uint8] | None]:
        """The grey frame and its ground-truth mask seen from ``pose`` (see the class docstring);
        the mask is None when the source was made with ``mask=False``."""
        w, h = self.camera.resolution
        sky = np.full((h, w), self.sky, np.uint8), (np.zeros((h, w), np.uint8) if self.with_mask else None)
        H = self.homography(pose)
        if H is None:
            return sky
        poly = self._visible_polygon(pose)
        if poly is None:
            return sky
        Hinv = np.linalg.inv(H)
        # the texture region the frame can see: the visible polygon mapped back onto the texture
        q = np.c_[poly, np.ones(len(poly))] @ Hinv.T
        with np.errstate(divide="ignore", invalid="ignore"):
            tq = q[:, :2] / q[:, 2:3]
        th, tw = self.surface.shape_px
        tq = np.nan_to_num(tq, nan=0.0, posinf=1e12, neginf=-1e12)
        x0, y0 = np.floor(np.clip(tq.min(0) - 2, [0, 0], [tw, th])).astype(int)
        x1, y1 = np.ceil(np.clip(tq.max(0) + 2, [0, 0], [tw, th])).astype(int)
        if x1 <= x0 or y1 <= y0:
            return sky
        # texture pixels per frame pixel at the middle of the visible region
        c = poly.mean(0)
        J = self._jacobian(Hinv, c)
        minify = math.sqrt(abs(np.linalg.det(J)))
        level = int(math.floor(math.log2(minify / self.MINIFY_LIMIT))) + 1 if minify > self.MINIFY_LIMIT else 0
        f = 1 << level
        tex, mask = self._level(level)
        lx0, ly0 = x0 // f, y0 // f
        lx1, ly1 = min(tex.shape[1], -(-x1 // f)), min(tex.shape[0], -(-y1 // f))
        if lx1 <= lx0 or ly1 <= ly0:
            return sky
        # level-L pixel x' (cropped at lx0) is texture pixel f (x' + lx0) + (f - 1) / 2
        S = np.array([[f, 0.0, f * lx0 + (f - 1) / 2.0], [0.0, f, f * ly0 + (f - 1) / 2.0], [0.0, 0.0, 1.0]])
        Hl = H @ S
        tex_roi, mask_roi = tex[ly0:ly1, lx0:lx1], mask[ly0:ly1, lx0:lx1]
        up = upsample_factor(minify, (w, h), self.MAGNIFY_LIMIT) if self.upsample else 1
        if up > 1:
            # reduced pixel x' is frame pixel up x' + (up - 1) / 2: the centres cv2.resize assumes
            sw, sh = -(-w // up), -(-h // up)
            D = np.array([[1.0 / up, 0.0, -(up - 1) / (2.0 * up)], [0.0, 1.0 / up, -(up - 1) / (2.0 * up)],
                          [0.0, 0.0, 1.0]])
            small = cv2.warpPerspective(tex_roi, D @ Hl, (sw, sh), flags=cv2.INTER_LINEAR,
                                        borderMode=cv2.BORDER_CONSTANT, borderValue=self.sky)
            img = cv2.resize(small, (sw * up, sh * up), interpolation=cv2.INTER_LINEAR)
            if img.shape != (h, w):
                img = np.ascontiguousarray(img[:h, :w])
        else:
            img = cv2.warpPerspective(tex_roi, Hl, (w, h), flags=cv2.INTER_LINEAR,
                                      borderMode=cv2.BORDER_CONSTANT, borderValue=self.sky)
        gt = None
        if self.with_mask:
            gt = cv2.warpPerspective(mask_roi, Hl, (w, h), flags=cv2.INTER_NEAREST,
                                     borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        if len(poly) != 4 or not np.allclose(poly, [[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]]):
            seen = np.zeros((h, w), np.uint8)
            cv2.fillConvexPoly(seen, np.round(poly * 16).astype(np.int32), 1, cv2.LINE_8, 4)
            img[seen == 0] = self.sky
            if gt is not None:
                gt[seen == 0] = 0
        return img.astype(np.uint8, copy=False), None if gt is None else gt.astype(np.uint8, copy=False)

    @staticmethod
    def _jacobian(Hinv: NDArray[np.float64], p: NDArray[np.float64]) -> NDArray[np.float64]:
        """d(texture pixel) / d(frame pixel) of the homography ``Hinv`` at frame point ``p``."""
        x = Hinv @ [p[0], p[1], 1.0]
        return (Hinv[:2, :2] * x[2] - np.outer(x[:2], Hinv[2, :2])) / x[2] ** 2

    def grab(self, pose: CameraPose | None, t: float) -> Frame:
        """Render the frame at ``pose`` (all sky without a pose), with its ground-truth mask (None
        with ``mask=False``)."""
        if pose is None:
            w, h = self.camera.resolution
            img = np.full((h, w), self.sky, np.uint8)
            gt = np.zeros((h, w), np.uint8) if self.with_mask else None
        else:
            img, gt = self.render(pose)
        if self.noise_sigma > 0:
            noisy = img + self._rng.standard_normal(img.shape, dtype=np.float32) * self.noise_sigma
            img = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
        frame = Frame(img, t, pose, gt, seq=self._seq)
        self._seq += 1
        return frame

    def close(self) -> None:
        pass
