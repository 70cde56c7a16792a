"""Task assessment: camera configurations that image a surface (the paper's Section 2, (P1)-(P3)).

Design notes: docs/planner.md (services/planner/task.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from edge.geometry.optics import CameraModel, overlap_spacing
from protocol.checks import positive as _positive

from .scenario import Camera, Scenario, Surface

__all__ = ["footprint", "standoff", "spacing", "footprint_at", "grid_stations", "camera_grid", "InspectionPass",
           "imaging_rows", "formation_pass", "coverage"]


def footprint(camera: Camera, smallest_feature: float) -> tuple[float, float]:
    """Footprint ``a = 1/2 r_c s_f`` (m) across and along the image, two pixels per feature (P1).

    >>> from services.planner.scenario import Camera
    >>> footprint(Camera(resolution=(4000, 3000), sensor_mm=(36, 27), focal_mm=34.4), 0.0025)
    (5.0, 3.75)
    """
    return CameraModel.of(camera).feature_footprint(smallest_feature)


def standoff(camera: Camera, smallest_feature: float) -> float:
    """Distance from the camera to the surface, ``d_f = a_fov f / s_s`` (P2), metres.

    Computed for both image axes; the smaller distance is returned (it resolves ``s_f`` on
    both). For square pixels the two are equal.

    >>> from services.planner.scenario import Camera
    >>> round(standoff(Camera(resolution=(4000, 3000), sensor_mm=(36, 27), focal_mm=34.4), 0.0025), 4)
    4.7778
    """
    return CameraModel.of(camera).standoff(smallest_feature)


def footprint_at(camera: Camera, distance: float) -> tuple[float, float]:
    """Footprint (width, height) in metres of a shot taken square-on from ``distance`` metres."""
    return CameraModel.of(camera).footprint(distance)


def spacing(a_fov: float, overlap: float) -> float:
    """Largest spacing between neighbouring shots, ``g = (1 - o_p) a_fov`` (P3), metres."""
    return overlap_spacing(a_fov, overlap)


def grid_stations(length: float, a_fov: float, g: float) -> NDArray[np.float64]:
    """Centres of the shots along one axis of a patch ``length`` metres long.

    ``n = ceil((length - a_fov) / g) + 1`` centres spread evenly from ``a_fov/2`` to
    ``length - a_fov/2``, so neighbours are at most ``g`` apart and the end footprints touch
    the patch's edges; a patch no longer than ``a_fov`` gets one shot at its middle.
    """
    L = _positive("length", length)
    a = _positive("a_fov", a_fov)
    gg = _positive("spacing", g)
    if L <= a:
        return np.array([0.5 * L])
    n = int(math.ceil((L - a) / gg - 1e-9)) + 1
    return np.linspace(0.5 * a, L - 0.5 * a, n)


def camera_grid(surface: Surface, camera: Camera, smallest_feature: float,
                overlap: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Camera positions ``(K, 3)`` at the (P2) stand-off, row-major from the bottom-left corner, and unit
    optical axes ``(K, 3)`` covering a planar rectangle from its front: the set G of (P1)-(P3)."""
    a_w, a_h = footprint(camera, smallest_feature)
    d = standoff(camera, smallest_feature)
    p0, u, n = surface.frame
    z0, z1 = surface.z_range
    s = grid_stations(surface.length, a_w, spacing(a_w, overlap))
    z = grid_stations(z1 - z0, a_h, spacing(a_h, overlap))
    S, Z = np.meshgrid(s, z)
    pos = p0 + S.reshape(-1, 1) * u + Z.reshape(-1, 1) * np.array([0.0, 0.0, 1.0]) + d * n
    look = np.broadcast_to(-n, pos.shape).copy()
    return pos, look


@dataclass(frozen=True)
class InspectionPass:
    """One straight pass of the formation along a vertical wall, and its K shots in the order taken;
    ``standoff``, ``footprint`` and ``spacing`` are those of (P1)-(P3), the arrays from ``uav`` on are per shot."""

    entry: NDArray[np.float64]  # the centroid's fixed via-points
    exit: NDArray[np.float64]
    direction: NDArray[np.float64]
    standoff: float
    footprint: tuple[float, float]
    spacing: tuple[float, float]
    uav: NDArray[np.int64]  # row of the offsets
    leg_s: NDArray[np.float64]  # centroid distance from entry
    positions: NDArray[np.float64]
    look: NDArray[np.float64]
    stations: NDArray[np.float64]  # on the wall: along the bottom edge from p0, z

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.exit - self.entry))


def imaging_rows(z_offsets: ArrayLike, wall_height: float, a_h: float) -> NDArray[np.float64]:
    """The formation rows (distinct z offsets, ascending) that image the wall in one pass.

    The fewest top rows whose band (top - bottom + one footprint ``a_h``) covers the wall's
    height, or every row if none does (:func:`formation_pass` then refuses the wall). Rows
    below them (a fleet stacked in height, :func:`edge.geometry.formation.offsets_for`) fly the same pass
    under the wall and take no shots; a formation of two rows images with both, as before.
    """
    heights = np.unique(np.round(np.asarray(z_offsets, float), 2))
    for k in range(1, heights.size + 1):
        rows = heights[-k:]
        if rows[-1] - rows[0] + a_h >= wall_height - 1e-9:
            return rows
    return heights


def formation_pass(scenario: Scenario) -> InspectionPass | None:
    """Plan the formation's pass along the scenario's wall (None if it has no surface); the geometry is in
    docs/planner.md (services/planner/task.py). ValueError if the UAVs do not share one lateral offset,
    the rows are further apart than the (P3) spacing, or the wall is taller than one pass images."""
    if scenario.surface is None:
        return None
    surf, cam, insp = scenario.surface, scenario.camera, scenario.inspection
    off = scenario.offsets
    a_w, a_h = footprint(cam, insp.smallest_feature)
    d = standoff(cam, insp.smallest_feature)
    a_w, a_h = footprint_at(cam, d)
    g_w, g_h = spacing(a_w, insp.overlap), spacing(a_h, insp.overlap)
    if np.ptp(off[:, 1]) > 0.01:
        raise ValueError(
            "formation.offsets: every UAV must have the same lateral (y) offset to image a wall "
            "from the stand-off distance in one pass"
        )
    z0, z1 = surf.z_range
    heights = imaging_rows(off[:, 2], z1 - z0, a_h)
    if heights.size > 1 and np.max(np.diff(heights)) > g_h + 1e-9:
        raise ValueError(
            f"formation.offsets: UAV rows {np.max(np.diff(heights)):.2f} m apart exceed the (P3) "
            f"spacing {g_h:.2f} m for overlap {insp.overlap}; lower inspection.overlap or "
            "bring the UAVs closer vertically"
        )
    band = float(heights[-1] - heights[0] + a_h)
    if z1 - z0 > band + 1e-9:
        raise ValueError(f"surface: the wall is {z1 - z0:.2f} m tall but one formation pass images {band:.2f} m")
    zc = 0.5 * (z0 + z1) - 0.5 * (heights[0] + heights[-1])
    p0, u, n = surf.frame
    L = surf.length
    e = float(np.max(np.abs(off[:, 0]))) + insp.lead_in
    start, goal = np.asarray(scenario.start, float), np.asarray(scenario.goal, float)
    candidates = []
    for sign in (1.0, -1.0):
        t = sign * u
        left = np.cross([0.0, 0.0, 1.0], t)
        dist_c = d - float(off[0, 1]) * float(left @ n)  # centroid distance so UAVs are at d
        base = p0 + dist_c * n
        base = np.array([base[0], base[1], zc])
        s_in, s_out = (-e, L + e) if sign > 0 else (L + e, -e)
        entry, exit_ = base + s_in * u, base + s_out * u
        total = np.linalg.norm(entry - start) + np.linalg.norm(goal - exit_)
        candidates.append((total, sign, t, entry, exit_, s_in))
    _, sign, t, entry, exit_, s_in = min(candidates, key=lambda c: c[0])  # the first of equals
    cols = grid_stations(L, a_w, g_w)
    uav, leg_s, pos, stations = [], [], [], []
    for h in heights:
        members = np.flatnonzero(np.abs(off[:, 2] - h) < 0.005)
        members = members[np.argsort(-off[members, 0] * 1.0)]  # leading UAV first
        for k, s in enumerate(cols):
            m = int(members[k % members.size])
            s_c = s - off[m, 0] * sign  # centroid station along u when UAV m is at s
            leg = (s_c - s_in) * sign
            p = p0 + s * u + d * n
            pos.append([p[0], p[1], zc + off[m, 2]])
            uav.append(m)
            leg_s.append(leg)
            stations.append([s, zc + off[m, 2]])
    order = np.lexsort((np.asarray(uav), np.asarray(leg_s)))
    pos_a = np.asarray(pos, float)[order]
    return InspectionPass(entry=entry, exit=exit_, direction=t, standoff=d, footprint=(a_w, a_h), spacing=(g_w, g_h),
                          uav=np.asarray(uav, np.int64)[order], leg_s=np.asarray(leg_s, float)[order], positions=pos_a,
                          look=np.broadcast_to(-n, pos_a.shape).copy(), stations=np.asarray(stations, float)[order])


def coverage(surface: Surface, camera: Camera, positions: ArrayLike, look: ArrayLike, resolution: float = 0.1) -> float:
    """Fraction of the wall imaged by square-on shots (footprint per :func:`footprint_at`).

    Samples the wall on a grid ``resolution`` metres apart (cell centres) and counts the samples
    inside at least one shot's footprint. Shots must look along the inverse wall normal.
    """
    pos = np.asarray(positions, float).reshape(-1, 3)
    lk = np.asarray(look, float).reshape(-1, 3)
    if pos.shape[0] == 0:
        return 0.0
    if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(lk))):
        raise ValueError("positions and look must be finite")
    p0, u, n = surface.frame
    if not np.allclose(lk, -n, atol=1e-6):
        raise ValueError("coverage() handles square-on shots only (look = -normal)")
    z0, z1 = surface.z_range
    dist = (pos - p0) @ n
    if np.any(dist <= 0):
        raise ValueError("every shot must be in front of the surface")
    half_w = 0.5 * dist * camera.sensor_mm[0] / camera.focal_mm
    half_h = 0.5 * dist * camera.sensor_mm[1] / camera.focal_mm
    s_c = (pos - p0) @ u
    z_c = pos[:, 2]
    r = _positive("resolution", resolution)
    s = np.arange(0.5 * r, surface.length, r)
    z = np.arange(z0 + 0.5 * r, z1, r)
    inside = (np.abs(s[None, :, None] - s_c[None, None, :]) <= half_w + 1e-9) & (
        np.abs(z[:, None, None] - z_c[None, None, :]) <= half_h + 1e-9
    )
    return float(np.mean(np.any(inside, axis=2)))
