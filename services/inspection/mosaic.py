"""A mosaic of the inspected surface from posed frames: each frame warped onto the surface plane.

Design notes: docs/report.md (services/inspection/mosaic.py).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from protocol.messages import ImageMeta
from protocol.scenario import surface_frame
from services.detector.exposure import exposure_problem

__all__ = ["Plane", "Mosaic", "PosedFrame", "alignment", "build_mosaic", "canvas_homography", "frame_gsd",
           "moved_camera", "plane_from_frames", "registration", "solve_shifts", "unusable_frames"]


@dataclass(frozen=True)
class Plane:
    """A rectangle of the world: ``origin + u u_axis + v v_axis``, ``0 <= u <= width_m``, ``0 <= v <= height_m``."""

    origin: NDArray[np.float64]
    u_axis: NDArray[np.float64]
    v_axis: NDArray[np.float64]
    width_m: float
    height_m: float

    @classmethod
    def from_corners(cls, corners: ArrayLike) -> Plane:
        """From the corners p0, p1, p2, p3 (p0-p1 the bottom edge, p3 above p0), ENU metres."""
        p0, u, v = surface_frame(corners)  # the one surface frame (protocol.scenario); ValueError when degenerate
        c = np.asarray(corners, float)
        return cls(p0.copy(), u, v, float((c[1] - p0) @ u), float((c[3] - p0) @ v))

    @property
    def normal(self) -> NDArray[np.float64]:
        return np.cross(self.u_axis, self.v_axis)

    @property
    def corners(self) -> NDArray[np.float64]:
        u, v = self.u_axis * self.width_m, self.v_axis * self.height_m
        return np.array([self.origin, self.origin + u, self.origin + u + v, self.origin + v])

    def to_world(self, uv: ArrayLike) -> NDArray[np.float64]:
        a = np.asarray(uv, float)
        return self.origin + a[..., :1] * self.u_axis + a[..., 1:2] * self.v_axis

    def to_uv(self, points: ArrayLike) -> NDArray[np.float64]:
        d = np.asarray(points, float) - self.origin
        return np.stack([d @ self.u_axis, d @ self.v_axis], axis=-1)


@dataclass(frozen=True)
class PosedFrame:
    """A grey frame with its pose and intrinsics (and optionally its defect mask)."""

    meta: ImageMeta
    grey: NDArray[np.uint8]
    mask: NDArray[np.uint8] | None = None


@dataclass
class Mosaic:
    """The surface seen by the frames: ``image`` (grey, 0 where no frame saw it), ``mask`` (defects),
    ``owner`` (index of the frame each pixel comes from, -1 for none), at ``m_per_px``."""

    plane: Plane
    m_per_px: float
    image: NDArray[np.uint8]
    mask: NDArray[np.uint8]
    owner: NDArray[np.int32]
    seconds: float = 0.0
    frames_used: int = 0
    skipped: list[str] = field(default_factory=list)
    #: each frame's move off its pose by the alignment, (u, v) metres along the surface (None: not placed);
    #: empty without an alignment
    shifts_m: list[tuple[float, float] | None] = field(default_factory=list)
    #: the frames that show no surface (index -> what is wrong, :func:`exposure_problem`): neither placed, nor
    #: aligned, nor counted in the coverage
    unusable: dict[int, str] = field(default_factory=dict)

    @property
    def moved_m(self) -> list[float]:
        """How far each placed frame was moved (metres)."""
        return [math.hypot(*d) for d in self.shifts_m if d is not None]

    @property
    def coverage(self) -> float:
        """Share of the surface seen by at least one frame."""
        return float(np.count_nonzero(self.owner >= 0)) / self.owner.size

    def pixel_to_uv(self, xy: ArrayLike) -> NDArray[np.float64]:
        a = np.asarray(xy, float)
        s = self.m_per_px
        return np.stack([(a[..., 0] + 0.5) * s, self.plane.height_m - (a[..., 1] + 0.5) * s], axis=-1)


def _meta_arrays(meta: ImageMeta) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    k = meta.intrinsics
    K = np.array([[k.fx, 0.0, k.cx], [0.0, k.fy, k.cy], [0.0, 0.0, 1.0]])
    return K, np.asarray(meta.cam_rot, float).reshape(3, 3), np.asarray(meta.cam_pos, float)


def moved_camera(meta: ImageMeta, plane: Plane, du: float, dv: float) -> ImageMeta:
    """``meta`` with its camera moved ``du``, ``dv`` metres along ``plane``'s axes: its frame's content moves as much
    on the surface (what the alignment does to a frame, :attr:`Mosaic.shifts_m`; a pose error along the wall)."""
    if du == 0.0 and dv == 0.0:
        return meta
    pos = np.asarray(meta.cam_pos, float) + du * plane.u_axis + dv * plane.v_axis
    return meta.model_copy(update={"cam_pos": (float(pos[0]), float(pos[1]), float(pos[2]))})


def canvas_homography(meta: ImageMeta, plane: Plane, m_per_px: float) -> NDArray[np.float64] | None:
    """Canvas pixel -> frame pixel homography ``K R^T (A − C e3^T)``; None if the camera is behind the plane."""
    K, R, C = _meta_arrays(meta)
    if float((C - plane.origin) @ plane.normal) <= 1e-9:
        return None
    s = m_per_px
    A = np.column_stack([plane.u_axis * s, -plane.v_axis * s,
                         plane.origin + plane.v_axis * (plane.height_m - 0.5 * s) + plane.u_axis * 0.5 * s])
    return K @ (R.T @ (A - np.outer(C, [0.0, 0.0, 1.0])))


def frame_gsd(meta: ImageMeta) -> float | None:
    """Metres per pixel at the frame centre, ``range / f`` (the inverse of (P2)); None without a range."""
    if meta.range_m is None:
        return None
    k = meta.intrinsics
    return meta.range_m / (0.5 * (k.fx + k.fy))


def plane_gsd(meta: ImageMeta, plane: Plane) -> float | None:
    """Metres per pixel at the frame centre where its optical axis meets ``plane`` (a camera without a rangefinder
    over a surface the scenario gives), as :func:`frame_gsd`; None when the axis does not meet it in front."""
    k, (_, R, C) = meta.intrinsics, _meta_arrays(meta)
    along = float(R[:, 2] @ plane.normal)
    d = float((plane.origin - C) @ plane.normal) / along if abs(along) > 1e-6 else -1.0
    return d / (0.5 * (k.fx + k.fy)) if 0.0 < d <= 1000.0 else None


def plane_from_frames(metas: Sequence[ImageMeta], margin_m: float = 0.0) -> Plane:
    """A plane for frames without a known surface: through the points where the optical axes meet
    the surface at the frames' ranges, facing the mean viewing direction, ``u`` horizontal, ``v``
    up (a wall; for a deck looking down, ``v`` is north), bounded by the frames' footprints."""
    pts, axes, feet = [], [], []
    for m in metas:
        if m.range_m is None:
            continue
        K, R, C = _meta_arrays(m)
        z = R[:, 2]
        pts.append(C + m.range_m * z)
        axes.append(z)
        w, h = m.intrinsics.width, m.intrinsics.height
        rays = np.linalg.inv(K) @ np.array([[-0.5, -0.5, 1], [w - 0.5, -0.5, 1], [w - 0.5, h - 0.5, 1], [-0.5, h - 0.5, 1]]).T
        feet.append((C, R, rays))
    if not pts:
        raise ValueError("no frame has a range: give the surface corners")
    n = -np.mean(axes, axis=0)
    n /= np.linalg.norm(n)
    p = np.mean(pts, axis=0)
    up = np.array([0.0, 0.0, 1.0])
    if abs(n @ up) > 0.9:  # looking down: v north
        u = np.cross(np.array([0.0, 1.0, 0.0]), n)
    else:
        u = np.cross(up, n)
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    corners = []
    for C, R, rays in feet:
        d = R @ rays
        lam = ((p - C) @ n) / (n @ d)
        corners.append((C[:, None] + d * lam).T)
    uv = (np.concatenate(corners) - p) @ np.column_stack([u, v])
    lo, hi = uv.min(0) - margin_m, uv.max(0) + margin_m
    origin = p + lo[0] * u + lo[1] * v
    return Plane(origin, u, v, float(hi[0] - lo[0]), float(hi[1] - lo[1]))


def _centre_weight(w: int, h: int) -> NDArray[np.float32]:
    """1 at the image centre falling to 0 at its border (Chebyshev distance, normalised per axis)."""
    x = 1.0 - np.abs((np.arange(w, dtype=np.float32) + 0.5) / w * 2.0 - 1.0)
    y = 1.0 - np.abs((np.arange(h, dtype=np.float32) + 0.5) / h * 2.0 - 1.0)
    return np.minimum(y[:, None], x[None, :]) + np.float32(1e-3)


MAX_CANVAS_PX = 80_000_000
#: the least overlap (canvas px, each side) and peak response a frame is aligned on
ALIGN_MIN_SIDE_PX = 24
ALIGN_MIN_RESPONSE = 0.1
#: the least contrast (standard deviation, grey levels) of the overlap on either side
ALIGN_MIN_CONTRAST = 2.0
#: the most pixels an overlap is correlated at (a larger one is reduced first: 12 MP frames)
ALIGN_MAX_PX = 1_000_000
#: a pair of frames whose measured shift disagrees with the solved moves by more than this (canvas px) is dropped
ALIGN_OUTLIER_PX = 2.0


def alignment(moving: NDArray[np.uint8], moving_in: NDArray[np.bool_], fixed: NDArray[np.uint8],
              fixed_in: NDArray[np.bool_], max_px: float) -> tuple[float, float, float] | None:
    """How far (dx, dy, canvas px) the content of ``moving`` sits from where ``fixed`` has it, where both have
    pixels (``*_in``), and the peak's response: phase correlation (Kuglin & Hines 1975; ``cv2.phaseCorrelate``)
    over the overlap's bounding box, Hann-windowed, each side's missing pixels filled with its mean. None when the
    overlap is too small or blank, the peak too weak or the shift beyond ``max_px``."""
    both = moving_in & fixed_in
    ys, xs = np.nonzero(both)
    if ys.size == 0:
        return None
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    if min(y1 - y0, x1 - x0) < ALIGN_MIN_SIDE_PX:
        return None
    inside = both[y0:y1, x0:x1]

    def patch(img: NDArray[np.uint8]) -> NDArray[np.float32]:
        p = img[y0:y1, x0:x1].astype(np.float32)
        p[~inside] = float(p[inside].mean())
        return p

    a, b = patch(fixed), patch(moving)
    if min(float(a[inside].std()), float(b[inside].std())) < ALIGN_MIN_CONTRAST:
        return None  # a blank wall: nothing to align on
    k = max(1, math.ceil(math.sqrt(a.size / ALIGN_MAX_PX)))  # a large overlap is correlated at 1/k the size
    if k > 1:
        size = (max(1, a.shape[1] // k), max(1, a.shape[0] // k))
        a, b = (np.asarray(cv2.resize(p, size, interpolation=cv2.INTER_AREA), np.float32) for p in (a, b))
    win = cv2.createHanningWindow((a.shape[1], a.shape[0]), cv2.CV_32F)
    (dx, dy), response = cv2.phaseCorrelate(a, b, win)
    dx, dy = dx * k, dy * k
    if response < ALIGN_MIN_RESPONSE or math.hypot(dx, dy) > max_px:
        return None
    return float(dx), float(dy), float(response)


def solve_shifts(n: int, pairs: Sequence[tuple[int, int, float, float, float]], outlier_px: float = ALIGN_OUTLIER_PX,
                 prior: float = 1e-3) -> NDArray[np.float64]:
    """Each of ``n`` frames' move (canvas px, n x 2) from ``pairs`` ``(a, b, dx, dy, weight)``: frame b's content
    sits (dx, dy) from frame a's. Weighted least squares of ``c_b - c_a = -(dx, dy)`` with a weak pull of every move
    to 0 (``prior``: the moves of a connected group of frames sum to about 0, a frame in no pair stays put); while
    the pair that disagrees most with the solution is off by more than ``outlier_px``, it is dropped (a false
    peak) and the rest solved again."""
    c: NDArray[np.float64] = np.zeros((n, 2))
    keep = list(pairs)
    while keep:
        A = np.zeros((len(keep) + n, n))
        rhs = np.zeros((len(keep) + n, 2))
        for r, (a, b, dx, dy, w) in enumerate(keep):
            A[r, a], A[r, b] = -w, w
            rhs[r] = (-w * dx, -w * dy)
        A[len(keep):] = prior * np.eye(n)
        c = np.asarray(np.linalg.lstsq(A, rhs, rcond=None)[0], np.float64)
        res = [math.hypot(c[b, 0] - c[a, 0] + dx, c[b, 1] - c[a, 1] + dy) for a, b, dx, dy, _ in keep]
        worst = int(np.argmax(res))
        if res[worst] <= outlier_px:
            break
        del keep[worst]
    return c


def unusable_frames(frames: Sequence[PosedFrame]) -> dict[int, str]:
    """Index -> what is wrong, of the frames that show no surface (:func:`exposure_problem`)."""
    return {i: p for i, f in enumerate(frames) if (p := exposure_problem(f.grey)) is not None}


def build_mosaic(frames: Sequence[PosedFrame], plane: Plane, m_per_px: float | None = None,
                 align_m: float = 0.0, unusable: dict[int, str] | None = None) -> Mosaic:
    """Warp every frame onto ``plane`` (docs/report.md) at ``m_per_px``, by default the frames' median ground
    sampling distance (their own resolution: nothing lost or invented). With ``align_m`` > 0 the frames are first
    moved along the surface to fit each other (:func:`registration`), by at most ``align_m`` between any two.
    ``unusable``: :func:`unusable_frames` of ``frames`` when the caller has it already."""
    import time

    t0 = time.perf_counter()
    if m_per_px is None:
        g = [x for x in (frame_gsd(f.meta) or plane_gsd(f.meta, plane) for f in frames) if x]
        if not g:
            raise ValueError("no frame has a range nor looks at the surface: give m_per_px")
        m_per_px = float(np.median(g))
    if not (math.isfinite(m_per_px) and m_per_px > 0):
        raise ValueError(f"m_per_px must be finite and > 0, got {m_per_px!r}")
    W = max(1, int(math.ceil(plane.width_m / m_per_px)))
    H = max(1, int(math.ceil(plane.height_m / m_per_px)))
    if W * H > MAX_CANVAS_PX:
        raise ValueError(f"mosaic of {W} x {H} px exceeds {MAX_CANVAS_PX / 1e6:.0f} MP: raise m_per_px")
    unusable = unusable_frames(frames) if unusable is None else unusable
    shifts = registration(frames, plane, m_per_px, align_m, set(unusable)) if align_m > 0 else None
    out = _compose(frames, plane, m_per_px, (H, W), shifts, unusable)
    shifts_m: list[tuple[float, float] | None] = []
    if shifts is not None:
        shifts_m = [None if d is None else (float(d[0]) * m_per_px, -float(d[1]) * m_per_px) for d in shifts]
    return Mosaic(plane=plane, m_per_px=m_per_px, image=out.image, mask=out.mask, owner=out.owner,
                  seconds=time.perf_counter() - t0, frames_used=out.used, skipped=out.skipped, shifts_m=shifts_m,
                  unusable=unusable)


def registration(frames: Sequence[PosedFrame], plane: Plane, m_per_px: float, align_m: float,
                 leave_out: set[int] | frozenset[int] = frozenset()) -> list[NDArray[np.float64] | None]:
    """Each frame's move (canvas px at ``m_per_px``, (dx, dy); None for a frame not placed nor in
    ``leave_out``) that makes the frames
    fit each other: every overlapping pair, warped by its poses, measured by :func:`alignment` (up to ``align_m``),
    the moves solved together (:func:`solve_shifts`). Frames of more than :data:`ALIGN_MAX_PX` are registered on a
    coarser canvas."""
    px = float(np.median([f.grey.shape[0] * f.grey.shape[1] for f in frames])) if frames else 0.0
    r = max(1, math.ceil(math.sqrt(px / ALIGN_MAX_PX)))
    s = m_per_px * r
    W, H = max(1, int(math.ceil(plane.width_m / s))), max(1, int(math.ceil(plane.height_m / s)))
    placed: list[tuple[int, int, int, NDArray[np.uint8], NDArray[np.bool_]]] = []
    for i, f in enumerate(frames):
        if i in leave_out:
            continue
        Hc = canvas_homography(f.meta, plane, s)
        p = None if Hc is None else _place(f, Hc, W, H)
        if p is None or isinstance(p, str):
            continue
        _, (ys, xs), img, wt = p
        placed.append((i, int(xs.start), int(ys.start), img, wt > 0))
    pairs = []
    for a, (_, xa, ya, ia, ma) in enumerate(placed):
        for b in range(a + 1, len(placed)):
            _, xb, yb, ib, mb = placed[b]
            x0, y0 = max(xa, xb), max(ya, yb)
            x1, y1 = min(xa + ia.shape[1], xb + ib.shape[1]), min(ya + ia.shape[0], yb + ib.shape[0])
            if min(x1 - x0, y1 - y0) < ALIGN_MIN_SIDE_PX:
                continue
            sa, sb = np.s_[y0 - ya:y1 - ya, x0 - xa:x1 - xa], np.s_[y0 - yb:y1 - yb, x0 - xb:x1 - xb]
            d = alignment(ib[sb], mb[sb], ia[sa], ma[sa], align_m / s)
            if d is not None:
                pairs.append((a, b, d[0], d[1], d[2]))
    c = solve_shifts(len(placed), pairs) * r
    out: list[NDArray[np.float64] | None] = [None] * len(frames)
    for k, (i, *_) in enumerate(placed):
        out[i] = c[k]
    return out


@dataclass
class _Composed:
    image: NDArray[np.uint8]
    mask: NDArray[np.uint8]
    owner: NDArray[np.int32]
    used: int
    skipped: list[str]


def _compose(frames: Sequence[PosedFrame], plane: Plane, m_per_px: float, shape: tuple[int, int],
             shifts: Sequence[NDArray[np.float64] | None] | None = None,
             unusable: dict[int, str] | None = None) -> _Composed:
    """Every frame but the ``unusable`` onto the canvas, nearest its centre wins, each moved by its ``shifts``
    (canvas px)."""
    H, W = shape
    image = np.zeros((H, W), np.uint8)
    mask = np.zeros((H, W), np.uint8)
    owner = np.full((H, W), -1, np.int32)
    best = np.zeros((H, W), np.float32)
    skipped: list[str] = []
    used = 0
    flags = cv2.WARP_INVERSE_MAP
    for i, f in enumerate(frames):
        if unusable and i in unusable:
            skipped.append(f"frame {i}: shows no surface: {unusable[i]}")
            continue
        Hc = canvas_homography(f.meta, plane, m_per_px)
        if Hc is None:
            skipped.append(f"frame {i}: camera behind the surface")
            continue
        d = None if shifts is None else shifts[i]
        if d is not None:  # the frame's content moves by d: canvas pixel p takes what p - d had
            Hc = Hc @ np.array([[1.0, 0.0, -float(d[0])], [0.0, 1.0, -float(d[1])], [0.0, 0.0, 1.0]])
        placed = _place(f, Hc, W, H)
        if isinstance(placed, str):
            skipped.append(f"frame {i}: {placed}")
            continue
        Hr, roi, img, wt = placed
        take = wt > best[roi]
        if not take.any():
            continue
        used += 1
        best[roi][take] = wt[take]
        image[roi][take] = img[take]
        owner[roi][take] = i
        if f.mask is not None:
            mw = cv2.warpPerspective(f.mask, Hr, (img.shape[1], img.shape[0]), flags=flags | cv2.INTER_NEAREST,
                                     borderMode=cv2.BORDER_CONSTANT)
            mask[roi][take] = mw[take]
        else:
            mask[roi][take] = 0
    return _Composed(image, mask, owner, used, skipped)


def _place(f: PosedFrame, Hc: NDArray[np.float64], W: int, H: int
           ) -> str | tuple[NDArray[np.float64], tuple[slice, slice], NDArray[np.uint8], NDArray[np.float32]]:
    """Frame ``f`` warped by the canvas -> frame homography ``Hc`` into the canvas region its footprint covers:
    (homography of that region, the region, image, centre weight), or why it cannot be placed."""
    h, w = f.grey.shape[:2]
    try:
        Hi = np.linalg.inv(Hc)
    except np.linalg.LinAlgError:
        return "degenerate pose"
    q = np.array([[-0.5, -0.5, 1], [w - 0.5, -0.5, 1], [w - 0.5, h - 0.5, 1], [-0.5, h - 0.5, 1]]) @ Hi.T
    if np.any(q[:, 2] <= 0):
        return "sees beyond the horizon of the surface"
    c = q[:, :2] / q[:, 2:3]
    x0, y0 = np.floor(np.clip(c.min(0), 0, [W, H])).astype(int)
    x1, y1 = np.ceil(np.clip(c.max(0), 0, [W, H])).astype(int)
    if x1 <= x0 or y1 <= y0:
        return "off the surface"
    Hr = Hc @ np.array([[1.0, 0.0, x0], [0.0, 1.0, y0], [0.0, 0.0, 1.0]])
    size = (int(x1 - x0), int(y1 - y0))
    flags = cv2.WARP_INVERSE_MAP
    img = cv2.warpPerspective(f.grey, Hr, size, flags=flags | cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    wt = cv2.warpPerspective(_centre_weight(w, h), Hr, size, flags=flags | cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return Hr, (slice(y0, y1), slice(x0, x1)), np.asarray(img, np.uint8), np.asarray(wt, np.float32)
