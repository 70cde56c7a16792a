"""The UAV's camera: frame sources behind one interface, and JPEG encoding off the control loop.

Sources (:class:`FrameSource`): :class:`SyntheticSource` renders the view of a
:class:`~edge.surface.SyntheticSurface` from the camera pose (its ground-truth mask comes
along); :class:`FolderSource` replays a folder of images; :class:`VideoCaptureSource` reads a
real camera or stream through OpenCV. :func:`make_source` picks one from a spec string.

Camera model: a pinhole with square pixels, the task-assessment model of (P1)-(P3): at a
distance ``d`` the footprint is ``d * s_s / f`` on each axis (the inverse of (P2)) and the
intrinsics are ``f_x = f * W / s_w``, ``f_y = f * H / s_h``, principal point at the centre.
Poses use OpenCV camera axes: x right, y down, z forward (the optical axis); ``rotation`` is
world-from-camera, so a world point ``X`` is at ``R^T (X - C)`` in the camera frame.
"""

from __future__ import annotations

import collections
import math
import os
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from .surface import SyntheticSurface

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff")


@dataclass(frozen=True)
class CameraModel:
    """Delivered frame size (px), sensor size (mm) and focal length (mm)."""

    resolution: tuple[int, int]  # width, height
    sensor_mm: tuple[float, float]  # width, height
    focal_mm: float

    def __post_init__(self) -> None:
        w, h = self.resolution
        if not (w >= 1 and h >= 1):
            raise ValueError("resolution must be positive")
        if not (self.focal_mm > 0 and min(self.sensor_mm) > 0 and all(map(math.isfinite, (*self.sensor_mm, self.focal_mm)))):
            raise ValueError("sensor size and focal length must be finite and positive")

    def intrinsics(self) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy) in pixels."""
        w, h = self.resolution
        return (self.focal_mm * w / self.sensor_mm[0], self.focal_mm * h / self.sensor_mm[1], w / 2.0, h / 2.0)

    def K(self) -> NDArray[np.float64]:
        fx, fy, cx, cy = self.intrinsics()
        return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])

    def footprint(self, distance_m: float) -> tuple[float, float]:
        """Footprint (width, height) in metres at ``distance_m`` (inverse of (P2): a = d s_s / f)."""
        return (distance_m * self.sensor_mm[0] / self.focal_mm, distance_m * self.sensor_mm[1] / self.focal_mm)

    def scaled(self, width: int, height: int) -> "CameraModel":
        """The same optics delivering ``width x height`` frames."""
        return CameraModel((int(width), int(height)), self.sensor_mm, self.focal_mm)


@dataclass(frozen=True)
class CameraPose:
    position: NDArray[np.float64]  # ENU metres
    rotation: NDArray[np.float64]  # world-from-camera, OpenCV axes

    @classmethod
    def looking(cls, position: Any, yaw: float, pitch: float = 0.0) -> "CameraPose":
        """A gimbal-stabilised camera looking along heading ``yaw`` (ENU, from east, CCW), tilted
        down by ``pitch`` radians."""
        c, s = math.cos(yaw), math.sin(yaw)
        cp, sp = math.cos(pitch), math.sin(pitch)
        z = np.array([c * cp, s * cp, -sp])
        x = np.array([s, -c, 0.0])
        y = np.cross(z, x)
        return cls(np.asarray(position, dtype=float), np.column_stack([x, y, z]))


@dataclass
class Frame:
    image: NDArray[np.uint8]
    t: float
    pose: CameraPose | None = None
    mask: NDArray[np.uint8] | None = None  # ground truth, synthetic source only


class FrameSource(Protocol):
    def grab(self, pose: CameraPose | None, t: float) -> Frame | None: ...

    def close(self) -> None: ...


class SyntheticSource:
    """Renders the surface as the camera sees it: the plane-to-image homography
    ``H = K R^T [A - C]`` of the texture (``A`` maps texture pixels to the wall,
    :meth:`SyntheticSurface.pixel_to_world_matrix`), applied with ``cv2.warpPerspective`` —
    its cost is the size of the frame, not of the texture. Where the wall is not in view the
    frame shows a bright sky (a dark border would look like a defect)."""

    def __init__(self, surface: SyntheticSurface, camera: CameraModel, sky: int = 200):
        self.surface, self.camera, self.sky = surface, camera, int(sky)
        self._A = surface.pixel_to_world_matrix()

    def homography(self, pose: CameraPose) -> NDArray[np.float64] | None:
        R, C = np.asarray(pose.rotation, float), np.asarray(pose.position, float)
        # the wall must be in front of the camera, seen from its inspected side
        to_wall = float(np.dot(self.surface.origin - C, self.surface.normal))
        if to_wall >= 0 or float(np.dot(R[:, 2], self.surface.normal)) >= 0:
            return None
        M = R.T @ (self._A - np.outer(C, [0.0, 0.0, 1.0]))
        return self.camera.K() @ M

    def grab(self, pose: CameraPose | None, t: float) -> Frame | None:
        w, h = self.camera.resolution
        H = None if pose is None else self.homography(pose)
        if H is None:
            return Frame(np.full((h, w), self.sky, np.uint8), t, pose, np.zeros((h, w), np.uint8))
        img = cv2.warpPerspective(self.surface.texture, H, (w, h), flags=cv2.INTER_LINEAR,
                                  borderMode=cv2.BORDER_CONSTANT, borderValue=self.sky)
        mask = cv2.warpPerspective(self.surface.mask, H, (w, h), flags=cv2.INTER_NEAREST,
                                   borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        return Frame(img, t, pose, mask)

    def close(self) -> None:
        pass


class FolderSource:
    """The images of a folder in name order (the pose is ignored), looping by default."""

    def __init__(self, path: str | os.PathLike, loop: bool = True, grey: bool = True):
        self.files = sorted(p for p in Path(path).iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS) \
            if Path(path).is_dir() else []
        if not self.files:
            raise ValueError(f"no images ({', '.join(IMAGE_EXTENSIONS)}) in {path}")
        self.loop, self.grey, self.index = loop, grey, 0

    def grab(self, pose: CameraPose | None, t: float) -> Frame | None:
        if self.index >= len(self.files):
            if not self.loop:
                return None
            self.index = 0
        path = self.files[self.index]
        self.index += 1
        img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE if self.grey else cv2.IMREAD_COLOR)
        if img is None:
            raise ValueError(f"cannot read image {path}")
        return Frame(img, t, pose)

    def close(self) -> None:
        pass


class VideoCaptureSource:
    """A real camera (an index) or a stream/file URL through ``cv2.VideoCapture``."""

    def __init__(self, url: str | int):
        self.url = url
        self.cap = cv2.VideoCapture(int(url) if isinstance(url, str) and url.isdigit() else url)
        if not self.cap.isOpened():
            raise ValueError(f"cannot open video source {url!r}")

    def grab(self, pose: CameraPose | None, t: float) -> Frame | None:
        ok, img = self.cap.read()
        if not ok or img is None:
            return None
        return Frame(img, t, pose)

    def close(self) -> None:
        self.cap.release()


def make_source(spec: str, surface: SyntheticSurface | None = None, camera: CameraModel | None = None) -> FrameSource:
    """``"synthetic"`` (needs ``surface`` and ``camera``), ``"video:<url or index>"``, or a folder."""
    if spec == "synthetic":
        if surface is None or camera is None:
            raise ValueError("the synthetic camera needs the scenario's surface and camera")
        return SyntheticSource(surface, camera)
    if spec.startswith("video:"):
        return VideoCaptureSource(spec[len("video:"):])
    return FolderSource(spec)


def encode_jpeg(image: NDArray[np.uint8], quality: int = 85) -> bytes:
    if not 1 <= quality <= 100:
        raise ValueError("JPEG quality must be in 1..100")
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return buf.tobytes()


def decode_jpeg(data: bytes, grey: bool = True) -> NDArray[np.uint8]:
    buf = np.frombuffer(data, np.uint8)
    img = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE if grey else cv2.IMREAD_COLOR) if buf.size else None
    if img is None:
        raise ValueError("bytes are not a decodable image")
    return img


class FrameEncoder:
    """JPEG encoding on a worker thread, fed by a bounded drop-oldest queue.

    ``submit(image, tag)`` returns at once; the worker calls ``on_encoded(tag, jpeg)``. When the
    queue is full the oldest waiting frame is dropped and counted in :attr:`dropped`, so the
    control loop never waits for the encoder.
    """

    def __init__(self, on_encoded: Callable[[Any, bytes], None], capacity: int = 4, quality: int = 85):
        if capacity < 1:
            raise ValueError("capacity must be >= 1")
        self.on_encoded, self.capacity, self.quality = on_encoded, capacity, quality
        self._q: collections.deque = collections.deque()
        self._cond = threading.Condition()
        self._closed = False
        self.dropped = self.encoded = self.failed = 0
        self._thread = threading.Thread(target=self._run, name="jpeg-encoder", daemon=True)
        self._thread.start()

    def submit(self, image: NDArray[np.uint8], tag: Any = None) -> None:
        with self._cond:
            if self._closed:
                raise ValueError("encoder is closed")
            if len(self._q) >= self.capacity:
                self._q.popleft()
                self.dropped += 1
            self._q.append((image, tag))
            self._cond.notify()

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._q and not self._closed:
                    self._cond.wait()
                if not self._q:
                    return
                image, tag = self._q.popleft()
            try:
                jpeg = encode_jpeg(image, self.quality)
                self.on_encoded(tag, jpeg)
                self.encoded += 1
            except Exception:  # a bad frame or a publish error must not kill the encoder
                self.failed += 1

    def close(self, timeout: float = 5.0) -> None:
        """Encode what is queued, then stop."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        self._thread.join(timeout)
