"""The deliverable's measurements against the ground truth: each crack's length, widths and class beside
the truth's, and the errors summarised (median and worst).

Design notes: docs/report.md (services/inspection/accuracy.py).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import cv2
import numpy as np

from services.detector.measure import measure_component

__all__ = ["TruthCrack", "Comparison", "Accuracy", "truth_cracks", "unseen_cracks", "seen_pixels", "compare",
           "markdown_accuracy"]


@dataclass(frozen=True)
class TruthCrack:
    """One ground-truth crack measured at the truth's resolution."""

    id: int
    u_m: float
    v_m: float
    length_m: float
    width_max_mm: float
    width_mean_mm: float
    severity: str
    label: int  # its label in the truth label image
    seen: float = 1.0  # share of its pixels some frame saw (what is measured is that part)


@dataclass(frozen=True)
class Comparison:
    """One truth crack beside what the deliverable measured of it (``defects`` empty: missed)."""

    truth: TruthCrack
    defects: tuple[int, ...]
    length_m: float | None = None
    width_max_mm: float | None = None
    width_mean_mm: float | None = None
    severity: str | None = None
    resolved: bool = True

    @property
    def length_error(self) -> float | None:
        """(measured - truth) / truth."""
        return None if self.length_m is None else (self.length_m - self.truth.length_m) / self.truth.length_m

    @property
    def width_max_error_mm(self) -> float | None:
        return None if self.width_max_mm is None else self.width_max_mm - self.truth.width_max_mm

    @property
    def width_mean_error_mm(self) -> float | None:
        return None if self.width_mean_mm is None else self.width_mean_mm - self.truth.width_mean_mm

    @property
    def class_agrees(self) -> bool | None:
        return None if self.severity is None else self.severity == self.truth.severity


@dataclass
class Accuracy:
    """Every comparison and the summary: median and worst absolute errors, the share in their true class."""

    rows: list[Comparison]
    unmatched: list[int] = field(default_factory=list)  # defects on no truth crack
    summary: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        rows = []
        for r in self.rows:
            d = {k: v for k, v in asdict(r).items() if k != "truth"}
            d.update(truth=asdict(r.truth), length_error=r.length_error, width_max_error_mm=r.width_max_error_mm,
                     width_mean_error_mm=r.width_mean_error_mm, class_agrees=r.class_agrees)
            rows.append(d)
        return {"summary": self.summary, "unmatched": self.unmatched, "rows": rows}


def truth_cracks(mask: np.ndarray, m_per_px: float, min_area_px: int = 20,
                 seen: np.ndarray | None = None) -> tuple[list[TruthCrack], np.ndarray]:
    """The truth cracks of a truth ``mask`` (row 0 at the top, v up; ``m_per_px`` its scale) and its label image.

    With ``seen`` (the pixels of the same raster some frame saw: :func:`seen_pixels`) each crack is measured
    on its seen part, and a crack with fewer than ``min_area_px`` seen pixels is left out: the deliverable
    is scored on what the flight imaged, its coverage is reported apart."""
    m = (np.asarray(mask) > 0).astype(np.uint8)
    n, labels, stats, cents = cv2.connectedComponentsWithStats(m, connectivity=8, ltype=cv2.CV_32S)
    if seen is not None:
        labels = np.where(seen, labels, 0)
    H = m.shape[0]
    out: list[TruthCrack] = []
    for i in range(1, n):
        x, y, w, h, a = (int(v) for v in stats[i])
        if a < min_area_px:
            continue
        part = labels[y:y + h, x:x + w] == i
        visible = int(np.count_nonzero(part))
        if visible < min_area_px:
            continue
        cm = measure_component(part, m_per_px)
        rows, cols = np.nonzero(part)
        out.append(TruthCrack(id=len(out), u_m=float((x + cols.mean() + 0.5) * m_per_px),
                              v_m=float((H - (y + rows.mean()) - 0.5) * m_per_px), length_m=cm.length_m,
                              width_max_mm=1e3 * cm.width_max_m, width_mean_mm=1e3 * cm.width_mean_m,
                              severity=cm.severity, label=i, seen=visible / a))
    return out, labels


def unseen_cracks(mask: np.ndarray, seen: np.ndarray, min_area_px: int = 20) -> int:
    """How many truth cracks of ``mask`` no frame saw (fewer than ``min_area_px`` of their pixels in ``seen``)."""
    m = (np.asarray(mask) > 0).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8, ltype=cv2.CV_32S)
    big = stats[1:, cv2.CC_STAT_AREA] >= min_area_px
    shown = np.bincount(labels[seen], minlength=n)[1:] >= min_area_px
    return int(np.count_nonzero(big & ~shown))


def seen_pixels(owner: np.ndarray, m_per_px: float, shape: tuple[int, int], truth_m_per_px: float) -> np.ndarray:
    """Which pixels of a truth raster (``shape`` at ``truth_m_per_px``, row 0 at the top) a frame saw, from a
    mosaic's ``owner`` (-1 where no frame saw, at ``m_per_px``) on the same plane."""
    H, W = shape
    r = np.minimum(((np.arange(H) + 0.5) * truth_m_per_px / m_per_px).astype(int), owner.shape[0] - 1)
    c = np.minimum(((np.arange(W) + 0.5) * truth_m_per_px / m_per_px).astype(int), owner.shape[1] - 1)
    return np.asarray(owner)[np.ix_(r, c)] >= 0


def _samples(line: Sequence[Sequence[float]], step: float) -> np.ndarray:
    p = np.asarray(line, float).reshape(-1, 2)
    if len(p) == 1:
        return p
    out = [p[:1]]
    for a, b in zip(p[:-1], p[1:]):
        k = max(1, int(math.ceil(np.linalg.norm(b - a) / step)))
        out.append(a + (b - a) * (np.arange(1, k + 1)[:, None] / k))
    return np.vstack(out)


def compare(defects: Sequence[Any], truth: Sequence[TruthCrack], labels: np.ndarray, m_per_px: float,
            search_px: int = 3, gsd_m: float | None = None, unseen: int | None = None) -> Accuracy:
    """Match the deliverable's ``defects`` (:class:`services.inspection.deliverable.InspectionDefect`:
    ``id``, ``centre_line_uv``, ``u_m``, ``v_m``, sizes) to ``truth`` on the truth's ``labels`` (see the module
    docstring). With the flown ground sampling distance ``gsd_m``, the summary counts the true cracks
    narrower than one of its pixels (``below_pixel``, ``below_pixel_found``): those the report cannot size;
    ``unseen``, the true cracks no frame saw (:func:`unseen_cracks`), is carried into the summary."""
    H, W = labels.shape
    by_label = {t.label: t for t in truth}
    k = 2 * search_px + 1
    near = cv2.dilate(labels.astype(np.float32), np.ones((k, k), np.uint8))  # a label within search_px
    hits: dict[int, list[Any]] = {}
    unmatched = []
    for d in defects:
        line = d.centre_line_uv or [(d.u_m, d.v_m)]
        uv = _samples(line, 0.5 * m_per_px)
        c = np.floor(uv[:, 0] / m_per_px).astype(int)
        r = np.floor((H * m_per_px - uv[:, 1]) / m_per_px).astype(int)
        ok = (c >= 0) & (c < W) & (r >= 0) & (r < H)
        lab = labels[r[ok], c[ok]]
        lab = np.where(lab > 0, lab, near[r[ok], c[ok]].astype(np.int32))
        lab = lab[np.isin(lab, list(by_label))]
        if lab.size == 0:
            unmatched.append(d.id)
            continue
        hits.setdefault(int(np.bincount(lab).argmax()), []).append(d)
    rows = []
    for t in truth:
        ds = hits.get(t.label, [])
        if not ds:
            rows.append(Comparison(truth=t, defects=()))
            continue
        length = sum(d.length_m for d in ds)
        wmax = max(d.width_max_mm for d in ds)
        wmean = sum(d.width_mean_mm * d.length_m for d in ds) / length if length > 0 else ds[0].width_mean_mm
        worst = max(ds, key=lambda d: d.width_max_mm)
        rows.append(Comparison(truth=t, defects=tuple(d.id for d in ds), length_m=length, width_max_mm=wmax,
                               width_mean_mm=wmean, severity=worst.severity, resolved=all(d.resolved for d in ds)))
    summary = summarise(rows, unmatched, gsd_m)
    if unseen is not None:
        summary["unseen"] = unseen
    if gsd_m is not None:
        below = [r for r in rows if r.truth.width_max_mm < 1e3 * gsd_m]
        summary.update(gsd_mm=1e3 * gsd_m, below_pixel=len(below), below_pixel_found=sum(bool(r.defects) for r in below))
    return Accuracy(rows=rows, unmatched=unmatched, summary=summary)


def summarise(rows: Sequence[Comparison], unmatched: Sequence[int] = (), gsd_m: float | None = None) -> dict[str, Any]:
    """Median and worst absolute errors over the matched cracks (widths and classes: those measured wider than
    one pixel). With the flown ground sampling distance ``gsd_m`` a true crack narrower than one pixel is
    left out of every error: it cannot be sized, only flagged (what the defects over it measure is texture)."""
    m = [r for r in rows if r.defects and (gsd_m is None or r.truth.width_max_mm >= 1e3 * gsd_m)]
    res = [r for r in m if r.resolved]

    def stats(xs: list[float | None]) -> tuple[float | None, float | None]:
        a = np.abs(np.asarray(xs, float))
        return (float(np.median(a)), float(a.max())) if a.size else (None, None)

    lm, lw = stats([r.length_error for r in m])
    xm, xw = stats([r.width_max_error_mm for r in res])
    mm, mw = stats([r.width_mean_error_mm for r in res])
    cls = [r.class_agrees for r in res]
    return {"truth": len(rows), "matched": sum(bool(r.defects) for r in rows), "sized": len(m),
            "unmatched_defects": len(unmatched),
            "resolved": len(res), "length_error_median": lm, "length_error_worst": lw,
            "width_max_error_mm_median": xm, "width_max_error_mm_worst": xw,
            "width_mean_error_mm_median": mm, "width_mean_error_mm_worst": mw,
            "class_agreement": (sum(cls) / len(cls)) if cls else None,
            "classes_true": sorted({r.truth.severity for r in rows})}


def _f(x: float | None, fmt: str) -> str:
    return "–" if x is None else format(x, fmt)


def markdown_accuracy(acc: Accuracy) -> str:
    """The comparison table and its summary line, in Markdown."""
    s = acc.summary
    lines = [
        f"Against the ground truth ({s['truth']} cracks, {s['matched']} found; {s['unmatched_defects']} defects on no "
        f"true crack): length error median {_f(s['length_error_median'] and 100 * s['length_error_median'], '.1f')} %, "
        f"worst {_f(s['length_error_worst'] and 100 * s['length_error_worst'], '.1f')} %; maximum width error median "
        f"{_f(s['width_max_error_mm_median'], '.2f')} mm, worst {_f(s['width_max_error_mm_worst'], '.2f')} mm; mean "
        f"width error median {_f(s['width_mean_error_mm_median'], '.2f')} mm, worst "
        f"{_f(s['width_mean_error_mm_worst'], '.2f')} mm; in their true class: "
        f"{_f(s['class_agreement'] and 100 * s['class_agreement'], '.0f')} % (widths and classes over the "
        f"{s['resolved']} cracks wider than one pixel)."
        + (" Scored on the imaged surface: a crack partly seen is measured on its seen part"
           + (f"; {s['unseen']} more true cracks lie where no capture saw." if s["unseen"] else ".")
           if s.get("unseen") is not None else "")
        + (f" {s['below_pixel']} true cracks are narrower than one pixel at the flown {s['gsd_mm']:.2f} mm/px "
           f"({s['below_pixel_found']} of them detected): their widths cannot be measured." if s.get("below_pixel") else ""),
        "",
        "| truth | length (m) truth / measured | width max (mm) truth / measured | width mean (mm) truth / measured "
        "| class truth / measured | defects |",
        "|---|---|---|---|---|---|",
    ]
    gsd_mm = s.get("gsd_mm")
    for r in acc.rows:
        t = r.truth
        lines.append(
            f"| {t.id} | {t.length_m:.2f} / {_f(r.length_m, '.2f')} | {t.width_max_mm:.2f} / {_f(r.width_max_mm, '.2f')}"
            f" | {t.width_mean_mm:.2f} / {_f(r.width_mean_mm, '.2f')} | {t.severity} / "
            f"{(r.severity or 'missed') + ('' if r.resolved else ' (below 1 px)')}"
            f"{' (narrower than one pixel)' if gsd_mm and t.width_max_mm < gsd_mm else ''}"
            f"{f' ({t.seen:.0%} of it seen)' if t.seen < 0.995 else ''} | "
            f"{', '.join(str(i) for i in r.defects) or '–'} |")
    return "\n".join(lines)
