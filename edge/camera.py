"""The UAV's camera: frame sources behind one interface, and JPEG encoding off the control loop.

Design notes: docs/edge.md (edge/camera.py).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from protocol.imagecodec import encode_jpeg
from protocol.ring import Ring

from .geometry.optics import CameraModel, CameraPose
from .world.camera import Frame, FrameSource, SyntheticSource
from .world.surface import SyntheticSurface

__all__ = ["IMAGE_EXTENSIONS", "FolderSource", "FrameEncoder", "VideoCaptureSource", "make_source"]

log = logging.getLogger(__name__)

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff")


class FolderSource:
    """The images (``IMAGE_EXTENSIONS``) of a folder in name order, looping unless ``loop`` is False (then
    :meth:`grab` gives None at the end); the pose is only recorded. ``grey`` reads the detector's input
    (the paper's Section 6); ``mask_dir`` holds ground-truth masks ``<stem>.png`` (a missing one: None).
    ValueError for a missing or empty folder; an unreadable image is skipped, counted and logged."""

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
    """A real camera (an index such as ``0``) or a stream or file URL, through ``cv2.VideoCapture``; the
    pose is only recorded. :meth:`grab` gives None when there is no frame (end of a file, a stalled or
    dropped stream), so the edge logs and goes on. ValueError when it cannot be opened."""

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


def make_source(spec: str, surface: SyntheticSurface | None = None, camera: CameraModel | None = None, *,
                loop: bool = True, grey: bool | None = None, mask: bool = True, upsample: bool = False) -> FrameSource:
    """A frame source from a spec string: ``"synthetic"`` (:class:`SyntheticSource` of ``surface`` and
    ``camera``), ``"video:<url or index>"`` (:class:`VideoCaptureSource`), else a folder
    (:class:`FolderSource`, with a data set's sibling ``masks/`` as ground truth). ValueError otherwise."""
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


# ============================================================================ off-loop encoding
class FrameEncoder:
    """JPEG encoding on one worker thread, fed by a bounded drop-oldest queue (a :class:`~protocol.ring.Ring`).

    :meth:`submit` returns at once; the worker calls ``on_encoded(item, jpeg)`` in submission order
    (``item`` the frame, or the ``tag`` given with it). Beyond ``capacity`` waiting frames the oldest is
    dropped (:attr:`dropped`): the control loop never waits and the newest view goes out. An exception
    is counted in :attr:`failed` and logged; the worker carries on.
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
        """Queue a frame (or a bare image) for encoding; returns False if an older one was dropped. ValueError
        after :meth:`close`, or when ``frame`` is neither a Frame nor a numpy image."""
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
