"""The paper's iterative thresholding (IT), (P18)-(P19), on a 256-bin histogram.

Design notes: docs/detector.md (services/detector/iterative.py).
"""

from __future__ import annotations

from bisect import bisect_right
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from .thresholds import _hist_of

__all__ = [
    "ITResult", "iterative_threshold", "threshold_it", "interclass_contrast", "C_S_DEFAULT",
    "MIN_REGION_DEFAULT", "C_S_UNGUARDED",
]

#: Default contrast threshold C_s, chosen together with :data:`MIN_REGION_DEFAULT` on the
#: DeepCrack training split (``bench/detect.py --only tune``, one-SE rule, see the module text).
C_S_DEFAULT: float = 0.425
#: Default size guard: a dark region with less than this share of the image is not split again.
MIN_REGION_DEFAULT: float = 0.025
#: C_s for the paper's bare stop rule (``min_region=0``), chosen on the DeepCrack training split:
#: mean defect-class F peaks at C_s = 0.35 (0.592) on a flat ridge; the smallest C_s within one
#: paired standard error of the peak (the "one-SE rule") is 0.30 (0.590).
C_S_UNGUARDED: float = 0.30

Background = Literal["above", "previous"]


@dataclass(frozen=True)
class ITResult:
    """Outcome of :func:`iterative_threshold`. ``stop`` says why the iteration ended: ``"contrast"``
    (``C_k > C_s``), ``"size"`` (the dark region holds less than ``min_region`` of the image), ``"region"`` (the
    dark region could not be split further: fewer than two levels or ``min_pixels``), ``"max_iter"``."""

    threshold: int  # final threshold T_f; pixels <= T_f are defects
    thresholds: tuple[int, ...]  # T_1, T_2, ... one per step (T_1 is the global Otsu threshold)
    contrasts: tuple[float, ...]  # C_1, C_2, ... (P19), one per step
    stop: str

    @property
    def steps(self) -> int:
        """Number of Otsu steps taken."""
        return len(self.thresholds)

    def mask(self, grey: np.ndarray) -> np.ndarray:
        """Binary defect mask (uint8 0/255): 255 where ``grey <= threshold``."""
        return cv2.threshold(grey, self.threshold, 255, cv2.THRESH_BINARY_INV)[1]


def interclass_contrast(mu_dark: float, mu_back: float) -> float:
    """Interclass contrast (P19): ``C = |μ_D − μ_B| / (μ_D + μ_B)``; 0 when both means are 0."""
    s = mu_dark + mu_back
    return float(abs(mu_dark - mu_back) / s) if s > 0 else 0.0


def iterative_threshold(
    image: np.ndarray | None = None,
    *,
    hist: np.ndarray | None = None,
    c_s: float = C_S_DEFAULT,
    background: Background = "above",
    min_region: float = MIN_REGION_DEFAULT,
    max_iter: int = 8,
    min_pixels: float = 1.0,
) -> ITResult:
    """The paper's iterative thresholding (IT), equations (P18)-(P19), of a grey image or a ``hist``.

    Stop at the first step with ``C_k > C_s`` (``c_s`` in [0, 1)). ``background`` ("above" or "previous"):
    which pixels form the background mean in (P19). ``min_region`` in [0, 1): a dark region with less than
    this share of all pixels is not split again (0 = the paper's bare stop rule; both in docs/detector.md);
    nor is one of fewer than ``min_pixels`` pixels; at most ``max_iter`` (>= 1) Otsu steps. For a histogram
    with a single occupied level ``v`` no step is taken and the threshold is ``v − 1``: nothing is darker than
    the rest, so nothing is a defect. ValueError on bad input or parameters.

    >>> h = np.zeros(256); h[[20, 100, 110, 200, 210]] = [5, 40, 40, 400, 400]
    >>> r = iterative_threshold(hist=h, c_s=0.5)
    >>> r.thresholds, r.threshold, r.stop
    ((110, 20), 20, 'contrast')
    >>> iterative_threshold(hist=h, c_s=0.5, min_region=0.1).stop  # 85 of 885 px < 10 %
    'size'
    """
    h = _hist_of(image, hist)
    if not 0.0 <= c_s < 1.0:  # also rejects NaN
        raise ValueError(f"c_s must lie in [0, 1), got {c_s}")
    if background not in ("above", "previous"):
        raise ValueError(f"background must be 'above' or 'previous', got {background!r}")
    if not 0.0 <= min_region < 1.0:  # also rejects NaN
        raise ValueError(f"min_region must lie in [0, 1), got {min_region}")
    if max_iter < 1:
        raise ValueError("max_iter must be >= 1")

    idx = np.arange(h.size)
    cnt = np.cumsum(h)
    mom = np.cumsum(h * idx)
    total_n, total_m = float(cnt[-1]), float(mom[-1])
    min_size = min_region * total_n
    occupied = np.flatnonzero(h).tolist()  # sorted occupied levels
    first = occupied[0]  # darkest occupied level

    top = h.size - 1  # R^D_0 = every level
    thresholds: list[int] = []
    contrasts: list[float] = []
    stop = "max_iter"
    for _ in range(max_iter):
        n, m = float(cnt[top]), float(mom[top])
        n_occ = bisect_right(occupied, top)  # occupied levels in 0..top
        if n_occ < 2 or n < min_pixels:
            stop = "region"
            break
        if n < min_size:
            stop = "size"
            break
        # (P18) on the prefix 0..top, whose cumulative sums are those of the whole histogram.
        # Candidates T in [first, last): both classes non-empty. σ² ∝ (m·ω0 − n·m0)² / (ω0 ω1),
        # the same argmax as ω0 ω1 (ε0 − ε1)².
        last = occupied[n_occ - 1]  # brightest occupied level of the region
        w0 = cnt[first:last]
        var = (m * w0 - n * mom[first:last]) ** 2 / (w0 * (n - w0))
        t = first + int(np.argmax(var))
        ct, mt = float(cnt[t]), float(mom[t])
        mu_d = mt / ct
        if background == "above":
            mu_b = (total_m - mt) / (total_n - ct)
        else:
            mu_b = (m - mt) / (n - ct)
        c = interclass_contrast(mu_d, mu_b)
        thresholds.append(t)
        contrasts.append(c)
        if c > c_s:
            stop = "contrast"
            break
        top = t
    if not thresholds:  # single-level image: nothing is darker than the rest, so no defect
        only = int(np.flatnonzero(h)[0])
        return ITResult(threshold=only - 1, thresholds=(), contrasts=(), stop="region")
    return ITResult(
        threshold=thresholds[-1],
        thresholds=tuple(thresholds),
        contrasts=tuple(contrasts),
        stop=stop,
    )


def threshold_it(
    image: np.ndarray | None = None, *, hist: np.ndarray | None = None, **params: object
) -> int:
    """Threshold of :func:`iterative_threshold`, as a plain function like the others."""
    return iterative_threshold(image, hist=hist, **params).threshold  # type: ignore[arg-type]
