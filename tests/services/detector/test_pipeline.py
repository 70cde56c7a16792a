"""services.detector.pipeline: a crack's length in a per-frame report comes from its skeleton, the same
measurement as the inspection deliverable's (services.detector.measure), not its bounding box;
a large frame's real-time report comes from a reduced decode, in full-frame pixels."""

from __future__ import annotations

import math
import time

import cv2
import numpy as np
import pytest

from edge.geometry.camera import camera_model, camera_rotation
from edge.geometry.optics import CameraPose
from edge.world.camera import SyntheticSource
from edge.world.surface import crack_image, textured_background
from edge.world.wall import synthetic_surface
from protocol.imagecodec import decode_image, encode_jpeg
from protocol.messages import ImageMeta, Intrinsics
from protocol.scenario import load_scenario
from services.detector.measure import frame_scale, measure_mask
from services.detector.pipeline import DETECT_MAX_MP, analyse, detection_scale
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


def _large(seed=4, shape=(1800, 2400)):
    grey, truth = crack_image(shape, np.random.default_rng(seed), n_cracks=2, width_px=(6.0, 9.0))
    h, w = shape
    meta = ImageMeta(uav=2, capture_id=1, t=0.0, stamp=time.time(), cam_pos=(10.0, 0.0, 20.0),
                     cam_rot=(1, 0, 0, 0, 0, 1, 0, -1, 0),
                     intrinsics=Intrinsics(width=w, height=h, fx=2000, fy=2000, cx=w / 2, cy=h / 2), range_m=5.0)
    return meta, cv2.imencode(".jpg", grey, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes(), truth


def test_detection_scale_brings_a_frame_under_the_limit():
    assert detection_scale(4000, 3000, None) == 1
    assert detection_scale(640, 480, 3_000_000) == 1
    assert detection_scale(4000, 3000, 3_000_000) == 2  # the paper's 12 MP GoPro frame: 3 MP
    assert detection_scale(4000, 3000, 1_000_000) == 4
    assert detection_scale(20000, 20000, 1000) == 8


def test_decode_reduced_sizes_and_bad_factor():
    meta, jpeg, _ = _large()
    assert decode_image(jpeg, grey=True).shape == (1800, 2400)
    assert decode_image(jpeg, grey=True, reduce=2).shape == (900, 1200)
    assert decode_image(jpeg, reduce=4).shape == (450, 600)  # reduced decodes are grey
    with pytest.raises(ValueError, match="reduce"):
        decode_image(jpeg, reduce=3)


@pytest.mark.slow
def test_a_reduced_report_finds_the_same_cracks_in_full_frame_pixels_and_on_the_wall():
    meta, jpeg, truth = _large()
    full = analyse(meta, jpeg, max_pixels=None)
    half = analyse(meta, jpeg, max_pixels=1_200_000)  # 2400 x 1800 -> 1200 x 900
    assert full.ok and half.ok and full.defects and half.defects
    big = lambda r: max(r.defects, key=lambda d: d.area_px)  # noqa: E731
    a, b = big(full), big(half)
    # the same crack: centroid and extent in the full frame's pixels, area within a third, same wall point
    assert np.hypot(a.centroid_px[0] - b.centroid_px[0], a.centroid_px[1] - b.centroid_px[1]) < 20
    assert abs(a.bbox[2] - b.bbox[2]) < 30 and abs(a.bbox[3] - b.bbox[3]) < 30
    assert 0.67 < b.area_px / a.area_px < 1.5
    assert np.linalg.norm(np.subtract(a.pos, b.pos)) < 0.05  # metres on the wall
    ys, xs = np.nonzero(truth)
    assert b.bbox[0] <= xs.max() and b.bbox[0] + b.bbox[2] >= xs.min()  # where the planted cracks are
    # its length: the skeleton measured on the reduced frame, near the planted crack's (the full 4.3 MP frame's
    # report falls back to the bounding-box diagonal, a third of it), within the length tolerance the report
    # states (15 %); the half-size network measures 10 % short, its branches' tips below a reduced pixel
    planted = max(measure_mask(truth.astype(np.uint8) * 255, meta.range_m / 2000, 12), key=lambda r: r[2].length_m)
    assert b.length_m == pytest.approx(planted[2].length_m, rel=0.15)


@pytest.mark.slow
def test_a_12_mp_mission_frame_at_the_default_budget_is_measured_on_its_quarter_decode():
    """The paper's 12 MP capture of the mission's wall at its 4.78 m stand-off, as the edge renders it: the
    default real-time budget detects it on the 1/4 decode (1000 x 750), and the report's cracks are the
    planted ones, in full-frame pixels, with their skeleton lengths near those of the full-size ground truth."""
    sc = load_scenario(None)
    wall, cam = synthetic_surface(sc), camera_model(sc, (4000, 3000))
    th, tw = wall.shape_px
    centre = wall.pixel_to_world_matrix() @ np.array([tw / 2, th / 2, 1.0])
    pos = centre + 4.78 * wall.normal
    R = camera_rotation(math.atan2(-wall.normal[1], -wall.normal[0]))
    frame = SyntheticSource(wall, cam, upsample=True).grab(CameraPose(position=pos, rotation=R), 0.0)
    fx, fy, cx, cy = cam.intrinsics()
    meta = ImageMeta(uav=1, capture_id=1, t=0.0, stamp=time.time(), cam_pos=tuple(pos), cam_rot=tuple(R.ravel()),
                     intrinsics=Intrinsics(width=4000, height=3000, fx=fx, fy=fy, cx=cx, cy=cy), range_m=4.78)
    budget = int(DETECT_MAX_MP * 1e6)
    assert detection_scale(4000, 3000, budget) == 4 and detection_scale(640, 480, budget) == 1
    rep = analyse(meta, encode_jpeg(frame.image, 85), "it+r", max_pixels=budget)
    truth = measure_mask(frame.mask, frame_scale(4.78, fx, fy), 12)
    assert rep.ok and len(truth) >= 2
    for bbox, _, m in truth[:2]:  # the two cracks in view, each found where it is and about as long
        x, y, w, h = bbox
        found = [d for d in rep.defects if abs(d.centroid_px[0] - (x + w / 2)) < w / 2
                 and abs(d.centroid_px[1] - (y + h / 2)) < h / 2 and abs(d.bbox[2] - w) < 40]
        assert found, (bbox, [d.bbox for d in rep.defects])
        assert found[0].length_m == pytest.approx(m.length_m, rel=0.10)


@pytest.mark.parametrize(("level", "says"), [(0, "under-exposed"), (255, "over-exposed"), (140, "blank")])
def test_a_frame_that_shows_no_surface_is_a_failed_report_saying_why(level, says):
    from services.detector.pipeline import UNUSABLE

    meta = capture_meta(1, 7, np.zeros(3), np.eye(3), (640, 480), F, F, 320.0, 240.0, RANGE)
    rep = analyse(meta, encode_jpeg(np.full((480, 640), level, np.uint8), 90), "it+")
    assert not rep.ok and not rep.defects and rep.error.startswith(f"{UNUSABLE}: {says}"), rep
    assert (rep.uav, rep.capture_id) == (1, 7)


def test_a_frame_declaring_another_size_than_its_metadata_is_refused_undecoded():
    """A few hundred bytes declaring 30000 x 30000 px took a detector worker 9 s and a gigabyte to 'decode'."""
    b = bytearray(encode_jpeg(np.zeros((8, 8), np.uint8)))
    i = b.find(b"\xff\xc0")
    b[i + 5:i + 9] = (30000).to_bytes(2, "big") + (30000).to_bytes(2, "big")
    meta = capture_meta(1, 3, np.zeros(3), np.eye(3), (640, 480), F, F, 320.0, 240.0, RANGE)
    rep = analyse(meta, bytes(b), "it+")
    assert not rep.ok and rep.error == "the JPEG is 30000 x 30000 px, its metadata says 640 x 480", rep
