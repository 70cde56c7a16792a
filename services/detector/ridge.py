"""IT+r: IT+ united with the crack-like part of a Hessian ridge response ("a better detector
for textured surfaces").

Design notes: docs/detector.md (services/detector/ridge.py).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .improved import (
    GUARD_CONTRAST_DEFAULT,
    MIN_CONTRAST_DEFAULT,
    MIN_FRACTION_DEFAULT,
    MIN_LONG_ELONGATION_DEFAULT,
    component_filter,
    reduced_grey,
    reduction_factor,
    threshold_it_plus,
    upsample,
)
from .iterative import C_S_DEFAULT
from .thresholds import as_grey_u8, histogram

__all__ = ["ridge_response", "hysteresis_top", "it_plus_ridge_mask", "RIDGE_DEFAULTS"]

#: ridge parameters (working-grid pixels), chosen on the training splits (see the module text)
RIDGE_DEFAULTS: dict[str, float] = {
    "sigma": 2.5, "edge_weight": 0.5, "q_high": 0.01, "q_low": 0.035, "rel_contrast": 0.5,
    "fallback_contrast": 0.08, "box": 31,
}


def ridge_response(grey: np.ndarray, sigma: float = 2.0, edge_weight: float = 0.5) -> np.ndarray:
    """Dark-line measure ``σ² λ₁ − γ σ |∇I_σ|`` (float32, same shape), see the module text.

    Derivatives are 3x3 Sobel differences of the Gaussian-smoothed image, scaled to unit-step
    differences (``/4`` for the second, ``/8`` for the first derivatives).
    """
    if not (math.isfinite(sigma) and sigma > 0):
        raise ValueError(f"sigma must be finite and > 0, got {sigma!r}")
    if not (math.isfinite(edge_weight) and edge_weight >= 0):
        raise ValueError(f"edge_weight must be finite and >= 0, got {edge_weight!r}")
    b = cv2.GaussianBlur(np.asarray(grey, np.float32), (0, 0), sigma)
    dxx = cv2.Sobel(b, cv2.CV_32F, 2, 0, ksize=3)
    dyy = cv2.Sobel(b, cv2.CV_32F, 0, 2, ksize=3)
    dxy = cv2.Sobel(b, cv2.CV_32F, 1, 1, ksize=3)
    lam = (dxx + dyy + cv2.magnitude(dxx - dyy, 2.0 * dxy)) * np.float32(0.125 * sigma * sigma)
    if edge_weight == 0:
        return lam
    grad = cv2.magnitude(cv2.Sobel(b, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(b, cv2.CV_32F, 0, 1, ksize=3))
    return lam - np.float32(edge_weight * sigma / 8.0) * grad


def hysteresis_top(response: np.ndarray, q_high: float, q_low: float) -> np.ndarray:
    """Mask (uint8 0/255) of the 8-connected regions of the top ``q_low`` of ``response`` that hold a
    pixel of its top ``q_high`` (shares of the pixels, ``0 < q_high <= q_low < 1``)."""
    if not (0.0 < q_high <= q_low < 1.0):
        raise ValueError(f"need 0 < q_high <= q_low < 1, got {q_high}, {q_low}")
    r = np.asarray(response, np.float32).ravel()
    n = r.size
    k_lo, k_hi = n - max(1, int(round(q_low * n))), n - max(1, int(round(q_high * n)))
    part = np.partition(r, [k_lo, k_hi])
    t_lo, t_hi = float(part[k_lo]), float(part[k_hi])
    resp = np.asarray(response, np.float32)
    lo = (resp >= t_lo).astype(np.uint8)
    nl, lab = cv2.connectedComponents(lo, connectivity=8, ltype=cv2.CV_32S)
    seed = np.zeros(nl, bool)
    seed[lab[resp >= t_hi]] = True
    seed[0] = False
    return np.where(seed, 255, 0).astype(np.uint8)[lab]


def it_plus_ridge_mask(
    image: np.ndarray,
    *,
    sigma: float = RIDGE_DEFAULTS["sigma"],
    edge_weight: float = RIDGE_DEFAULTS["edge_weight"],
    q_high: float = RIDGE_DEFAULTS["q_high"],
    q_low: float = RIDGE_DEFAULTS["q_low"],
    rel_contrast: float = RIDGE_DEFAULTS["rel_contrast"],
    fallback_contrast: float = RIDGE_DEFAULTS["fallback_contrast"],
    box: int = int(RIDGE_DEFAULTS["box"]),
    work_px: int = 400_000,
    c_s: float = C_S_DEFAULT,
    min_fraction: float = MIN_FRACTION_DEFAULT,
    guard_contrast: float = GUARD_CONTRAST_DEFAULT,
    min_area: float = 30.0,
    min_elongation: float = 8.0,
    min_length: float = 40.0,
    min_contrast: float = MIN_CONTRAST_DEFAULT,
    min_long_elongation: float = MIN_LONG_ELONGATION_DEFAULT,
    ring: int = 5,
    **it_params: object,
) -> tuple[np.ndarray, int]:
    """IT+r defect mask of a grey image (see the module text); returns ``(mask, IT+'s threshold)``.

    Sizes (``sigma``, ``box``, the component limits) are in pixels of the working grid, the image
    reduced by :func:`services.detector.improved.reduction_factor` to at most ``work_px`` pixels.
    """
    if not (math.isfinite(rel_contrast) and rel_contrast >= 0):
        raise ValueError(f"rel_contrast must be finite and >= 0, got {rel_contrast!r}")
    if not (math.isfinite(fallback_contrast) and fallback_contrast >= 0):
        raise ValueError(f"fallback_contrast must be finite and >= 0, got {fallback_contrast!r}")
    if not (isinstance(box, (int, np.integer)) and box >= 3):
        raise ValueError(f"box must be an integer >= 3, got {box!r}")
    grey = as_grey_u8(image)
    H, W = grey.shape
    t = threshold_it_plus(hist=histogram(grey), c_s=c_s, min_fraction=min_fraction,
                          guard_contrast=guard_contrast, **it_params)
    s = reduction_factor(H * W, work_px)
    gmin, gpick = reduced_grey(grey, s)
    shape = dict(min_area=min_area, min_elongation=min_elongation, min_length=min_length,
                 min_long_elongation=min_long_elongation, ring=ring)
    # IT+ on the working grid: a block holds a defect pixel (<= t) exactly when its minimum does
    small = cv2.threshold(gmin, t, 255, cv2.THRESH_BINARY_INV)[1]
    lab_i, keep_i, c_i = component_filter(small, s, grey=grey, min_contrast=min_contrast,
                                          reduced=(gmin, gpick), **shape)
    # the ridge cue on the block minima (a crack thinner than a block keeps its depth there)
    back = cv2.blur(gpick, (box, box))
    cand = hysteresis_top(ridge_response(gmin, sigma, edge_weight), q_high, q_low)
    cand = cv2.bitwise_and(cand, cv2.compare(gmin, back, cv2.CMP_LT))
    lab_r, keep_r, c_r = component_filter(cand, s, grey=grey, reduced=(gmin, gpick), measure_contrast=True, **shape)
    ref = c_i[keep_i]
    floor = rel_contrast * float(np.median(ref)) if ref.size else fallback_contrast
    keep_r &= c_r >= floor
    # one threshold per block: pixels < thr are defects (uint8: IT+'s t + 1, half depth + 1, or 0)
    thr = np.zeros(gmin.shape, np.uint8)
    if t < 255:
        thr[keep_i[lab_i]] = t + 1
    on_r = keep_r[lab_r]
    if on_r.any():
        half = ((gmin[on_r].astype(np.uint16) + back[on_r] + 1) // 2 + 1).clip(0, 255).astype(np.uint8)
        thr[on_r] = np.maximum(thr[on_r], half)
    full = thr if s == 1 else upsample(thr, s, H, W)
    return cv2.compare(grey, full, cv2.CMP_LT), t
