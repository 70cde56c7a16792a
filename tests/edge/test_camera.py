"""Tests for the camera: camera model (P1)-(P3) and poses (edge.geometry.optics), rendering of the synthetic
surface (edge.world.camera), folder and video sources and the off-loop encoder (edge.camera), JPEG (protocol.imagery)."""

from __future__ import annotations

import math
import threading
import time

import cv2
import numpy as np
import pytest

from edge.camera import FolderSource, FrameEncoder, VideoCaptureSource, make_source
from edge.geometry.camera import camera_rotation
from edge.geometry.optics import CameraModel, CameraPose
from edge.world.camera import Frame, FrameSource, SyntheticSource, upsample_factor
from edge.world.surface import SyntheticSurface, crack_image
from protocol.imagecodec import decode_image, encode_jpeg

# the default scenario's wall (50 m x 6 m at x = 60, facing west) and camera
CORNERS = [[60, 85, 25.5], [60, 35, 25.5], [60, 35, 31.5], [60, 85, 31.5]]
GOPRO = CameraModel((640, 480), (36.0, 27.0), 34.4)


@pytest.fixture(scope="module")
def wall() -> SyntheticSurface:
    return SyntheticSurface.from_corners(CORNERS, px_per_m=100, seed=5)


def backproject(surface: SyntheticSurface, cam: CameraModel, pose: CameraPose) -> tuple[np.ndarray, np.ndarray]:
    """Independent reference: for every frame pixel centre, the (u, v) where its ray meets the plane
    and whether it meets it in front of the camera."""
    w, h = cam.resolution
    xs, ys = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    fx, fy, cx, cy = cam.intrinsics()
    d_cam = np.stack([(xs - cx) / fx, (ys - cy) / fy, np.ones_like(xs)], -1)
    d = d_cam @ pose.rotation.T
    n = surface.normal
    t = ((surface.origin - pose.position) @ n) / (d @ n)
    hit = pose.position + t[..., None] * d
    return surface.world_to_surface(hit), t > 0


# ---------------------------------------------------------------- camera model
def test_intrinsics_and_task_assessment_p1_to_p3() -> None:
    fx, fy, cx, cy = GOPRO.intrinsics()
    assert fx == pytest.approx(34.4 * 640 / 36) and fy == pytest.approx(34.4 * 480 / 27)
    assert (cx, cy) == (319.5, 239.5)  # pixel centres at integers (OpenCV)
    np.testing.assert_allclose(GOPRO.K(), [[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
    # (P1)-(P2) on the paper's 4000 x 3000 stills: s_f = 2.5 mm -> a_fov = 5 m at 4.778 m
    stills = GOPRO.scaled(4000, 3000)
    assert stills.feature_footprint(0.0025) == pytest.approx((5.0, 3.75))
    assert stills.standoff(0.0025) == pytest.approx(5 * 34.4 / 36)
    assert GOPRO.footprint(5 * 34.4 / 36) == pytest.approx((5.0, 3.75))
    # the footprint at the (P2) stand-off is the (P1) footprint, whatever the frame size
    d = GOPRO.standoff(0.01)
    assert GOPRO.footprint(d) == pytest.approx(GOPRO.feature_footprint(0.01))
    assert GOPRO.gsd(d) == pytest.approx((0.005, 0.005))  # two pixels per 1 cm feature
    # (P3)
    assert GOPRO.spacing(d, 0.25) == pytest.approx((0.75 * 3.2, 0.75 * 2.4))
    assert GOPRO.fov_rad[0] == pytest.approx(2 * math.atan(18 / 34.4))


@pytest.mark.parametrize(
    "kwargs",
    [
        {"resolution": (0, 480)},
        {"resolution": (640.5, 480)},
        {"sensor_mm": (36.0, float("nan"))},
        {"sensor_mm": (36.0,)},
        {"focal_mm": 0.0},
        {"focal_mm": float("inf")},
    ],
)
def test_camera_model_bad_input(kwargs: dict) -> None:
    with pytest.raises(ValueError):
        CameraModel(**kwargs)


def test_camera_model_bad_arguments() -> None:
    with pytest.raises(ValueError):
        GOPRO.footprint(-1.0)
    with pytest.raises(ValueError):
        GOPRO.spacing(5.0, 1.0)
    with pytest.raises(ValueError):
        GOPRO.standoff(float("nan"))


# ---------------------------------------------------------------- poses
def test_pose_conventions() -> None:
    p = CameraPose.looking([1, 2, 3], yaw=0.0)
    np.testing.assert_allclose(p.rotation, camera_rotation(0.0), atol=1e-12)  # the edge's convention
    np.testing.assert_allclose(p.rotation[:, 0], [0, -1, 0], atol=1e-12)  # x right = south
    np.testing.assert_allclose(p.rotation[:, 1], [0, 0, -1], atol=1e-12)  # y down
    np.testing.assert_allclose(p.optical_axis, [1, 0, 0], atol=1e-12)
    down = CameraPose.looking([0, 0, 10], yaw=math.pi / 2, pitch=math.pi / 2)
    np.testing.assert_allclose(down.optical_axis, [0, 0, -1], atol=1e-12)
    # rolled by +90 deg: image x turns to where y was (down)
    r = CameraPose.looking([0, 0, 0], yaw=0.0, roll=math.pi / 2)
    np.testing.assert_allclose(r.rotation[:, 0], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(r.optical_axis, [1, 0, 0], atol=1e-12)
    # a point straight ahead projects to the principal point
    px, z = GOPRO.project([[11.0, 2.0, 3.0]], p)
    np.testing.assert_allclose(px, [[319.5, 239.5]])
    assert z[0] == pytest.approx(10.0)


def test_pose_facing_a_surface(wall: SyntheticSurface) -> None:
    p = CameraPose.facing(wall.center, wall.normal, 4.0)
    np.testing.assert_allclose(p.position, wall.center + 4 * wall.normal)
    np.testing.assert_allclose(p.rotation[:, 0], wall.u_axis, atol=1e-12)  # texture unmirrored
    np.testing.assert_allclose(p.rotation[:, 1], -wall.v_axis, atol=1e-12)  # wall up = image up
    top = CameraPose.facing([0, 0, 0], [0, 0, 1], 10.0)  # straight down: north is image up
    np.testing.assert_allclose(top.rotation[:, 1], [0, -1, 0], atol=1e-12)


def test_pose_bad_input() -> None:
    with pytest.raises(ValueError):
        CameraPose(np.zeros(3), np.diag([1.0, 1.0, -1.0]))  # a reflection
    with pytest.raises(ValueError):
        CameraPose(np.zeros(3), 2 * np.eye(3))
    with pytest.raises(ValueError):
        CameraPose(np.array([0, np.nan, 0]), np.eye(3))
    with pytest.raises(ValueError):
        CameraPose.looking([0, 0, 0], yaw=float("inf"))
    with pytest.raises(ValueError):
        CameraPose.facing([0, 0, 0], [0, 0, 0], 1.0)


# ---------------------------------------------------------------- synthetic rendering
def test_stripe_appears_where_the_geometry_says() -> None:
    # a plain wall with one vertical crack 5 cm wide at u = 2.00..2.05 m
    tex = np.full((300, 500), 150, np.uint8)
    mask = np.zeros_like(tex)
    mask[:, 200:205] = 255
    tex[mask > 0] = 60
    s = SyntheticSurface([0, 0, 0], [1, 0, 0], [0, 0, 1], 5.0, 3.0, px_per_m=100, texture=tex, mask=mask)
    cam = CameraModel((640, 480))
    d = cam.standoff(0.01)  # 3.2 m wide footprint, 5 mm per frame pixel
    pose = CameraPose.facing(s.surface_to_world([2.5, 1.5]), s.normal, d)
    frame = SyntheticSource(s, cam).grab(pose, 3.0)
    assert frame.t == 3.0 and frame.pose is pose and frame.image.shape == (480, 640)
    cols = np.nonzero(frame.mask[240])[0]
    # u = 2.0..2.05 m is -0.5..-0.45 m from the centre: x = 319.5 + (-100..-90) px
    assert cols.min() == pytest.approx(219.5, abs=1.0) and cols.max() == pytest.approx(229.5, abs=1.0)
    assert (frame.mask > 0).any(axis=1).all()  # the crack crosses the whole frame
    assert frame.image[240, cols].mean() < 70 and frame.image[240, 400] == 150
    # footprint (P1)-(P2): the frame spans 3.2 m x 2.4 m of wall
    uv, _ = backproject(s, cam, pose)
    width = (uv[240, -1, 0] - uv[240, 0, 0]) * 640 / 639
    height = (uv[0, 320, 1] - uv[-1, 320, 1]) * 480 / 479
    assert (width, height) == pytest.approx(cam.footprint(d))
    assert cam.footprint(d) == pytest.approx(cam.feature_footprint(0.01))


def test_view_straight_at_a_crack_agrees_with_the_surface_mask(wall: SyntheticSurface) -> None:
    d = max(wall.defects(), key=lambda d: d.area_px)
    pose = CameraPose.facing(d.centroid_world, wall.normal, 4.778)
    frame = SyntheticSource(wall, GOPRO).grab(pose, 1.0)
    ys, xs = np.nonzero(frame.mask)
    assert len(xs) > 50
    # the crack's centroid projects to the image centre (the centroid of its pixels there)
    assert abs(np.mean(xs) - 319.5) < 40 and abs(np.mean(ys) - 239.5) < 40
    # the view's mask is the surface's mask where the pixel rays meet the wall
    uv, ahead = backproject(wall, GOPRO, pose)
    truth = wall.is_crack(uv) & ahead
    view = frame.mask > 0
    assert (view == truth).mean() > 0.995
    assert (view & truth).sum() > 0.9 * truth.sum()
    # and the cracks are darker in the frame
    assert frame.image[view].mean() < frame.image[~view].mean() - 20


def test_upsample_factor_keeps_two_frame_pixels_per_texel() -> None:
    assert upsample_factor(0.125, (4000, 3000)) == 4  # the paper's 12 MP frame of a 100 px/m wall at 4.78 m
    assert upsample_factor(0.24, (640, 480)) == 2
    assert upsample_factor(0.3, (640, 480)) == 1 and upsample_factor(3.0, (640, 480)) == 1
    assert upsample_factor(1e-6, (64, 48)) == 2  # the reduced frame keeps 16 pixels a side
    assert upsample_factor(0.125, (4000, 3000), limit=0.25) == 2
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError):
            upsample_factor(bad, (640, 480))
    with pytest.raises(ValueError):
        upsample_factor(0.1, (640, 480), limit=0.0)


@pytest.mark.slow
def test_upsampled_12_mp_view_matches_the_direct_warp(wall: SyntheticSurface) -> None:
    stills = GOPRO.scaled(4000, 3000)
    d = max(wall.defects(), key=lambda d: d.area_px)
    cracked = 0
    for pose in (CameraPose.facing(d.centroid_world, wall.normal, 4.778),
                 CameraPose.looking([57.0, 60, 28], math.radians(20))):  # oblique: sky beside the wall
        direct = SyntheticSource(wall, stills).grab(pose, 0.0)
        fast = SyntheticSource(wall, stills, upsample=True).grab(pose, 0.0)
        lean = SyntheticSource(wall, stills, mask=False, upsample=True).grab(pose, 0.0)
        assert fast.image.shape == direct.image.shape == (3000, 4000) and fast.image.dtype == np.uint8
        diff = np.abs(fast.image.astype(int) - direct.image)
        assert diff.mean() < 1.0 and np.percentile(diff, 99) <= 4  # bilinear of bilinear: grey levels apart
        assert np.array_equal(fast.mask, direct.mask)  # the mask is always warped at full size
        assert lean.mask is None and np.array_equal(lean.image, fast.image)
        view = direct.mask > 0
        if view.any():  # the cracks are there (the view straight at the largest one)
            cracked += 1
            assert fast.image[view].mean() < fast.image[~view].mean() - 20
        assert np.array_equal(fast.image == 200, direct.image == 200) or (
            (fast.image == 200) != (direct.image == 200)).mean() < 0.01  # the same sky
    assert cracked == 1
    assert SyntheticSource(wall, stills, mask=False).grab(None, 0.0).mask is None


def test_oblique_view_shows_sky_above_the_horizon(wall: SyntheticSurface) -> None:
    # 2 m in front of the wall, looking along it (north, 20 deg into the wall): the far part of the
    # frame sees past the end of the wall or above its horizon
    pos = np.array([58.0, 40.0, 28.5])
    pose = CameraPose.looking(pos, yaw=math.radians(70.0), pitch=math.radians(-10.0))
    frame = SyntheticSource(wall, GOPRO).grab(pose, 0.0)
    uv, ahead = backproject(wall, GOPRO, pose)
    on_wall = ahead & wall.contains(uv)
    assert 0.1 < on_wall.mean() < 0.9
    # away from the boundary, off-wall pixels are sky and on-wall pixels are texture
    inner = cv2.erode(on_wall.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    outer = cv2.erode((~on_wall).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    assert (frame.image[outer] == 200).all() and not frame.mask[outer].any()
    assert (frame.image[inner] != 200).mean() > 0.9


def test_behind_or_looking_away_gives_sky(wall: SyntheticSurface) -> None:
    src = SyntheticSource(wall, GOPRO)
    behind = src.grab(CameraPose.looking([70.0, 60, 28], 0.0), 0)  # east of the wall, facing its back
    away = src.grab(CameraPose.looking([55.0, 60, 28], math.pi), 0)  # in front, looking west
    nopose = src.grab(None, 0)
    for f in (behind, away, nopose):
        assert (f.image == 200).all() and not f.mask.any()
    assert [behind.seq, away.seq, nopose.seq] == [0, 1, 2]


def test_far_view_is_filtered_not_aliased() -> None:
    # a 1 px checkerboard seen from 8x the 1:1 distance: the frame should be an even grey
    tex = ((np.indices((400, 800)).sum(0) % 2) * 200 + 20).astype(np.uint8)
    mask = np.zeros_like(tex)
    mask[195:205, 395:405] = 255
    s = SyntheticSurface([0, 0, 0], [1, 0, 0], [0, 0, 1], 8.0, 4.0, px_per_m=100, texture=tex, mask=mask)
    cam = CameraModel((160, 120))
    one_to_one = 0.01 * cam.focal_mm * 160 / cam.sensor_mm[0]  # 1 texture pixel per frame pixel
    pose = CameraPose.facing(s.center, s.normal, 8 * one_to_one)
    frame = SyntheticSource(s, cam).grab(pose, 0.0)
    uv, _ = backproject(s, cam, pose)
    inside = cv2.erode(s.contains(uv).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    vals = frame.image[inside].astype(float)
    assert abs(vals.mean() - 120) < 3 and vals.std() < 4
    assert frame.mask.any()  # the small defect is still marked at 1:8
    # near the 1:1 distance the checkerboard is resolved
    near = SyntheticSource(s, cam).grab(CameraPose.facing(s.center, s.normal, one_to_one), 0.0)
    assert near.image.astype(float).std() > 60


def test_synthetic_noise_is_seeded(wall: SyntheticSurface) -> None:
    pose = CameraPose.facing(wall.center, wall.normal, 5.0)
    a = SyntheticSource(wall, GOPRO, noise_sigma=3.0, seed=1).grab(pose, 0).image
    b = SyntheticSource(wall, GOPRO, noise_sigma=3.0, seed=1).grab(pose, 0).image
    clean = SyntheticSource(wall, GOPRO).grab(pose, 0).image
    assert np.array_equal(a, b) and not np.array_equal(a, clean)
    assert 1.5 < np.std(a.astype(float) - clean) < 4.5


def test_synthetic_source_bad_input(wall: SyntheticSurface) -> None:
    with pytest.raises(ValueError):
        SyntheticSource(wall, GOPRO, sky=300)
    with pytest.raises(ValueError):
        SyntheticSource("wall", GOPRO)  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        make_source("synthetic")  # no surface, no camera
    assert isinstance(SyntheticSource(wall, GOPRO), FrameSource)


# ---------------------------------------------------------------- folder and video sources
def test_folder_source_order_and_loop(tmp_path) -> None:
    for name, value in (("b.png", 20), ("a.png", 10), ("c.JPG", 30)):
        cv2.imwrite(str(tmp_path / name), np.full((8, 8), value, np.uint8))
    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / "broken.png").write_bytes(b"not an image")
    src = make_source(str(tmp_path))
    assert isinstance(src, FolderSource) and isinstance(src, FrameSource)
    frames = [src.grab(None, float(t)) for t in range(4)]
    assert [int(f.image.mean() + 0.5) for f in frames] == [10, 20, 30, 10]
    assert [f.name for f in frames] == ["a.png", "b.png", "c.JPG", "a.png"]
    assert [f.seq for f in frames] == [0, 1, 2, 3] and frames[2].t == 2.0
    assert src.skipped == 1  # broken.png, between a.png and b.png
    once = FolderSource(tmp_path, loop=False)
    assert [once.grab(None, 0) is not None for _ in range(5)] == [True, True, True, False, False]
    colour = FolderSource(tmp_path, grey=False).grab(None, 0)
    assert colour.image.shape == (8, 8, 3)
    with pytest.raises(ValueError):
        FolderSource(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError):
        FolderSource(tmp_path / "empty")


def test_folder_source_brings_masks_of_a_data_set(tmp_path) -> None:
    (tmp_path / "images").mkdir()
    (tmp_path / "masks").mkdir()
    for i in range(2):
        cv2.imwrite(str(tmp_path / "images" / f"00{i}.jpg"), np.full((6, 9), 100, np.uint8))
    m = np.zeros((6, 9), np.uint8)
    m[2, 3:6] = 1
    cv2.imwrite(str(tmp_path / "masks" / "000.png"), m)
    src = make_source(str(tmp_path / "images"))
    f0, f1 = src.grab(None, 0), src.grab(None, 0)
    assert f0.mask is not None and f0.mask.sum() == 3 * 255
    assert f1.mask is None  # no mask for 001


@pytest.mark.data
def test_folder_source_on_crackforest() -> None:
    from pathlib import Path

    images = Path("/work/shared/data/crackforest/images")
    if not images.is_dir():
        pytest.skip("the CrackForest images are not on this machine (/work/shared/data)")
    src = make_source(str(images), loop=False)
    f = src.grab(None, 0)
    assert f.name == "001.jpg" and f.image.shape == (320, 480) and f.mask is not None


def test_video_capture_source(tmp_path) -> None:
    path = str(tmp_path / "v.avi")
    writer = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"MJPG"), 10, (64, 48))
    if not writer.isOpened():
        pytest.skip("this OpenCV build cannot write MJPG .avi (no video writer backend)")
    for i in range(5):
        writer.write(np.full((48, 64, 3), 40 * i, np.uint8))
    writer.release()
    src = make_source(f"video:{path}")
    assert isinstance(src, VideoCaptureSource)
    frames = [src.grab(None, 0.5) for _ in range(6)]
    assert all(f is not None for f in frames[:5]) and frames[5] is None
    assert frames[0].image.shape == (48, 64, 3)
    assert [round(float(f.image.mean()) / 40) for f in frames[:5]] == [0, 1, 2, 3, 4]
    assert src.failed == 1
    src.close()
    grey = VideoCaptureSource(path, grey=True)
    assert grey.grab(None, 0).image.shape == (48, 64)
    grey.close()
    with pytest.raises(ValueError):
        VideoCaptureSource(str(tmp_path / "none.avi"))
    with pytest.raises(ValueError):
        make_source("video:")


# ---------------------------------------------------------------- JPEG
def test_jpeg_round_trip_grey_and_colour() -> None:
    grey, _ = crack_image((48, 64), 0)
    back = decode_image(encode_jpeg(grey, 95))
    assert back.shape == grey.shape and back.dtype == np.uint8
    assert np.abs(back.astype(int) - grey).mean() < 4
    bgr = np.dstack([grey, grey // 2, 255 - grey])
    back3 = decode_image(encode_jpeg(bgr, 90))
    assert back3.shape == bgr.shape and np.abs(back3.astype(int) - bgr).mean() < 8
    assert decode_image(encode_jpeg(bgr), grey=True).shape == grey.shape
    assert len(encode_jpeg(grey, 30)) < len(encode_jpeg(grey, 95))


def test_jpeg_corrupt_bytes_raise_value_error() -> None:
    good = encode_jpeg(np.full((32, 32), 128, np.uint8))
    for bad in (b"", b"\xff\xd8garbage", bytes(100), good[: len(good) // 2], b"\x89PNG" + good[4:],
                good[:200] + bytes(64) + good[-2:]):
        with pytest.raises(ValueError):
            decode_image(bad)
    with pytest.raises(ValueError):
        decode_image("text")  # type: ignore[arg-type]


@pytest.mark.parametrize(
    "image,quality",
    [
        (np.zeros((8, 8), np.float32), 85),
        (np.zeros((8, 8, 2), np.uint8), 85),
        (np.zeros((0, 8), np.uint8), 85),
        (np.zeros((8, 8), np.uint8), 0),
        (np.zeros((8, 8), np.uint8), 101),
        ("image", 85),
    ],
)
def test_encode_bad_input(image, quality) -> None:
    with pytest.raises(ValueError):
        encode_jpeg(image, quality)


# ---------------------------------------------------------------- off-loop encoder
def test_frame_encoder_in_order_and_on_its_own_thread() -> None:
    got: list[tuple[int, int, str]] = []
    enc = FrameEncoder(lambda f, jpeg: got.append((f.seq, decode_image(jpeg)[0, 0], threading.current_thread().name)),
                       capacity=64)
    for i in range(20):
        assert enc.submit(Frame(np.full((16, 16), 10 * i, np.uint8), float(i), seq=i))
    enc.close()
    assert [g[0] for g in got] == list(range(20))
    assert all(abs(int(g[1]) - 10 * g[0]) <= 2 for g in got)
    assert {g[2] for g in got} == {"jpeg-encoder"}
    assert (enc.submitted, enc.encoded, enc.dropped, enc.failed) == (20, 20, 0, 0)


def test_frame_encoder_drops_oldest_when_full_and_closes() -> None:
    got, gate, started = [], threading.Event(), threading.Event()

    def slow(tag, jpeg):
        started.set()
        gate.wait(5)
        got.append(tag)

    enc = FrameEncoder(slow, capacity=2)
    img = np.zeros((16, 16), np.uint8)
    enc.submit(img, 0)
    assert started.wait(5)  # the worker holds frame 0 until the gate opens
    kept = [enc.submit(img, i) for i in range(1, 6)]
    assert kept == [True, True, False, False, False]
    assert enc.pending == 2 and enc.dropped == 3
    gate.set()
    enc.close()
    assert got == [0, 4, 5]  # the oldest waiting frames (1, 2, 3) were dropped
    assert not enc.alive
    with pytest.raises(ValueError):
        enc.submit(img, 7)
    enc.close()  # idempotent


def test_frame_encoder_survives_callback_errors_and_bad_frames() -> None:
    got = []

    def flaky(tag, jpeg):
        if tag == 1:
            raise RuntimeError("publish failed")
        got.append(tag)

    enc = FrameEncoder(flaky)
    enc.submit(np.zeros((8, 8), np.uint8), 0)
    enc.submit(np.zeros((8, 8), np.uint8), 1)
    enc.submit(np.zeros((8, 8), np.float64), 2)  # not encodable
    enc.submit(np.zeros((8, 8), np.uint8), 3)
    enc.close()
    assert got == [0, 3] and enc.failed == 2 and enc.encoded == 2
    with pytest.raises(ValueError):
        enc.submit("frame", 4)  # type: ignore[arg-type]


def test_frame_encoder_close_without_drain() -> None:
    gate = threading.Event()
    enc = FrameEncoder(lambda tag, jpeg: gate.wait(5), capacity=8)
    for i in range(5):
        enc.submit(np.zeros((8, 8), np.uint8), i)
    time.sleep(0.05)
    enc.close(timeout=0.0, drain=False)
    gate.set()
    enc.close(timeout=5)  # idempotent: joins the worker
    assert not enc.alive
    assert enc.encoded + enc.dropped == 5 and enc.dropped >= 3


@pytest.mark.parametrize("kwargs", [{"capacity": 0}, {"quality": 0}, {"on_encoded": None}])
def test_frame_encoder_bad_arguments(kwargs: dict) -> None:
    args = {"on_encoded": lambda t, j: None} | kwargs
    with pytest.raises(ValueError):
        FrameEncoder(**args)
