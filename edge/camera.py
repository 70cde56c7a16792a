"""The UAV's camera: frame sources behind one interface, and JPEG encoding off the control loop.

Sources (:class:`FrameSource`): :class:`SyntheticSource` renders the view of a
:class:`~edge.surface.SyntheticSurface` from the camera pose, with the view's ground-truth mask;
:class:`FolderSource` replays a folder of images; :class:`VideoCaptureSource` reads a real camera
or a stream through OpenCV. :func:`make_source` picks one from a spec string. :class:`FrameEncoder`
JPEG-encodes frames on its own thread, so that the control loop that fires the camera at each
capture point never waits for the encoder (the bus publishing is in :mod:`edge.runtime`).

The camera model and poses (:class:`CameraModel`, :class:`CameraPose`) live in
:mod:`edge.optics` and are imported here for the sources.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import cv2
import numpy as np
from numpy.typing import NDArray

from protocol.ring import Ring

from .optics import CameraModel, CameraPose
from .surface import SyntheticSurface

__all__ = [
    "IMAGE_EXTENSIONS",
    "CameraModel",
    "CameraPose",
    "FolderSource",
    "Frame",
    "FrameEncoder",
    "FrameSource",
    "SyntheticSource",
    "VideoCaptureSource",
    "decode_image",
    "decode_jpeg",
    "encode_jpeg",
    "make_source",
    "upsample_factor",
]

log = logging.getLogger(__name__)

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff")


# ============================================================================ frames and sources
@dataclass
class Frame:
    """One captured frame.

    Attributes
    ----------
    image : numpy.ndarray
        ``uint8``, grey (H, W) or BGR (H, W, 3).
    t : float
        Capture time, seconds (the caller's clock: mission time on the edge).
    pose : CameraPose or None
        The camera pose at capture, as given to :meth:`FrameSource.grab`.
    mask : numpy.ndarray or None
        Ground truth of the frame (uint8, 255 on cracks), when the source knows it.
    seq : int
        The source's frame counter, from 0.
    name : str
        Where the frame came from (file name, stream), empty for the synthetic source.
    """

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
    """The reduction 2^k at which :class:`SyntheticSource` warps a magnified view before resizing it
    to the frame: the largest with at most ``limit`` texture pixels per reduced pixel (``k = 0``
    when the frame does not magnify that much), and with a reduced frame of at least 16 pixels a
    side. ``texels_per_px`` is the texture pixels per frame pixel (the homography's Jacobian).

    Raises
    ------
    ValueError
        On a non-finite or non-positive scale or limit.
    """
    if not (math.isfinite(texels_per_px) and texels_per_px > 0):
        raise ValueError(f"texture pixels per frame pixel must be finite and > 0, got {texels_per_px!r}")
    if not (math.isfinite(limit) and limit > 0):
        raise ValueError(f"limit must be finite and > 0, got {limit!r}")
    f = 1
    while texels_per_px * f * 2 <= limit and min(frame_size) // (f * 2) >= 16:
        f *= 2
    return f


class SyntheticSource:
    """The view of a :class:`~edge.surface.SyntheticSurface` from the camera pose.

    The surface plane maps to the image by the homography ``H = K R^T (A - C e3^T)`` (``A`` maps
    texture pixels to the world, :meth:`SyntheticSurface.pixel_to_world_matrix`), applied with
    ``cv2.warpPerspective`` -- bilinear for the texture, nearest neighbour for the mask. The cost
    is that of the frame, not of the texture:

    - only the texture region the frame can see is handed to the warp (the bounding box of the
      view's corners mapped back onto the texture);
    - where the frame looks at the surface from afar (more than two texture pixels per frame
      pixel), the warp reads a 2^L-times box-filtered copy of the texture (built once per level)
      instead of aliasing; the mask copy marks a pixel as crack if any texture pixel under it is;
    - pixels whose rays miss the plane (above its horizon, or pointing away) are sky, as are
      pixels off the rectangle and every pixel when the camera is behind the surface (its back
      is not textured).

    Parameters
    ----------
    surface : SyntheticSurface
    camera : CameraModel
    sky : int
        Grey level where the surface is not seen. Default 200: bright, so that a frame edge is not
        a dark stripe the detector would take for a defect.
    noise_sigma : float
        Standard deviation of Gaussian sensor noise added to each frame, grey levels. Default 0
        (the texture already has grain).
    seed : int or None
        Seed of the sensor noise.
    mask : bool
        Render the ground-truth mask with each frame (default). False: :meth:`grab` gives
        ``mask=None`` and saves the mask's warp (the edge's captures never send it).
    upsample : bool
        Where the frame magnifies the texture (fewer than :data:`MAGNIFY_LIMIT` texture pixels per
        frame pixel, e.g. 0.125 for a 12 MP frame of the default 100 px/m wall at 4.8 m), warp at
        1/2^k of the frame size, the smallest that keeps ``1 / MAGNIFY_LIMIT`` reduced pixels per
        texture pixel, and resize that (bilinear) to the frame: the frame holds no detail the texture
        has not, and the warp's cost is that of the reduced frame (12 MP captures).
        Default False (one warp at the frame size). The mask is always warped at full size.
    """

    #: frame pixels of texture, at most, before a coarser texture level is used
    MINIFY_LIMIT = 2.0
    #: with ``upsample``: texture pixels per reduced frame pixel, at most (0.5: two pixels per texel)
    MAGNIFY_LIMIT = 0.5

    def __init__(self, surface: SyntheticSurface, camera: CameraModel, sky: int = 200,
                 noise_sigma: float = 0.0, seed: int | None = None, *, mask: bool = True,
                 upsample: bool = False) -> None:
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
            self._levels[level] = (t, np.where(m > 0, 255, 0).astype(np.uint8))
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
        return img, gt

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


class FolderSource:
    """The images of a folder in name order, looping by default; the pose is only recorded.

    Parameters
    ----------
    path : str or path
        Folder of images (``IMAGE_EXTENSIONS``, case-insensitive), e.g. a data set's ``images/``.
    loop : bool
        Start again after the last image; otherwise :meth:`grab` returns None from then on.
    grey : bool
        Read as grey (the detector's input, PAPER.md Section 6) rather than BGR. Default True.
    mask_dir : str or path, optional
        Folder of ground-truth masks with the same base names (``<stem>.png``), as the data sets
        under ``/work/shared/data`` have them; a frame whose mask is missing has ``mask=None``.

    Raises
    ------
    ValueError
        When the folder does not exist or holds no image. An unreadable image is skipped, counted
        in :attr:`skipped` and logged.
    """

    def __init__(self, path: str | os.PathLike, loop: bool = True, grey: bool = True,
                 mask_dir: str | os.PathLike | None = None) -> None:
        folder = Path(path)
        if not folder.is_dir():
            raise ValueError(f"not a folder: {folder}")
        self.files = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS)
        if not self.files:
            raise ValueError(f"no images ({', '.join(IMAGE_EXTENSIONS)}) in {folder}")
        if mask_dir is not None and not Path(mask_dir).is_dir():
            raise ValueError(f"mask_dir is not a folder: {mask_dir}")
        self.mask_dir = Path(mask_dir) if mask_dir is not None else None
        self.loop, self.grey, self.index = bool(loop), bool(grey), 0
        self.skipped = 0
        self._seq = 0

    def _next_path(self) -> Path | None:
        if self.index >= len(self.files):
            if not self.loop:
                return None
            self.index = 0
        path = self.files[self.index]
        self.index += 1
        return path

    def grab(self, pose: CameraPose | None, t: float) -> Frame | None:
        """The next readable image; None at the end (``loop=False``) or if none of the files reads."""
        for _ in range(len(self.files)):
            path = self._next_path()
            if path is None:
                return None
            img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE if self.grey else cv2.IMREAD_COLOR)
            if img is None:
                self.skipped += 1
                log.warning("folder source: cannot read %s, skipped", path)
                continue
            mask = None
            if self.mask_dir is not None:
                mpath = self.mask_dir / (path.stem + ".png")
                m = cv2.imread(str(mpath), cv2.IMREAD_GRAYSCALE) if mpath.is_file() else None
                if m is not None and m.shape == img.shape[:2]:
                    mask = np.where(m > 0, 255, 0).astype(np.uint8)
            frame = Frame(img, t, pose, mask, seq=self._seq, name=path.name)
            self._seq += 1
            return frame
        return None

    def close(self) -> None:
        pass


class VideoCaptureSource:
    """A real camera (an index such as ``0``) or a stream or file URL, through ``cv2.VideoCapture``.

    :meth:`grab` reads the next frame; it returns None when there is none (end of a file, a stream
    that stalled or dropped), so the edge logs and goes on. The pose is only recorded.

    Parameters
    ----------
    url : str or int
        Device index (an int, or a string of digits) or anything ``cv2.VideoCapture`` opens.
    grey : bool
        Convert frames to grey. Default False (frames as captured, BGR).

    Raises
    ------
    ValueError
        When the source cannot be opened.
    """

    def __init__(self, url: str | int, grey: bool = False) -> None:
        if isinstance(url, str) and not url.strip():
            raise ValueError("empty video source")
        self.url = url
        self.grey = bool(grey)
        self.cap = cv2.VideoCapture(int(url) if isinstance(url, str) and url.strip().isdigit() else url)
        if not self.cap.isOpened():
            self.cap.release()
            raise ValueError(f"cannot open video source {url!r}")
        self.failed = 0
        self._seq = 0

    def grab(self, pose: CameraPose | None, t: float) -> Frame | None:
        ok, img = self.cap.read()
        if not ok or img is None:
            self.failed += 1
            return None
        if self.grey and img.ndim == 3:
            img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        frame = Frame(img, t, pose, seq=self._seq, name=str(self.url))
        self._seq += 1
        return frame

    def close(self) -> None:
        self.cap.release()


def make_source(spec: str, surface: SyntheticSurface | None = None, camera: CameraModel | None = None,
                *, loop: bool = True, grey: bool | None = None, mask: bool = True,
                upsample: bool = False) -> FrameSource:
    """A frame source from a spec string.

    - ``"synthetic"``: :class:`SyntheticSource` of ``surface`` and ``camera`` (both required), with its
      ``mask`` and ``upsample`` options;
    - ``"video:<url or index>"``: :class:`VideoCaptureSource` (``grey`` default False);
    - anything else: a folder for :class:`FolderSource` (``grey`` default True); when the folder
      is a data set's ``images/`` with a sibling ``masks/``, the masks come along as ground truth.

    Raises
    ------
    ValueError
        On an empty spec, a synthetic source without surface or camera, or a source that does not
        open.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise ValueError(f"camera spec must be a non-empty string, got {spec!r}")
    if spec == "synthetic":
        if surface is None or camera is None:
            raise ValueError("the synthetic camera needs the scenario's surface and camera")
        return SyntheticSource(surface, camera, mask=mask, upsample=upsample)
    if spec.startswith("video:"):
        return VideoCaptureSource(spec[len("video:"):], grey=bool(grey))
    folder = Path(spec)
    masks = folder.parent / "masks"
    mask_dir = masks if folder.name == "images" and masks.is_dir() else None
    return FolderSource(folder, loop=loop, grey=True if grey is None else grey, mask_dir=mask_dir)


# ============================================================================ JPEG
def encode_jpeg(image: NDArray[np.uint8], quality: int = 85) -> bytes:
    """JPEG bytes of a ``uint8`` grey (H, W) or BGR (H, W, 3) image (``cv2.imencode``).

    Raises
    ------
    ValueError
        On a non-image array or a quality outside 1..100.
    """
    if isinstance(quality, bool) or not isinstance(quality, (int, np.integer)) or not 1 <= quality <= 100:
        raise ValueError(f"JPEG quality must be an integer in 1..100, got {quality!r}")
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8:
        raise ValueError("image must be a uint8 numpy array")
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] in (1, 3))) or image.size == 0:
        raise ValueError(f"image must be (H, W) or (H, W, 3), got shape {image.shape}")
    if max(image.shape[:2]) > 65500:
        raise ValueError(f"image of {image.shape[1]} x {image.shape[0]} px is too large for JPEG")
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return buf.tobytes()


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"  # RFC 2083, section 3.1


#: cv2.imdecode flags of a grey image decoded at 1/2, 1/4, 1/8 of its size (JPEG: by the DCT, not a resize)
_REDUCED_GREY = {1: cv2.IMREAD_GRAYSCALE, 2: cv2.IMREAD_REDUCED_GRAYSCALE_2, 4: cv2.IMREAD_REDUCED_GRAYSCALE_4,
                 8: cv2.IMREAD_REDUCED_GRAYSCALE_8}


def decode_image(data: bytes | bytearray | memoryview, grey: bool = False, reduce: int = 1) -> NDArray[np.uint8]:
    """The image of JPEG or PNG bytes (``cv2.imdecode``): grey or BGR as stored, or grey if ``grey``;
    ``reduce`` 2, 4 or 8 decodes it grey at that fraction of its size (libjpeg scales in the DCT,
    so a 12 MP frame decodes at 1/4 in a fraction of the full decode's time).

    The one decoder of the project (the camera's tests, the detector). JPEG must be complete
    (ITU T.81 start- and end-of-image markers: libjpeg would otherwise half-decode a truncated
    frame with only a warning); PNG must start with its signature.

    Raises
    ------
    ValueError
        When the bytes are not a complete JPEG or PNG, or the codec refuses them.
    """
    try:
        buf = np.frombuffer(data, np.uint8)
    except TypeError:
        raise ValueError(f"image data must be bytes, got {type(data).__name__}") from None
    if buf.size == 0:
        raise ValueError("cannot decode an empty image")
    if buf[:8].tobytes() == _PNG_SIGNATURE:
        kind = "PNG"
    elif buf.size >= 4 and buf[0] == 0xFF and buf[1] == 0xD8:
        kind = "JPEG"
        if b"\xff\xd9" not in buf[-64:].tobytes():
            raise ValueError("cannot decode a truncated JPEG: no end-of-image marker")
    else:
        raise ValueError("cannot decode: neither a JPEG (no start-of-image marker) nor a PNG (no signature)")
    if reduce not in _REDUCED_GREY:
        raise ValueError(f"reduce must be one of {sorted(_REDUCED_GREY)}, got {reduce!r}")
    flag = _REDUCED_GREY[reduce] if grey or reduce > 1 else cv2.IMREAD_UNCHANGED
    img = cv2.imdecode(buf, flag)
    if img is None:
        raise ValueError(f"cannot decode a corrupt {kind}")
    return img


decode_jpeg = decode_image  # the name the camera's callers know


# ============================================================================ off-loop encoding
class FrameEncoder:
    """JPEG encoding on one worker thread, fed by a bounded drop-oldest queue (a :class:`~protocol.ring.Ring`).

    :meth:`submit` returns at once; the worker encodes in submission order and calls
    ``on_encoded(item, jpeg)``, where ``item`` is the submitted :class:`Frame`, or the ``tag`` given
    with it (the edge passes the frame's metadata as the tag). When ``capacity`` frames are already
    waiting, the oldest waiting one is dropped and counted in :attr:`dropped`: the control loop
    never waits for the encoder, and what goes out is the newest view. An exception in the
    encoder or the callback is counted in :attr:`failed` and logged; the worker carries on.

    Parameters
    ----------
    on_encoded : callable
        ``on_encoded(item, jpeg_bytes)``, called on the worker thread.
    capacity : int
        Frames waiting at most (the one being encoded not included). Default 4.
    quality : int
        JPEG quality 1..100. Default 85.
    """

    def __init__(self, on_encoded: Callable[[Any, bytes], None], capacity: int = 4, quality: int = 85) -> None:
        if not callable(on_encoded):
            raise ValueError("on_encoded must be callable")
        if isinstance(capacity, bool) or not isinstance(capacity, (int, np.integer)) or capacity < 1:
            raise ValueError(f"capacity must be an integer >= 1, got {capacity!r}")
        if isinstance(quality, bool) or not isinstance(quality, (int, np.integer)) or not 1 <= quality <= 100:
            raise ValueError(f"JPEG quality must be an integer in 1..100, got {quality!r}")
        self.on_encoded, self.capacity, self.quality = on_encoded, int(capacity), int(quality)
        self.submitted = self.encoded = 0
        self._ring = Ring(self.capacity, self._encode, name="jpeg-encoder")

    @property
    def dropped(self) -> int:
        """Frames dropped unencoded (the oldest waiting one when full, or what ``close(drain=False)`` left)."""
        return self._ring.dropped

    @property
    def failed(self) -> int:
        """Frames whose encoding or delivery raised (logged; the worker carries on)."""
        return self._ring.failed

    def submit(self, frame: Frame | NDArray[np.uint8], tag: Any = None) -> bool:
        """Queue a frame (or a bare image) for encoding; returns False if an older one was dropped.

        Raises
        ------
        ValueError
            After :meth:`close`, or when ``frame`` is neither a Frame nor a numpy image.
        """
        if isinstance(frame, Frame):
            image, item = frame.image, frame if tag is None else tag
        elif isinstance(frame, np.ndarray):
            image, item = frame, tag
        else:
            raise ValueError(f"submit takes a Frame or an image, got {type(frame).__name__}")
        if self._ring.closed:
            raise ValueError("encoder is closed")
        self.submitted += 1
        return self._ring.push((image, item))

    @property
    def pending(self) -> int:
        """Frames waiting to be encoded."""
        return len(self._ring)

    @property
    def alive(self) -> bool:
        """Whether the worker thread still runs."""
        return self._ring.alive

    def _encode(self, job: tuple[NDArray[np.uint8], Any]) -> None:
        image, item = job
        jpeg = encode_jpeg(image, self.quality)
        self.on_encoded(item, jpeg)
        self.encoded += 1

    def close(self, timeout: float | None = 5.0, drain: bool = True) -> None:
        """Stop: encode what is queued (or drop it, counted, if not ``drain``), then join the worker.

        Idempotent. With a ``timeout`` the join gives up after that many seconds (the worker is a
        daemon thread and ends with the process).
        """
        self._ring.close(timeout, drain)

    def __enter__(self) -> FrameEncoder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
