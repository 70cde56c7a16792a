"""Tests for edge.surface: crack-image generators and the synthetic inspected surface."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from edge.surface import crack_image, draw_cracks, textured_background


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
