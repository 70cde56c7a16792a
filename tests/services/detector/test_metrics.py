"""F-measure (P20) three ways, against hand-counted masks."""

from __future__ import annotations

import numpy as np
import pytest

from services.detector.metrics import confusion, f_measure, f_tolerant, score


def m(rows: list[str]) -> np.ndarray:
    return np.array([[255 if c == "#" else 0 for c in r] for r in rows], np.uint8)


GT = m(["......",
        ".####.",
        "......",
        "......"])
PRED = m(["......",
          "..###.",
          "..#...",
          "......"])


def test_confusion_and_exact_f_by_hand():
    assert confusion(PRED, GT) == (3, 1, 1, 19)
    f, p, r = f_measure(PRED, GT)
    assert p == pytest.approx(3 / 4) and r == pytest.approx(3 / 4) and f == pytest.approx(3 / 4)


def test_two_class_mean_f_by_hand():
    # background: tp = 19, fp = 1 (gt defect px 1,1 predicted background), fn = 1
    fb = 2 * 19 / (2 * 19 + 1 + 1)
    s = score(PRED, GT)
    assert s.f_mean2 == pytest.approx((3 / 4 + fb) / 2)
    assert s.f == pytest.approx(3 / 4)


def test_tolerance_two_pixels():
    gt = np.zeros((20, 20), np.uint8)
    gt[10, 3:15] = 255
    for shift, expect in ((0, 1.0), (1, 1.0), (2, 1.0), (3, 0.0)):
        pred = np.roll(gt, shift, axis=0)
        assert f_tolerant(pred, gt, 2)[0] == pytest.approx(expect)
        assert f_measure(pred, gt)[0] == pytest.approx(1.0 if shift == 0 else 0.0)
    # Euclidean: a pixel at (2, 1) from the nearest truth pixel is √5 > 2 away
    g1 = np.zeros((9, 9), np.uint8)
    g1[4, 4] = 255
    p1 = np.zeros_like(g1)
    p1[6, 5] = 255
    assert f_tolerant(p1, g1)[0] == 0.0
    p1[:] = 0
    p1[6, 4] = 255
    assert f_tolerant(p1, g1)[0] == 1.0


def test_tolerance_precision_and_recall_are_separate():
    # truth: a 10-px line; prediction: the line's first 5 px plus 5 px far away
    gt = np.zeros((20, 20), np.uint8)
    gt[5, 0:10] = 255
    pred = np.zeros_like(gt)
    pred[5, 0:5] = 255
    pred[15, 10:15] = 255
    f, p, r = f_tolerant(pred, gt, 2)
    # precision 5/10; recall: truth px within 2 of a prediction: columns 0..6 -> 7/10
    assert p == pytest.approx(0.5) and r == pytest.approx(0.7)
    assert f == pytest.approx(2 * 0.5 * 0.7 / 1.2)
    assert f_tolerant(pred, gt, 0)[:3] == pytest.approx(f_measure(pred, gt))


def test_empty_cases():
    z = np.zeros((4, 4), np.uint8)
    one = z.copy()
    one[1, 1] = 255
    assert f_measure(z, z) == (1.0, 1.0, 1.0)
    assert f_tolerant(z, z) == (1.0, 1.0, 1.0)
    assert f_measure(z, one) == (0.0, 0.0, 0.0)
    assert f_measure(one, z) == (0.0, 0.0, 0.0)
    assert f_tolerant(one, z) == (0.0, 0.0, 0.0)
    assert score(z, z).f_mean2 == 1.0


def test_bad_input():
    z = np.zeros((4, 4), np.uint8)
    with pytest.raises(ValueError):
        f_measure(z, np.zeros((4, 5), np.uint8))
    with pytest.raises(ValueError):
        f_measure(np.zeros((0, 3)), np.zeros((0, 3)))
    with pytest.raises(ValueError):
        f_measure(np.full((2, 2), np.nan), np.zeros((2, 2)))
    with pytest.raises(ValueError):
        f_tolerant(z, z, tol=-1)
