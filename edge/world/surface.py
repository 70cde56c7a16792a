"""Synthetic inspected surface: concrete-like texture with procedurally drawn cracks.

Design notes: docs/edge.md (edge/world/surface.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from protocol.checks import finite_vec3 as _vec3
from protocol.checks import positive as _positive

__all__ = ["DEFAULT_PX_PER_M", "Defect", "SurfaceDefect", "SyntheticSurface", "crack_image", "draw_cracks",
           "graded_crack_image", "surface_options", "textured_background"]

#: Default texture resolution: 1 cm per texture pixel (docs/edge.md, edge/world/surface.py)
DEFAULT_PX_PER_M = 100.0

RngLike = np.random.Generator | int | None


def _rng(rng: RngLike) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    if rng is None or (isinstance(rng, (int, np.integer)) and not isinstance(rng, bool)):
        return np.random.default_rng(rng)
    raise ValueError(f"rng must be a numpy Generator, an int seed or None, got {type(rng).__name__}")


def _shape(shape: Any) -> tuple[int, int]:
    try:
        h, w = (int(s) for s in shape)
    except (TypeError, ValueError):
        raise ValueError(f"shape must be (height, width), got {shape!r}") from None
    if h <= 0 or w <= 0 or h != float(shape[0]) or w != float(shape[1]):
        raise ValueError(f"shape must be two positive integers (height, width), got {shape!r}")
    return h, w


def _range(name: str, value: Any, lo: float = 0.0, hi: float = math.inf) -> tuple[float, float]:
    try:
        a, b = (float(x) for x in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a (min, max) pair, got {value!r}") from None
    if not (math.isfinite(a) and math.isfinite(b)) or a > b or a < lo or b > hi:
        raise ValueError(f"{name} must be finite with {lo} <= min <= max <= {hi}, got {value!r}")
    return a, b


def _value_noise(h: int, w: int, cell: float, rng: np.random.Generator) -> NDArray[np.float32]:
    """Smooth noise of unit variance-ish with features about ``cell`` px across.

    A small field of independent normals, one per ``cell`` x ``cell`` block, enlarged with
    bicubic interpolation (value noise; Perlin 1985 describes the family).
    """
    gh = max(2, int(math.ceil(h / cell)) + 2)
    gw = max(2, int(math.ceil(w / cell)) + 2)
    small = rng.standard_normal((gh, gw), dtype=np.float32)
    big = cv2.resize(small, (int(round(gw * cell)), int(round(gh * cell))), interpolation=cv2.INTER_CUBIC)
    oy = int(rng.integers(0, max(1, big.shape[0] - h + 1)))
    ox = int(rng.integers(0, max(1, big.shape[1] - w + 1)))
    out = big[oy : oy + h, ox : ox + w]
    if out.shape != (h, w):  # cell < 1 px: the enlarged field may be one pixel short
        out = cv2.resize(big, (w, h), interpolation=cv2.INTER_LINEAR)
    return out.astype(np.float32, copy=False)


def textured_background(shape: tuple[int, int], rng: RngLike = None, *, mean: float = 140.0, roughness: float = 14.0,
                        blotches: float = 1.0, gradient: float = 0.12, grain: float = 4.0) -> NDArray[np.uint8]:
    """Concrete-like grey ``uint8`` texture of ``shape`` ``(height, width)``: ``mean`` grey level times an
    illumination ramp (``gradient``: peak-to-peak fraction of ``mean``), multi-scale value noise of std
    ``roughness``, soft blotches (``blotches`` per 200 x 200 px) and per-pixel ``grain`` (std, grey levels)."""
    h, w = _shape(shape)
    for name, val in (("mean", mean), ("roughness", roughness), ("blotches", blotches),
                      ("gradient", gradient), ("grain", grain)):
        if not math.isfinite(val) or val < 0:
            raise ValueError(f"{name} must be finite and >= 0, got {val!r}")
    if mean > 255:
        raise ValueError(f"mean must be <= 255, got {mean!r}")
    g = _rng(rng)

    # multi-scale value noise, weights so that the sum has std ~ roughness
    cells = (2.0, 6.0, 24.0, 96.0)
    amps = np.array([0.35, 0.45, 0.6, 0.55], dtype=np.float32)
    amps *= roughness / float(np.sqrt(np.sum(amps**2)))
    img: NDArray[Any] = np.zeros((h, w), np.float32)
    for cell, amp in zip(cells, amps):
        img += amp * _value_noise(h, w, cell, g)

    # blotches: soft ellipses, some darker (stains), some lighter (patches)
    n_blot = int(g.poisson(blotches * h * w / 200.0**2)) if blotches > 0 else 0
    if n_blot:
        f = 8  # draw on a coarse canvas, then enlarge: soft edges for free
        sh, sw = max(1, h // f + 1), max(1, w // f + 1)
        canvas = np.zeros((sh, sw), np.float32)
        for _ in range(n_blot):
            c = (int(g.integers(0, sw)), int(g.integers(0, sh)))
            ax = (int(g.integers(2, 12)), int(g.integers(2, 12)))
            level = float(g.normal(0.0, 1.0)) * roughness * 0.9
            cv2.ellipse(canvas, c, ax, float(g.uniform(0, 180)), 0, 360, level, -1)
        blurred = cv2.GaussianBlur(canvas, (0, 0), 2.0)
        img += cv2.resize(blurred, (w, h), interpolation=cv2.INTER_LINEAR)

    # illumination: a linear ramp in a random direction, peak-to-peak = gradient * mean
    ang = float(g.uniform(0, 2 * np.pi))
    ramp_x = np.linspace(-0.5, 0.5, w, dtype=np.float32) * math.cos(ang)
    ramp_y = np.linspace(-0.5, 0.5, h, dtype=np.float32) * math.sin(ang)
    norm = abs(math.cos(ang)) + abs(math.sin(ang))
    illum = 1.0 + gradient * (ramp_y[:, None] + ramp_x[None, :]) / norm
    img = (img + mean) * illum

    if grain > 0:
        img += g.standard_normal((h, w), dtype=np.float32) * grain
    return np.clip(img, 0, 255).astype(np.uint8)


def _walk_crack(mask: NDArray[np.uint8], g: np.random.Generator, start: tuple[float, float], heading: float,
                length: float, width: tuple[float, float], branch_prob: float, depth: int) -> None:
    """Draw one crack (and recursively its branches) into ``mask`` in place."""
    h, w = mask.shape
    step = 3.0
    n = max(2, int(length / step))
    # smoothly varying direction: curvature is an AR(1) process plus small jitter
    kappa = 0.0
    heading_k = np.empty(n)
    th = heading
    for k in range(n):
        kappa = 0.85 * kappa + g.normal(0.0, 0.012)
        th += kappa
        heading_k[k] = th + g.normal(0.0, 0.25)  # jagged, but does not accumulate
    pts = np.empty((n + 1, 2))
    pts[0] = start
    pts[1:] = start + np.cumsum(step * np.stack([np.cos(heading_k), np.sin(heading_k)], 1), 0)
    # smoothly varying width, tapered at both ends
    wmin, wmax = width
    w0 = g.uniform(wmin, wmax)
    wn = np.convolve(g.normal(0.0, 1.0, n + 8), np.ones(9) / 3.0, mode="valid")[:n]
    s = np.arange(n) / max(1, n - 1)
    taper = np.minimum(1.0, np.minimum(s, 1.0 - s) / 0.15 + 0.25)
    widths = np.clip((w0 + 0.6 * wn) * taper, wmin, wmax)
    ipts = np.round(pts).astype(np.int32)
    for k in range(n):
        x0, y0 = ipts[k]
        if not (-8 <= x0 < w + 8 and -8 <= y0 < h + 8):
            break  # walked off the image
        thick = max(1, int(round(widths[k])))
        cv2.line(mask, (int(x0), int(y0)), (int(ipts[k + 1, 0]), int(ipts[k + 1, 1])), 255, thick, cv2.LINE_8)
        if depth > 0 and k > n // 10 and g.random() < branch_prob:
            side = 1.0 if g.random() < 0.5 else -1.0
            _walk_crack(mask, g, (float(pts[k, 0]), float(pts[k, 1])), heading_k[k] + side * g.uniform(0.35, 1.0),
                        length * g.uniform(0.15, 0.45), (wmin, max(wmin, min(wmax, widths[k]))), branch_prob * 0.5,
                        depth - 1)


def draw_cracks(shape: tuple[int, int], rng: RngLike = None, n_cracks: int = 3, *,
                length_px: tuple[float, float] | None = None, width_px: tuple[float, float] = (1.0, 5.0),
                branch_prob: float = 0.015) -> NDArray[np.uint8]:
    """Binary crack mask (255 on cracks) of ``shape``: ``n_cracks`` random-walk polylines of ``length_px``
    (default ``(0.25, 0.75) * hypot(h, w)``) and ``width_px``, forking with ``branch_prob`` per 3 px step."""
    h, w = _shape(shape)
    if isinstance(n_cracks, bool) or not isinstance(n_cracks, (int, np.integer)) or n_cracks < 0:
        raise ValueError(f"n_cracks must be an integer >= 0, got {n_cracks!r}")
    if length_px is None:
        diag = math.hypot(h, w)
        length_px = (0.25 * diag, 0.75 * diag)
    lo_len, hi_len = _range("length_px", length_px, lo=1.0)
    width = _range("width_px", width_px, lo=1.0, hi=255.0)
    if not (0.0 <= branch_prob <= 1.0):
        raise ValueError(f"branch_prob must be in [0, 1], got {branch_prob!r}")
    g = _rng(rng)
    mask = np.zeros((h, w), np.uint8)
    for _ in range(int(n_cracks)):
        start = (float(g.uniform(0, w)), float(g.uniform(0, h)))
        if hi_len >= 0.5 * min(h, w):
            # long cracks head roughly towards the centre so that most of them stay in view
            to_centre = math.atan2(h / 2 - start[1], w / 2 - start[0])
            heading = to_centre + float(g.uniform(-1.0, 1.0))
        else:
            heading = float(g.uniform(0, 2 * np.pi))
        _walk_crack(mask, g, start, heading, float(g.uniform(lo_len, hi_len)), width, branch_prob, 2)
    return mask


def crack_image(shape: tuple[int, int] = (480, 640), rng: RngLike = None, n_cracks: int = 3, *,
                contrast: tuple[float, float] = (0.25, 0.55), noise_sigma: float = 3.0,
                length_px: tuple[float, float] | None = None, width_px: tuple[float, float] = (1.0, 5.0),
                background: dict[str, float] | None = None) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
    """Grey image of a cracked concrete-like surface and its ground-truth mask (255 on cracks).

    The background is darkened under the mask by a relative depth within ``contrast`` plus Gaussian
    noise of ``noise_sigma``: the paper's defect model, darker pixel groups on a repetitive background
    ((P18)-(P19)). ``background`` holds keyword arguments of :func:`textured_background`.

    >>> grey, mask = crack_image((320, 480), rng=1)
    >>> bool(grey[mask > 0].mean() < grey[mask == 0].mean())
    True
    """
    h, w = _shape(shape)
    dmin, dmax = _range("contrast", contrast, lo=0.0, hi=1.0)
    if not math.isfinite(noise_sigma) or noise_sigma < 0:
        raise ValueError(f"noise_sigma must be finite and >= 0, got {noise_sigma!r}")
    g = _rng(rng)
    bg = textured_background((h, w), g, **(background or {}))
    mask = draw_cracks((h, w), g, n_cracks, length_px=length_px, width_px=width_px)
    img = bg.astype(np.float32)
    if mask.any():
        # depth varies smoothly along the cracks (features ~ 40 px)
        depth = dmin + (dmax - dmin) * np.clip(0.5 + 0.35 * _value_noise(h, w, 40.0, g), 0.0, 1.0)
        core = mask.astype(np.float32) / 255.0
        prof = np.maximum(core, 0.5 * cv2.GaussianBlur(core, (3, 3), 0.8))
        img *= 1.0 - depth * prof
    if noise_sigma > 0:
        img += g.standard_normal((h, w), dtype=np.float32) * noise_sigma
    return np.clip(np.rint(img), 0, 255).astype(np.uint8), mask


def graded_crack_image(shape: tuple[int, int], rng: RngLike = None, widths_px: Any = ((1.0, 5.0),),
                       n_cracks: int | None = None, *, contrast: tuple[float, float] = (0.35, 0.6),
                       noise_sigma: float = 3.0, length_px: tuple[float, float] | None = None,
                       background: dict[str, float] | None = None) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
    """Like :func:`crack_image`, but main crack ``k`` takes its width range from ``widths_px[k % len]``.

    Real concrete cracks of a wall span classes (AASHTO MBEI: < 0.3 mm, 0.3-1.3 mm, > 1.3 mm); a
    width range per crack puts every class on one wall at known sizes. ``n_cracks`` defaults to one
    crack per range. Darkening, feather and noise are those of :func:`crack_image`.
    """
    h, w = _shape(shape)
    ranges = [_range("widths_px", r, lo=1.0, hi=255.0) for r in widths_px]
    if not ranges:
        raise ValueError("widths_px must hold at least one (min, max) range")
    n = len(ranges) if n_cracks is None else int(n_cracks)
    g = _rng(rng)
    img, mask = crack_image((h, w), g, 0, contrast=contrast, noise_sigma=0.0, background=background)
    for k in range(n):
        one = draw_cracks((h, w), g, 1, length_px=length_px, width_px=ranges[k % len(ranges)], branch_prob=0.005)
        mask |= one
    out = img.astype(np.float32)
    if mask.any():
        dmin, dmax = _range("contrast", contrast, lo=0.0, hi=1.0)
        depth = dmin + (dmax - dmin) * np.clip(0.5 + 0.35 * _value_noise(h, w, 40.0, g), 0.0, 1.0)
        core = mask.astype(np.float32) / 255.0
        out *= 1.0 - depth * np.maximum(core, 0.5 * cv2.GaussianBlur(core, (3, 3), 0.8))
    if noise_sigma > 0:
        out += g.standard_normal((h, w), dtype=np.float32) * noise_sigma
    return np.clip(np.rint(out), 0, 255).astype(np.uint8), mask


def surface_options(spec: Any) -> dict[str, Any]:
    """:class:`SyntheticSurface` keyword arguments from a scenario's ``[surface]`` table
    (:class:`protocol.scenario.Surface`: ``texture_mm``, ``crack_widths_mm``, ``crack_length_m``,
    ``cracks``); an empty dict keeps the defaults."""
    out: dict[str, Any] = {}
    tex = getattr(spec, "texture_mm", None)
    px_per_m = 1e3 / tex if tex else DEFAULT_PX_PER_M
    if tex:
        out["px_per_m"] = px_per_m
    widths = getattr(spec, "crack_widths_mm", None)
    if widths:
        out["crack_width_ranges_px"] = [(max(1.0, lo * 1e-3 * px_per_m), max(1.0, hi * 1e-3 * px_per_m))
                                        for lo, hi in widths]
    if getattr(spec, "crack_length_m", None) is not None:
        out["crack_length_m"] = tuple(spec.crack_length_m)
    if getattr(spec, "cracks", None) is not None:
        out["n_cracks"] = int(spec.cracks)
    return out


# ============================================================================ the wall in the world
@dataclass(frozen=True)
class SurfaceDefect:
    """One ground-truth crack of a :class:`SyntheticSurface`: an 8-connected component of its mask
    (``id`` stable per surface; ``*_uv`` in surface metres, ``bbox_px`` ``(x, y, w, h)`` in texture pixels)."""

    id: int
    centroid_uv: tuple[float, float]
    centroid_world: tuple[float, float, float]
    bbox_uv: tuple[float, float, float, float]
    area_px: int
    area_m2: float
    bbox_px: tuple[int, int, int, int] = (0, 0, 0, 0)


#: Alias: the name the assignment uses for a ground-truth crack component.
Defect = SurfaceDefect


class SyntheticSurface:
    """A planar, textured, cracked rectangle ``origin + u u_axis + v v_axis`` in the world (local ENU
    metres), with its ground truth; the coordinates and options are in docs/edge.md (edge/world/surface.py)."""

    MAX_PIXELS = 100_000_000

    def __init__(self, origin: ArrayLike, u_axis: ArrayLike, v_axis: ArrayLike, width_m: float, height_m: float,
                 px_per_m: float = DEFAULT_PX_PER_M, texture: NDArray[np.uint8] | None = None,
                 mask: NDArray[np.uint8] | None = None, seed: int = 0, *, cracks_per_m2: float = 1 / 12,
                 crack_length_m: tuple[float, float] = (0.8, 3.0), crack_width_px: tuple[float, float] = (2.0, 5.0),
                 contrast: tuple[float, float] = (0.35, 0.6), n_cracks: int | None = None,
                 crack_width_ranges_px: Any = None) -> None:
        o = _vec3("origin", origin)
        u = _vec3("u_axis", u_axis)
        v = _vec3("v_axis", v_axis)
        nu, nv = float(np.linalg.norm(u)), float(np.linalg.norm(v))
        if nu < 1e-9 or nv < 1e-9:
            raise ValueError("u_axis and v_axis must be non-zero")
        u, v = u / nu, v / nv
        if abs(float(u @ v)) > math.sin(math.radians(0.1)):
            ang = math.degrees(math.acos(float(np.clip(u @ v, -1.0, 1.0))))
            raise ValueError(f"u_axis and v_axis must be orthogonal, they make {ang:.3f} deg")
        width_m, height_m = _positive("width_m", width_m), _positive("height_m", height_m)
        px_per_m = _positive("px_per_m", px_per_m)
        w_px, h_px = int(round(width_m * px_per_m)), int(round(height_m * px_per_m))
        if w_px < 1 or h_px < 1:
            raise ValueError(f"the surface is smaller than one pixel at {px_per_m:g} px/m")
        if w_px * h_px > self.MAX_PIXELS:
            raise ValueError(f"texture of {w_px} x {h_px} px = {w_px * h_px / 1e6:.0f} MP exceeds "
                             f"{self.MAX_PIXELS / 1e6:.0f} MP: lower px_per_m")
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
            raise ValueError(f"seed must be an integer, got {seed!r}")
        self.origin, self.u_axis, self.v_axis = o, u, v
        self.width_m, self.height_m, self.px_per_m, self.seed = width_m, height_m, px_per_m, int(seed)
        if texture is None and mask is None:
            if not (math.isfinite(cracks_per_m2) and cracks_per_m2 >= 0):
                raise ValueError(f"cracks_per_m2 must be finite and >= 0, got {cracks_per_m2!r}")
            lo, hi = _range("crack_length_m", crack_length_m, lo=0.0)
            if n_cracks is None:
                n_cracks = max(1, int(round(width_m * height_m * cracks_per_m2)))
            rng, length_px = np.random.default_rng(self.seed), (max(1.0, lo * px_per_m), max(1.0, hi * px_per_m))
            if crack_width_ranges_px:  # real-size cracks: a width range per crack (graded_crack_image)
                blotches = min(1.0, (DEFAULT_PX_PER_M / px_per_m) ** 2)  # stains per m² as on the default wall
                texture, mask = graded_crack_image((h_px, w_px), rng, crack_width_ranges_px, n_cracks,
                                                   length_px=length_px, contrast=contrast,
                                                   background={"blotches": blotches})
            else:
                texture, mask = crack_image((h_px, w_px), rng, n_cracks, length_px=length_px, width_px=crack_width_px,
                                            contrast=contrast)
        elif texture is None or mask is None:
            raise ValueError("give both texture and mask, or neither")
        for name, img in (("texture", texture), ("mask", mask)):
            if not (isinstance(img, np.ndarray) and img.dtype == np.uint8 and img.shape == (h_px, w_px)):
                raise ValueError(f"{name} must be a uint8 array of shape {(h_px, w_px)}")
        self.texture: NDArray[np.uint8] = texture
        self.mask: NDArray[np.uint8] = np.where(mask > 0, 255, 0).astype(np.uint8)
        self._defects: dict[int, list[SurfaceDefect]] = {}

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_corners(cls, corners: ArrayLike, px_per_m: float = DEFAULT_PX_PER_M, seed: int = 0,
                     **kwargs: Any) -> SyntheticSurface:
        """Build a surface on 2, 3 or 4 corner points (ENU metres): ``p0, p1, p2, p3`` around the rectangle
        (the scenario's ``surface.corners``), ``p0, p1, p3``, or opposite corners ``p0, p2`` (a vertical wall
        if their heights differ, else a deck facing up); the rules are in docs/edge.md."""
        p = np.asarray(corners, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3 or not 2 <= p.shape[0] <= 4 or not np.all(np.isfinite(p)):
            raise ValueError(f"corners must be 2 to 4 finite [x, y, z] points, got shape {p.shape}")
        if p.shape[0] == 2:
            p0, p2 = p
            dz = float(p2[2] - p0[2])
            horiz = p2[:2] - p0[:2]
            if abs(dz) > 1e-9:  # vertical wall
                w = float(np.linalg.norm(horiz))
                if w < 1e-9:
                    raise ValueError("the two corners of a wall must differ horizontally")
                u = np.array([horiz[0] / w, horiz[1] / w, 0.0])
                origin = np.array([p0[0], p0[1], min(p0[2], p2[2])])  # the bottom edge, whichever corner is lower
                return cls(origin, u, (0.0, 0.0, 1.0), w, abs(dz), px_per_m, seed=seed, **kwargs)
            lo, hi = np.minimum(p0, p2), np.maximum(p0, p2)
            w, h = float(hi[0] - lo[0]), float(hi[1] - lo[1])
            if w < 1e-9 or h < 1e-9:
                raise ValueError("the two corners of a horizontal surface must differ in x and in y")
            return cls(np.array([lo[0], lo[1], p0[2]]), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), w, h,
                       px_per_m, seed=seed, **kwargs)
        p0, eu, ev = p[0], p[1] - p[0], p[-1] - p[0]
        w, h = float(np.linalg.norm(eu)), float(np.linalg.norm(ev))
        if w < 1e-9 or h < 1e-9:
            raise ValueError("corners are degenerate (repeated points)")
        if abs(float(eu @ ev)) > math.sin(math.radians(0.1)) * w * h:
            raise ValueError("corners do not make a right angle at p0")
        if p.shape[0] == 4 and np.linalg.norm(p[2] - (p[1] + p[3] - p0)) > 0.01 * max(w, h):
            raise ValueError("the four corners are not a rectangle (p2 is off p1 + p3 - p0 by more than 1 %)")
        return cls(p0, eu, ev, w, h, px_per_m, seed=seed, **kwargs)

    # ------------------------------------------------------------------ geometry
    @property
    def normal(self) -> NDArray[np.float64]:
        """Unit normal of the front (inspected) side, ``u_axis x v_axis``."""
        n = np.cross(self.u_axis, self.v_axis)
        return n / np.linalg.norm(n)

    @property
    def shape_px(self) -> tuple[int, int]:
        """Texture shape ``(height, width)`` in pixels."""
        return int(self.texture.shape[0]), int(self.texture.shape[1])

    @property
    def corners(self) -> NDArray[np.float64]:
        """The four world corners (4, 3): p0, p1 = p0 + u, p2, p3 = p0 + v."""
        u, v = self.u_axis * self.width_m, self.v_axis * self.height_m
        return np.array([self.origin, self.origin + u, self.origin + u + v, self.origin + v])

    @property
    def center(self) -> NDArray[np.float64]:
        """Centre of the rectangle, ENU metres."""
        return self.origin + 0.5 * (self.u_axis * self.width_m + self.v_axis * self.height_m)

    @staticmethod
    def _points(name: str, points: ArrayLike, dim: int) -> NDArray[np.float64]:
        a = np.asarray(points, dtype=np.float64)
        if a.ndim == 0 or a.shape[-1] != dim:
            raise ValueError(f"{name} must have shape (..., {dim}), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name} must be finite")
        return a

    def world_to_surface(self, points: ArrayLike) -> NDArray[np.float64]:
        """World points (..., 3) projected onto the plane: surface coordinates (..., 2), metres."""
        d = self._points("points", points, 3) - self.origin
        return np.stack([d @ self.u_axis, d @ self.v_axis], axis=-1)

    def distance_to_plane(self, points: ArrayLike) -> NDArray[np.float64]:
        """Signed distance (...,) of world points (..., 3) to the plane, positive in front."""
        return (self._points("points", points, 3) - self.origin) @ self.normal

    def surface_to_world(self, uv: ArrayLike) -> NDArray[np.float64]:
        """Surface coordinates (..., 2), metres -> world points (..., 3) on the plane."""
        a = self._points("uv", uv, 2)
        return self.origin + a[..., :1] * self.u_axis + a[..., 1:2] * self.v_axis

    def surface_to_pixel(self, uv: ArrayLike) -> NDArray[np.float64]:
        """Surface coordinates (..., 2), metres -> texture pixel coordinates ``(column, row)`` (..., 2)."""
        a = self._points("uv", uv, 2)
        return np.stack([a[..., 0] * self.px_per_m - 0.5, (self.height_m - a[..., 1]) * self.px_per_m - 0.5], -1)

    def pixel_to_surface(self, xy: ArrayLike) -> NDArray[np.float64]:
        """Texture pixel coordinates ``(column, row)`` (..., 2) -> surface coordinates (..., 2), metres."""
        a = self._points("xy", xy, 2)
        return np.stack([(a[..., 0] + 0.5) / self.px_per_m, self.height_m - (a[..., 1] + 0.5) / self.px_per_m], -1)

    def pixel_to_world_matrix(self) -> NDArray[np.float64]:
        """The (3, 3) ``A`` with ``X = A [column, row, 1]^T``: texture pixel -> ENU point.

        The camera's plane-to-image homography is ``K R^T (A - C e3^T)`` (see
        :class:`edge.world.camera.SyntheticSource`).
        """
        s = 1.0 / self.px_per_m
        return np.column_stack([self.u_axis * s, -self.v_axis * s,
                                self.origin + self.v_axis * (self.height_m - 0.5 * s) + self.u_axis * 0.5 * s])

    def contains(self, uv: ArrayLike) -> NDArray[np.bool_]:
        """Whether surface coordinates (..., 2) lie on the rectangle (edges included)."""
        a = self._points("uv", uv, 2)
        return (a[..., 0] >= 0) & (a[..., 0] <= self.width_m) & (a[..., 1] >= 0) & (a[..., 1] <= self.height_m)

    def is_crack(self, uv: ArrayLike) -> NDArray[np.bool_]:
        """Ground truth at surface coordinates (..., 2): True on a crack pixel, False elsewhere
        (and off the surface)."""
        a = self._points("uv", uv, 2)
        col = np.floor(a[..., 0] * self.px_per_m).astype(np.int64)
        row = np.floor((self.height_m - a[..., 1]) * self.px_per_m).astype(np.int64)
        h, w = self.shape_px
        ok = (col >= 0) & (col < w) & (row >= 0) & (row < h)
        out = np.zeros(a.shape[:-1], dtype=bool)
        out[ok] = self.mask[row[ok], col[ok]] > 0
        return out

    # ------------------------------------------------------------------ ground truth
    def defects(self, min_area_px: int = 20) -> list[SurfaceDefect]:
        """The ground-truth cracks: 8-connected components of the mask of at least ``min_area_px`` texture
        pixels, cached; the report matches detections against them ((P20))."""
        if isinstance(min_area_px, bool) or not isinstance(min_area_px, (int, np.integer)) or min_area_px < 0:
            raise ValueError(f"min_area_px must be an integer >= 0, got {min_area_px!r}")
        key = int(min_area_px)
        if key not in self._defects:
            n, _, stats, cents = cv2.connectedComponentsWithStats(self.mask, connectivity=8)
            s = 1.0 / self.px_per_m
            out: list[SurfaceDefect] = []
            for i in range(1, n):
                x, y, w, h, area = (int(t) for t in stats[i, :5])
                if area < key:
                    continue
                cu, cv_ = self.pixel_to_surface(cents[i])
                world = self.surface_to_world(np.array([cu, cv_]))
                out.append(SurfaceDefect(
                    id=len(out), centroid_uv=(float(cu), float(cv_)),
                    centroid_world=(float(world[0]), float(world[1]), float(world[2])),
                    bbox_uv=(x * s, self.height_m - (y + h) * s, (x + w) * s, self.height_m - y * s), area_px=area,
                    area_m2=area * s * s, bbox_px=(x, y, w, h)))
            self._defects[key] = out
        return list(self._defects[key])

    def __repr__(self) -> str:
        h, w = self.shape_px
        return (f"SyntheticSurface(origin={self.origin.round(3).tolist()}, u={self.u_axis.round(6).tolist()}, "
                f"v={self.v_axis.round(6).tolist()}, {self.width_m:g} m x {self.height_m:g} m, "
                f"{self.px_per_m:g} px/m = {w}x{h} px, seed={self.seed})")
