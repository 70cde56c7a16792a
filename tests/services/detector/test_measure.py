"""Crack measurements: skeleton length, widths, severity (services.detector.measure)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from services.detector.measure import (
    fill_holes,
    frame_scale,
    half_depth_mask,
    measure_component,
    measure_mask,
    prune_spurs,
    severity,
    skeleton_length,
)


def band(length: float, width: float, angle_deg: float, shape=(400, 400)) -> np.ndarray:
    m = np.zeros(shape, np.uint8)
    box = cv2.boxPoints(((shape[1] / 2, shape[0] / 2), (length, width), angle_deg))
    cv2.fillConvexPoly(m, np.round(box * 16).astype(np.int32), 255, cv2.LINE_8, 4)
    return m


@pytest.mark.parametrize("angle", [0.0, 22.5, 45.0, 70.0, 90.0, 135.0])
@pytest.mark.parametrize("width", [2.0, 3.0, 5.0, 8.0])
def test_straight_band_length_and_width(angle, width):
    m = band(250.0, width, angle)
    true_w = np.count_nonzero(m) / 250.0  # the drawn band's real mean width, pixels
    r = measure_component(m, 0.01)
    assert abs(r.length_px / 250.0 - 1.0) < 0.05
    assert abs(r.width_mean_px - true_w) <= 1.0
    assert abs(r.width_max_px - true_w) <= 1.5
    assert r.length_m == pytest.approx(0.01 * r.length_px)
    assert r.width_mean_m == pytest.approx(0.01 * r.width_mean_px)


def test_chain_code_length_of_a_diagonal_and_a_straight_line():
    s = np.zeros((50, 50), bool)
    s[10, 5:45] = True  # 40 pixels, 39 orthogonal links
    n, ends = skeleton_length(s)
    assert n == pytest.approx(0.948 * 39)
    assert len(ends) == 2
    d = np.eye(30, dtype=bool)  # 29 diagonal links
    assert skeleton_length(d)[0] == pytest.approx(1.343 * 29)


def test_spurs_are_pruned_but_the_crack_is_kept():
    s = np.zeros((60, 120), bool)
    s[30, 10:110] = True
    s[25:30, 60] = True  # a 5 px spur
    p = prune_spurs(s, 8)
    assert p[30, 10:110].all() and not p[25:29, 60].any()


def test_a_short_piece_of_a_broken_crack_is_kept_whole_not_pruned_as_a_spur():
    # a faint stretch breaks the half-depth mask: the 12 px piece past the gap has no junction, so it is
    # crack, not a spur of a rough edge, and pruning at 8 px (which strips up to 16 px of it) keeps it all
    s = np.zeros((40, 120), bool)
    s[20, 10:80] = True
    s[20, 84:96] = True
    s[15:20, 40] = True  # a 5 px spur on the long piece still goes
    p = prune_spurs(s, 8)
    assert p[20, 10:80].all() and p[20, 84:96].all() and not p[15:19, 40].any()

def test_half_depth_mask_narrows_a_loose_mask_to_the_crack():
    g = np.full((80, 200), 150, np.uint8)
    g[38:42, 10:190] = 60  # 4 px crack
    g[36:38, 10:190] = 135  # darker texture along its edges that a loose threshold takes in
    g[42:44, 10:190] = 135
    loose = (g <= 140).astype(np.uint8) * 255
    tight = half_depth_mask(g, loose > 0)
    assert np.count_nonzero(tight) == 4 * 180
    r = measure_component(loose, 1.0, grey=g)
    assert r.width_mean_px == pytest.approx(4.0, abs=0.5)


def test_severity_classes_and_resolution():
    assert severity(0.0001) == "insignificant"
    assert severity(0.0005) == "moderate"
    assert severity(0.002) == "wide"
    with pytest.raises(ValueError):
        severity(math.nan)
    assert measure_component(band(100, 3, 0), 0.00005).severity == "insignificant"  # ~0.2 mm
    assert measure_component(band(100, 3, 0), 0.001).severity == "wide"


def test_measure_mask_lists_components_largest_first():
    m = band(200, 4, 10) | np.roll(band(80, 3, 60), 150, axis=1)
    rows = measure_mask(m, 0.002, min_area_px=5)
    assert len(rows) == 2
    assert rows[0][2].length_px > rows[1][2].length_px
    assert frame_scale(4.78, 600.0, 600.0) == pytest.approx(4.78 / 600.0)
    with pytest.raises(ValueError):
        measure_component(np.zeros((5, 5), np.uint8), 0.01)
    with pytest.raises(ValueError):
        measure_component(m, -1.0)


def test_a_speck_inside_a_wide_crack_is_filled_and_a_gap_between_branches_is_not():
    """Thinning loops around a hole: specks of one to eight pixels in a 12 pixel wide band made its skeleton
    longer (a real-size crack measured 15 % long, its mean width as much short); two thin parallel branches
    with a gap between them stay two."""
    wide = np.zeros((40, 220), np.uint8)
    wide[14:26, 10:210] = 255
    whole = measure_component(wide, 1.0)
    specked = wide.copy()
    for x in (40, 80, 120, 160):
        specked[19:21, x:x + 2] = 0  # 2 x 2 holes off the axis
    assert measure_component(specked, 1.0).length_px == pytest.approx(whole.length_px, rel=0.02)
    assert measure_component(specked, 1.0).width_mean_px == pytest.approx(whole.width_mean_px, rel=0.03)
    two = np.zeros((40, 220), np.uint8)
    two[14:17, 10:210] = 255
    two[20:23, 10:210] = 255
    two[14:23, 10:13] = 255  # joined at one end: a gap of 3 x 197 pixels between them
    assert fill_holes(two, np.full(two.shape, 1.5)) is None
    assert measure_component(two, 1.0).length_px > 1.8 * 200
