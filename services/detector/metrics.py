"""Pixel scores of a binary defect mask against ground truth: F-measure (P20) three ways.

Design notes: docs/detector.md (services/detector/metrics.py).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import cv2
import numpy as np

__all__ = ["Scores", "confusion", "f_measure", "f_tolerant", "score"]


def _as_bool(mask: np.ndarray, name: str) -> np.ndarray:
    m = np.asarray(mask)
    if m.ndim != 2 or m.size == 0:
        raise ValueError(f"{name} must be a non-empty 2-D mask, got shape {m.shape}")
    if np.issubdtype(m.dtype, np.floating) and not np.all(np.isfinite(m)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return m != 0


def _pair(pred: np.ndarray, gt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    p, g = _as_bool(pred, "pred"), _as_bool(gt, "gt")
    if p.shape != g.shape:
        raise ValueError(f"pred shape {p.shape} != gt shape {g.shape}")
    return p, g


def _ratio(num: float, den: float, both_empty: bool) -> float:
    if den > 0:
        return float(num / den)
    return 1.0 if both_empty else 0.0


def _f(p: float, r: float) -> float:
    return 2 * p * r / (p + r) if p + r > 0 else 0.0


def confusion(pred: np.ndarray, gt: np.ndarray) -> tuple[int, int, int, int]:
    """Counts ``(tp, fp, fn, tn)`` of the defect class (non-zero pixels), exact matching."""
    p, g = _pair(pred, gt)
    tp = int(np.count_nonzero(p & g))
    fp = int(np.count_nonzero(p)) - tp
    fn = int(np.count_nonzero(g)) - tp
    return tp, fp, fn, p.size - tp - fp - fn


def f_measure(pred: np.ndarray, gt: np.ndarray) -> tuple[float, float, float]:
    """Exact-pixel ``(F, precision, recall)`` of the defect class (P20)."""
    tp, fp, fn, _ = confusion(pred, gt)
    empty = tp + fp + fn == 0
    p = _ratio(tp, tp + fp, empty)
    r = _ratio(tp, tp + fn, empty)
    return (1.0 if empty else _f(p, r)), p, r


def _within(mask: np.ndarray, tol: float) -> np.ndarray:
    """Pixels whose Euclidean distance to the nearest ``mask`` pixel is ``<= tol``."""
    if not mask.any():
        return np.zeros_like(mask)
    inv = np.where(mask, 0, 255).astype(np.uint8)
    dist = cv2.distanceTransform(inv, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return dist <= tol + 1e-6


def f_tolerant(pred: np.ndarray, gt: np.ndarray, tol: float = 2.0) -> tuple[float, float, float]:
    """Defect-class ``(F, precision, recall)`` with a ``tol``-pixel matching tolerance.

    Precision = share of predicted pixels within ``tol`` (Euclidean) of a ground-truth pixel;
    recall = share of ground-truth pixels within ``tol`` of a predicted pixel; F by (P20).
    With ``tol = 0`` this equals :func:`f_measure`.
    """
    if not (np.isfinite(tol) and tol >= 0):
        raise ValueError(f"tol must be finite and >= 0, got {tol}")
    p, g = _pair(pred, gt)
    n_p, n_g = int(np.count_nonzero(p)), int(np.count_nonzero(g))
    empty = n_p == 0 and n_g == 0
    prec = _ratio(np.count_nonzero(p & _within(g, tol)), n_p, empty)
    rec = _ratio(np.count_nonzero(g & _within(p, tol)), n_g, empty)
    return (1.0 if empty else _f(prec, rec)), prec, rec


@dataclass(frozen=True)
class Scores:
    """All scores of one prediction; ``f`` / ``precision`` / ``recall`` are defect-class, exact."""

    f: float
    f_tol: float
    f_mean2: float
    precision: float
    recall: float
    precision_tol: float
    recall_tol: float

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def score(pred: np.ndarray, gt: np.ndarray, tol: float = 2.0) -> Scores:
    """Every score of :class:`Scores` for one predicted mask against its ground truth."""
    p, g = _pair(pred, gt)
    f, prec, rec = f_measure(p, g)
    fb, _, _ = f_measure(~p, ~g)
    ft, pt, rt = f_tolerant(p, g, tol)
    return Scores(
        f=f, f_tol=ft, f_mean2=(f + fb) / 2, precision=prec, recall=rec,
        precision_tol=pt, recall_tol=rt,
    )
