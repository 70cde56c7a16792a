"""Per-frame defect reports (services.detector.pipeline): a crack's length comes from its skeleton, the
same measurement as the inspection deliverable's (services.inspection.measure), not its bounding box."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from edge.camera import encode_jpeg
from edge.surface import textured_background
from services.detector.pipeline import analyse
from services.inspection.captures import capture_meta

F, RANGE = 800.0, 4.0  # focal length (px), range (m): 5 mm per pixel


def _frame(kind: str) -> tuple[bytes, float]:
    """A frame with one crack of known length (pixels): a half circle or a straight line."""
    g = textured_background((480, 640), np.random.default_rng(5), roughness=6.0).astype(np.float32)
    m = np.zeros(g.shape, np.uint8)
    if kind == "arc":
        r = 150
        cv2.ellipse(m, (320, 120), (r, r), 0, 0, 180, 255, 4)
        length = math.pi * r
    else:
        cv2.line(m, (100, 100), (540, 380), 255, 4)
        length = math.hypot(440, 280)
    g[m > 0] *= 0.4
    return encode_jpeg(np.clip(g, 0, 255).astype(np.uint8), 95), length


@pytest.mark.parametrize("kind", ["arc", "line"])
def test_report_length_is_the_skeleton_length(kind):
    jpeg, length_px = _frame(kind)
    meta = capture_meta(1, 1, np.zeros(3), np.eye(3), (640, 480), F, F, 320.0, 240.0, RANGE)
    rep = analyse(meta, jpeg, "it+")
    assert rep.ok and rep.defects
    d = max(rep.defects, key=lambda d: d.area_px)
    gsd = RANGE / F
    assert d.length_m == pytest.approx(length_px * gsd, rel=0.05)
    if kind == "arc":  # the bounding-box diagonal it replaces is a third short on a half circle
        x, y, w, h = d.bbox
        assert math.hypot(w, h) * gsd < 0.8 * d.length_m


def test_no_range_no_length():
    jpeg, _ = _frame("line")
    meta = capture_meta(1, 1, np.zeros(3), np.eye(3), (640, 480), F, F, 320.0, 240.0, None)
    rep = analyse(meta, jpeg, "it+")
    assert rep.defects and all(d.length_m is None and d.pos is None for d in rep.defects)
