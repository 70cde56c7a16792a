"""Synthetic inspected surface: concrete-like texture with procedurally drawn cracks.

The paper's detector (Section 6, (P18)-(P20)) works on grey-scale images of a surface whose
defects are "abnormal, darker pixel groups on a repetitive background". This module makes such
images with a *known* ground-truth mask, so that the detector can be scored (P20) and a whole
mission can be scored against the defects that are really on the wall.

Three plain generators work on image-sized arrays:

- :func:`textured_background` -- concrete-like grey texture (multi-scale value noise, blotches,
  a mild illumination gradient, grain);
- :func:`draw_cracks` -- binary crack mask (random-walk polylines with smoothly varying
  direction and width, occasional branches);
- :func:`crack_image` -- the two combined: background darkened under the mask.

:class:`SyntheticSurface` places such a texture on a planar rectangle in the world (local ENU
metres), so that :mod:`edge.camera` can render the view of it from any camera pose, and lists
its ground-truth defects (:meth:`SyntheticSurface.defects`) in surface and world coordinates.

All randomness comes from a ``numpy.random.Generator`` (or an integer seed), so the same seed
gives the same image, bit for bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "textured_background",
    "draw_cracks",
    "crack_image",
    "Defect",
    "SyntheticSurface",
    "DEFAULT_PX_PER_M",
    "SurfaceDefect",
    "SyntheticSurface",
]

#: Default texture resolution of :class:`SyntheticSurface`: 100 px/m, i.e. 1 cm per texture
#: pixel. A 60 m x 20 m wall is then 6000 x 2000 px = 12 MP (12 MB for the texture, 12 MB for
#: the mask), and cracks drawn 1..5 px wide are 1..5 mm wide -- the range of hairline to
#: structural cracks in concrete. A camera frame of 640 px across at the (P2) inspection
#: distance for a 1 cm feature (footprint 3.2 m) samples the texture at about 1:2.
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
    return out


def textured_background(
    shape: tuple[int, int],
    rng: RngLike = None,
    *,
    mean: float = 140.0,
    roughness: float = 14.0,
    blotches: float = 1.0,
    gradient: float = 0.12,
    grain: float = 4.0,
) -> NDArray[np.uint8]:
    """Concrete-like grey texture.

    The intensity is ``mean`` times an illumination ramp, plus value noise at four scales
    (2, 6, 24 and 96 px cells, amplitudes falling with scale), plus a few soft blotches (stains
    and patches, darker or lighter), plus per-pixel grain. Everything is made from small noise
    fields enlarged with ``cv2.resize`` and blurred with ``cv2.GaussianBlur``, so a 12 MP
    texture takes well under a second.

    Parameters
    ----------
    shape : (int, int)
        ``(height, width)`` in pixels.
    rng : numpy.random.Generator, int or None
        Source of randomness (an int is a seed; None is unseeded).
    mean : float
        Mean grey level, 0..255. Default 140 (mid-grey concrete; CrackForest's pavement
        backgrounds measure 128..140).
    roughness : float
        Standard deviation, in grey levels, of the multi-scale noise. Default 14.
    blotches : float
        Density of blotches relative to one per 200 x 200 px; 0 disables them.
    gradient : float
        Peak-to-peak illumination change across the image, as a fraction of ``mean``
        (direction random). Default 0.12.
    grain : float
        Standard deviation of the per-pixel grain, in grey levels. Default 4.

    Returns
    -------
    numpy.ndarray
        ``uint8`` array of ``shape``.

    Raises
    ------
    ValueError
        On a bad shape or a non-finite/negative parameter.
    """
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
    img = np.zeros((h, w), np.float32)
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
        canvas = cv2.GaussianBlur(canvas, (0, 0), 2.0)
        img += cv2.resize(canvas, (w, h), interpolation=cv2.INTER_LINEAR)

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


def _walk_crack(
    mask: NDArray[np.uint8],
    g: np.random.Generator,
    start: tuple[float, float],
    heading: float,
    length: float,
    width: tuple[float, float],
    branch_prob: float,
    depth: int,
) -> None:
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
            _walk_crack(
                mask, g, (float(pts[k, 0]), float(pts[k, 1])),
                heading_k[k] + side * g.uniform(0.35, 1.0),
                length * g.uniform(0.15, 0.45),
                (wmin, max(wmin, min(wmax, widths[k]))),
                branch_prob * 0.5, depth - 1,
            )


def draw_cracks(
    shape: tuple[int, int],
    rng: RngLike = None,
    n_cracks: int = 3,
    *,
    length_px: tuple[float, float] | None = None,
    width_px: tuple[float, float] = (1.0, 5.0),
    branch_prob: float = 0.015,
) -> NDArray[np.uint8]:
    """Procedural crack mask: random-walk polylines with occasional branches.

    Each crack starts at a random point with a random heading and walks in 3 px steps; its
    heading changes smoothly (curvature follows an AR(1) process, plus a little jitter for a
    jagged edge), its width varies smoothly within ``width_px`` and tapers at both ends. At each
    step a crack may fork (probability ``branch_prob``) into a shorter, thinner branch leaving
    at 20..57 degrees; branches fork again at half the rate, two levels deep at most. Segments
    are drawn with ``cv2.line`` (8-connected, no anti-aliasing), so the mask is exactly binary.

    Parameters
    ----------
    shape : (int, int)
        ``(height, width)`` in pixels.
    rng : numpy.random.Generator, int or None
        Source of randomness.
    n_cracks : int
        Number of main cracks (branches come on top). 0 gives an empty mask.
    length_px : (float, float) or None
        Range of main-crack lengths in pixels; default ``(0.25, 0.75) * hypot(h, w)``.
    width_px : (float, float)
        Range of crack widths in pixels, ``1 <= min <= max``. Default ``(1, 5)``.
    branch_prob : float
        Probability, per 3 px step, that a crack forks. Default 0.015.

    Returns
    -------
    numpy.ndarray
        ``uint8`` mask of ``shape``, 255 on cracks and 0 elsewhere.
    """
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


def crack_image(
    shape: tuple[int, int] = (480, 640),
    rng: RngLike = None,
    n_cracks: int = 3,
    *,
    contrast: tuple[float, float] = (0.25, 0.55),
    noise_sigma: float = 3.0,
    length_px: tuple[float, float] | None = None,
    width_px: tuple[float, float] = (1.0, 5.0),
    background: dict[str, float] | None = None,
) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
    """Grey image of a cracked concrete-like surface and its ground-truth mask.

    The background (:func:`textured_background`) is darkened under the crack mask
    (:func:`draw_cracks`) by a relative depth that varies smoothly along the cracks within
    ``contrast`` -- a crack pixel is ``(1 - depth)`` times the background there, e.g. 25-55 %
    darker. (CrackForest's cracks, for comparison, are about 20-25 % darker than their
    surroundings with a background std of 9-14 grey levels.) Pixels next to a crack are
    darkened a little by a one-pixel feather, so edges are not perfectly crisp, but the mask
    stays the set of pixels drawn as crack. Finally Gaussian sensor noise is added.

    Cracks are therefore "abnormal, darker pixel groups on a repetitive background", the
    defect model of the paper's detector ((P18)-(P19)).

    Parameters
    ----------
    shape : (int, int)
        ``(height, width)`` in pixels. Default ``(480, 640)``.
    rng : numpy.random.Generator, int or None
        Source of randomness; the same seed gives the same image and mask.
    n_cracks : int
        Number of main cracks.
    contrast : (float, float)
        Range of the relative darkening of crack pixels, ``0 <= min <= max <= 1``.
    noise_sigma : float
        Standard deviation of the additive noise, grey levels.
    length_px, width_px
        Passed to :func:`draw_cracks`.
    background : dict, optional
        Keyword arguments for :func:`textured_background`.

    Returns
    -------
    grey : numpy.ndarray
        ``uint8`` image of ``shape``.
    mask : numpy.ndarray
        ``uint8`` mask of ``shape``, 255 on cracks, 0 elsewhere.

    Examples
    --------
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


# ============================================================================ the wall in the world
@dataclass(frozen=True)
class SurfaceDefect:
    """One ground-truth crack (a connected component of the surface mask)."""

    id: int
    centroid_uv: tuple[float, float]  # surface metres: u along the bottom edge, v up
    centroid_world: tuple[float, float, float]  # ENU metres
    bbox_uv: tuple[float, float, float, float]  # u0, v0, u1, v1, metres
    area_px: int
    area_m2: float


@dataclass
class SyntheticSurface:
    """A planar, textured, cracked rectangle in the world (local ENU metres).

    Surface coordinates ``(u, v)`` in metres: ``u`` along the bottom edge from ``origin``
    (corner p0 towards p1), ``v`` up the wall (p0 towards p3). The texture is an image whose
    column ``c`` is ``u = (c + 0.5) / px_per_m`` and whose row ``r`` is
    ``v = height_m - (r + 0.5) / px_per_m`` (row 0 is the top of the wall, so the texture looks
    upright). :attr:`normal` ``= u x v`` points to the side the wall is inspected from.
    """

    origin: NDArray[np.float64]
    u_axis: NDArray[np.float64]
    v_axis: NDArray[np.float64]
    width_m: float
    height_m: float
    px_per_m: float
    texture: NDArray[np.uint8]
    mask: NDArray[np.uint8]
    seed: int = 0
    _defects: list[SurfaceDefect] | None = field(default=None, repr=False)

    @classmethod
    def from_corners(cls, corners: ArrayLike, px_per_m: float = DEFAULT_PX_PER_M, seed: int = 0,
                     cracks_per_m2: float = 1 / 12, crack_length_m: tuple[float, float] = (0.8, 3.0),
                     crack_width_px: tuple[float, float] = (2.0, 5.0)) -> "SyntheticSurface":
        """A wall on the rectangle ``corners`` (4, 3): p0, p1 (bottom edge), p2, p3 (p3 above p0).

        About one crack per ``1 / cracks_per_m2`` square metres, lengths in ``crack_length_m``.
        """
        c = np.asarray(corners, dtype=float)
        if c.shape != (4, 3) or not np.all(np.isfinite(c)):
            raise ValueError("corners must be 4 finite points (4, 3)")
        if not (math.isfinite(px_per_m) and 1.0 <= px_per_m <= 2000.0):
            raise ValueError("px_per_m must be in [1, 2000]")
        du, dv = c[1] - c[0], c[3] - c[0]
        width, height = float(np.linalg.norm(du)), float(np.linalg.norm(dv))
        if width < 0.1 or height < 0.1 or abs(float(np.dot(du, dv))) > 1e-6 * width * height:
            raise ValueError("corners must form a rectangle at least 0.1 m on each side")
        w_px, h_px = int(round(width * px_per_m)), int(round(height * px_per_m))
        if w_px * h_px > 200_000_000:
            raise ValueError(f"texture of {w_px}x{h_px} px is too large; lower px_per_m")
        g = np.random.default_rng(seed)
        n = max(1, int(round(width * height * cracks_per_m2)))
        lo, hi = (float(x) * px_per_m for x in crack_length_m)
        grey, mask = crack_image((h_px, w_px), g, n, length_px=(lo, hi), width_px=crack_width_px,
                                 contrast=(0.35, 0.6))
        return cls(c[0].copy(), du / width, dv / height, width, height, float(px_per_m), grey, mask, seed)

    @property
    def normal(self) -> NDArray[np.float64]:
        n = np.cross(self.u_axis, self.v_axis)
        return n / np.linalg.norm(n)

    @property
    def corners(self) -> NDArray[np.float64]:
        u, v = self.u_axis * self.width_m, self.v_axis * self.height_m
        return np.array([self.origin, self.origin + u, self.origin + u + v, self.origin + v])

    def world_to_surface(self, points: ArrayLike) -> NDArray[np.float64]:
        """(N, 3) ENU points -> (N, 2) surface coordinates (projected onto the plane)."""
        d = np.atleast_2d(np.asarray(points, dtype=float)) - self.origin
        return np.column_stack([d @ self.u_axis, d @ self.v_axis])

    def surface_to_world(self, uv: ArrayLike) -> NDArray[np.float64]:
        uv = np.atleast_2d(np.asarray(uv, dtype=float))
        return self.origin + uv[:, :1] * self.u_axis + uv[:, 1:2] * self.v_axis

    def surface_to_pixel(self, uv: ArrayLike) -> NDArray[np.float64]:
        """(N, 2) surface metres -> (N, 2) texture pixel coordinates (column, row), continuous."""
        uv = np.atleast_2d(np.asarray(uv, dtype=float))
        return np.column_stack([uv[:, 0] * self.px_per_m - 0.5, (self.height_m - uv[:, 1]) * self.px_per_m - 0.5])

    def pixel_to_world_matrix(self) -> NDArray[np.float64]:
        """A (3, 3) with ``X = A [c, r, 1]^T``: texture pixel (column, row) -> ENU point."""
        s = 1.0 / self.px_per_m
        return np.column_stack([self.u_axis * s, -self.v_axis * s,
                                self.origin + self.v_axis * (self.height_m - 0.5 * s) + self.u_axis * 0.5 * s])

    def defects(self, min_area_px: int = 20) -> list[SurfaceDefect]:
        """The ground-truth cracks: connected components of the mask (8-connected)."""
        if self._defects is None:
            n, _, stats, cents = cv2.connectedComponentsWithStats((self.mask > 0).astype(np.uint8), connectivity=8)
            out = []
            s = 1.0 / self.px_per_m
            for i in range(1, n):
                area = int(stats[i, cv2.CC_STAT_AREA])
                if area < min_area_px:
                    continue
                x, y, w, h = (int(v) for v in stats[i, :4])
                cu, cv_ = (cents[i, 0] + 0.5) * s, self.height_m - (cents[i, 1] + 0.5) * s
                world = self.surface_to_world([[cu, cv_]])[0]
                out.append(SurfaceDefect(len(out), (float(cu), float(cv_)), tuple(float(v) for v in world),
                                         (x * s, self.height_m - (y + h) * s, (x + w) * s, self.height_m - y * s),
                                         area, area * s * s))
            object.__setattr__(self, "_defects", out)
        return list(self._defects)


# ------------------------------------------------------------------ the surface in the world
@dataclass(frozen=True)
class Defect:
    """One ground-truth crack component of a :class:`SyntheticSurface`.

    A component is an 8-connected set of crack pixels of the surface mask: a crack with its
    branches, or several cracks that cross.

    Attributes
    ----------
    label : int
        Component number, 1-based, stable for a given surface.
    centroid_uv : numpy.ndarray
        Centroid ``(u, v)`` on the surface, metres.
    centroid_enu : numpy.ndarray
        The same point in the world, local ENU metres.
    bbox_uv : tuple of float
        ``(u_min, v_min, u_max, v_max)`` on the surface, metres (pixel edges included).
    bbox_px : tuple of int
        ``(x, y, w, h)`` in texture pixels.
    area_px : int
        Number of crack pixels.
    area_m2 : float
        Crack area, square metres.
    """

    label: int
    centroid_uv: NDArray[np.float64]
    centroid_enu: NDArray[np.float64]
    bbox_uv: tuple[float, float, float, float]
    bbox_px: tuple[int, int, int, int]
    area_px: int
    area_m2: float


def _vec3(name: str, value: ArrayLike) -> NDArray[np.float64]:
    a = np.asarray(value, dtype=np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be a finite 3-vector, got {value!r}")
    return a


class SyntheticSurface:
    """A planar rectangular surface in the world, textured like concrete, with known cracks.

    Geometry: the rectangle spans ``origin + u * u_axis + v * v_axis`` for ``0 <= u <=
    width_m`` and ``0 <= v <= height_m`` (local ENU metres). ``u_axis`` and ``v_axis`` are
    orthonormal. The texture is an image whose column grows with ``u`` and row with ``v``, so
    a wall made by :meth:`from_corners` (``u`` horizontal, ``v`` pointing down) reads like a
    photograph of the wall taken from the front. The front is the side :attr:`normal` points
    to: a camera there, with its x axis along ``u_axis`` and its y axis along ``v_axis``, sees
    the texture unmirrored.

    Pixel convention (as OpenCV): texture pixel ``(col, row)`` covers ``u`` in
    ``[col, col + 1) / px_per_m`` and its centre is at integer coordinates, so
    ``x = u * px_per_m - 0.5``, ``y = v * px_per_m - 0.5``.

    Parameters
    ----------
    origin, u_axis, v_axis : array_like, shape (3,)
        Corner of texture pixel (0, 0) and the two in-plane axes (normalised here; they must be
        orthogonal to within 0.1 degree).
    width_m, height_m : float
        Extent along ``u_axis`` and ``v_axis``, metres.
    px_per_m : float
        Texture resolution; default :data:`DEFAULT_PX_PER_M` (100 px/m, 1 cm per pixel). The
        texture may not exceed 100 MP (a 60 m x 20 m wall at 100 px/m is 12 MP).
    seed : int
        Seed of the texture and the cracks.
    n_cracks : int, optional
        Number of main cracks; default ``max(1, round(crack_density * area))``.
    crack_density : float
        Main cracks per square metre when ``n_cracks`` is not given. Default 0.05 (60 cracks
        on a 60 m x 20 m wall: about one per 4.5 m x 4.5 m patch).
    crack_length_m : (float, float)
        Range of main-crack lengths, metres. Default 0.3..2.5 m.
    crack_width_px : (float, float)
        Range of crack widths in texture pixels (1..5 px = 1..5 mm at 100 px/m).
    contrast : (float, float)
        Relative darkening of crack pixels, see :func:`crack_image`.
    """

    MAX_PIXELS = 100_000_000

    def __init__(
        self,
        origin: ArrayLike,
        u_axis: ArrayLike,
        v_axis: ArrayLike,
        width_m: float,
        height_m: float,
        *,
        px_per_m: float = DEFAULT_PX_PER_M,
        seed: int = 0,
        n_cracks: int | None = None,
        crack_density: float = 0.05,
        crack_length_m: tuple[float, float] = (0.3, 2.5),
        crack_width_px: tuple[float, float] = (1.0, 5.0),
        contrast: tuple[float, float] = (0.25, 0.55),
    ) -> None:
        o = _vec3("origin", origin)
        u = _vec3("u_axis", u_axis)
        v = _vec3("v_axis", v_axis)
        nu, nv = float(np.linalg.norm(u)), float(np.linalg.norm(v))
        if nu < 1e-9 or nv < 1e-9:
            raise ValueError("u_axis and v_axis must be non-zero")
        u, v = u / nu, v / nv
        if abs(float(u @ v)) > math.sin(math.radians(0.1)):
            raise ValueError(f"u_axis and v_axis must be orthogonal, angle {math.degrees(math.acos(np.clip(u @ v, -1, 1))):.3f} deg")
        for name, val in (("width_m", width_m), ("height_m", height_m), ("px_per_m", px_per_m)):
            if not (isinstance(val, (int, float, np.floating, np.integer)) and math.isfinite(val) and val > 0):
                raise ValueError(f"{name} must be finite and > 0, got {val!r}")
        w_px = int(round(float(width_m) * px_per_m))
        h_px = int(round(float(height_m) * px_per_m))
        if w_px < 1 or h_px < 1:
            raise ValueError(f"surface is smaller than one pixel at {px_per_m} px/m")
        if w_px * h_px > self.MAX_PIXELS:
            raise ValueError(
                f"texture would be {w_px} x {h_px} px = {w_px * h_px / 1e6:.0f} MP > "
                f"{self.MAX_PIXELS / 1e6:.0f} MP: lower px_per_m"
            )
        if not (math.isfinite(crack_density) and crack_density >= 0):
            raise ValueError(f"crack_density must be finite and >= 0, got {crack_density!r}")
        lo_m, hi_m = _range("crack_length_m", crack_length_m, lo=0.0)
        if n_cracks is None:
            n_cracks = max(1, int(round(crack_density * float(width_m) * float(height_m))))

        self.origin = o
        self.u_axis = u
        self.v_axis = v
        self.width_m = float(width_m)
        self.height_m = float(height_m)
        self.px_per_m = float(px_per_m)
        self.seed = int(seed)
        self.n_cracks = int(n_cracks)
        self.texture, self.mask = crack_image(
            (h_px, w_px),
            np.random.default_rng(self.seed),
            self.n_cracks,
            contrast=contrast,
            length_px=(max(1.0, lo_m * px_per_m), max(1.0, hi_m * px_per_m)),
            width_px=crack_width_px,
        )
        self._defects: list[Defect] | None = None

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_corners(
        cls, corners: ArrayLike, px_per_m: float = DEFAULT_PX_PER_M, seed: int = 0, **kwargs: Any
    ) -> "SyntheticSurface":
        """Build a surface from 2, 3 or 4 corner points (ENU metres, rows of an array).

        - **2 points**, opposite corners. If their heights differ, a vertical wall: ``u`` is
          the horizontal direction from point 0 to point 1, ``v`` points straight down, the
          origin is point 0's top corner, and the front faces the right-hand side of someone
          walking from point 0 to point 1. If their heights are equal, a horizontal,
          axis-aligned deck seen from above: ``u`` east, ``v`` south, origin the north-west
          corner.
        - **3 points**: the origin, the end of the ``u`` edge, the end of the ``v`` edge.
        - **4 points**, in order around the rectangle: origin, end of ``u`` edge, opposite
          corner, end of ``v`` edge; the opposite corner must close the rectangle to 1 %.

        Other keyword arguments go to the constructor.

        Raises
        ------
        ValueError
            On non-finite points, degenerate or non-rectangular corners.
        """
        p = np.asarray(corners, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3 or not 2 <= p.shape[0] <= 4 or not np.all(np.isfinite(p)):
            raise ValueError(f"corners must be a finite (2..4, 3) array, got shape {p.shape}")
        if p.shape[0] == 2:
            p0, p1 = p
            dz = p1[2] - p0[2]
            horiz = p1[:2] - p0[:2]
            if abs(dz) > 1e-9:
                wh = float(np.linalg.norm(horiz))
                if wh < 1e-9:
                    raise ValueError("the two corners of a wall must differ horizontally")
                u = np.array([horiz[0] / wh, horiz[1] / wh, 0.0])
                origin = np.array([p0[0], p0[1], max(p0[2], p1[2])])
                return cls(origin, u, (0.0, 0.0, -1.0), wh, abs(dz), px_per_m=px_per_m, seed=seed, **kwargs)
            lo, hi = np.minimum(p0, p1), np.maximum(p0, p1)
            w, h = hi[0] - lo[0], hi[1] - lo[1]
            if w < 1e-9 or h < 1e-9:
                raise ValueError("the two corners of a horizontal surface must differ in x and in y")
            origin = np.array([lo[0], hi[1], p0[2]])
            return cls(origin, (1.0, 0.0, 0.0), (0.0, -1.0, 0.0), w, h, px_per_m=px_per_m, seed=seed, **kwargs)
        p0 = p[0]
        eu = p[1] - p0
        ev = p[-1] - p0
        w, h = float(np.linalg.norm(eu)), float(np.linalg.norm(ev))
        if w < 1e-9 or h < 1e-9:
            raise ValueError("corners are degenerate (repeated points)")
        if abs(float(eu @ ev)) / (w * h) > math.sin(math.radians(0.1)):
            raise ValueError("corners do not make a right angle at the origin")
        if p.shape[0] == 4 and np.linalg.norm(p[2] - (p[1] + p[3] - p0)) > 0.01 * max(w, h):
            raise ValueError("the four corners are not a rectangle (third corner off by > 1 %)")
        return cls(p0, eu, ev, w, h, px_per_m=px_per_m, seed=seed, **kwargs)

    # ------------------------------------------------------------------ geometry
    @property
    def normal(self) -> NDArray[np.float64]:
        """Unit normal of the front side, ``v_axis x u_axis`` (points towards the viewer)."""
        return np.cross(self.v_axis, self.u_axis)

    @property
    def shape_px(self) -> tuple[int, int]:
        """Texture shape ``(height, width)`` in pixels."""
        return self.texture.shape[0], self.texture.shape[1]

    @property
    def corners(self) -> NDArray[np.float64]:
        """The four world corners, (4, 3): origin, +u, +u+v, +v."""
        uv = np.array([[0, 0], [self.width_m, 0], [self.width_m, self.height_m], [0, self.height_m]])
        return self.surface_to_world(uv)

    @property
    def center(self) -> NDArray[np.float64]:
        """Centre of the rectangle, world ENU metres."""
        return self.surface_to_world(np.array([self.width_m / 2, self.height_m / 2]))

    @staticmethod
    def _points(name: str, points: ArrayLike, dim: int) -> NDArray[np.float64]:
        a = np.asarray(points, dtype=np.float64)
        if a.ndim == 0 or a.shape[-1] != dim:
            raise ValueError(f"{name} must have shape (..., {dim}), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name} must be finite")
        return a

    def world_to_surface(self, points: ArrayLike) -> NDArray[np.float64]:
        """Project world points (..., 3) onto the plane: surface coordinates (..., 2), metres."""
        d = self._points("points", points, 3) - self.origin
        return np.stack([d @ self.u_axis, d @ self.v_axis], axis=-1)

    def distance_to_plane(self, points: ArrayLike) -> NDArray[np.float64]:
        """Signed distance (..., ) of world points from the plane, positive on the front side."""
        return (self._points("points", points, 3) - self.origin) @ self.normal

    def surface_to_world(self, uv: ArrayLike) -> NDArray[np.float64]:
        """Surface coordinates (..., 2) metres -> world points (..., 3) on the plane."""
        a = self._points("uv", uv, 2)
        return self.origin + a[..., :1] * self.u_axis + a[..., 1:2] * self.v_axis

    def surface_to_pixel(self, uv: ArrayLike) -> NDArray[np.float64]:
        """Surface coordinates (..., 2) metres -> texture pixel coordinates ``(x, y)`` (..., 2)."""
        return self._points("uv", uv, 2) * self.px_per_m - 0.5

    def pixel_to_surface(self, xy: ArrayLike) -> NDArray[np.float64]:
        """Texture pixel coordinates ``(x, y)`` (..., 2) -> surface coordinates (..., 2) metres."""
        return (self._points("xy", xy, 2) + 0.5) / self.px_per_m

    def contains(self, uv: ArrayLike) -> NDArray[np.bool_]:
        """Whether surface coordinates (..., 2) lie on the rectangle."""
        a = self._points("uv", uv, 2)
        return (a[..., 0] >= 0) & (a[..., 0] <= self.width_m) & (a[..., 1] >= 0) & (a[..., 1] <= self.height_m)

    def is_crack(self, uv: ArrayLike) -> NDArray[np.bool_]:
        """Ground truth at surface coordinates (..., 2): True on a crack pixel (False off the surface)."""
        a = self._points("uv", uv, 2)
        col = np.floor(a[..., 0] * self.px_per_m).astype(np.int64)
        row = np.floor(a[..., 1] * self.px_per_m).astype(np.int64)
        h, w = self.shape_px
        ok = (col >= 0) & (col < w) & (row >= 0) & (row < h)
        out = np.zeros(a.shape[:-1], dtype=bool)
        out[ok] = self.mask[row[ok], col[ok]] > 0
        return out

    # ------------------------------------------------------------------ ground truth
    def defects(self) -> list[Defect]:
        """Ground-truth crack components (8-connected), in surface and world coordinates.

        Computed once with ``cv2.connectedComponentsWithStats`` and cached. A mission report
        can match detections mapped to surface coordinates against these to compute the
        system's recall and precision ((P20) at the defect level).
        """
        if self._defects is None:
            n, _, stats, cents = cv2.connectedComponentsWithStats(self.mask, connectivity=8)
            out: list[Defect] = []
            s = self.px_per_m
            for k in range(1, n):
                x, y, w, h, area = (int(t) for t in stats[k])
                c_uv = (cents[k] + 0.5) / s
                out.append(
                    Defect(
                        label=k,
                        centroid_uv=c_uv,
                        centroid_enu=self.surface_to_world(c_uv),
                        bbox_uv=(x / s, y / s, (x + w) / s, (y + h) / s),
                        bbox_px=(x, y, w, h),
                        area_px=area,
                        area_m2=area / s**2,
                    )
                )
            self._defects = out
        return list(self._defects)

    def __repr__(self) -> str:
        h, w = self.shape_px
        return (
            f"SyntheticSurface(origin={self.origin.tolist()}, u={self.u_axis.round(6).tolist()}, "
            f"v={self.v_axis.round(6).tolist()}, {self.width_m:g} m x {self.height_m:g} m, "
            f"{self.px_per_m:g} px/m -> {w}x{h} px, seed={self.seed}, n_cracks={self.n_cracks})"
        )
