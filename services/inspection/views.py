"""Views of the mosaic a person can read: orientation, a gridded overview with a scale bar, zoomable tiles.

Design notes: docs/report.md (services/inspection/views.py).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from .mosaic import Mosaic, Plane

__all__ = ["orientation", "compass", "overview_figure", "write_tiles", "PANEL_M", "TILE_PX"]

#: longest stretch of wall (m along u) in one panel of the overview
PANEL_M = 12.5
#: tile size of the zoomable view, pixels
TILE_PX = 256
_COMPASS = ("N", "NE", "E", "SE", "S", "SW", "W", "NW")


def compass(enu_dir: Sequence[float]) -> tuple[float, str]:
    """Bearing (deg clockwise from north) and 8-point compass name of an ENU direction's horizontal part."""
    e, n = float(enu_dir[0]), float(enu_dir[1])
    if math.hypot(e, n) < 1e-9:
        return float("nan"), "up" if float(enu_dir[2]) > 0 else "down"
    b = math.degrees(math.atan2(e, n)) % 360.0
    return b, _COMPASS[int((b + 22.5) // 45) % 8]


def orientation(plane: Plane, origin: Sequence[float] | None = None) -> dict[str, Any]:
    """The wall's ends and bearings (docs/report.md); geodetic ends only with an ``origin``."""
    from edge.geometry.waypoint_mission import enu_to_geodetic

    ub, uname = compass(plane.u_axis)
    fb, fname = compass(plane.normal)
    ends = {"u0": plane.origin, "u1": plane.origin + plane.width_m * plane.u_axis}
    out: dict[str, Any] = {"u_bearing_deg": ub, "u_towards": uname, "facing_deg": fb, "facing": fname,
                           "width_m": plane.width_m, "height_m": plane.height_m,
                           "ends_enu": {k: [float(x) for x in v] for k, v in ends.items()}}
    if origin is not None:
        out["ends_lla"] = {k: [float(x) for x in enu_to_geodetic(v, origin)] for k, v in ends.items()}
    return out


def orientation_text(o: dict[str, Any]) -> str:
    """One sentence: which end is u = 0, which way u runs, which way the face looks."""
    def end(k: str) -> str:
        if "ends_lla" in o:
            la, lo, al = o["ends_lla"][k]
            return f"{la:.6f}, {lo:.6f}, {al:.1f} m"
        return ", ".join(f"{x:.1f}" for x in o["ends_enu"][k]) + " (ENU m)"
    return (f"Seen from the front (the inspected face looks {o['facing']}, bearing {o['facing_deg']:.0f}°): "
            f"u runs along the wall towards {o['u_towards']} (bearing {o['u_bearing_deg']:.0f}°) from the end "
            f"u = 0 at {end('u0')} to the end u = {o['width_m']:.1f} m at {end('u1')}; v is height above the "
            f"wall's bottom edge (0 to {o['height_m']:.1f} m).")


def overview_figure(bgr: np.ndarray, mos: Mosaic, labels: Sequence[tuple[int, float, float]], path: str | Path,
                    title: str = "", panel_m: float = PANEL_M, width_px: int = 1600) -> None:
    """Write the gridded overview of the annotated mosaic ``bgr`` (docs/report.md).

    ``labels`` are ``(id, u, v)`` of each defect (surface metres), drawn in boxes beside the crack.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import MultipleLocator

    W_m, H_m = mos.plane.width_m, mos.plane.height_m
    n = max(1, math.ceil(W_m / panel_m - 1e-9))
    span = min(panel_m, W_m)
    dpi = 100
    fig_w = width_px / dpi
    panel_h = fig_w * 0.86 * H_m / span + 0.55
    fig = Figure(figsize=(fig_w, panel_h * n + (0.5 if title else 0.1)), dpi=dpi)
    FigureCanvasAgg(fig)
    rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    s = mos.m_per_px
    for i in range(n):
        u0, u1 = i * panel_m, min(W_m, (i + 1) * panel_m)
        c0, c1 = int(math.floor(u0 / s)), min(rgb.shape[1], int(math.ceil(u1 / s)))
        part = rgb[:, c0:c1]
        step = max(1, int(part.shape[1] / (width_px * 0.9)))  # no more pixels than the page shows
        part = cv2.resize(part, (max(1, part.shape[1] // step), max(1, part.shape[0] // step)),
                          interpolation=cv2.INTER_AREA) if step > 1 else part
        ax = fig.add_axes((0.06, 1 - (i + 1) / n + 0.45 / (panel_h * n), 0.9, (panel_h - 0.55) / (panel_h * n) * 0.92))
        ax.imshow(part, extent=(c0 * s, c1 * s, 0.0, H_m), interpolation="antialiased")
        ax.set_xlim(u0, u0 + span)
        ax.set_ylim(0.0, H_m)
        ax.xaxis.set_major_locator(MultipleLocator(1.0 if span <= 5 else 2.0 if span <= 15 else 5.0))
        ax.yaxis.set_major_locator(MultipleLocator(1.0 if H_m > 1.5 else 0.2))
        ax.xaxis.set_minor_locator(MultipleLocator(1.0 if span > 2 else 0.1))
        ax.yaxis.set_minor_locator(MultipleLocator(1.0 if H_m > 1.5 else 0.1))
        ax.grid(which="both", color="white", alpha=0.35, linewidth=0.6)
        ax.set_xlabel("u (m along the wall)", fontsize=9)
        ax.set_ylabel("v (m up)", fontsize=9)
        ax.tick_params(labelsize=8)
        bar = 1.0 if span >= 3 else 0.1
        bx, by = u0 + 0.02 * span, 0.06 * H_m
        ax.plot([bx, bx + bar], [by, by], color="white", linewidth=4, solid_capstyle="butt")
        ax.plot([bx, bx + bar], [by, by], color="black", linewidth=1.5, solid_capstyle="butt")
        ax.text(bx + bar / 2, by + 0.04 * H_m, f"{bar:g} m" if bar >= 1 else f"{bar * 100:g} cm", ha="center",
                va="bottom", fontsize=8, color="black", bbox={"facecolor": "white", "alpha": 0.8, "pad": 1,
                                                              "linewidth": 0})
        for k, u, v in labels:
            if u0 <= u < u1:
                ax.annotate(str(k), (u, v), xytext=(6, 6), textcoords="offset points", fontsize=8, color="black",
                            bbox={"facecolor": "yellow", "alpha": 0.9, "pad": 1.2, "linewidth": 0},
                            arrowprops={"arrowstyle": "-", "color": "yellow", "linewidth": 0.8})
    if title:
        import textwrap

        fig.suptitle("\n".join(textwrap.wrap(title, 190)), fontsize=9, y=0.998, va="top")
    fig.savefig(str(path), dpi=dpi)


def write_tiles(bgr: np.ndarray, folder: str | Path, tile: int = TILE_PX, quality: int = 85) -> dict[str, int]:
    """Write the tile pyramid of ``bgr`` into ``folder`` (``z/x_y.jpg``); returns its geometry:
    ``width``, ``height`` (full size, px), ``tile`` and ``zmax`` (full size is level ``zmax``)."""
    root = Path(folder)
    h, w = bgr.shape[:2]
    zmax = max(0, math.ceil(math.log2(max(w, h) / tile))) if max(w, h) > tile else 0
    img = bgr
    for z in range(zmax, -1, -1):
        d = root / str(z)
        d.mkdir(parents=True, exist_ok=True)
        ih, iw = img.shape[:2]
        for ty in range(0, ih, tile):
            for tx in range(0, iw, tile):
                cv2.imwrite(str(d / f"{tx // tile}_{ty // tile}.jpg"), img[ty:ty + tile, tx:tx + tile],
                            [cv2.IMWRITE_JPEG_QUALITY, quality])
        if z:
            img = cv2.resize(img, (max(1, (iw + 1) // 2), max(1, (ih + 1) // 2)), interpolation=cv2.INTER_AREA)
    return {"width": int(w), "height": int(h), "tile": int(tile), "zmax": int(zmax)}
