"""Thresholds against hand-made histograms, small synthetic images, OpenCV and scikit-image."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from skimage.filters import threshold_otsu as sk_otsu
from skimage.filters import threshold_sauvola as sk_sauvola

from services.detector.thresholds import (
    as_grey_u8,
    between_class_variance,
    histogram,
    slope_difference,
    threshold_itth,
    threshold_otsu,
    threshold_sauvola,
    threshold_sdd,
    threshold_valley_emphasis,
)

GLOBAL = [threshold_otsu, threshold_valley_emphasis, threshold_itth, threshold_sdd]


def bimodal(rng: np.random.Generator, n_dark: int, n_bright: int, mu=(60, 180), sd=(10, 12)) -> np.ndarray:
    v = np.concatenate([rng.normal(mu[0], sd[0], n_dark), rng.normal(mu[1], sd[1], n_bright)])
    return np.clip(np.rint(v), 0, 255).astype(np.uint8).reshape(1, -1)


def hist_of(values: np.ndarray) -> np.ndarray:
    return np.bincount(values.ravel(), minlength=256).astype(float)


# ------------------------------------------------------------------------------- histogram
def test_histogram_counts_levels_and_respects_mask():
    img = np.array([[0, 0, 7], [255, 7, 7]], np.uint8)
    h = histogram(img)
    assert h.shape == (256,) and h[0] == 2 and h[7] == 3 and h[255] == 1 and h.sum() == 6
    hm = histogram(img, mask=np.array([[1, 0, 0], [1, 1, 0]], np.uint8))
    assert hm[0] == 1 and hm[7] == 1 and hm[255] == 1 and hm.sum() == 3


def test_as_grey_u8_converts_and_rejects():
    bgr = np.zeros((2, 3, 3), np.uint8)
    bgr[..., 2] = 255  # pure red in BGR
    assert as_grey_u8(bgr).shape == (2, 3) and as_grey_u8(bgr)[0, 0] == 76  # 0.299 * 255
    assert as_grey_u8(np.array([[1.4, 254.6]])).tolist() == [[1, 255]]
    for bad in (np.array([[np.nan, 1.0]]), np.array([[-1.0, 3.0]]), np.array([[300]]),
                np.zeros((0, 3), np.uint8), np.zeros((2, 2, 2), np.uint8), np.ones((2, 2), bool)):
        with pytest.raises(ValueError):
            as_grey_u8(bad)


@pytest.mark.parametrize("fn", GLOBAL)
@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_global_thresholds_reject_bad_input(fn):
    for bad in ([], [0, 0, 0], [1, np.nan, 2], [1, -2, 3], [1, np.inf, 2], np.ones((2, 2))):
        with pytest.raises(ValueError):
            fn(hist=np.array(bad, dtype=float))
    with pytest.raises(ValueError):
        fn()  # neither image nor hist
    with pytest.raises(ValueError):
        fn(np.zeros((2, 2), np.uint8), hist=np.ones(256))  # both
    with pytest.raises(ValueError):
        fn(np.array([[np.nan, 1.0]]))


@pytest.mark.parametrize("fn", GLOBAL)
def test_single_level_returns_that_level(fn):
    h = np.zeros(256)
    h[93] = 1000
    assert fn(hist=h) == 93
    assert fn(np.full((5, 5), 93, np.uint8)) == 93


@pytest.mark.parametrize("fn", GLOBAL)
def test_two_levels_split_between_them(fn):
    h = np.zeros(256)
    h[40], h[200] = 100, 900
    assert 40 <= fn(hist=h) < 200


@pytest.mark.parametrize("fn", GLOBAL)
def test_image_and_histogram_inputs_agree(fn):
    img = bimodal(np.random.default_rng(1), 300, 3000)
    assert fn(img) == fn(hist=histogram(img))


# ------------------------------------------------------------------------------------ Otsu
def test_otsu_hand_made_histogram():
    # levels 0,1 | 4,5 equally weighted: every split 1..3 has the same variance; first wins
    assert threshold_otsu(hist=np.array([5, 5, 0, 0, 5, 5])) == 1
    var = between_class_variance(np.array([5, 5, 0, 0, 5, 5]))
    # ω0 = ω1 = 1/2, ε0 = 0.5, ε1 = 4.5: σ² = 1/4 * 16 = 4
    assert var[1] == pytest.approx(4.0) and var[5] == -1.0
    assert threshold_otsu(hist=np.array([0, 10, 0, 0, 0, 0, 0, 10, 10])) == 1


def test_otsu_bimodal_lands_between_modes():
    img = bimodal(np.random.default_rng(0), 4000, 6000)
    t = threshold_otsu(img)
    # σ² is nearly flat across the empty gap between the modes; any split there is right
    assert 60 < t < 180
    errors = np.count_nonzero(img[0, :4000] > t) + np.count_nonzero(img[0, 4000:] <= t)
    assert errors < 0.01 * img.size


@pytest.mark.parametrize("seed", range(8))
def test_otsu_matches_opencv_and_skimage(seed):
    rng = np.random.default_rng(seed)
    img = bimodal(rng, int(rng.integers(200, 4000)), 5000, mu=(rng.integers(30, 110), rng.integers(130, 230)),
                  sd=(rng.uniform(5, 25), rng.uniform(5, 25)))
    t = threshold_otsu(img)
    t_cv, _ = cv2.threshold(img, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    var = between_class_variance(histogram(img))
    # equal up to ties of σ² (plateaus between occupied levels)
    assert t == int(t_cv) or var[t] == pytest.approx(var[int(t_cv)], rel=1e-9)
    t_sk = int(sk_otsu(img))
    assert t == t_sk or var[t] == pytest.approx(var[t_sk], rel=1e-9)


# -------------------------------------------------------------------------- valley emphasis
def test_valley_emphasis_prefers_the_valley_for_a_small_dark_class():
    # 3 % dark pixels around 40, background around 170: Otsu cuts into the background's tail,
    # valley-emphasis stays in the empty valley between the modes
    img = bimodal(np.random.default_rng(3), 300, 9700, mu=(40, 170), sd=(6, 25))
    h = histogram(img)
    t_ve, t_otsu = threshold_valley_emphasis(hist=h), threshold_otsu(hist=h)
    assert 55 <= t_ve <= 110
    assert h[t_ve] <= 2  # in the valley
    assert t_ve <= t_otsu


def test_valley_emphasis_hand_made():
    # dark class 0..2, valley at 3, background 4..6; the weight (1 - p_T) favours the empty
    # level 3, but splits at 2 and 3 separate the same pixels, so the first maximum is 2 or 3
    t = threshold_valley_emphasis(hist=np.array([4, 6, 1, 0, 30, 40, 30]))
    assert t in (2, 3)


# --------------------------------------------------------------------------------------- ITTH
def _itth_reference(h: np.ndarray, tol: float = 1.0, max_iter: int = 50) -> int:
    """Loop-by-loop ITTH, written independently of the module."""
    lv = np.arange(h.size)

    def otsu(lo, hi):
        best, bt = -1.0, lo
        for t in range(lo, hi):
            w0, w1 = h[lo : t + 1].sum(), h[t + 1 : hi + 1].sum()
            if w0 == 0 or w1 == 0:
                continue
            m0 = (h[lo : t + 1] * lv[lo : t + 1]).sum() / w0
            m1 = (h[t + 1 : hi + 1] * lv[t + 1 : hi + 1]).sum() / w1
            v = w0 * w1 * (m0 - m1) ** 2
            if v > best * (1 + 1e-12):
                best, bt = v, t
        return bt

    lo, hi = 0, h.size - 1
    t = otsu(lo, hi)
    for _ in range(max_iter):
        w0, w1 = h[lo : t + 1].sum(), h[t + 1 : hi + 1].sum()
        m0 = (h[lo : t + 1] * lv[lo : t + 1]).sum() / w0
        m1 = (h[t + 1 : hi + 1] * lv[t + 1 : hi + 1]).sum() / w1
        nlo, nhi = int(np.ceil(m0)), int(np.floor(m1))
        if nhi <= nlo or np.count_nonzero(h[nlo : nhi + 1]) < 2:
            break
        lo, hi = nlo, nhi
        tn = otsu(lo, hi)
        done = abs(tn - t) < tol
        t = tn
        if done:
            break
    return t


@pytest.mark.parametrize("seed", range(5))
def test_itth_matches_reference_loop(seed):
    rng = np.random.default_rng(seed)
    img = bimodal(rng, 800, 4000, mu=(70, 150), sd=(20, 20))
    h = histogram(img)
    assert threshold_itth(hist=h) == _itth_reference(h)


def test_itth_moves_towards_the_weak_dark_class():
    # a weak (few, spread) dark class next to a big background: the TBD band keeps shrinking
    # around the valley and ITTH ends below Otsu's first split
    img = bimodal(np.random.default_rng(7), 600, 9400, mu=(80, 150), sd=(20, 10))
    h = histogram(img)
    t1 = threshold_otsu(hist=h)
    t = threshold_itth(hist=h)
    assert t != t1
    assert 80 <= t <= 150


# ---------------------------------------------------------------------------------------- SDD
def test_slope_difference_is_positive_at_a_valley_and_negative_at_a_peak():
    x = np.arange(256)
    h = 1000 * np.exp(-0.5 * ((x - 60) / 10) ** 2) + 1000 * np.exp(-0.5 * ((x - 180) / 10) ** 2)
    sdd = slope_difference(h)
    assert sdd[120] > 0 and sdd[60] < 0 and sdd[180] < 0
    assert sdd[:8].tolist() == [0.0] * 8  # no full window: 0


def test_sdd_bimodal_threshold_between_valley_and_main_mode():
    # SDD peaks where the histogram bends upwards; the deepest such point below the main mode
    # is the foot of that mode, on the valley's bright side, holding few pixels
    x = np.arange(256)
    h = 300 * np.exp(-0.5 * ((x - 100) / 15) ** 2) + 1000 * np.exp(-0.5 * ((x - 175) / 15) ** 2)
    valley = 100 + int(np.argmin(h[100:175]))
    t = threshold_sdd(hist=h)
    assert valley <= t < 175
    assert h[t] < 0.5 * h.max()
    # well separated modes: the split lies in the empty gap
    h2 = 200 * np.exp(-0.5 * ((x - 60) / 10) ** 2) + 1000 * np.exp(-0.5 * ((x - 180) / 12) ** 2)
    t2 = threshold_sdd(hist=h2)
    assert 90 <= t2 < 180 and h2[91 : t2 + 1].sum() < 0.05 * h2[120:].sum()


def test_sdd_unimodal_with_dark_tail_is_below_the_mode_at_the_knee():
    x = np.arange(256).astype(float)
    h = 1000 * np.exp(-0.5 * ((x - 170) / 10) ** 2) + np.where(x < 170, 4.0, 0.0)
    t = threshold_sdd(hist=h)
    assert 130 <= t < 165  # where the tail bends into the mode, not inside the tail


def test_sdd_falls_back_to_otsu_when_the_mode_is_darkest():
    h = np.zeros(256)
    h[:40] = np.linspace(100, 1, 40)
    h[200] = 5
    assert threshold_sdd(hist=h) == threshold_otsu(hist=h)


# ------------------------------------------------------------------------------------ Sauvola
def test_sauvola_matches_skimage_away_from_the_border():
    img = bimodal(np.random.default_rng(2), 1000, 2600).reshape(60, 60)
    ours = threshold_sauvola(img, window_size=15, k=0.2, r=127.5)
    ref = sk_sauvola(img, window_size=15, k=0.2)
    assert ours.shape == img.shape
    np.testing.assert_allclose(ours[8:-8, 8:-8], ref[8:-8, 8:-8], rtol=1e-4, atol=1e-3)


def test_sauvola_flat_image_and_dark_spot():
    img = np.full((31, 31), 200, np.uint8)
    t = threshold_sauvola(img)
    np.testing.assert_allclose(t, 200 * (1 - 0.2), rtol=1e-6)  # s = 0: T = m (1 - k)
    img[15, 15] = 20
    assert threshold_sauvola(img)[15, 15] > 20


def test_sauvola_rejects_bad_parameters():
    img = np.zeros((9, 9), np.uint8)
    for kw in ({"window_size": 4}, {"window_size": 1}, {"k": 0}, {"r": -1}, {"k": float("nan")}):
        with pytest.raises(ValueError):
            threshold_sauvola(img, **kw)
