"""The detection API: ``detect(grey, method) -> Detection`` and the ``METHODS`` registry.

Polarity: defects are darker than the background; a global method marks the pixels ``<= T``.
Every method in :data:`METHODS` maps a grey ``uint8`` image (plus keyword parameters) to a
binary mask (uint8 0/255) and its global threshold (``None`` for the local Sauvola).

Defects are the 8-connected components of the mask, each with its pixel area, bounding box,
centroid and its interclass contrast (P19) against the local background: the non-defect pixels
within ``ring`` pixels of the component.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from .improved import it_plus_mask
from .iterative import iterative_threshold
from .thresholds import (
    as_grey_u8,
    histogram,
    threshold_itth,
    threshold_otsu,
    threshold_sauvola,
    threshold_sdd,
    threshold_valley_emphasis,
)

__all__ = ["Defect", "Detection", "METHODS", "detect", "defects_of", "mask_at"]

MethodFn = Callable[..., tuple[np.ndarray, "int | None"]]


def mask_at(grey: np.ndarray, t: int) -> np.ndarray:
    """Mask (uint8 0/255) of the pixels ``<= t``, with one ``cv2.threshold``."""
    return cv2.threshold(grey, t, 255, cv2.THRESH_BINARY_INV)[1]


def _global(fn: Callable[..., int]) -> MethodFn:
    def run(grey: np.ndarray, **params: object) -> tuple[np.ndarray, int]:
        t = fn(hist=histogram(grey), **params)
        return mask_at(grey, t), t

    run.__doc__ = f"Mask of ``{fn.__name__}`` (global threshold on the histogram)."
    return run


def _it(grey: np.ndarray, **params: object) -> tuple[np.ndarray, int]:
    t = iterative_threshold(hist=histogram(grey), **params).threshold  # type: ignore[arg-type]
    return mask_at(grey, t), t


def _sauvola(grey: np.ndarray, **params: object) -> tuple[np.ndarray, None]:
    t = threshold_sauvola(grey, **params)  # type: ignore[arg-type]
    return np.where(grey <= t, 255, 0).astype(np.uint8), None


#: Method name -> mask function ``fn(grey_uint8, **params) -> (mask, threshold or None)``.
METHODS: dict[str, MethodFn] = {
    "otsu": _global(threshold_otsu),
    "ve": _global(threshold_valley_emphasis),
    "sauvola": _sauvola,
    "itth": _global(threshold_itth),
    "sdd": _global(threshold_sdd),
    "it": _it,
    "it+": it_plus_mask,
}


@dataclass(frozen=True)
class Defect:
    """One connected component of a defect mask (pixel units, x right, y down)."""

    area_px: int
    bbox: tuple[int, int, int, int]  # x, y, w, h
    centroid: tuple[float, float]  # x, y
    contrast: float  # (P19) against the local background ring; 0 when there is no ring


@dataclass(frozen=True)
class Detection:
    """Result of :func:`detect`: the mask, its defects, and how it was made."""

    mask: np.ndarray  # uint8 0/255
    defects: list[Defect] = field(default_factory=list)
    method: str = "it+"
    threshold: int | None = None

    @property
    def defect_fraction(self) -> float:
        """Share of the image marked as defect."""
        return float(np.count_nonzero(self.mask)) / self.mask.size


def defects_of(
    grey: np.ndarray, mask: np.ndarray, *, ring: int = 5, min_area: int = 1
) -> list[Defect]:
    """Connected components of ``mask`` with their contrast (P19) to a local background ring.

    Each non-defect pixel within ``ring`` pixels (square neighbourhood) of a component is given
    to the highest-numbered nearby component (a label-image dilation); the component's
    background mean is the mean grey of its ring pixels. Vectorised with ``np.bincount``.
    Components smaller than ``min_area`` are left out. Sorted by area, largest first.
    """
    g = as_grey_u8(grey)
    m = np.asarray(mask)
    if m.shape != g.shape:
        raise ValueError(f"mask shape {m.shape} != image shape {g.shape}")
    if ring < 1:
        raise ValueError("ring must be >= 1")
    fg = (m != 0).astype(np.uint8)
    n, labels, stats, cents = cv2.connectedComponentsWithStats(fg, connectivity=8, ltype=cv2.CV_32S)
    if n <= 1:
        return []
    gf = g.astype(np.float64).ravel()
    lab = labels.ravel()
    sum_d = np.bincount(lab, weights=gf, minlength=n)
    k = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * ring + 1, 2 * ring + 1))
    dil = cv2.dilate(labels.astype(np.float32), k).astype(np.int64).ravel()
    ringpx = (fg.ravel() == 0) & (dil > 0)
    cnt_b = np.bincount(dil[ringpx], minlength=n)
    sum_b = np.bincount(dil[ringpx], weights=gf[ringpx], minlength=n)
    area = stats[:, cv2.CC_STAT_AREA]
    out: list[Defect] = []
    order = np.argsort(-area[1:], kind="stable") + 1
    for i in order:
        if area[i] < min_area:
            continue
        mu_d = sum_d[i] / area[i]
        if cnt_b[i] > 0:
            mu_b = sum_b[i] / cnt_b[i]
            c = abs(mu_b - mu_d) / (mu_b + mu_d) if mu_b + mu_d > 0 else 0.0
        else:
            c = 0.0
        x, y, w, h = (int(v) for v in stats[i, :4])
        out.append(
            Defect(
                area_px=int(area[i]), bbox=(x, y, w, h),
                centroid=(float(cents[i, 0]), float(cents[i, 1])), contrast=float(c),
            )
        )
    return out


def detect(
    grey: np.ndarray,
    method: str = "it+",
    *,
    with_defects: bool = True,
    min_defect_area: int = 1,
    **params: object,
) -> Detection:
    """Detect dark defects in a grey (or BGR) image.

    Parameters
    ----------
    grey : ndarray
        Grey uint8 image (colour BGR is converted, see
        :func:`services.detector.thresholds.as_grey_u8`).
    method : str
        A key of :data:`METHODS`.
    with_defects : bool
        List the connected components (skip for mask-only use).
    min_defect_area : int
        Leave components smaller than this out of the defect list (the mask is unchanged).
    **params
        Passed to the method (e.g. ``c_s=0.3`` for ``"it"``).

    Returns
    -------
    Detection
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose from {sorted(METHODS)}")
    g = as_grey_u8(grey)
    mask, t = METHODS[method](g, **params)
    defects = defects_of(g, mask, min_area=min_defect_area) if with_defects else []
    return Detection(mask=mask, defects=defects, method=method, threshold=t)
