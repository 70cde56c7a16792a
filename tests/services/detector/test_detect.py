"""Detection API, IT+ (area guard, shape filter), defect list."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from services.detector.detect import METHODS, defects_of, detect, mask_at
from services.detector.improved import it_plus_mask, reduction_factor, shape_filter, threshold_it_plus
from services.detector.iterative import C_S_UNGUARDED, iterative_threshold
from services.detector.metrics import f_measure
from services.detector.thresholds import histogram


def bar_image() -> np.ndarray:
    g = np.full((60, 80), 200, np.uint8)
    g[20:23, 10:60] = 50  # a 3 x 50 dark crack
    g[45, 70] = 100  # a single dark speck
    return g


def test_registry_names_every_method():
    assert set(METHODS) == {"otsu", "ve", "sauvola", "itth", "sdd", "it", "it-paper", "it+", "it+bh", "it+r", "learned"}


def test_it_paper_is_the_bare_stop_rule():
    # a dark ramp: the guarded default stops on size, the bare rule runs on to its C_s
    g = np.full((100, 100), 200, np.uint8)
    g[:, :4] = np.arange(10, 90, 20, dtype=np.uint8)  # 4 columns of 10, 30, 50, 70
    h = histogram(g)
    bare = iterative_threshold(hist=h, c_s=C_S_UNGUARDED, min_region=0.0)
    mask, t = METHODS["it-paper"](g)
    assert t == bare.threshold and (mask == mask_at(g, t)).all()
    assert METHODS["it"](g)[1] == iterative_threshold(hist=h).threshold
    loose = iterative_threshold(hist=h, c_s=0.9, min_region=0).threshold
    assert METHODS["it-paper"](g, c_s=0.9)[1] == loose


@pytest.mark.parametrize("method", sorted(METHODS))
def test_every_method_finds_the_bar(method):
    g = bar_image()
    d = detect(g, method)
    assert d.mask.dtype == np.uint8 and d.mask.shape == g.shape
    assert set(np.unique(d.mask)) <= {0, 255}
    core = d.mask[20:23, 12:58] == 255
    # the network's mask of a perfectly flat bar is soft at the bar's ends (a pixel or two short of them)
    assert core.mean() >= 0.95 if method == "learned" else core.all()
    assert d.method == method


def test_defects_by_hand():
    g = bar_image()
    mask = np.where(g < 150, 255, 0).astype(np.uint8)
    ds = defects_of(g, mask)
    assert len(ds) == 2
    bar, speck = ds
    assert bar.area_px == 150 and bar.bbox == (10, 20, 50, 3)
    assert bar.centroid == pytest.approx((34.5, 21.0))
    assert bar.contrast == pytest.approx((200 - 50) / (200 + 50))
    assert speck.area_px == 1 and speck.bbox == (70, 45, 1, 1)
    assert speck.contrast == pytest.approx(100 / 300)
    assert defects_of(g, mask, min_area=2) == [bar]
    assert defects_of(g, np.zeros_like(mask)) == []


def test_defects_on_reduced_grid_keep_area_and_position():
    g = np.full((600, 900), 180, np.uint8)
    g[300:306, 120:720] = 60  # block-aligned for s = 3
    mask = np.where(g < 100, 255, 0).astype(np.uint8)
    exact = defects_of(g, mask)[0]
    approx = defects_of(g, mask, work_px=60_000)[0]  # s = 3
    assert reduction_factor(g.size, 60_000) == 3
    assert approx.area_px == exact.area_px == 3600
    assert approx.centroid == pytest.approx(exact.centroid, abs=1.0)
    assert approx.contrast == pytest.approx(exact.contrast, rel=1e-6)
    assert approx.bbox == exact.bbox


def test_detect_accepts_bgr_and_rejects_bad_input():
    g = bar_image()
    bgr = cv2.cvtColor(g, cv2.COLOR_GRAY2BGR)
    assert np.array_equal(detect(bgr, "it").mask, detect(g, "it").mask)
    with pytest.raises(ValueError):
        detect(g, "magic")
    with pytest.raises(ValueError):
        detect(np.full((4, 4), np.nan), "it")
    with pytest.raises(ValueError):
        detect(np.zeros((0, 4), np.uint8), "otsu")
    with pytest.raises(ValueError):
        defects_of(g, np.zeros((3, 3), np.uint8))


def test_shape_filter_keeps_lines_drops_blobs_and_specks():
    m = np.zeros((100, 100), np.uint8)
    m[10, 5:95] = 255  # long thin line: kept
    cv2.circle(m, (50, 60), 8, 255, -1)  # round blob (area ~200): dropped
    m[90, 90] = 255  # speck: dropped
    out = shape_filter(m)
    assert out[10, 5:95].all()
    assert not out[60, 50] and not out[90, 90]


def test_shape_filter_on_reduced_grid_matches_full():
    m = np.zeros((1200, 1500), np.uint8)
    cv2.line(m, (100, 100), (1400, 900), 255, 3)
    cv2.circle(m, (300, 800), 10, 255, -1)
    for x in range(200, 1400, 97):
        m[1100, x] = 255
    full = shape_filter(m, work_px=10_000_000)
    small = shape_filter(m, work_px=200_000, min_area=10, min_length=20)  # s = 3
    assert np.array_equal(full > 0, small > 0)
    assert np.count_nonzero(full) > 0.9 * np.count_nonzero(m)  # the line stays
    assert not full[800, 300] and not full[1100, 200]


def test_area_guard():
    h = np.zeros(256)
    h[10], h[60:200] = 10, 100.0  # 10 very dark px + a wide background
    r = iterative_threshold(hist=h, c_s=0.8)
    assert r.threshold == 10  # IT drills down to the 10 dark pixels (0.07 % of the image)
    t = threshold_it_plus(hist=h, c_s=0.8, min_fraction=0.05)
    cum = np.cumsum(h)
    assert cum[t] >= 0.05 * cum[-1] and cum[t - 1] < 0.05 * cum[-1]  # lowest level with 5 %
    assert t <= r.thresholds[0]  # never above the global Otsu step
    assert threshold_it_plus(hist=h, c_s=0.8, min_fraction=0.0) == 10
    assert threshold_it_plus(hist=h, c_s=0.8, min_fraction=0.9) == r.thresholds[0]
    with pytest.raises(ValueError):
        threshold_it_plus(hist=h, min_fraction=1.0)


def test_it_plus_beats_it_on_synthetic_cracks():
    surface = pytest.importorskip("edge.world.surface", reason="edge/world/surface.py (crack generator) not present")
    f_it, f_plus = [], []
    for seed in range(6):
        grey, gt = surface.crack_image((240, 320), np.random.default_rng(100 + seed))
        f_it.append(f_measure(detect(grey, "it", with_defects=False).mask, gt)[0])
        f_plus.append(f_measure(it_plus_mask(grey)[0], gt)[0])
    assert np.mean(f_plus) > np.mean(f_it) + 0.1
