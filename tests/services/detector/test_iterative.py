"""The paper's iterative thresholding (P18)-(P19): steps, stop rule, guards, readings."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.detector.iterative import (
    C_S_DEFAULT,
    C_S_UNGUARDED,
    MIN_REGION_DEFAULT,
    interclass_contrast,
    iterative_threshold,
    threshold_it,
)
from services.detector.metrics import f_measure
from services.detector.thresholds import threshold_otsu


def five_level_hist() -> np.ndarray:
    h = np.zeros(256)
    h[[20, 100, 110, 200, 210]] = [5, 40, 40, 400, 400]
    return h


def test_steps_by_hand():
    # step 1: Otsu on everything splits {20, 100, 110} | {200, 210}: T1 = 110
    #   μD = (20·5 + 100·40 + 110·40) / 85 = 100, μB = 205, C1 = 105 / 305
    # step 2: Otsu on levels 0..110 splits {20} | {100, 110}: T2 = 20
    #   "above":    μB = mean of all levels > 20 = (4000 + 4400 + 80000 + 84000) / 880, C2 = (μB − 20) / (μB + 20)
    #   "previous": μB = mean of (20, 110] = 105, C2 = 85 / 125
    h = five_level_hist()
    r = iterative_threshold(hist=h, c_s=0.5)
    assert r.thresholds == (110, 20) and r.threshold == 20 and r.stop == "contrast"
    assert r.contrasts[0] == pytest.approx(105 / 305)
    mu_b = 172400 / 880
    assert r.contrasts[1] == pytest.approx((mu_b - 20) / (mu_b + 20))
    rp = iterative_threshold(hist=h, c_s=0.5, background="previous")
    assert rp.thresholds == (110, 20)
    assert rp.contrasts == pytest.approx((105 / 305, 85 / 125))


def test_stop_rule_is_strictly_greater_than_c_s():
    h = five_level_hist()
    c1 = 105 / 305
    assert iterative_threshold(hist=h, c_s=c1 - 1e-9).thresholds == (110,)  # C1 > C_s: stop
    assert iterative_threshold(hist=h, c_s=c1).thresholds == (110, 20)  # C1 = C_s: go on
    assert iterative_threshold(hist=h, c_s=0.0).threshold == threshold_otsu(hist=h)


def test_region_guard_stops_at_a_single_level_region():
    h = five_level_hist()
    r = iterative_threshold(hist=h, c_s=0.99)
    # after T2 = 20 the dark region is the single level 20: nothing left to split
    assert r.thresholds == (110, 20) and r.threshold == 20 and r.stop == "region"


def test_min_pixels_guard():
    h = five_level_hist()
    r = iterative_threshold(hist=h, c_s=0.99, min_pixels=100)  # region 0..110 holds 85 px
    assert r.thresholds == (110,) and r.stop == "region"


def test_size_guard_stops_below_min_region():
    # uniform histogram: each Otsu step halves the dark region (50 %, 25 %, 12.5 %, 6.25 %, ...)
    h = np.full(256, 10.0)
    bare = iterative_threshold(hist=h, c_s=0.999, min_region=0.0, max_iter=6)
    assert bare.steps == 6 and bare.stop == "max_iter"
    shares = [(t + 1) / 256 for t in bare.thresholds]
    assert shares[:4] == pytest.approx([0.5, 0.25, 0.125, 0.0625], abs=0.01)
    # min_region 0.1: the region after step 4 (6.25 %) is not split again; T_f = T_4
    r = iterative_threshold(hist=h, c_s=0.999, min_region=0.1, max_iter=6)
    assert r.thresholds == bare.thresholds[:4] and r.threshold == bare.thresholds[3]
    assert r.stop == "size"
    # exactly at the limit the region is still split (strictly "less than")
    at = (bare.thresholds[2] + 1) / 256  # share of the region after step 3
    r_at = iterative_threshold(hist=h, c_s=0.999, min_region=at, max_iter=6)
    assert r_at.thresholds == bare.thresholds[:4]
    # the contrast rule, when it fires first, wins over the guard
    c2 = bare.contrasts[1]
    r2 = iterative_threshold(hist=h, c_s=c2 - 1e-9, min_region=0.1)
    assert r2.thresholds == bare.thresholds[:2] and r2.stop == "contrast"


def test_default_is_the_guarded_rule_and_bare_rule_differs():
    assert 0.0 < MIN_REGION_DEFAULT < 0.1 and 0.0 < C_S_UNGUARDED < C_S_DEFAULT < 1.0
    # a faint dark tail: contrast never exceeds the defaults, so the guard decides
    h = np.zeros(256)
    h[100:140] = 1000.0
    h[80:100] = np.linspace(5, 100, 20)
    r = iterative_threshold(hist=h)
    assert r.stop == "size"
    region = h[: r.threshold + 1].sum() / h.sum()
    prev = h[: r.thresholds[-2] + 1].sum() / h.sum()
    assert region < MIN_REGION_DEFAULT <= prev
    assert iterative_threshold(hist=h, min_region=0.0).threshold < r.threshold


def test_max_iter_caps_the_steps():
    h = np.full(256, 10.0)
    r = iterative_threshold(hist=h, c_s=0.999, max_iter=3)
    assert r.steps == 3 and r.stop == "max_iter"
    assert r.thresholds[0] > r.thresholds[1] > r.thresholds[2]


def test_single_level_image_marks_nothing():
    img = np.full((8, 8), 77, np.uint8)
    r = iterative_threshold(img)
    assert r.steps == 0 and r.threshold == 76 and r.stop == "region"
    assert not r.mask(img).any()
    black = np.zeros((4, 4), np.uint8)
    assert not iterative_threshold(black).mask(black).any()  # threshold −1: nothing


def test_two_level_image():
    img = np.array([[10, 10, 200, 200, 200]], np.uint8)
    r = iterative_threshold(img, c_s=0.2)
    assert r.threshold == 10 and r.contrasts == (pytest.approx(190 / 210),)
    assert r.mask(img).tolist() == [[255, 255, 0, 0, 0]]


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_bad_input():
    h = five_level_hist()
    for kw in ({"c_s": 1.0}, {"c_s": -0.1}, {"c_s": float("nan")}, {"background": "left"},
               {"max_iter": 0}, {"min_region": 1.0}, {"min_region": -0.01},
               {"min_region": float("nan")}):
        with pytest.raises(ValueError):
            iterative_threshold(hist=h, **kw)
    for bad in (np.zeros(256), np.array([1.0, np.nan]), np.array([-1.0, 2.0]), np.array([])):
        with pytest.raises(ValueError):
            iterative_threshold(hist=bad)
    with pytest.raises(ValueError):
        iterative_threshold()
    with pytest.raises(ValueError):
        iterative_threshold(np.zeros((0, 0), np.uint8))


def test_interclass_contrast():
    assert interclass_contrast(50, 150) == pytest.approx(0.5)
    assert interclass_contrast(150, 50) == pytest.approx(0.5)
    assert interclass_contrast(0, 0) == 0.0


def test_threshold_it_matches_result():
    h = five_level_hist()
    assert threshold_it(hist=h, c_s=0.5) == 20
    assert 0.0 < C_S_DEFAULT < 1.0


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 500), min_size=256, max_size=256).filter(lambda v: sum(v) > 0),
       st.floats(0.0, 0.95), st.sampled_from(["above", "previous"]),
       st.sampled_from([0.0, 0.02, 0.2]))
def test_properties_on_random_histograms(counts, c_s, background, min_region):
    h = np.array(counts, float)
    r = iterative_threshold(hist=h, c_s=c_s, background=background, max_iter=8,
                            min_region=min_region)
    occ = np.flatnonzero(h)
    assert len(r.thresholds) == len(r.contrasts) <= 8
    if occ.size >= 2:
        assert r.thresholds[0] == threshold_otsu(hist=h)  # step 1 is global Otsu
        assert all(a > b for a, b in zip(r.thresholds, r.thresholds[1:]))  # dark region shrinks
        assert all(0.0 <= c <= 1.0 for c in r.contrasts)
        assert occ[0] <= r.threshold < occ[-1]
        # the stop rule: only the last contrast may exceed C_s
        assert all(c <= c_s for c in r.contrasts[:-1])
        assert (r.contrasts[-1] > c_s) == (r.stop == "contrast")
        # the guard: every region that was split held at least min_region of the pixels
        cum = np.cumsum(h)
        assert all(cum[t] >= min_region * cum[-1] for t in r.thresholds[:-1])
        if r.stop == "size":
            assert cum[r.threshold] < min_region * cum[-1]
        if background == "above":  # a darker class against everything brighter: C grows
            assert all(b >= a - 1e-12 for a, b in zip(r.contrasts, r.contrasts[1:]))


def test_it_beats_otsu_on_synthetic_cracks():
    surface = pytest.importorskip("edge.world.surface", reason="edge/world/surface.py (crack generator) not present")
    f_it, f_otsu = [], []
    for seed in range(6):
        grey, gt = surface.crack_image((240, 320), np.random.default_rng(seed))
        f_it.append(f_measure(iterative_threshold(grey).mask(grey), gt)[0])
        f_otsu.append(f_measure(grey <= threshold_otsu(grey), gt)[0])
    assert np.mean(f_it) > np.mean(f_otsu) + 0.1
