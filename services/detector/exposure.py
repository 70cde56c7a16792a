"""Whether a frame shows a surface at all: a black, white or featureless frame is not an inspection.

A camera with its lens covered, its exposure failed or its gimbal turned to the sky still sends frames;
a detector finds no crack in them and, counted as imaged, they would say that the surface they were meant to
show is sound. :func:`exposure_problem` names what is wrong with such a frame (or None); the detector reports
it as a failed analysis and the inspection deliverable leaves it out of its coverage.

Design notes and the measured margins: docs/detector.md (services/detector/exposure.py).
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

#: a pixel at or below / at or above these grey levels carries no detail (clipped by the sensor or the encoder)
BLACK_LEVEL = 2
WHITE_LEVEL = 253
#: a frame more than this share of whose pixels are clipped to black (or to white) shows too little surface
MAX_CLIPPED_SHARE = 0.5
#: a frame whose grey levels between the 1st and the 99th percentile span fewer than this shows no texture
MIN_SPREAD = 8
#: the frame is judged at this many pixels (area-averaged down to it): one resolution whatever size it was decoded
#: at, so that the detector (at its reduced decode), the ground station and the report agree on a frame
JUDGED_PX = 80_000


def exposure_problem(grey: NDArray[np.uint8]) -> str | None:
    """What makes ``grey`` (a 2-D uint8 frame) show no surface, in a few words, or None for a usable frame:
    more than :data:`MAX_CLIPPED_SHARE` of it black or white (under- or over-exposed), or its 1-99 % grey
    spread below :data:`MIN_SPREAD` (blank); judged at :data:`JUDGED_PX` pixels."""
    g = np.ascontiguousarray(grey)
    if g.ndim != 2 or g.size == 0:
        return f"not a grey image (shape {g.shape})"
    s: np.ndarray = g
    if g.size > JUDGED_PX:
        k = math.sqrt(JUDGED_PX / g.size)
        s = cv2.resize(g, (max(1, round(g.shape[1] * k)), max(1, round(g.shape[0] * k))), interpolation=cv2.INTER_AREA)
    black = float(np.count_nonzero(s <= BLACK_LEVEL)) / s.size
    white = float(np.count_nonzero(s >= WHITE_LEVEL)) / s.size
    if black > MAX_CLIPPED_SHARE:
        return f"under-exposed, {black:.0%} of the frame black"
    if white > MAX_CLIPPED_SHARE:
        return f"over-exposed, {white:.0%} of the frame white"
    lo, hi = np.percentile(s, (1, 99))
    if hi - lo < MIN_SPREAD:
        return f"blank, its grey levels within {hi - lo:.0f} over 98% of the frame"
    return None


def judged_reduction(width: int, height: int) -> int:
    """The largest decode reduction (1, 2, 4 or 8) that leaves a ``width`` x ``height`` frame at least
    :data:`JUDGED_PX` pixels: what a reader that only needs :func:`exposure_problem`'s verdict decodes at."""
    for f in (8, 4, 2):
        if (width // f) * (height // f) >= JUDGED_PX:
            return f
    return 1
