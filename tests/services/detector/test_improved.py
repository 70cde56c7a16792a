"""IT+ beyond the area guard and the bounding-box shape rule: the per-component contrast floor
(P19), the length rule that needs real elongation, and the guard that a crack-free frame does not
trigger."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from edge.world.surface import crack_image, textured_background
from services.detector.improved import (
    GUARD_CONTRAST_DEFAULT,
    component_contrast,
    it_plus_mask,
    shape_filter,
    threshold_it_plus,
)
from services.detector.thresholds import histogram


def _lines() -> tuple[np.ndarray, np.ndarray]:
    g = np.full((120, 200), 150, np.uint8)
    m = np.zeros_like(g)
    cv2.line(m, (10, 20), (190, 30), 255, 3)  # a dark crack
    g[m > 0] = 70
    faint = np.zeros_like(g)
    cv2.line(faint, (10, 80), (190, 90), 255, 3)  # a line barely darker than its surroundings
    g[faint > 0] = 140
    return g, cv2.bitwise_or(m, faint)


def test_contrast_floor_keeps_dark_cracks_and_drops_faint_ones():
    g, m = _lines()
    out = shape_filter(m, grey=g, min_contrast=0.1)
    assert out[25, 100] and not out[85, 100]
    assert shape_filter(m, grey=g, min_contrast=0.0)[85, 100]  # no floor: both stay
    assert shape_filter(m, min_contrast=0.1)[85, 100]  # no grey: the floor cannot apply


def test_component_contrast_is_p19_against_the_ring():
    g, m = _lines()
    n, lab = cv2.connectedComponents(m, connectivity=8, ltype=cv2.CV_32S)
    c = component_contrast(g, lab, n)
    assert sorted(np.round(c[1:], 3)) == [round(10 / 290, 3), round(80 / 220, 3)]


def test_robust_ring_ignores_the_bright_scene_beyond_the_surface():
    g = np.full((100, 200), 140, np.uint8)
    g[:40] = 220  # sky above the wall's edge
    m = np.zeros_like(g)
    m[40:46, 20:180] = 255  # a dark-ish band of texture along the edge
    g[m > 0] = 120
    n, lab = cv2.connectedComponents(m, connectivity=8, ltype=cv2.CV_32S)
    mean_c = component_contrast(g, lab, n)[1]
    med_c = component_contrast(g, lab, n, robust=True)[1]
    assert mean_c > 0.1 > med_c  # the mean ring is half sky; its median is the wall
    assert not shape_filter(m, grey=g, min_contrast=0.1).any()
    assert shape_filter(m, grey=g, min_contrast=0.1, robust=False).any()


def test_long_components_need_real_elongation():
    m = np.zeros((120, 160), np.uint8)
    cv2.ellipse(m, (80, 60), (35, 14), 0, 0, 360, 255, -1)  # 70 px long but fat: (w²+h²)/area ~ 4
    assert shape_filter(m, min_long_elongation=0.0).any()  # the old rule: long enough
    assert not shape_filter(m, min_long_elongation=5.0).any()
    line = np.zeros_like(m)
    cv2.line(line, (10, 10), (150, 100), 255, 4)
    assert shape_filter(line, min_long_elongation=5.0).any()


def test_guard_does_not_force_a_threshold_on_a_crack_free_frame():
    rng = np.random.default_rng(5)
    hits_forced, hits = 0, 0
    for _ in range(5):
        g = textured_background((480, 640), rng)
        h = histogram(g)
        forced = threshold_it_plus(hist=h, guard_contrast=0.0)
        gated = threshold_it_plus(hist=h, guard_contrast=GUARD_CONTRAST_DEFAULT)
        assert gated <= forced
        hits_forced += int(it_plus_mask(g, guard_contrast=0.0, min_contrast=0.0, min_long_elongation=0.0)[0].any())
        hits += int(it_plus_mask(g)[0].any())
    assert hits_forced >= 4  # the bare guard makes texture blobs into defects
    assert hits == 0


def test_it_plus_still_finds_synthetic_cracks():
    from services.detector.metrics import f_measure

    fs = []
    for seed in range(6):
        grey, gt = crack_image((240, 320), np.random.default_rng(100 + seed))
        fs.append(f_measure(it_plus_mask(grey)[0], gt)[0])
        assert it_plus_mask(grey)[0].any()
    assert np.mean(fs) > 0.5


def test_bad_contrast_floor_is_rejected():
    m = np.zeros((10, 10), np.uint8)
    with pytest.raises(ValueError):
        shape_filter(m, min_contrast=1.0)
    with pytest.raises(ValueError):
        shape_filter(m, grey=np.zeros((5, 5), np.uint8), min_contrast=0.1)


def test_blackhat_cue_finds_a_faint_crack_under_uneven_light():
    from services.detector.improved import it_plus_bh_mask

    h, w = 240, 320
    ramp = np.linspace(90, 190, w, dtype=np.float32)[None, :].repeat(h, 0)  # strong illumination gradient
    rng = np.random.default_rng(2)
    g = ramp + rng.normal(0, 3, (h, w)).astype(np.float32)
    crack = np.zeros((h, w), np.uint8)
    cv2.line(crack, (200, 20), (300, 220), 255, 2)  # on the bright side, 22 % darker than around it
    g[crack > 0] *= 0.78
    g = np.clip(g, 0, 255).astype(np.uint8)
    plain = it_plus_mask(g)[0]
    cued = it_plus_bh_mask(g)[0]
    hit = lambda m: np.count_nonzero((m > 0) & (crack > 0)) / np.count_nonzero(crack)  # noqa: E731
    assert hit(plain) < 0.2  # the global threshold takes the dark side of the ramp, not the crack
    assert hit(cued) > 0.6
    assert np.count_nonzero(cued[:, :150]) < 0.01 * cued[:, :150].size  # the ramp's dark side stays out
    with pytest.raises(ValueError):
        it_plus_bh_mask(g, size=2)
    with pytest.raises(ValueError):
        it_plus_bh_mask(g, top_fraction=0.0)


def test_blackhat_on_a_large_frame_works_on_the_reduced_grid():
    from services.detector.improved import it_plus_bh_mask

    g = np.full((1500, 2000), 150, np.uint8)
    cv2.line(g, (100, 100), (1900, 1400), 80, 9)
    m, _ = it_plus_bh_mask(g, work_px=200_000)  # s = 4
    assert m.shape == g.shape and m[750, 1000 - 9:1000 + 9].any()
