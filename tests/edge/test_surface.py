"""Tests for edge.surface: crack-image generators and the synthetic inspected surface."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from edge.surface import SyntheticSurface, crack_image, draw_cracks, textured_background


# ---------------------------------------------------------------- generators
def test_background_shape_dtype_and_level() -> None:
    bg = textured_background((120, 200), 3, mean=140.0)
    assert bg.shape == (120, 200) and bg.dtype == np.uint8
    assert 120 < bg.mean() < 160
    assert bg.std() > 3  # textured, not flat


def test_background_deterministic_by_seed() -> None:
    a = textured_background((64, 80), 7)
    b = textured_background((64, 80), 7)
    c = textured_background((64, 80), 8)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_background_gradient_zero_and_flat() -> None:
    flat = textured_background((50, 60), 1, roughness=0, blotches=0, gradient=0, grain=0, mean=100)
    assert np.all(flat == 100)


def test_draw_cracks_binary_thin_and_seeded() -> None:
    m = draw_cracks((240, 320), 5, n_cracks=4)
    assert m.shape == (240, 320) and m.dtype == np.uint8
    assert set(np.unique(m)) <= {0, 255}
    frac = (m > 0).mean()
    assert 0.002 < frac < 0.15  # cracks are thin lines, not blobs
    assert np.array_equal(m, draw_cracks((240, 320), 5, n_cracks=4))
    assert not np.any(draw_cracks((50, 50), 0, n_cracks=0))


def test_crack_width_within_range() -> None:
    # the distance transform inside the mask is at most about half the widest stroke
    m = draw_cracks((300, 300), 11, n_cracks=5, width_px=(1, 3))
    dist = cv2.distanceTransform((m > 0).astype(np.uint8), cv2.DIST_L2, 5)
    assert dist.max() <= 3.0
    wide = draw_cracks((300, 300), 11, n_cracks=5, width_px=(5, 9))
    dist_w = cv2.distanceTransform((wide > 0).astype(np.uint8), cv2.DIST_L2, 5)
    assert dist_w.max() > dist.max()


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_crack_image_cracks_darker_than_surroundings(seed: int) -> None:
    grey, mask = crack_image((320, 480), seed, n_cracks=3)
    assert grey.shape == mask.shape == (320, 480)
    assert grey.dtype == mask.dtype == np.uint8
    on = mask > 0
    assert on.any()
    # compare with a ring 3..8 px around the cracks (local background)
    near = cv2.dilate(mask, np.ones((17, 17), np.uint8)) > 0
    ring = near & ~(cv2.dilate(mask, np.ones((7, 7), np.uint8)) > 0)
    assert grey[on].mean() < 0.85 * grey[ring].mean()


def test_crack_image_deterministic() -> None:
    a = crack_image((100, 120), 42)
    b = crack_image((100, 120), np.random.default_rng(42))
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


@pytest.mark.parametrize(
    "kwargs",
    [
        {"shape": (0, 10)},
        {"shape": (10,)},
        {"shape": (10.5, 10)},
        {"n_cracks": -1},
        {"contrast": (0.6, 0.2)},
        {"contrast": (0.1, float("nan"))},
        {"noise_sigma": -1.0},
        {"width_px": (0.5, 3)},
        {"rng": "seed"},
    ],
)
def test_crack_image_bad_input(kwargs: dict) -> None:
    args = {"shape": (20, 20), "rng": 0} | kwargs
    with pytest.raises(ValueError):
        crack_image(**args)


# ---------------------------------------------------------------- the surface in the world
@pytest.fixture(scope="module")
def wall() -> SyntheticSurface:
    # a 6 m x 3 m wall along east, from (10, 5) to (16, 5), 1..4 m high: front faces south
    return SyntheticSurface.from_corners([[10, 5, 1], [16, 5, 4]], px_per_m=50, seed=3, n_cracks=4)


def test_wall_from_two_corners(wall: SyntheticSurface) -> None:
    assert wall.shape_px == (150, 300)
    np.testing.assert_allclose(wall.origin, [10, 5, 4])
    np.testing.assert_allclose(wall.u_axis, [1, 0, 0])
    np.testing.assert_allclose(wall.v_axis, [0, 0, -1])
    np.testing.assert_allclose(wall.normal, [0, -1, 0], atol=1e-12)  # right of walking east
    np.testing.assert_allclose(wall.corners[2], [16, 5, 1])
    np.testing.assert_allclose(wall.center, [13, 5, 2.5])


def test_deck_from_two_corners_faces_up() -> None:
    s = SyntheticSurface.from_corners([[0, 0, 2], [4, 3, 2]], px_per_m=20, n_cracks=1)
    np.testing.assert_allclose(s.normal, [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(s.origin, [0, 3, 2])  # north-west corner
    assert s.shape_px == (60, 80)


def test_oblique_from_four_corners_round_trip() -> None:
    # a tilted rectangle: u along (1, 1, 0)/sqrt2, v along (0, 0, -1) rotated 30 deg about u
    rng = np.random.default_rng(0)
    u = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)
    a = np.radians(30)
    v = np.cos(a) * np.array([0, 0, -1.0]) + np.sin(a) * np.cross(u, [0, 0, -1.0])
    o = np.array([3.0, -2.0, 7.0])
    corners = np.array([o, o + 4 * u, o + 4 * u + 2 * v, o + 2 * v])
    s = SyntheticSurface.from_corners(corners, px_per_m=25, seed=1, n_cracks=2)
    assert s.width_m == pytest.approx(4) and s.height_m == pytest.approx(2)
    assert np.linalg.norm(s.normal) == pytest.approx(1)
    assert abs(s.normal @ s.u_axis) < 1e-12 and abs(s.normal @ s.v_axis) < 1e-12
    uv = rng.uniform([0, 0], [4, 2], size=(50, 2))
    world = s.surface_to_world(uv)
    np.testing.assert_allclose(s.world_to_surface(world), uv, atol=1e-12)
    np.testing.assert_allclose(s.distance_to_plane(world), 0, atol=1e-12)
    # points off the plane project along the normal
    off = world + 1.5 * s.normal
    np.testing.assert_allclose(s.world_to_surface(off), uv, atol=1e-12)
    np.testing.assert_allclose(s.distance_to_plane(off), 1.5, atol=1e-12)
    np.testing.assert_allclose(s.pixel_to_surface(s.surface_to_pixel(uv)), uv, atol=1e-12)
    np.testing.assert_allclose(s.surface_to_pixel([[0.02, 0.02]]), [[0.0, 0.0]])  # pixel centre


def test_bad_corners() -> None:
    with pytest.raises(ValueError):
        SyntheticSurface.from_corners([[0, 0, 0], [0, 0, 5]])  # no horizontal extent
    with pytest.raises(ValueError):
        SyntheticSurface.from_corners([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 2, 0]])  # not a rectangle
    with pytest.raises(ValueError):
        SyntheticSurface.from_corners([[0, 0, 0], [1, 0, 0], [1, 1, 0]])  # not a right angle
    with pytest.raises(ValueError):
        SyntheticSurface.from_corners([[0, 0, np.nan], [1, 0, 1]])
    with pytest.raises(ValueError):
        SyntheticSurface.from_corners([[0, 0, 0]])
    with pytest.raises(ValueError):
        SyntheticSurface([0, 0, 0], [1, 0, 0], [0, 0, -1], 1000, 1000)  # 10^10 px
    with pytest.raises(ValueError):
        SyntheticSurface([0, 0, 0], [1, 0, 0], [0, 0, -1], -1, 1)


def test_surface_deterministic_by_seed() -> None:
    a = SyntheticSurface.from_corners([[0, 0, 0], [3, 0, 2]], px_per_m=40, seed=9)
    b = SyntheticSurface.from_corners([[0, 0, 0], [3, 0, 2]], px_per_m=40, seed=9)
    assert np.array_equal(a.texture, b.texture) and np.array_equal(a.mask, b.mask)
    assert a.mask.any()


def test_defects_match_mask(wall: SyntheticSurface) -> None:
    defects = wall.defects()
    assert defects
    assert sum(d.area_px for d in defects) == int((wall.mask > 0).sum())
    for d in defects:
        x, y, w, h = d.bbox_px
        assert wall.mask[y : y + h, x : x + w].any()
        u0, v0, u1, v1 = d.bbox_uv
        assert u0 <= d.centroid_uv[0] <= u1 and v0 <= d.centroid_uv[1] <= v1
        np.testing.assert_allclose(wall.world_to_surface(d.centroid_enu), d.centroid_uv, atol=1e-9)
        assert d.area_m2 == pytest.approx(d.area_px / 50**2)
    # is_crack agrees with the mask at pixel centres
    rows, cols = np.nonzero(wall.mask)
    uv = wall.pixel_to_surface(np.stack([cols, rows], 1).astype(float))
    assert wall.is_crack(uv).all()
    assert not wall.is_crack([[-1.0, 0.5], [0.5, 99.0]]).any()
