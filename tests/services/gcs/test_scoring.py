"""services.gcs.scoring: surface coordinates and object-level defect recall/precision."""

from __future__ import annotations

import math

import numpy as np
import pytest

from protocol.messages import Defect, DefectReport
from services.gcs.scoring import bbox_distance, score_defects, surface_frame, surface_uv
from services.recording.record import GroundTruthDefect

# The scenario's girder face: x = 60, bottom edge running south (u = -y), v up.
CORNERS = [(60.0, 85.0, 25.5), (60.0, 35.0, 25.5), (60.0, 35.0, 31.5), (60.0, 85.0, 31.5)]


def world(u: float, v: float) -> tuple[float, float, float]:
    """ENU point of surface coordinates (u, v) on CORNERS."""
    return (60.0, 85.0 - u, 25.5 + v)


def gt(i: int, u0: float, v0: float, u1: float, v1: float) -> GroundTruthDefect:
    uc, vc = (u0 + u1) / 2, (v0 + v1) / 2
    return GroundTruthDefect(id=i, pos=world(uc, vc), uv=(uc, vc), bbox_uv=(u0, v0, u1, v1))


def defect(pos=None) -> Defect:
    return Defect(area_px=10, bbox=(0, 0, 2, 5), centroid_px=(1.0, 2.0), contrast=0.4, pos=pos)


def report(uav: int, cid: int, *defects: Defect, ok: bool = True) -> DefectReport:
    return DefectReport(uav=uav, capture_id=cid, stamp_capture=100.0, stamp_report=100.1, method="it",
                        ok=ok, defects=list(defects))


TRUTH = [gt(1, 5.0, 1.0, 6.0, 1.5), gt(2, 20.0, 3.0, 20.5, 4.0), gt(3, 40.0, 0.5, 41.0, 1.0)]


def test_surface_uv_maps_the_corners_to_the_rectangle():
    uv = surface_uv(CORNERS, CORNERS)
    np.testing.assert_allclose(uv, [[0, 0], [50, 0], [50, 6], [0, 6]], atol=1e-12)
    # off-plane points project orthogonally; a single (3,) point is accepted
    np.testing.assert_allclose(surface_uv((58.0, 80.0, 27.5), CORNERS), [[5.0, 2.0]])
    assert surface_uv(np.zeros((0, 3)), CORNERS).shape == (0, 2)


def test_surface_frame_is_orthonormal_even_for_a_skewed_top_corner():
    p0, u, v = surface_frame([(0, 0, 0), (2, 0, 0), (2.5, 0, 1), (0.5, 0, 1)])
    np.testing.assert_allclose([u @ u, v @ v, u @ v], [1, 1, 0], atol=1e-12)
    np.testing.assert_allclose(v, [0, 0, 1], atol=1e-12)


@pytest.mark.parametrize("corners", [np.zeros((3, 3)), [(0, 0, 0)] * 4, [(0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0)],
                                     [(0, 0, math.nan), (1, 0, 0), (1, 0, 1), (0, 0, 1)]])
def test_bad_corners_are_refused(corners):
    with pytest.raises(ValueError):
        surface_uv([(0, 0, 0)], corners)


def test_surface_uv_refuses_nan_points():
    with pytest.raises(ValueError, match="finite"):
        surface_uv([(60.0, math.nan, 27.0)], CORNERS)


def test_bbox_distance_inside_edge_and_corner():
    d = bbox_distance([(0.5, 0.5), (1.3, 0.5), (-0.3, -0.4), (0.5, 2.0)], [(0, 0, 1, 1), (1, 1, 0, 0)])
    np.testing.assert_allclose(d[:, 0], [0.0, 0.3, 0.5, 1.0])
    np.testing.assert_allclose(d[:, 1], d[:, 0])  # corner order does not matter


def test_recall_and_precision_by_hand():
    reports = [
        report(1, 101, defect(world(5.5, 1.2)), defect(world(5.9, 1.4))),  # both inside crack 1
        report(2, 201, defect(world(20.7, 3.5)), defect(None)),  # 0.2 m from crack 2; one unplaced
        report(3, 301, defect(world(41.5, 0.75))),  # 0.5 m from crack 3: too far
        report(3, 302, defect(world(30.0, 5.0))),  # nowhere
        report(1, 102, defect(world(40.5, 0.7)), ok=False),  # failed report: ignored
    ]
    s = score_defects(reports, TRUTH, CORNERS, tolerance_m=0.3)
    assert (s.n_truth, s.n_found, s.n_reported, s.n_true, s.without_pos) == (3, 2, 5, 3, 1)
    assert s.recall == pytest.approx(2 / 3)
    assert s.precision == pytest.approx(3 / 5)
    assert s.f_measure == pytest.approx(2 * 0.6 * (2 / 3) / (0.6 + 2 / 3))
    assert s.found_ids == [1, 2] and s.missed_ids == [3]
    assert sorted((m.report, m.defect, m.truth_id) for m in s.matches) == [(0, 0, 1), (0, 1, 1), (1, 0, 2)]
    m2 = next(m for m in s.matches if m.truth_id == 2)
    assert m2.distance_m == pytest.approx(0.2) and (m2.uav, m2.capture_id) == (2, 201)
    assert [(r, d) for r, d, _, _ in s.false_positives] == [(2, 0), (3, 0)]
    # a larger tolerance takes crack 3 in
    s5 = score_defects(reports, TRUTH, CORNERS, tolerance_m=0.6)
    assert (s5.recall, s5.precision) == (1.0, 0.8)


def test_no_reports_and_no_ground_truth():
    s = score_defects([], TRUTH, CORNERS)
    assert (s.recall, s.precision, s.n_reported, s.missed_ids) == (0.0, 1.0, 0, [1, 2, 3])
    assert s.f_measure == 0.0
    s = score_defects([report(1, 1, defect(world(1.0, 1.0)))], [], CORNERS)
    assert (s.recall, s.precision, s.n_truth, len(s.false_positives)) == (1.0, 0.0, 0, 1)
    s = score_defects([], [], [])  # nothing to place: the corners are not needed
    assert (s.recall, s.precision, s.f_measure) == (1.0, 1.0, 1.0)


def test_a_report_without_positions_is_tallied_not_scored():
    s = score_defects([report(1, 1, defect(None), defect(None))], TRUTH, CORNERS)
    assert (s.without_pos, s.n_reported, s.precision, s.recall) == (2, 0, 1.0, 0.0)


@pytest.mark.parametrize("tol", [-0.1, math.nan, math.inf])
def test_bad_tolerance_is_refused(tol):
    with pytest.raises(ValueError, match="tolerance"):
        score_defects([], TRUTH, CORNERS, tolerance_m=tol)


def test_wrong_item_types_are_refused():
    with pytest.raises(ValueError, match="DefectReport"):
        score_defects([{"uav": 1}], TRUTH, CORNERS)
    with pytest.raises(ValueError, match="GroundTruthDefect"):
        score_defects([], [(0, 0, 1, 1)], CORNERS)
