"""IT+: the paper's iterative thresholding with an area guard and crack-shape filtering.

Design notes: docs/detector.md (services/detector/improved.py).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .iterative import C_S_DEFAULT, interclass_contrast, iterative_threshold
from .thresholds import _hist_of, as_grey_u8, histogram

__all__ = [
    "threshold_it_plus", "shape_filter", "component_filter", "it_plus_mask", "it_plus_bh_mask", "component_contrast",
    "reduction_factor", "reduced_grey", "upsample", "MIN_FRACTION_DEFAULT",
]

#: Smallest share of the image the defect class may shrink to (chosen on DeepCrack train).
MIN_FRACTION_DEFAULT: float = 0.03
#: Per-component contrast floor (P19) of IT+ (chosen on DeepCrack train, ``bench/detect.py --only tune``).
MIN_CONTRAST_DEFAULT: float = 0.10
#: Elongation a component passing by its length alone must still have (DeepCrack train).
MIN_LONG_ELONGATION_DEFAULT: float = 5.0
#: The area guard applies only when its split has at least this contrast (DeepCrack train).
GUARD_CONTRAST_DEFAULT: float = 0.10


def threshold_it_plus(
    image: np.ndarray | None = None,
    *,
    hist: np.ndarray | None = None,
    c_s: float = C_S_DEFAULT,
    min_fraction: float = MIN_FRACTION_DEFAULT,
    guard_contrast: float = 0.0,
    **it_params: object,
) -> int:
    """IT threshold (P18)-(P19) with the area guard of this module; pixels ``<= T`` are defects.

    Of an image or a ``hist``; ``c_s`` and ``**it_params`` go to
    :func:`services.detector.iterative.iterative_threshold`. ``min_fraction`` in [0, 1): the dark class keeps
    at least this share of the pixels (unless that would need a threshold above the global Otsu step ``T_1``).
    The guard applies only when the interclass contrast (P19) of the guarded split (dark class ``<= T_guard``
    against the rest) reaches ``guard_contrast``: a frame that holds no crack has a dark class of texture with
    a low contrast, and the guard must not force a threshold on it; 0 (the default) always applies it.
    """
    h = _hist_of(image, hist)
    if not (np.isfinite(min_fraction) and 0.0 <= min_fraction < 1.0):
        raise ValueError(f"min_fraction must lie in [0, 1), got {min_fraction}")
    r = iterative_threshold(hist=h, c_s=c_s, **it_params)  # type: ignore[arg-type]
    if not r.thresholds or min_fraction == 0.0:
        return r.threshold
    cum = np.cumsum(h)
    t_frac = int(np.searchsorted(cum, min_fraction * cum[-1]))
    t_guard = min(t_frac, r.thresholds[0])
    if t_guard <= r.threshold:
        return r.threshold
    if guard_contrast > 0.0:
        levels = np.arange(256, dtype=np.float64)
        n_d, n_b = cum[t_guard], cum[-1] - cum[t_guard]
        if n_d <= 0 or n_b <= 0:
            return r.threshold
        mu_d = float(h[: t_guard + 1] @ levels[: t_guard + 1]) / n_d
        mu_b = float(h[t_guard + 1:] @ levels[t_guard + 1:]) / n_b
        if interclass_contrast(mu_d, mu_b) < guard_contrast:
            return r.threshold
    return t_guard


def shape_filter(
    mask: np.ndarray,
    *,
    min_area: float = 30.0,
    min_elongation: float = 8.0,
    min_length: float = 40.0,
    work_px: int = 400_000,
    grey: np.ndarray | None = None,
    min_contrast: float = 0.0,
    min_long_elongation: float = 0.0,
    ring: int = 5,
    robust: bool = True,
) -> np.ndarray:
    """Keep the crack-like connected components of a binary mask.

    A component (8-connectivity) is kept when ``area >= min_area`` and either
    ``(w² + h²) / area >= min_elongation`` or (``max(w, h) >= min_length`` and
    ``(w² + h²) / area >= min_long_elongation``) (bounding box w, h), and, when ``grey`` is
    given, its interclass contrast (P19) against its local background is at least
    ``min_contrast``: ``|μ_B − μ_D| / (μ_B + μ_D)`` with ``μ_D`` the component's mean grey and
    ``μ_B`` the mean of the non-defect pixels within ``ring`` pixels of it (the contrast
    :func:`services.detector.detect.defects_of` reports). Sizes are in pixels of the *working* image, the mask
    reduced to at most ``work_px`` pixels (docs/detector.md; exact up to ``work_px``). ``mask``: non-zero = defect;
    ``min_contrast`` in [0, 1) (ignored without ``grey``); ``ring`` in full-resolution pixels. Returns a 0/255
    uint8 mask of the same shape.

    Crack tokens are thin and elongated, small isolated blobs are texture: Y. Shi, L. Cui, Z. Qi, F. Meng,
    Z. Chen, "Automatic road crack detection using random structured forests", IEEE Trans. ITS 17(12),
    3434-3445, 2016.
    """
    m = np.asarray(mask)
    if m.ndim != 2 or m.size == 0:
        raise ValueError(f"mask must be a non-empty 2-D array, got shape {m.shape}")
    if not (math.isfinite(min_contrast) and 0.0 <= min_contrast < 1.0):
        raise ValueError(f"min_contrast must lie in [0, 1), got {min_contrast}")
    use_contrast = min_contrast > 0.0 and grey is not None
    if use_contrast and np.shape(grey) != m.shape:
        raise ValueError(f"grey shape {np.shape(grey)} != mask shape {m.shape}")
    m = np.where(m != 0, 255, 0).astype(np.uint8) if m.dtype != np.uint8 else m
    H, W = m.shape
    s = reduction_factor(H * W, work_px)
    if s == 1:
        small = m
    else:  # block "any": dilate with an s x s box anchored at its corner, take every s-th pixel
        box = cv2.getStructuringElement(cv2.MORPH_RECT, (s, s))
        small = np.ascontiguousarray(cv2.dilate(m, box, anchor=(0, 0))[::s, ::s])
    labels, keep, _ = component_filter(
        small, s, min_area=min_area, min_elongation=min_elongation, min_length=min_length,
        min_long_elongation=min_long_elongation, grey=grey if use_contrast else None, min_contrast=min_contrast,
        ring=ring, robust=robust,
    )
    lut = np.where(keep, 255, 0).astype(np.uint8)
    keep_small = lut[labels]
    if s == 1:
        return cv2.bitwise_and(m, keep_small)
    return cv2.bitwise_and(m, upsample(keep_small, s, H, W))


def upsample(small: np.ndarray, s: int, H: int, W: int) -> np.ndarray:
    """``small`` enlarged ``s`` times by pixel repetition (nearest neighbour) and cut to ``H x W``
    (two ``np.repeat``: several times faster than ``cv2.resize`` at 12 MP)."""
    return np.ascontiguousarray(np.repeat(np.repeat(small, s, axis=1), s, axis=0)[:H, :W])


def component_filter(
    small: np.ndarray,
    s: int,
    *,
    min_area: float,
    min_elongation: float,
    min_length: float,
    min_long_elongation: float = 0.0,
    grey: np.ndarray | None = None,
    min_contrast: float = 0.0,
    ring: int = 5,
    robust: bool = True,
    reduced: tuple[np.ndarray, np.ndarray] | None = None,
    measure_contrast: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The component rules of :func:`shape_filter` on a mask already on the working grid (its arguments:
    docs/detector.md, services/detector/improved.py)."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(small, connectivity=8, ltype=cv2.CV_32S)
    area = stats[:, cv2.CC_STAT_AREA].astype(np.float64)
    w = stats[:, cv2.CC_STAT_WIDTH].astype(np.float64)
    h = stats[:, cv2.CC_STAT_HEIGHT].astype(np.float64)
    elong = (w * w + h * h) / np.maximum(area, 1.0)
    keep = (area >= min_area) & (
        (elong >= min_elongation) | ((np.maximum(w, h) >= min_length) & (elong >= min_long_elongation))
    )
    keep[0] = False
    contrast = np.zeros(n)
    if grey is not None and (min_contrast > 0.0 or measure_contrast) and n > 1 and keep.any():
        # contrast of the shape-kept components only (relabelled 1..k); every other pixel of the
        # mask stays out of their rings, as when all components are measured
        sel = np.flatnonzero(keep)
        dt = np.uint16 if len(sel) < 65535 else np.int32  # uint16 dilates faster than float32
        relabel = np.zeros(n, dt)
        relabel[sel] = np.arange(1, len(sel) + 1, dtype=dt)
        c = component_contrast(as_grey_u8(grey), relabel[labels], len(sel) + 1, s, ring, robust=robust,
                               free=labels == 0, reduced=reduced)
        contrast[sel] = c[1:]
        keep[sel] = c[1:] >= min_contrast
    return labels, keep, contrast


def component_contrast(grey: np.ndarray, labels: np.ndarray, n: int, s: int = 1, ring: int = 5,
                       robust: bool = False, free: np.ndarray | None = None,
                       reduced: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Contrast (P19) of every labelled component against the background ring around it, ``n`` values (index 0
    unused; its arguments: docs/detector.md, services/detector/improved.py)."""
    hs, ws = labels.shape
    if grey.shape == labels.shape:
        g_d = g_b = grey
    elif reduced is not None:
        g_d, g_b = (_fit(a, hs, ws) for a in reduced)
    else:
        # reduced grid (block "any" labels): a labelled block holds a defect pixel somewhere, so its
        # darkest pixel (an s x s erosion anchored at the corner, like the mask's dilation) stands for
        # the defect; an unlabelled block is all background, so any of its pixels stands for it
        box = cv2.getStructuringElement(cv2.MORPH_RECT, (s, s))
        g_d = _fit(cv2.erode(grey, box, anchor=(0, 0))[::s, ::s], hs, ws)
        g_b = _fit(grey[::s, ::s], hs, ws)
    r = max(1, round(ring / s))
    lab = labels.ravel()
    cnt_d = np.bincount(lab, minlength=n).astype(np.float64)
    sum_d = np.bincount(lab, weights=g_d.ravel().astype(np.float64), minlength=n)
    gb = g_b.ravel()
    k = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * r + 1, 2 * r + 1))
    lab_img = labels if labels.dtype == np.uint16 else labels.astype(np.float32)
    dil = cv2.dilate(lab_img, k).ravel()
    if dil.dtype != np.uint16:
        dil = dil.astype(np.int64)
    near = (dil > 0) & ((lab == 0) if free is None else np.asarray(free).ravel())
    cnt_b = np.bincount(dil[near], minlength=n).astype(np.float64)
    mu_d = sum_d / np.maximum(cnt_d, 1.0)
    if robust:  # the median of each ring, from a 256-level histogram per component
        rl = dil[near]
        hist = np.bincount(rl.astype(np.int64) * 256 + gb[near], minlength=n * 256).reshape(n, 256)
        cum = np.cumsum(hist, axis=1)
        half = cum[:, -1:] / 2.0
        lo = np.argmax(cum >= half, axis=1)  # first level holding half of the ring
        hi = np.argmax(cum > half, axis=1)  # ... and the level just past it (even counts)
        mu_b = np.where(cnt_b > 0, 0.5 * (lo + hi), 0.0)
    else:
        mu_b = np.bincount(dil[near], weights=gb[near].astype(np.float64), minlength=n) / np.maximum(cnt_b, 1.0)
    den = mu_b + mu_d
    return np.where((cnt_b > 0) & (den > 0), np.abs(mu_b - mu_d) / np.where(den > 0, den, 1.0), 0.0)


def reduced_grey(grey: np.ndarray, s: int) -> tuple[np.ndarray, np.ndarray]:
    """The grey image on the working grid of factor ``s``: (block minimum, block corner pixel)."""
    if s == 1:
        return grey, grey
    box = cv2.getStructuringElement(cv2.MORPH_RECT, (s, s))
    return np.ascontiguousarray(cv2.erode(grey, box, anchor=(0, 0))[::s, ::s]), np.ascontiguousarray(grey[::s, ::s])


def _fit(a: np.ndarray, hs: int, ws: int) -> np.ndarray:
    """``a`` cut or edge-padded to ``hs x ws``."""
    a = a[:hs, :ws]
    if a.shape != (hs, ws):
        a = cv2.copyMakeBorder(np.ascontiguousarray(a), 0, hs - a.shape[0], 0, ws - a.shape[1], cv2.BORDER_REPLICATE)
    return a


def reduction_factor(n_pixels: int, work_px: int) -> int:
    """Smallest integer ``s >= 1`` with ``n_pixels / s² <= work_px``."""
    if work_px < 1:
        raise ValueError("work_px must be >= 1")
    s = max(1, math.ceil(math.sqrt(n_pixels / work_px)))
    while s > 1 and n_pixels / (s - 1) ** 2 <= work_px:  # guard against float rounding
        s -= 1
    return s


def it_plus_mask(
    image: np.ndarray,
    *,
    c_s: float = C_S_DEFAULT,
    min_fraction: float = MIN_FRACTION_DEFAULT,
    min_area: float = 30.0,
    min_elongation: float = 8.0,
    min_length: float = 40.0,
    work_px: int = 400_000,
    min_contrast: float = MIN_CONTRAST_DEFAULT,
    min_long_elongation: float = MIN_LONG_ELONGATION_DEFAULT,
    guard_contrast: float = GUARD_CONTRAST_DEFAULT,
    **it_params: object,
) -> tuple[np.ndarray, int]:
    """IT+ defect mask (0/255) of a grey image and the global threshold before shape filtering: guarded IT
    threshold, then :func:`shape_filter`."""
    grey = as_grey_u8(image)
    t = threshold_it_plus(hist=histogram(grey), c_s=c_s, min_fraction=min_fraction,
                          guard_contrast=guard_contrast, **it_params)
    raw = cv2.threshold(grey, t, 255, cv2.THRESH_BINARY_INV)[1]
    mask = shape_filter(
        raw, min_area=min_area, min_elongation=min_elongation, min_length=min_length,
        work_px=work_px, grey=grey, min_contrast=min_contrast, min_long_elongation=min_long_elongation,
    )
    return mask, t


#: black-hat structuring element (pixels) and share of the image its response keeps (DeepCrack train)
BLACKHAT_SIZE_DEFAULT = 15
BLACKHAT_FRACTION_DEFAULT = 0.03


def it_plus_bh_mask(
    image: np.ndarray,
    *,
    size: int = BLACKHAT_SIZE_DEFAULT,
    top_fraction: float = BLACKHAT_FRACTION_DEFAULT,
    work_px: int = 400_000,
    **it_plus: object,
) -> tuple[np.ndarray, int]:
    """IT+ with a local cue: the union of the IT+ mask and the crack-like part of a black-hat response (the
    ``top_fraction`` of the pixels with the strongest ``size × size`` black-hat, through IT+'s component filter;
    docs/detector.md, services/detector/improved.py). Returns ``(mask, threshold)`` with IT+'s global threshold.
    """
    if not (isinstance(size, (int, np.integer)) and size >= 3):
        raise ValueError(f"size must be an integer >= 3, got {size!r}")
    if not (math.isfinite(top_fraction) and 0.0 < top_fraction < 1.0):
        raise ValueError(f"top_fraction must lie in (0, 1), got {top_fraction}")
    grey = as_grey_u8(image)
    mask, t = it_plus_mask(grey, work_px=work_px, **it_plus)  # type: ignore[arg-type]
    H, W = grey.shape
    s = reduction_factor(H * W, work_px)
    g = grey if s == 1 else cv2.resize(grey[: (H // s) * s, : (W // s) * s], (W // s, H // s),
                                       interpolation=cv2.INTER_AREA)
    k = max(3, int(round(size / s)) | 1)
    inv = 255 - cv2.morphologyEx(g, cv2.MORPH_BLACKHAT, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
    cum = np.cumsum(histogram(inv))
    tb = int(np.searchsorted(cum, top_fraction * cum[-1]))
    raw = cv2.threshold(inv, tb, 255, cv2.THRESH_BINARY_INV)[1]
    keys = ("min_area", "min_elongation", "min_length", "min_contrast", "min_long_elongation")
    kw = {k2: it_plus[k2] for k2 in keys if k2 in it_plus}
    kw.setdefault("min_contrast", MIN_CONTRAST_DEFAULT)
    kw.setdefault("min_long_elongation", MIN_LONG_ELONGATION_DEFAULT)
    local = shape_filter(raw, grey=g, work_px=work_px, **kw)  # type: ignore[arg-type]
    if s > 1:
        big = cv2.resize(local, ((W // s) * s, (H // s) * s), interpolation=cv2.INTER_NEAREST)
        local = np.zeros_like(mask)
        local[: big.shape[0], : big.shape[1]] = big
    return cv2.bitwise_or(mask, local), t
