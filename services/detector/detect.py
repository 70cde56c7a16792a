"""The detection API: ``detect(grey, method) -> Detection`` and the ``METHODS`` registry.

Design notes: docs/detector.md (services/detector/detect.py).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from .improved import it_plus_bh_mask, it_plus_mask, reduction_factor
from .iterative import C_S_UNGUARDED, iterative_threshold
from .learned import learned_mask
from .ridge import it_plus_ridge_mask
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


def _it_paper(grey: np.ndarray, **params: object) -> tuple[np.ndarray, int]:
    """IT with the paper's bare stop rule only (``C_k > C_s``, no size guard), for comparison."""
    kw: dict[str, object] = {"c_s": C_S_UNGUARDED, "min_region": 0.0, **params}
    return _it(grey, **kw)


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
    "it-paper": _it_paper,
    "it+": it_plus_mask,
    "it+bh": it_plus_bh_mask,
    "it+r": it_plus_ridge_mask,
    "learned": learned_mask,
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
    grey: np.ndarray,
    mask: np.ndarray,
    *,
    ring: int = 5,
    min_area: int = 1,
    work_px: int = 2_000_000,
) -> list[Defect]:
    """Connected components of ``mask`` with their contrast (P19) to a local background ring.

    Each non-defect pixel within ``ring`` pixels (square neighbourhood) of a component is given
    to the highest-numbered nearby component (a label-image dilation); the component's
    background mean is the mean grey of its ring pixels, its defect mean that of its own pixels,
    and its contrast ``|μ_B − μ_D| / (μ_B + μ_D)`` (P19). Vectorised with ``np.bincount``; frames above
    ``work_px`` pixels are analysed on blocks (docs/detector.md, services/detector/detect.py).

    Components smaller than ``min_area`` pixels are left out. Sorted by area, largest first.
    """
    g = as_grey_u8(grey)
    m = np.asarray(mask)
    if m.shape != g.shape:
        raise ValueError(f"mask shape {m.shape} != image shape {g.shape}")
    if ring < 1:
        raise ValueError("ring must be >= 1")
    fg = np.where(m != 0, 255, 0).astype(np.uint8) if m.dtype != np.uint8 else m
    H, W = g.shape
    s = reduction_factor(H * W, work_px)
    if s == 1:
        frac = (fg > 0).astype(np.float64)  # defect share of each pixel (0/1)
        dark = g.astype(np.float64) * frac  # grey summed over defect pixels
        back = g.astype(np.float64) - dark  # grey summed over background pixels
        ring_s = ring
    else:
        Hs, Ws = H // s, W // s
        crop = (slice(0, Hs * s), slice(0, Ws * s))
        area_resize = lambda a: cv2.resize(a[crop], (Ws, Hs), interpolation=cv2.INTER_AREA)  # noqa: E731
        f32 = lambda a: a.astype(np.float32)  # noqa: E731
        frac = area_resize(f32(fg)).astype(np.float64) / 255.0
        dark = area_resize(f32(cv2.bitwise_and(g, fg))).astype(np.float64)
        back = area_resize(f32(g)).astype(np.float64) - dark
        ring_s = max(1, round(ring / s))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(
        (frac > 0).astype(np.uint8), connectivity=8, ltype=cv2.CV_32S
    )
    if n <= 1:
        return []
    lab = labels.ravel()
    fr = frac.ravel()
    cnt_d = np.bincount(lab, weights=fr, minlength=n)
    sum_d = np.bincount(lab, weights=dark.ravel(), minlength=n)
    ys, xs = np.indices(labels.shape, dtype=np.float64)
    cx = np.bincount(lab, weights=(xs.ravel() + 0.5) * fr, minlength=n)
    cy = np.bincount(lab, weights=(ys.ravel() + 0.5) * fr, minlength=n)
    k = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * ring_s + 1, 2 * ring_s + 1))
    dil = cv2.dilate(labels.astype(np.float32), k).astype(np.int64).ravel()
    near = (dil > 0) & (fr < 1.0)
    bw = 1.0 - fr[near]
    cnt_b = np.bincount(dil[near], weights=bw, minlength=n)
    sum_b = np.bincount(dil[near], weights=back.ravel()[near], minlength=n)
    area = cnt_d * s * s
    out: list[Defect] = []
    for i in np.argsort(-area[1:], kind="stable") + 1:
        if area[i] < min_area or cnt_d[i] <= 0:
            continue
        mu_d = sum_d[i] / cnt_d[i]
        if cnt_b[i] > 0:
            mu_b = sum_b[i] / cnt_b[i]
            c = abs(mu_b - mu_d) / (mu_b + mu_d) if mu_b + mu_d > 0 else 0.0
        else:
            c = 0.0
        x, y, w, h = (int(v) * s for v in stats[i, :4])
        # exact pixel centres at s == 1: (x + 0.5) - 0.5 = x
        ctr = (s * cx[i] / cnt_d[i] - 0.5, s * cy[i] / cnt_d[i] - 0.5)
        out.append(
            Defect(
                area_px=int(round(area[i])), bbox=(x, y, min(w, W - x), min(h, H - y)),
                centroid=(float(ctr[0]), float(ctr[1])), contrast=float(c),
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
    """Detect dark defects in a grey (or BGR, :func:`services.detector.thresholds.as_grey_u8`) image with
    ``method`` (a key of :data:`METHODS`, given ``**params``, e.g. ``c_s=0.3`` for ``"it"``).

    ``with_defects``: list the connected components (skip for mask-only use), leaving those smaller than
    ``min_defect_area`` out of the list (the mask is unchanged).
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose from {sorted(METHODS)}")
    g = as_grey_u8(grey)
    mask, t = METHODS[method](g, **params)
    defects = defects_of(g, mask, min_area=min_defect_area) if with_defects else []
    return Detection(mask=mask, defects=defects, method=method, threshold=t)
