"""Tests for edge.world.surface: crack-image generators and the synthetic inspected surface."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from edge.world.surface import SyntheticSurface, crack_image, draw_cracks, textured_background


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
# the default scenario's wall: 50 m x 6 m along north-south at x = 60, inspected from the west
CORNERS = [[60, 85, 25.5], [60, 35, 25.5], [60, 35, 31.5], [60, 85, 31.5]]


@pytest.fixture(scope="module")
def wall() -> SyntheticSurface:
    return SyntheticSurface.from_corners(CORNERS, px_per_m=50, seed=3)


def test_scenario_wall_geometry(wall: SyntheticSurface) -> None:
    assert wall.shape_px == (300, 2500) and wall.texture.dtype == np.uint8
    np.testing.assert_allclose(wall.normal, [-1, 0, 0], atol=1e-12)  # faces west, where the UAVs fly
    np.testing.assert_allclose(wall.corners, CORNERS)
    np.testing.assert_allclose(wall.center, [60, 60, 28.5])
    uv = np.array([[0.0, 0.0], [50.0, 6.0], [12.5, 3.0]])
    world = wall.surface_to_world(uv)
    np.testing.assert_allclose(world[0], CORNERS[0])
    np.testing.assert_allclose(world[1], CORNERS[2])
    np.testing.assert_allclose(wall.world_to_surface(world), uv, atol=1e-12)
    # a point off the plane projects onto it along the normal
    np.testing.assert_allclose(wall.world_to_surface([55.0, 60.0, 28.0]), [25.0, 2.5])
    assert wall.distance_to_plane([55.0, 60.0, 28.0]) == pytest.approx(5.0)


def test_texture_is_upright_and_matrix_consistent(wall: SyntheticSurface) -> None:
    # row 0 is the top of the wall, column 0 the p0 end
    np.testing.assert_allclose(wall.surface_to_pixel([[0.01, 5.99]]), [[0.0, 0.0]], atol=1e-9)
    np.testing.assert_allclose(wall.surface_to_pixel([[0.01, 0.01]]), [[0.0, 299.0]], atol=1e-9)
    A = wall.pixel_to_world_matrix()
    for col, row in [(0, 0), (2499, 299), (1250, 150), (7.25, 3.5)]:
        X = A @ [col, row, 1.0]
        np.testing.assert_allclose(wall.surface_to_pixel(wall.world_to_surface(X)), [col, row], atol=1e-9)
    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 300, size=(20, 2))
    np.testing.assert_allclose(wall.surface_to_pixel(wall.pixel_to_surface(xy)), xy, atol=1e-9)


def test_wall_from_two_corners() -> None:
    s = SyntheticSurface.from_corners([[10, 5, 1], [16, 5, 4]], px_per_m=20, n_cracks=1)
    assert s.shape_px == (60, 120)
    np.testing.assert_allclose(s.origin, [10, 5, 1])
    np.testing.assert_allclose(s.u_axis, [1, 0, 0])
    np.testing.assert_allclose(s.v_axis, [0, 0, 1])
    np.testing.assert_allclose(s.normal, [0, -1, 0], atol=1e-12)  # right of walking east
    np.testing.assert_allclose(s.corners[2], [16, 5, 4])
    # given top corner first: same wall
    t = SyntheticSurface.from_corners([[10, 5, 4], [16, 5, 1]], px_per_m=20, n_cracks=1)
    np.testing.assert_allclose(t.corners, s.corners)


def test_deck_from_two_corners_faces_up() -> None:
    s = SyntheticSurface.from_corners([[4, 3, 2], [0, 0, 2]], px_per_m=20, n_cracks=1)
    np.testing.assert_allclose(s.normal, [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(s.origin, [0, 0, 2])  # south-west corner
    assert s.shape_px == (60, 80)


def test_oblique_from_three_and_four_corners_round_trip() -> None:
    rng = np.random.default_rng(0)
    u = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)
    a = np.radians(30)
    v = np.cos(a) * np.array([0, 0, 1.0]) + np.sin(a) * np.cross([0, 0, 1.0], u)
    o = np.array([3.0, -2.0, 7.0])
    four = np.array([o, o + 4 * u, o + 4 * u + 2 * v, o + 2 * v])
    s = SyntheticSurface.from_corners(four, px_per_m=25, seed=1, n_cracks=2)
    s3 = SyntheticSurface.from_corners(four[[0, 1, 3]], px_per_m=25, seed=1, n_cracks=2)
    np.testing.assert_allclose(s3.corners, s.corners, atol=1e-12)
    assert s.width_m == pytest.approx(4) and s.height_m == pytest.approx(2)
    np.testing.assert_allclose(s.normal, np.cross(u, v), atol=1e-12)
    uv = rng.uniform([0, 0], [4, 2], size=(50, 2))
    world = s.surface_to_world(uv)
    np.testing.assert_allclose(s.world_to_surface(world), uv, atol=1e-12)
    np.testing.assert_allclose(s.distance_to_plane(world), 0, atol=1e-12)
    off = world + 1.5 * s.normal
    np.testing.assert_allclose(s.world_to_surface(off), uv, atol=1e-12)
    np.testing.assert_allclose(s.distance_to_plane(off), 1.5, atol=1e-12)
    assert s.contains(uv).all() and not s.contains([[4.1, 1.0], [1.0, -0.1]]).any()


@pytest.mark.parametrize(
    "corners",
    [
        [[0, 0, 0], [0, 0, 5]],  # no horizontal extent
        [[0, 0, 0], [3, 0, 0]],  # flat and no extent in y
        [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 2, 0]],  # not a rectangle
        [[0, 0, 0], [1, 0, 0], [1, 1, 1]],  # not a right angle
        [[0, 0, 0], [10, 0, 0], [11, 0, 3], [1, 0, 3]],  # a parallelogram
        [[0, 0, np.nan], [1, 0, 1]],
        [[0, 0, 0]],
        [[0, 0], [1, 1]],
    ],
)
def test_bad_corners(corners: list) -> None:
    with pytest.raises(ValueError):
        SyntheticSurface.from_corners(corners, px_per_m=10)


def test_bad_construction() -> None:
    with pytest.raises(ValueError):
        SyntheticSurface([0, 0, 0], [1, 0, 0], [0, 0, 1], 1000, 1000)  # 10^10 px
    with pytest.raises(ValueError):
        SyntheticSurface([0, 0, 0], [1, 0, 0], [0, 0, 1], -1, 1)
    with pytest.raises(ValueError):
        SyntheticSurface([0, 0, 0], [1, 0, 0], [0, 0, 1], 1, 1, px_per_m=float("inf"))
    with pytest.raises(ValueError):
        SyntheticSurface([0, 0, 0], [1, 0, 0], [0.1, 0, 1], 1, 1)  # not orthogonal
    with pytest.raises(ValueError):
        SyntheticSurface([0, 0, 0], [1, 0, 0], [0, 0, 1], 1, 1, px_per_m=10, texture=np.zeros((10, 10), np.uint8))
    with pytest.raises(ValueError):
        SyntheticSurface([0, 0, 0], [1, 0, 0], [0, 0, 1], 1, 1, px_per_m=10,
                         texture=np.zeros((9, 10), np.uint8), mask=np.zeros((9, 10), np.uint8))
    with pytest.raises(ValueError):
        SyntheticSurface.from_corners(CORNERS, px_per_m=10).world_to_surface([[1.0, 2.0]])


def test_given_texture_and_mask_are_used() -> None:
    tex = np.full((10, 20), 100, np.uint8)
    mask = np.zeros((10, 20), np.uint8)
    mask[2:4, 5:15] = 1
    s = SyntheticSurface([0, 0, 0], [1, 0, 0], [0, 0, 1], 2, 1, px_per_m=10, texture=tex, mask=mask)
    assert set(np.unique(s.mask)) == {0, 255}
    (d,) = s.defects()
    assert d.area_px == 20 and d.bbox_px == (5, 2, 10, 2)
    assert d.bbox_uv == pytest.approx((0.5, 0.6, 1.5, 0.8))
    assert d.centroid_uv == pytest.approx((1.0, 0.7))


def test_surface_deterministic_by_seed() -> None:
    a = SyntheticSurface.from_corners(CORNERS, px_per_m=10, seed=9)
    b = SyntheticSurface.from_corners(CORNERS, px_per_m=10, seed=9)
    c = SyntheticSurface.from_corners(CORNERS, px_per_m=10, seed=10)
    assert np.array_equal(a.texture, b.texture) and np.array_equal(a.mask, b.mask)
    assert not np.array_equal(a.mask, c.mask)


def test_defects_match_the_mask(wall: SyntheticSurface) -> None:
    every = wall.defects(min_area_px=0)
    assert sum(d.area_px for d in every) == int((wall.mask > 0).sum())
    defects = wall.defects()
    assert defects and len(defects) <= len(every) and all(d.area_px >= 20 for d in defects)
    assert [d.id for d in defects] == list(range(len(defects)))
    for d in defects:
        u0, v0, u1, v1 = d.bbox_uv
        assert 0 <= u0 <= d.centroid_uv[0] <= u1 <= 50 and 0 <= v0 <= d.centroid_uv[1] <= v1 <= 6
        assert d.centroid_world[0] == pytest.approx(60.0)
        np.testing.assert_allclose(wall.world_to_surface(d.centroid_world), d.centroid_uv, atol=1e-9)
        assert d.area_m2 == pytest.approx(d.area_px / 50**2)
        x, y, w, h = d.bbox_px
        assert wall.mask[y : y + h, x : x + w].any()
        # the pixel box and the surface box are the same rectangle
        np.testing.assert_allclose(wall.pixel_to_surface([[x - 0.5, y + h - 0.5]]), [[u0, v0]], atol=1e-9)
    # is_crack agrees with the mask at pixel centres
    rows, cols = np.nonzero(wall.mask)
    uv = wall.pixel_to_surface(np.stack([cols, rows], 1).astype(float))
    assert wall.is_crack(uv).all()
    rows0, cols0 = np.nonzero(wall.mask == 0)
    pick = np.random.default_rng(1).choice(len(rows0), 500)
    assert not wall.is_crack(wall.pixel_to_surface(np.stack([cols0[pick], rows0[pick]], 1).astype(float))).any()
    assert not wall.is_crack([[-1.0, 0.5], [0.5, 99.0]]).any()
    with pytest.raises(ValueError):
        wall.defects(min_area_px=-1)
