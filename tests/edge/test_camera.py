import math
import threading
import time

import cv2
import numpy as np
import pytest

from edge.camera import (CameraModel, CameraPose, FolderSource, FrameEncoder, SyntheticSource, VideoCaptureSource,
                         decode_jpeg, encode_jpeg, make_source)
from edge.runtime import camera_rotation
from edge.surface import SyntheticSurface

CORNERS = [[60, 85, 25.5], [60, 35, 25.5], [60, 35, 31.5], [60, 85, 31.5]]
GOPRO = CameraModel((640, 480), (36.0, 27.0), 34.4)


@pytest.fixture(scope="module")
def wall():
    return SyntheticSurface.from_corners(CORNERS, px_per_m=100, seed=5)


def test_intrinsics_and_footprint_follow_p1_p2():
    fx, fy, cx, cy = GOPRO.intrinsics()
    assert math.isclose(fx, 34.4 * 640 / 36) and math.isclose(fy, 34.4 * 480 / 27) and (cx, cy) == (320, 240)
    # (P1)-(P2): s_f = 2.5 mm on 4000 px -> a_fov = 5 m at d = a_fov f / s_s = 4.778 m
    assert np.allclose(GOPRO.footprint(5 * 34.4 / 36), (5.0, 3.75))


def test_view_straight_at_a_crack_shows_it_at_the_centre(wall):
    d = max(wall.defects(), key=lambda d: d.area_px)
    pos = np.array(d.centroid_world) - [4.778, 0, 0]  # stand-off west of the wall, looking east
    frame = SyntheticSource(wall, GOPRO).grab(CameraPose(pos, camera_rotation(0.0)), 1.0)
    ys, xs = np.nonzero(frame.mask)
    assert len(xs) > 50
    # the crack's centroid (surface) projects to the image centre, within its spread
    assert abs(np.mean(xs) - 320) < 60 and abs(np.mean(ys) - 240) < 60
    # the view's mask agrees with the surface's: same pixels darker
    assert frame.image[frame.mask > 0].mean() < frame.image[frame.mask == 0].mean() - 15
    # footprint (P1)-(P2): at the stand-off the frame spans 5 m of wall, edge to edge
    R = camera_rotation(0.0)
    for du, x_expected in ((+2.5, 0.0), (-2.5, 640.0)):  # u runs south: +y is to the left
        X = np.array(d.centroid_world) + [0, du, 0]
        p = GOPRO.K() @ (R.T @ (X - pos))
        assert abs(p[0] / p[2] - x_expected) < 1.0


def test_wall_out_of_view_gives_sky(wall):
    src = SyntheticSource(wall, GOPRO)
    behind = src.grab(CameraPose(np.array([70.0, 60, 28]), camera_rotation(0.0)), 0)  # east of the wall
    away = src.grab(CameraPose(np.array([55.0, 60, 28]), camera_rotation(math.pi)), 0)  # looking west
    for f in (behind, away):
        assert (f.image == 200).all() and not f.mask.any()


def test_folder_source_order_and_loop(tmp_path):
    for name, value in (("b.png", 20), ("a.png", 10), ("c.jpg", 30), ("notes.txt", 0)):
        if name.endswith("txt"):
            (tmp_path / name).write_text("x")
        else:
            cv2.imwrite(str(tmp_path / name), np.full((8, 8), value, np.uint8))
    src = make_source(str(tmp_path))
    values = [int(src.grab(None, t).image.mean() + 0.5) for t in range(4)]
    assert values[:3] == [10, 20, 30] and values[3] == 10
    once = FolderSource(tmp_path, loop=False)
    assert [once.grab(None, 0) is not None for _ in range(4)] == [True, True, True, False]
    with pytest.raises(ValueError):
        FolderSource(tmp_path / "missing")


def test_video_capture_source(tmp_path):
    path = str(tmp_path / "v.avi")
    writer = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"MJPG"), 10, (64, 48))
    if not writer.isOpened():
        pytest.skip("OpenCV here has no MJPG writer")
    for i in range(5):
        writer.write(np.full((48, 64, 3), 40 * i, np.uint8))
    writer.release()
    src = make_source(f"video:{path}")
    frames = [src.grab(None, 0) for _ in range(6)]
    assert all(f is not None for f in frames[:5]) and frames[5] is None
    assert frames[4].image.mean() > frames[0].image.mean()
    src.close()
    with pytest.raises(ValueError):
        VideoCaptureSource(str(tmp_path / "none.avi"))


def test_jpeg_round_trip_and_corrupt_bytes():
    img = (np.arange(64 * 48) % 251).astype(np.uint8).reshape(48, 64)
    back = decode_jpeg(encode_jpeg(img, 95))
    assert back.shape == img.shape and np.abs(back.astype(int) - img).mean() < 6
    for bad in (b"", b"\xff\xd8garbage", bytes(100)):
        with pytest.raises(ValueError):
            decode_jpeg(bad)


def test_frame_encoder_in_order_drops_oldest_and_closes():
    got, gate = [], threading.Event()

    def slow(tag, jpeg):
        gate.wait(5)
        got.append(tag)

    enc = FrameEncoder(slow, capacity=2)
    img = np.zeros((16, 16), np.uint8)
    for i in range(6):
        enc.submit(img, i)
        time.sleep(0.01)
    gate.set()
    enc.close()
    assert got == sorted(got) and got[-1] == 5
    assert enc.dropped == 6 - len(got) and enc.dropped >= 2
    assert not enc._thread.is_alive()
    with pytest.raises(ValueError):
        enc.submit(img, 7)
