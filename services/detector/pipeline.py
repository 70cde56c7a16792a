"""From one imagery payload to one defect report (pure: no bus code).

Design notes: docs/detector.md (services/detector/pipeline.py).
"""

from __future__ import annotations

import time

import numpy as np

from protocol.imagecodec import decode_image
from protocol.messages import Defect, DefectReport, ImageMeta
from services.detector.measure import frame_scale, measure_mask

from .config import DETECT_MAX_MP  # noqa: F401  (the budget's one place: the config)
from .detect import Defect as PixelDefect
from .detect import Detection, detect
from .exposure import exposure_problem

#: components smaller than this are not reported (the mask is unchanged)
MIN_REPORT_AREA_PX = 12
MAX_REPORTED_DEFECTS = 500
#: how a report of a frame that shows no surface begins its error
UNUSABLE = "frame shows no surface"


def pixels_to_world(meta: ImageMeta, px: np.ndarray) -> np.ndarray | None:
    """World ENU points (N, 3) of pixel coordinates (N, 2) on the surface; None without a range."""
    if meta.range_m is None:
        return None
    k = meta.intrinsics
    px = np.asarray(px, dtype=float).reshape(-1, 2)
    rays = np.column_stack([(px[:, 0] - k.cx) / k.fx, (px[:, 1] - k.cy) / k.fy, np.ones(len(px))])
    R = np.asarray(meta.cam_rot, dtype=float).reshape(3, 3)
    return np.asarray(meta.cam_pos) + (meta.range_m * rays) @ R.T


def skeleton_lengths(det: Detection, m_per_px: float, grey: np.ndarray | None = None,
                     max_components: int = MAX_REPORTED_DEFECTS) -> dict[tuple[int, int, int, int], float]:
    """Skeleton length (m) of the mask's components, by bounding box (x, y, w, h), largest first;
    at most ``max_components`` of at least :data:`MIN_REPORT_AREA_PX` pixels."""
    rows = measure_mask(det.mask, m_per_px, MIN_REPORT_AREA_PX, grey, max_components=max_components)
    return {bbox: m.length_m for bbox, _, m in rows}


def to_report(meta: ImageMeta, det: Detection, stamp_report: float | None = None,
              grey: np.ndarray | None = None, scale: int = 1) -> DefectReport:
    """The defect report of a detection; ``grey`` (the frame) sizes each crack on its half-depth pixels.

    ``det`` and ``grey`` may be of the frame decoded at 1/``scale`` size (:func:`analyse`): the
    cracks are measured there at ``scale`` times the ground sampling distance and reported in the
    full frame's pixels (:func:`scaled`)."""
    full = scaled(det, scale)
    keep = [(d, r) for d, r in zip(full.defects, det.defects) if d.area_px >= MIN_REPORT_AREA_PX]
    keep = keep[:MAX_REPORTED_DEFECTS]
    world = pixels_to_world(meta, np.array([d.centroid for d, _ in keep])) if keep else None
    k = meta.intrinsics
    gsd = None if meta.range_m is None else frame_scale(meta.range_m, k.fx, k.fy)  # m per full-frame pixel
    lengths = skeleton_lengths(det, gsd * scale, grey) if gsd is not None and keep else {}  # by reduced bbox
    defects = []
    for i, (d, reduced) in enumerate(keep):
        pos = None if world is None else tuple(float(v) for v in world[i])
        length = None if gsd is None else lengths.get(reduced.bbox, float(np.hypot(d.bbox[2], d.bbox[3]) * gsd))
        defects.append(Defect(area_px=d.area_px, bbox=d.bbox, centroid_px=d.centroid, contrast=d.contrast,
                              pos=pos, length_m=length))
    return DefectReport(uav=meta.uav, capture_id=meta.capture_id, stamp_capture=meta.stamp,
                        stamp_report=stamp_report or time.time(), method=det.method,
                        threshold=float(det.threshold or 0), defects=defects,
                        defect_fraction=det.defect_fraction)


def detection_scale(width: int, height: int, max_pixels: int | None) -> int:
    """The decode reduction (1, 2, 4 or 8) that brings a ``width`` x ``height`` frame to at most
    ``max_pixels`` (None: always 1), so that the real-time report of a 12 MP frame costs what a
    small frame's does."""
    if max_pixels is None:
        return 1
    for f in (1, 2, 4):
        if (width // f) * (height // f) <= max_pixels:
            return f
    return 8


def scaled(det: Detection, f: int) -> Detection:
    """``det`` found on a frame decoded at 1/``f`` size, in the full frame's pixels: a reduced pixel
    ``i`` covers full pixels ``f i .. f i + f - 1`` (centre ``f i + (f - 1) / 2``). The mask stays small."""
    if f == 1:
        return det
    out = [PixelDefect(area_px=d.area_px * f * f, bbox=tuple(int(v) * f for v in d.bbox),
                  centroid=(d.centroid[0] * f + (f - 1) / 2, d.centroid[1] * f + (f - 1) / 2), contrast=d.contrast)
           for d in det.defects]
    return Detection(mask=det.mask, defects=out, method=det.method, threshold=det.threshold)


def failed_report(meta: ImageMeta, method: str, error: str) -> DefectReport:
    """The ``ok=False`` report of a frame that could not be analysed, saying why."""
    return DefectReport(uav=meta.uav, capture_id=meta.capture_id, stamp_capture=meta.stamp,
                        stamp_report=time.time(), method=method, ok=False, error=error)


def analyse(meta: ImageMeta, image: bytes | memoryview, method: str = "it+", max_pixels: int | None = None,
            **params: object) -> DefectReport:
    """Decode, detect and map one frame; a frame that does not decode, or shows no surface
    (:func:`~services.detector.exposure.exposure_problem`), gives an ``ok=False`` report saying why.

    With ``max_pixels``, a larger frame is decoded at 1/2, 1/4 or 1/8 of its size
    (:func:`detection_scale`) and its defects reported in full-frame pixels (:func:`scaled`): the
    real-time report of a 12 MP capture. The frame the inspection deliverable measures (the capture
    as logged by the ground station) is the full one; a crack thinner than the reduction's pixel may go unreported.
    """
    f = detection_scale(meta.intrinsics.width, meta.intrinsics.height, max_pixels)
    try:
        grey = decode_image(image, grey=True, reduce=f, size=(meta.intrinsics.width, meta.intrinsics.height))
    except ValueError as exc:
        return failed_report(meta, method, str(exc))
    problem = exposure_problem(grey)
    if problem is not None:
        return failed_report(meta, method, f"{UNUSABLE}: {problem}")
    det = detect(grey, method, min_defect_area=max(1, MIN_REPORT_AREA_PX // (f * f)), **params)
    return to_report(meta, det, grey=grey, scale=f)
