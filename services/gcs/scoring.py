"""Scoring the defects a mission found against the ground truth of the inspected surface.

Design notes: docs/report.md (services/gcs/scoring.py).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from protocol.messages import DefectReport
from protocol.scenario import surface_frame
from services.recording.record import GroundTruthDefect

__all__ = ["DefectMatch", "DefectScore", "surface_frame", "surface_uv", "bbox_distance", "score_defects"]


@dataclass(frozen=True)
class DefectMatch:
    """One reported defect position lying within tolerance of a ground-truth crack."""

    report: int  # index in the list of reports given to score_defects
    defect: int  # index in that report's defects
    uav: int
    capture_id: int
    truth_id: int  # GroundTruthDefect.id
    distance_m: float  # (u, v) distance from the position to the crack's bounding box (0 inside it)
    uv: tuple[float, float]


@dataclass
class DefectScore:
    """Object-level score of the reported defects against the ground truth (docs/report.md):
    ``f_measure = 2pr / (p + r)`` (P20), 0 when ``p + r = 0``; ``false_positives`` and ``reported_uv`` are
    ``(report, defect, u, v)``."""

    recall: float
    precision: float
    f_measure: float
    n_truth: int
    n_found: int  # cracks with a reported position within tolerance
    n_reported: int  # positions: defects with pos of reports with ok=True
    n_true: int  # of those, near a crack
    without_pos: int  # defects not scored (no position)
    tolerance_m: float
    matches: list[DefectMatch] = field(default_factory=list)  # every (position, crack) pair within tolerance
    found_ids: list[int] = field(default_factory=list)
    missed_ids: list[int] = field(default_factory=list)
    false_positives: list[tuple[int, int, float, float]] = field(default_factory=list)
    reported_uv: list[tuple[int, int, float, float]] = field(default_factory=list)


def surface_uv(points: ArrayLike, corners: ArrayLike) -> NDArray[np.float64]:
    """Surface coordinates ``(N, 2)`` of ENU points, ``u = (p - p0)·û``, ``v = (p - p0)·v̂`` (m along the
    bottom edge and up from ``corners[0]``; off-plane points projected orthogonally).

    >>> corners = [(60, 85, 25.5), (60, 35, 25.5), (60, 35, 31.5), (60, 85, 31.5)]
    >>> surface_uv([(60.0, 80.0, 27.5)], corners)
    array([[5., 2.]])
    """
    p0, u, v = surface_frame(corners)
    p = np.asarray(points, dtype=float)
    if p.ndim == 1 and p.shape == (3,):
        p = p[None, :]
    if p.ndim != 2 or p.shape[1] != 3:
        if p.size == 0:
            return np.zeros((0, 2))
        raise ValueError(f"points must have shape (N, 3), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError("points must be finite (got NaN or inf)")
    d = p - p0
    return np.stack([d @ u, d @ v], axis=1)


def bbox_distance(uv: ArrayLike, bboxes: ArrayLike) -> NDArray[np.float64]:
    """Distances ``(N, M)`` from points ``(N, 2)`` to boxes ``(M, 4)`` ``(u0, v0, u1, v1)`` (either corner
    order) in the (u, v) plane: ``hypot(max(u0 - u, 0, u - u1), max(v0 - v, 0, v - v1))``, 0 inside."""
    p = np.asarray(uv, dtype=float).reshape(-1, 2)
    b = np.asarray(bboxes, dtype=float).reshape(-1, 4)
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(b))):
        raise ValueError("points and boxes must be finite (got NaN or inf)")
    lo = np.minimum(b[:, :2], b[:, 2:])  # (M, 2)
    hi = np.maximum(b[:, :2], b[:, 2:])
    gap = np.maximum(np.maximum(lo[None] - p[:, None], p[:, None] - hi[None]), 0.0)  # (N, M, 2)
    return np.hypot(gap[..., 0], gap[..., 1])


def score_defects(reports: Sequence[DefectReport], ground_truth: Sequence[GroundTruthDefect], corners: ArrayLike,
                  tolerance_m: float = 0.3) -> DefectScore:
    """Object-level recall ``n_found / n_truth`` and precision ``n_true / n_reported`` of reported defects
    against the ground truth, the analogues of ``r = tp / (tp + fn)`` and ``p = tp / (tp + fp)`` of (P20).

    A position counts when its (u, v) distance to a crack's bounding box is at most ``tolerance_m``;
    ``corners`` (:func:`surface_frame`) may be empty when no report carries a position. ValueError on a
    bad tolerance, bad corners or items of the wrong type.
    """
    tol = float(tolerance_m)
    if not (math.isfinite(tol) and tol >= 0.0):
        raise ValueError(f"tolerance_m must be finite and >= 0, got {tolerance_m!r}")
    for r in reports:
        if not isinstance(r, DefectReport):
            raise ValueError(f"reports must be DefectReport, got {type(r).__name__}")
    for g in ground_truth:
        if not isinstance(g, GroundTruthDefect):
            raise ValueError(f"ground_truth must be GroundTruthDefect, got {type(g).__name__}")

    keys: list[tuple[int, int]] = []
    pts: list[tuple[float, float, float]] = []
    without_pos = 0
    for i, r in enumerate(reports):
        if not r.ok:
            continue
        for j, d in enumerate(r.defects):
            if d.pos is None:
                without_pos += 1
            else:
                keys.append((i, j))
                pts.append(d.pos)

    n_truth, n_rep = len(ground_truth), len(pts)
    uv = surface_uv(np.asarray(pts, dtype=float).reshape(-1, 3), corners) if n_rep else np.zeros((0, 2))
    boxes = np.array([g.bbox_uv for g in ground_truth], dtype=float).reshape(-1, 4)
    dist = bbox_distance(uv, boxes)  # (n_rep, n_truth)
    near = dist <= tol

    matches = [
        DefectMatch(report=keys[a][0], defect=keys[a][1], uav=reports[keys[a][0]].uav,
                    capture_id=reports[keys[a][0]].capture_id, truth_id=ground_truth[b].id,
                    distance_m=float(dist[a, b]), uv=(float(uv[a, 0]), float(uv[a, 1])))
        for a, b in zip(*np.nonzero(near))
    ]
    found = near.any(axis=0) if n_rep else np.zeros(n_truth, dtype=bool)
    true = near.any(axis=1) if n_truth else np.zeros(n_rep, dtype=bool)
    n_found, n_true = int(found.sum()), int(true.sum())
    recall = n_found / n_truth if n_truth else 1.0
    precision = n_true / n_rep if n_rep else 1.0
    f = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    rows = [(k[0], k[1], float(p[0]), float(p[1])) for k, p in zip(keys, uv)]
    return DefectScore(recall=recall, precision=precision, f_measure=f, n_truth=n_truth, n_found=n_found,
                       n_reported=n_rep, n_true=n_true, without_pos=without_pos, tolerance_m=tol, matches=matches,
                       found_ids=[g.id for g, ok in zip(ground_truth, found) if ok],
                       missed_ids=[g.id for g, ok in zip(ground_truth, found) if not ok],
                       false_positives=[row for row, ok in zip(rows, true) if not ok], reported_uv=rows)
