"""IT+r: IT+ united with Hessian ridges under a contrast floor relative to IT+'s own cracks
(services.detector.ridge)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from edge.world.surface import textured_background
from services.detector.detect import METHODS, detect
from services.detector.evaluate import load_dataset
from services.detector.improved import it_plus_mask
from services.detector.metrics import f_measure
from services.detector.ridge import hysteresis_top, it_plus_ridge_mask, ridge_response

DATA = Path(__file__).resolve().parents[4] / "shared" / "data"


def _wall(seed: int = 0, shape=(320, 480)) -> np.ndarray:
    return textured_background(shape, np.random.default_rng(seed)).astype(np.float32)


def _faint_and_dark() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A dark crack IT+ finds, and a thin faint one only its darkness profile tells from the texture."""
    g = _wall()
    dark = np.zeros(g.shape, np.uint8)
    cv2.line(dark, (20, 60), (460, 90), 255, 4)
    faint = np.zeros(g.shape, np.uint8)
    cv2.polylines(faint, [np.array([[30, 250], [200, 215], [450, 240]], np.int32)], False, 255, 2)
    g[dark > 0] *= 0.45
    g[faint > 0] *= 0.8
    return np.clip(g, 0, 255).astype(np.uint8), dark, faint


def test_registered_and_its_it_plus_part_is_it_plus_exactly():
    assert "it+r" in METHODS
    g, _, _ = _faint_and_dark()
    only_it = dict(rel_contrast=1e9, fallback_contrast=1e9)  # no ridge can pass
    assert np.array_equal(it_plus_ridge_mask(g, **only_it)[0], it_plus_mask(g)[0])
    big = cv2.resize(g, (1600, 1200), interpolation=cv2.INTER_CUBIC)  # reduced working grid (s = 4)
    assert np.array_equal(it_plus_ridge_mask(big, work_px=150_000, **only_it)[0],
                          it_plus_mask(big, work_px=150_000)[0])


def test_faint_thin_crack_is_found_that_it_plus_misses():
    g, dark, faint = _faint_and_dark()
    ip = it_plus_mask(g)[0]
    ir, t = it_plus_ridge_mask(g)
    assert t == it_plus_mask(g)[1]
    on_faint = lambda m: np.count_nonzero((m > 0) & (faint > 0)) / np.count_nonzero(faint)  # noqa: E731
    assert on_faint(ip) < 0.4 < 0.8 < on_faint(ir)
    assert f_measure(ir, dark | faint)[0] > f_measure(ip, dark | faint)[0] + 0.1
    # the ridge keeps a thin crack thin: few marked pixels away from it
    assert np.count_nonzero((ir > 0) & (cv2.dilate(dark | faint, np.ones((7, 7), np.uint8)) == 0)) < 0.01 * g.size


def test_texture_alone_and_a_step_edge_give_no_ridge():
    g = np.clip(_wall(3), 0, 255).astype(np.uint8)
    g[:60] = 230  # bright sky above the wall's edge
    assert not it_plus_ridge_mask(g)[0][40:].any()  # nothing on the bare textured wall or along its edge
    step = np.full((100, 100), 80, np.float32)
    step[:, 50:] = 200
    r = ridge_response(cv2.GaussianBlur(step, (0, 0), 1.0), 2.0, 0.5)
    line = np.full((100, 100), 200, np.float32)
    line[:, 49:51] = 80
    assert r.max() < 0.5 * ridge_response(line, 2.0, 0.5).max()


def test_hysteresis_keeps_only_seeded_regions_and_rejects_bad_input():
    r = np.zeros((50, 50), np.float32)
    r[10, 5:45] = 1.0  # a weak line...
    r[10, 20] = 5.0  # ...with one strong pixel: kept whole
    r[30, 5:45] = 1.0  # a weak line without a strong pixel: dropped
    m = hysteresis_top(r, 1 / 2500, 80 / 2500)
    assert m[10, 5:45].all() and not m[30].any()
    for bad in ((0.0, 0.1), (0.2, 0.1), (0.1, 1.0)):
        with pytest.raises(ValueError):
            hysteresis_top(r, *bad)
    g, _, _ = _faint_and_dark()
    for kw in ({"sigma": 0.0}, {"edge_weight": float("nan")}, {"rel_contrast": -1.0}, {"box": 2},
               {"fallback_contrast": float("inf")}):
        with pytest.raises(ValueError):
            it_plus_ridge_mask(g, **kw)
    with pytest.raises(ValueError):
        detect(np.full((4, 4), np.nan), "it+r")


@pytest.mark.data
@pytest.mark.skipif(not (DATA / "crackforest").is_dir(), reason="CrackForest not in ../shared/data")
def test_better_than_it_plus_on_crackforest_sample():
    samples = load_dataset(DATA / "crackforest", limit=16)
    f = lambda fn: np.mean([f_measure(fn(s.grey)[0], s.mask)[0] for s in samples])  # noqa: E731
    assert f(it_plus_ridge_mask) > f(it_plus_mask) + 0.05
