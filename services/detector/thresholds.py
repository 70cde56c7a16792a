"""Grey-level thresholds for dark-defect detection: plain functions of an image or a histogram.

Design notes: docs/detector.md (services/detector/thresholds.py).
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = [
    "as_grey_u8",
    "histogram",
    "between_class_variance",
    "threshold_otsu",
    "threshold_valley_emphasis",
    "threshold_itth",
    "threshold_sdd",
    "threshold_sauvola",
]


# ----------------------------------------------------------------------------- input handling
def as_grey_u8(image: np.ndarray) -> np.ndarray:
    """Return ``image`` as a 2-D ``uint8`` grey image, or raise ``ValueError``.

    ``uint8`` 2-D input passes through unchanged (no copy). Three-channel input is taken as BGR
    (OpenCV's order) and converted with ``cv2.cvtColor``; a four-channel image as BGRA. Other
    numeric dtypes must be finite and within [0, 255]; they are rounded.
    """
    a = np.asarray(image)
    if a.dtype == np.uint8 and a.ndim == 2 and a.size:  # fast path: already grey uint8
        return a
    if a.dtype == np.bool_ or not (np.issubdtype(a.dtype, np.number)):
        raise ValueError(f"image must be numeric, got dtype {a.dtype}")
    if a.ndim == 3 and a.shape[2] in (3, 4):
        if a.dtype != np.uint8:
            a = _to_u8(a)
        code = cv2.COLOR_BGR2GRAY if a.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        a = cv2.cvtColor(np.ascontiguousarray(a), code)
    elif a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if a.ndim != 2:
        raise ValueError(f"image must be 2-D grey or (H, W, 3|4) colour, got shape {a.shape}")
    if a.size == 0:
        raise ValueError("image is empty")
    if a.dtype != np.uint8:
        a = _to_u8(a)
    return a


def _to_u8(a: np.ndarray) -> np.ndarray:
    if np.issubdtype(a.dtype, np.floating) and not np.all(np.isfinite(a)):
        raise ValueError("image contains NaN or infinite values")
    if a.size and (a.min() < 0 or a.max() > 255):
        raise ValueError(f"image values must lie in [0, 255], got [{a.min()}, {a.max()}]")
    return np.rint(a).astype(np.uint8)


def histogram(image: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """256-bin grey-level histogram (float64, ``hist[x]`` = pixels of level ``x``) of a grey or colour image
    (:func:`as_grey_u8`), counting only pixels where ``mask != 0`` if given, in one pass of ``cv2.calcHist``.

    >>> histogram(np.array([[0, 0, 255]], np.uint8))[[0, 255]]
    array([2., 1.])
    """
    grey = as_grey_u8(image)
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != grey.shape:
            raise ValueError(f"mask shape {mask.shape} != image shape {grey.shape}")
        mask = (mask != 0).astype(np.uint8)
    return cv2.calcHist([grey], [0], mask, [256], [0, 256]).ravel().astype(np.float64)


def _check_hist(hist: np.ndarray) -> np.ndarray:
    h = np.asarray(hist, dtype=np.float64)
    if h.ndim != 1 or h.size == 0:
        raise ValueError(f"hist must be a non-empty 1-D array, got shape {h.shape}")
    total = h.sum()  # NaN or inf anywhere makes the sum non-finite
    if not np.isfinite(total):
        raise ValueError("hist contains NaN or infinite values")
    if h.min() < 0:
        raise ValueError("hist has negative counts")
    if total <= 0:
        raise ValueError("hist is empty (all counts are zero)")
    return h


def _hist_of(image: np.ndarray | None, hist: np.ndarray | None) -> np.ndarray:
    if (image is None) == (hist is None):
        raise ValueError("give exactly one of image or hist")
    return _check_hist(histogram(image) if hist is None else hist)


def _single_level(h: np.ndarray) -> int | None:
    nz = np.flatnonzero(h)
    return int(nz[0]) if nz.size == 1 else None


# --------------------------------------------------------------------------------- Otsu (P18)
def between_class_variance(hist: np.ndarray) -> np.ndarray:
    """Otsu's between-class variance ``σ²(T)`` for every split ``T`` of a histogram (P18).

    ``σ²(T) = ω0(T) ω1(T) (ε0(T) − ε1(T))²`` with ω the class probabilities (class 0 = levels
    ``<= T``) and ε the class mean levels. Splits that leave a class empty get ``-1`` so that
    ``argmax`` never picks them. ``hist``: counts per level ``0..L-1``; returns ``(L,)`` float64.
    N. Otsu, "A threshold selection method from gray-level histograms", IEEE Trans. SMC 9(1), 62-66, 1979.
    """
    h = _check_hist(hist)
    levels = np.arange(h.size, dtype=np.float64)
    n = h.sum()
    w0 = np.cumsum(h)
    m0 = np.cumsum(h * levels)
    w1 = n - w0
    with np.errstate(divide="ignore", invalid="ignore"):
        mu0 = m0 / w0
        mu1 = (m0[-1] - m0) / w1
        var = (w0 / n) * (w1 / n) * (mu0 - mu1) ** 2
    var[~((w0 > 0) & (w1 > 0.5))] = -1.0  # w1 > 0.5: guard against rounding in n - w0
    return var


def threshold_otsu(image: np.ndarray | None = None, *, hist: np.ndarray | None = None) -> int:
    """Otsu's threshold (P18): the level ``T*`` maximising the between-class variance (Otsu 1979).

    Of a grey image (:func:`as_grey_u8`) or, keyword only, a precomputed ``hist``. Pixels ``<= T*`` form the
    dark class; for a histogram with a single occupied level that level is returned (every pixel is in the dark
    class, as OpenCV does). ValueError on empty, non-finite or negative input, or when both or neither input is
    given.

    >>> threshold_otsu(hist=np.array([5, 5, 0, 0, 5, 5]))
    1
    """
    h = _hist_of(image, hist)
    if (single := _single_level(h)) is not None:
        return single
    return int(np.argmax(between_class_variance(h)))


# ------------------------------------------------------------------ Valley emphasis (Ng 2006)
def threshold_valley_emphasis(
    image: np.ndarray | None = None, *, hist: np.ndarray | None = None
) -> int:
    """Ng's valley-emphasis threshold: the level maximising ``(1 − p_T) (ω0 μ0² + ω1 μ1²)`` (Otsu weighted
    towards low-probability levels; docs/detector.md). Of an image or a ``hist``; pixels ``<= T`` are the dark class.
    H.-F. Ng, "Automatic thresholding for defect detection", Pattern Recognition Letters 27(14), 1644-1649, 2006.

    >>> threshold_valley_emphasis(hist=np.array([4, 6, 1, 0, 30, 40, 30]))  # empty level: p_T = 0
    3
    """
    h = _hist_of(image, hist)
    if (single := _single_level(h)) is not None:
        return single
    levels = np.arange(h.size, dtype=np.float64)
    n = h.sum()
    p = h / n
    w0 = np.cumsum(p)
    m0 = np.cumsum(p * levels)
    w1 = 1.0 - w0
    with np.errstate(divide="ignore", invalid="ignore"):
        mu0 = m0 / w0
        mu1 = (m0[-1] - m0) / w1
        score = (1.0 - p) * (w0 * mu0**2 + w1 * mu1**2)
    cum = np.cumsum(h)
    score[~((cum > 0) & (n - cum > 0.5))] = -np.inf
    return int(np.argmax(score))


# --------------------------------------------------------------------- ITTH (Cai et al. 2014)
def threshold_itth(
    image: np.ndarray | None = None,
    *,
    hist: np.ndarray | None = None,
    tol: float = 1.0,
    max_iter: int = 50,
) -> int:
    """Iterative triclass thresholding (ITTH) of Cai, Yang, Cao et al.: Otsu (P18) on a shrinking
    "to-be-determined" band until the threshold moves by less than ``tol`` levels, the band holds fewer than two
    occupied levels, or ``max_iter`` steps (docs/detector.md). Of an image or a ``hist``; pixels ``<= T`` are the
    dark class.

    H. Cai, Z. Yang, X. Cao, W. Xia, X. Xu, "A new iterative triclass thresholding technique in image
    segmentation", IEEE Trans. Image Processing 23(3), 1038-1046, 2014.
    """
    h = _hist_of(image, hist)
    if max_iter < 1:
        raise ValueError("max_iter must be >= 1")
    if (single := _single_level(h)) is not None:
        return single
    levels = np.arange(h.size, dtype=np.float64)
    lo, hi = 0, h.size - 1
    t = threshold_otsu(hist=h)
    for _ in range(max_iter):
        band = h[lo : hi + 1]
        lv = levels[lo : hi + 1]
        k = t - lo
        w0, w1 = band[: k + 1].sum(), band[k + 1 :].sum()
        if w0 <= 0 or w1 <= 0:
            break
        mu0 = float(band[: k + 1] @ lv[: k + 1] / w0)
        mu1 = float(band[k + 1 :] @ lv[k + 1 :] / w1)
        new_lo, new_hi = int(np.ceil(mu0)), int(np.floor(mu1))
        sub = h[new_lo : new_hi + 1]
        if new_hi <= new_lo or np.count_nonzero(sub) < 2:
            break
        lo, hi = new_lo, new_hi
        t_new = lo + threshold_otsu(hist=sub)
        done = abs(t_new - t) < tol
        t = t_new
        if done:
            break
    return int(t)


# --------------------------------------------------------------------------------- SDD (Wang)
def _gaussian_smooth(h: np.ndarray, sigma: float) -> np.ndarray:
    if sigma <= 0:
        return h.copy()
    r = max(1, int(np.ceil(3 * sigma)))
    x = np.arange(-r, r + 1, dtype=np.float64)
    k = np.exp(-0.5 * (x / sigma) ** 2)
    k /= k.sum()
    return np.convolve(np.pad(h, r, mode="reflect" if h.size > r else "edge"), k, mode="valid")


def slope_difference(hist: np.ndarray, *, sigma: float = 3.0, n: int = 8) -> np.ndarray:
    """Wang's slope difference distribution of a histogram, ``(L,)`` float64: ``SDD(x) = slope_right(x) −
    slope_left(x)``, least-squares slopes of ``n`` values each side of ``x`` after a Gaussian of ``sigma`` levels
    (docs/detector.md); 0 where a window is not full.

    Z. Wang, "A new approach for segmentation and quantification of cells or nanoparticles", IEEE Trans.
    Industrial Informatics 12(3), 962-971, 2016 (slope difference distribution).
    """
    h = _check_hist(hist)
    if n < 2:
        raise ValueError("n must be >= 2")
    s = _gaussian_smooth(h / h.sum(), sigma)
    L = s.size
    sdd = np.zeros(L)
    if L < 2 * n + 1:
        return sdd
    x = np.arange(n, dtype=np.float64)
    w = (x - x.mean()) / np.sum((x - x.mean()) ** 2)  # least-squares slope weights
    # slope of window starting at i: sum_j w[j] * s[i + j]
    win = np.correlate(s, w, mode="valid")  # length L - n + 1
    idx = np.arange(n, L - n)
    sdd[idx] = win[idx + 1] - win[idx - n]
    return sdd


def threshold_sdd(
    image: np.ndarray | None = None,
    *,
    hist: np.ndarray | None = None,
    sigma: float = 3.0,
    n: int = 8,
) -> int:
    """Slope-difference-distribution threshold (Wang), on the dark side of the main mode: the deepest valley of
    :func:`slope_difference` below the mode, else its knee, else Otsu (P18) (docs/detector.md). Of an image or a
    ``hist``; ``sigma``, ``n`` as :func:`slope_difference`; pixels ``<= T`` are the dark class.

    Z. Wang, IEEE Trans. Industrial Informatics 12(3), 962-971, 2016; Z. Wang, "Automatic segmentation and
    classification of the reflected laser dots during analytic measurement of mirror surfaces", Optics and
    Lasers in Engineering 83, 10-22, 2016.
    """
    h = _hist_of(image, hist)
    if (single := _single_level(h)) is not None:
        return single
    sdd = slope_difference(h, sigma=sigma, n=n)
    mode = int(np.argmax(_gaussian_smooth(h, sigma)))
    lo = int(np.flatnonzero(h)[0])
    if mode <= lo or not np.any(sdd[lo:mode] > 0):
        return threshold_otsu(hist=h)
    seg = sdd[lo:mode]
    inner = np.zeros_like(seg, dtype=bool)
    if seg.size >= 3:
        inner[1:-1] = (seg[1:-1] >= seg[:-2]) & (seg[1:-1] >= seg[2:]) & (seg[1:-1] > 0)
    cand = np.flatnonzero(inner)
    if cand.size:
        return lo + int(cand[np.argmax(seg[cand])])
    return lo + int(np.argmax(seg))


# ---------------------------------------------------------------------------- Sauvola (local)
def threshold_sauvola(
    image: np.ndarray, window_size: int = 15, k: float = 0.2, r: float = 128.0
) -> np.ndarray:
    """Sauvola's local threshold image ``T = m (1 + k (s / R − 1))`` (float32, the image's shape; dark-class
    pixels are ``image <= T``), ``m`` and ``s`` the mean and standard deviation in a ``window_size`` square
    (odd, >= 3) around each pixel (docs/detector.md); ``k``, ``r`` > 0.

    J. Sauvola, M. Pietikäinen, "Adaptive document image binarization", Pattern Recognition 33(2), 225-236, 2000.
    """
    grey = as_grey_u8(image)
    if window_size < 3 or window_size % 2 == 0:
        raise ValueError(f"window_size must be odd and >= 3, got {window_size}")
    if not (k > 0 and r > 0 and np.isfinite(k) and np.isfinite(r)):
        raise ValueError("k and r must be positive and finite")
    f = grey.astype(np.float32)
    ksize = (window_size, window_size)
    mean = cv2.boxFilter(f, cv2.CV_32F, ksize, borderType=cv2.BORDER_REFLECT)
    sq = cv2.boxFilter(f * f, cv2.CV_32F, ksize, borderType=cv2.BORDER_REFLECT)
    std = np.sqrt(np.maximum(sq - mean * mean, 0.0))
    return mean * (1.0 + k * (std / r - 1.0))
