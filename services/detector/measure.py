"""Crack measurements on a binary defect mask: skeleton length, maximum and mean width, severity.

Design notes: docs/detector.md (services/detector/measure.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = [
    "SEVERITY_LIMITS_M", "CrackMeasure", "measure_component", "measure_mask", "severity", "skeleton_length",
    "frame_scale", "centre_line", "outline", "fill_holes",
]

#: upper width limits of the severity classes, metres (AASHTO MBEI, reinforced concrete cracking)
SEVERITY_LIMITS_M: tuple[tuple[str, float], ...] = (("insignificant", 0.0003), ("moderate", 0.0013))
#: class of wider cracks
SEVERITY_WIDE = "wide"

# Kimura-Kikuchi-Yamasaki weights of orthogonal and diagonal chain links (Dorst & Smeulders 1987)
_W_EVEN, _W_ODD = 0.948, 1.343


@dataclass(frozen=True)
class CrackMeasure:
    """Size of one crack (one connected component of a mask)."""

    length_m: float
    width_max_m: float
    width_mean_m: float
    area_m2: float
    severity: str
    resolved: bool  # the maximum width is at least one pixel's footprint
    length_px: float
    width_max_px: float
    width_mean_px: float

    def as_dict(self) -> dict[str, float | str | bool]:
        return {"length_m": self.length_m, "width_max_mm": 1e3 * self.width_max_m,
                "width_mean_mm": 1e3 * self.width_mean_m, "area_m2": self.area_m2, "severity": self.severity,
                "resolved": self.resolved}


def severity(width_m: float) -> str:
    """Severity class of a crack of maximum width ``width_m`` (see :data:`SEVERITY_LIMITS_M`)."""
    if not math.isfinite(width_m) or width_m < 0:
        raise ValueError(f"width must be finite and >= 0, got {width_m!r}")
    for name, hi in SEVERITY_LIMITS_M:
        if width_m < hi:
            return name
    return SEVERITY_WIDE


def _skeletonize(mask: np.ndarray) -> np.ndarray:
    from skimage.morphology import skeletonize

    return skeletonize(mask > 0)


def skeleton_length(skel: np.ndarray) -> tuple[float, np.ndarray]:
    """Chain-code length (pixels) of a one-pixel-wide skeleton, and its end pixels (row, col)."""
    s = np.asarray(skel, dtype=bool)
    if s.ndim != 2:
        raise ValueError("skeleton must be 2-D")
    p = np.pad(s, 1)
    c = p[1:-1, 1:-1]
    right, down = p[1:-1, 2:], p[2:, 1:-1]
    n_even = int(np.count_nonzero(c & right) + np.count_nonzero(c & down))
    # diagonal down-right: (r, c) - (r+1, c+1), common orthogonal neighbours (r, c+1) and (r+1, c)
    dr = c & p[2:, 2:] & ~p[1:-1, 2:] & ~p[2:, 1:-1]
    # diagonal down-left: (r, c) - (r+1, c-1), common neighbours (r, c-1) and (r+1, c)
    dl = c & p[2:, :-2] & ~p[1:-1, :-2] & ~p[2:, 1:-1]
    n_odd = int(np.count_nonzero(dr) + np.count_nonzero(dl))
    nb = sum(np.roll(np.roll(p, dy, 0), dx, 1)[1:-1, 1:-1].astype(np.int32)
             for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0))
    ends = np.argwhere(c & (nb <= 1))
    return _W_EVEN * n_even + _W_ODD * n_odd, ends


def half_depth_mask(grey: np.ndarray, mask: np.ndarray, ring: int = 4, grow: int = 2) -> np.ndarray:
    """The crack's pixels at half its depth: ``grey <= (B + D) / 2`` near the detected component.

    ``B`` is the median grey of the background ring (``ring`` pixels around the component, outside
    it), ``D`` the 10th percentile of the component's own pixels (its core); why half depth: docs/detector.md.
    Pixels are taken within ``grow`` pixels of the component and only where connected to it; a component
    without a ring keeps its mask.
    """
    g = np.asarray(grey)
    m = np.asarray(mask) != 0
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * ring + 1, 2 * ring + 1))
    m8 = m.astype(np.uint8)
    near = cv2.dilate(m8, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow + 1, 2 * grow + 1))) > 0
    band = (cv2.dilate(m8, k) > 0) & ~near
    if not band.any() or not m.any():
        return m
    b = float(np.median(g[band]))
    d = float(np.percentile(g[m], 10))
    if b <= d:
        return m
    cand = (near & (g <= 0.5 * (b + d))).astype(np.uint8)
    n, lab = cv2.connectedComponents(cand, connectivity=8)
    hit = np.unique(lab[m & (cand > 0)])
    hit = hit[hit > 0]
    out = np.isin(lab, hit)
    return out if out.any() else m


def _endpoints(skel: np.ndarray) -> np.ndarray:
    p = np.pad(skel, 1).astype(np.uint8)
    nb = cv2.filter2D(p, cv2.CV_16S, np.ones((3, 3), np.int16), borderType=cv2.BORDER_CONSTANT)[1:-1, 1:-1] - p[1:-1, 1:-1]
    return skel & (nb <= 1)


def prune_spurs(skel: np.ndarray, n: int) -> np.ndarray:
    """Remove skeleton branches shorter than ``n`` pixels (the spurs thinning grows from a rough
    edge): strip end pixels ``n`` times, then regrow the surviving ends ``n`` steps along the
    original skeleton (Gonzalez & Woods, *Digital Image Processing*, pruning)."""
    s = np.asarray(skel, bool)
    if n <= 0 or not s.any():
        return s
    x = s.copy()
    for _ in range(n):
        e = _endpoints(x)
        if not e.any() or e.sum() == x.sum():
            break
        x &= ~e
    if not x.any():
        return s
    grown = _endpoints(x)
    k = np.ones((3, 3), np.uint8)
    for _ in range(n):
        grown = (cv2.dilate(grown.astype(np.uint8), k) > 0) & s & ~x | grown
    _, pieces = cv2.connectedComponents(s.astype(np.uint8), connectivity=8)
    size = np.bincount(pieces[s])
    gone = np.setdiff1d(np.flatnonzero(size >= n), np.unique(pieces[x]))
    return x | (grown & s) | np.isin(pieces, gone)


def fill_holes(mask: np.ndarray, dist: np.ndarray) -> np.ndarray | None:
    """``mask`` (uint8, 0/255) with its specks filled; None when it has none.

    A hole is a 4-connected background region that does not reach the border (Soille, *Morphological Image
    Analysis*, hole filling); it is a speck, filled, when its area is at most the square of the crack's
    half-width around it (``dist``, the mask's distance transform, within 2 pixels of the hole): a gap
    between two branches of a crack network is bounded by thin branches and stays open.
    """
    n, lab, stats, _ = cv2.connectedComponentsWithStats(
        cv2.copyMakeBorder(255 - mask, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=255), connectivity=4)
    lab, stats[:, :2] = lab[1:-1, 1:-1], stats[:, :2] - 1
    H, W = mask.shape
    dmax = float(dist.max())
    out = None
    for i in np.flatnonzero(stats[:, cv2.CC_STAT_AREA] <= dmax * dmax):
        x, y, w, h, a = (int(v) for v in stats[i])
        if x < 0 or y < 0 or x + w > W or y + h > H:
            continue  # the background at the border
        y0, y1, x0, x1 = max(0, y - 2), min(H, y + h + 2), max(0, x - 2), min(W, x + w + 2)
        hole = lab[y0:y1, x0:x1] == i
        if not hole.any() or mask[y0:y1, x0:x1][hole].any():
            continue
        if a <= float(dist[y0:y1, x0:x1].max()) ** 2:
            out = mask.copy() if out is None else out
            out[y0:y1, x0:x1][hole] = 255
    return out


def measure_component(mask: np.ndarray, m_per_px: float, grey: np.ndarray | None = None) -> CrackMeasure:
    """Measure the defect pixels of ``mask`` (non-zero) as one crack at ``m_per_px`` metres per pixel.

    With ``grey`` (the image under the mask) the crack is sized on its half-depth mask
    (:func:`half_depth_mask`) rather than on the detector's.
    """
    if not (math.isfinite(m_per_px) and m_per_px > 0):
        raise ValueError(f"m_per_px must be finite and > 0, got {m_per_px!r}")
    m = np.asarray(mask) != 0
    if m.ndim != 2 or not m.any():
        raise ValueError("mask must be 2-D with at least one defect pixel")
    if grey is not None:
        if np.shape(grey) != m.shape:
            raise ValueError(f"grey shape {np.shape(grey)} != mask shape {m.shape}")
        m = half_depth_mask(grey, m)
    m = np.ascontiguousarray(np.where(m, 255, 0).astype(np.uint8))
    fg = cv2.copyMakeBorder(m, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
    dist = cv2.distanceTransform(fg, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[1:-1, 1:-1]
    filled = fill_holes(m, dist)
    if filled is not None:  # specks inside the crack: the skeleton would loop around them
        m = filled
        fg = cv2.copyMakeBorder(m, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
        dist = cv2.distanceTransform(fg, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[1:-1, 1:-1]
    skel = _skeletonize(m)
    if skel.any():
        skel = prune_spurs(skel, int(math.ceil(2.0 * float(dist[skel].max()))))
    else:  # a tiny blob thins to nothing: its centre pixel stands for it
        r, c = np.unravel_index(int(np.argmax(dist)), dist.shape)
        skel[r, c] = True
    length, ends = skeleton_length(skel)
    d = dist[skel]
    widths = np.maximum(2.0 * d - 0.5, 1.0)
    # thinning stops about half a width short of each tip
    length_px = length + float(sum(dist[r, c] for r, c in ends))
    if len(ends) == 0 and int(np.count_nonzero(skel)) == 1:
        length_px = float(widths[0])
    area = float(np.count_nonzero(m))
    # mean width: area over length (sub-pixel, unlike the distance transform's half-pixel steps)
    w_mean = min(area / length_px, float(widths.max())) if length_px > 0 else float(widths.mean())
    w_max = max(float(np.percentile(widths, 95)), w_mean)
    return CrackMeasure(
        length_m=length_px * m_per_px, width_max_m=w_max * m_per_px, width_mean_m=w_mean * m_per_px,
        area_m2=area * m_per_px * m_per_px, severity=severity(w_max * m_per_px), resolved=w_max >= 1.0,
        length_px=length_px, width_max_px=w_max, width_mean_px=w_mean,
    )


def measure_mask(mask: np.ndarray, m_per_px: float, min_area_px: int = 1, grey: np.ndarray | None = None,
                 margin: int = 8, max_components: int | None = None,
                 ) -> list[tuple[tuple[int, int, int, int], tuple[float, float], CrackMeasure]]:
    """Every 8-connected component of ``mask``: ``(bbox x, y, w, h; centroid x, y; measure)``.

    Sorted by area, largest first; components under ``min_area_px`` pixels are left out, and only
    the first ``max_components`` are measured when it is given. With
    ``grey`` each component is sized on its half-depth mask (in a window ``margin`` pixels wider
    than its box; other components in the window are masked out of it).
    """
    m = np.where(np.asarray(mask) != 0, 255, 0).astype(np.uint8)
    H, W = m.shape
    n, labels, stats, cents = cv2.connectedComponentsWithStats(m, connectivity=8, ltype=cv2.CV_32S)
    out: list[tuple[tuple[int, int, int, int], tuple[float, float], CrackMeasure]] = []
    for i in np.argsort(-stats[1:, cv2.CC_STAT_AREA], kind="stable") + 1:
        x, y, w, h, a = (int(v) for v in stats[i])
        if a < min_area_px:
            continue
        if max_components is not None and len(out) >= max_components:
            break
        x0, y0, x1, y1 = max(0, x - margin), max(0, y - margin), min(W, x + w + margin), min(H, y + h + margin)
        lab = labels[y0:y1, x0:x1]
        sub = lab == i
        g = None
        if grey is not None:
            g = np.asarray(grey)[y0:y1, x0:x1].copy()
            others = (lab != i) & (lab != 0)
            if others.any():  # other defects in the window must not read as this one's background
                g[others] = int(np.median(g[lab == 0])) if (lab == 0).any() else 255
        out.append(((x, y, w, h), (float(cents[i, 0]), float(cents[i, 1])), measure_component(sub, m_per_px, g)))
    return out


def frame_scale(range_m: float, fx: float, fy: float) -> float:
    """Ground sampling distance at the image centre of a frame facing the surface, m per pixel
    (the inverse of (P2): ``range / f``, with ``f`` the mean of the two focal lengths in pixels)."""
    if not (math.isfinite(range_m) and range_m > 0 and fx > 0 and fy > 0):
        raise ValueError("range and focal lengths must be finite and > 0")
    return range_m / (0.5 * (fx + fy))


# ------------------------------------------------------------------------------------ geometry
def centre_line(mask: np.ndarray, simplify_px: float = 0.7) -> np.ndarray:
    """The crack's centre line: the longest path through its skeleton, ``(N, 2)`` pixel ``(x, y)``."""
    m = np.asarray(mask) != 0
    if m.ndim != 2 or not m.any():
        raise ValueError("mask must be 2-D with at least one defect pixel")
    skel = _skeletonize(m)
    if not skel.any():
        r, c = np.argwhere(m).mean(0)
        return np.array([[c, r], [c, r]], float)
    pts = np.argwhere(skel)
    index = {(int(r), int(c)): i for i, (r, c) in enumerate(pts)}
    nbrs = [[index[(r + dr, c + dc)] for dr in (-1, 0, 1) for dc in (-1, 0, 1)
             if (dr or dc) and (r + dr, c + dc) in index] for r, c in ((int(a), int(b)) for a, b in pts)]

    def far(start: int) -> tuple[int, list[int]]:
        prev = {start: -1}
        queue, k = [start], 0
        while k < len(queue):
            for j in nbrs[queue[k]]:
                if j not in prev:
                    prev[j] = queue[k]
                    queue.append(j)
            k += 1
        end, path = queue[-1], []
        while end != -1:
            path.append(end)
            end = prev[end]
        return queue[-1], path

    a, _ = far(0)
    _, path = far(a)
    xy = pts[path][:, ::-1].astype(np.float32)
    if len(xy) < 2:
        return np.vstack([xy, xy]).astype(float)
    simple = cv2.approxPolyDP(xy.reshape(-1, 1, 2), simplify_px, False).reshape(-1, 2)
    return simple.astype(float) if len(simple) >= 2 else xy[[0, -1]].astype(float)


def _crossing(ring: np.ndarray) -> bool:
    """Whether a closed ring (first point not repeated) has two non-adjacent edges that meet."""
    a = ring
    b = np.roll(ring, -1, axis=0)
    n = len(a)
    if n < 4:
        return False

    def orient(p: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
        return np.sign((q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0]))

    for i in range(n - 2):
        j = np.arange(i + 2, n if i else n - 1)
        if j.size == 0:
            continue
        p, q, r, t = a[i], b[i], a[j], b[j]
        o1, o2 = orient(p, q, r), orient(p, q, t)
        o3, o4 = orient(r, t, p[None]), orient(r, t, q[None])
        if np.any((o1 * o2 <= 0) & (o3 * o4 <= 0) & ~((o1 == 0) & (o2 == 0))):
            return True
        col = (o1 == 0) & (o2 == 0)  # collinear: overlapping extents
        if col.any():
            lo = np.minimum(r[col], t[col]) - 1e-9
            hi = np.maximum(r[col], t[col]) + 1e-9
            if np.any(np.all((np.minimum(p, q) <= hi) & (np.maximum(p, q) >= lo), axis=1)):
                return True
    return False


def outline(mask: np.ndarray, simplify_px: float = 0.5) -> np.ndarray:
    """The crack's outline: a simple closed ring around its pixels, ``(N, 2)`` pixel ``(x, y)``, first
    point repeated last, counter-clockwise once the rows point up (seen from the front of a wall, the
    (u, v) frame of :class:`services.inspection.mosaic.Plane`; RFC 7946 Sec. 3.1.6 orders exterior rings so).
    Holes are not kept; how it is traced: docs/detector.md (services/detector/measure.py).
    """
    m = np.asarray(mask) != 0
    if m.ndim != 2 or not m.any():
        raise ValueError("mask must be 2-D with at least one defect pixel")
    pad = 6
    big = np.kron(m.astype(np.uint8), np.ones((2, 2), np.uint8)) * 255
    big = cv2.copyMakeBorder(big, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=0)
    k3 = np.ones((3, 3), np.uint8)
    ring: np.ndarray = np.zeros((0, 2), np.int32)
    for grow in range(pad - 1):
        g = cv2.dilate(big, k3, iterations=grow) if grow else big
        g = cv2.morphologyEx(g, cv2.MORPH_CLOSE, k3)
        contours, _ = cv2.findContours(g, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        ring = max(contours, key=cv2.contourArea).reshape(-1, 2)
        if len(np.unique(ring, axis=0)) == len(ring):
            break
    simple = cv2.approxPolyDP(ring.reshape(-1, 1, 2), 2.0 * simplify_px, True).reshape(-1, 2)
    if len(simple) >= 3 and not _crossing(simple.astype(float)):
        ring = simple
    else:
        ring = cv2.approxPolyDP(ring.reshape(-1, 1, 2), 0.1, True).reshape(-1, 2)  # collinear runs only
    xy = (ring.astype(float) - pad) / 2.0 - 0.25  # doubled pixel centres back to the mask's pixel coordinates
    if len(xy) < 3:  # cannot happen for a closed doubled pixel, kept for safety
        c = xy.mean(0)
        xy = c + np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])
    # rows grow downwards: a positive shoelace area in (column, row) is clockwise once rows point up
    area = 0.5 * float(np.sum(xy[:, 0] * np.roll(xy[:, 1], -1) - np.roll(xy[:, 0], -1) * xy[:, 1]))
    if area > 0:
        xy = xy[::-1]
    return np.vstack([xy, xy[:1]])
