"""Real crack sizes: the ``real-cracks`` scenario (0.1-3 mm cracks, every AASHTO class) flown at the
ground sampling distance the task assessment (P1)-(P2) plans for them, its 12 MP captures measured by the
deliverable against the wall's truth, with stated tolerances; cracks narrower than one pixel are told
apart, not sized."""

from __future__ import annotations

import numpy as np
import pytest

from edge.world.surface import graded_crack_image
from edge.world.wall import synthetic_surface
from protocol.scenario import ScenarioError, load_scenario, validate_scenario
from services.inspection.accuracy import compare, markdown_accuracy, seen_pixels, truth_cracks, unseen_cracks
from services.inspection.captures import decode, synthetic_captures
from services.inspection.deliverable import inspect_frames, resolution_note
from services.inspection.mosaic import Plane, PosedFrame
from services.planner.task import footprint, standoff

#: the stated tolerances on the real-size wall (0.25 mm/px): length relative, widths in mm
REAL_TOLERANCE = {"length_error_median": 0.05, "length_error_worst": 0.15, "width_mean_error_mm_median": 0.1,
                  "width_mean_error_mm_worst": 0.3, "width_max_error_mm_median": 0.2, "width_max_error_mm_worst": 0.4}


@pytest.fixture(scope="module")
def real():
    sc = load_scenario("real-cracks")  # a packaged scenario by name
    surf = synthetic_surface(sc)
    caps = synthetic_captures(sc, surf, frame_size=sc.camera.resolution)
    o = sc.origin
    res = inspect_frames([PosedFrame(c.meta, decode(c)) for c in caps], Plane.from_corners(surf.corners),
                         (o.lat, o.lon, o.alt))
    return sc, surf, caps, res


def test_the_scenario_plans_the_gsd_for_its_cracks(real):
    sc, surf, caps, res = real
    # (P1): two pixels per smallest feature -> 0.25 mm/px on the 4000 x 3000 frame; (P2) the stand-off
    assert footprint(sc.camera, sc.inspection.smallest_feature) == pytest.approx((1.0, 0.75))
    assert standoff(sc.camera, sc.inspection.smallest_feature) == pytest.approx(0.956, abs=1e-3)
    assert res.mosaic.m_per_px == pytest.approx(0.00025, rel=0.02)
    assert caps[0].meta.intrinsics.width == 4000  # measured on full-resolution frames
    truth, _ = truth_cracks(surf.mask, 1 / surf.px_per_m)
    assert {t.severity for t in truth} == {"insignificant", "moderate", "wide"}
    assert min(t.width_max_mm for t in truth) < 0.3 and max(t.width_max_mm for t in truth) > 1.3
    note = resolution_note(res.mosaic.m_per_px)
    # every class has widths above one pixel (insignificant only from 0.25 to 0.3 mm); narrower is flagged
    assert note["classes_unresolved"] == [] and note["smallest_width_mm"] == pytest.approx(0.25, rel=0.02)


def test_real_sizes_against_truth_within_tolerance(real):
    sc, surf, caps, res = real
    truth, labels = truth_cracks(surf.mask, 1 / surf.px_per_m)
    acc = compare(res.defects, truth, labels, 1 / surf.px_per_m, gsd_m=res.mosaic.m_per_px)
    s = acc.summary
    print(markdown_accuracy(acc))
    wide_enough = [r for r in acc.rows if r.truth.width_max_mm >= 1e3 * res.mosaic.m_per_px]
    assert wide_enough and all(r.defects for r in wide_enough)  # every crack wider than a pixel is found
    for k, tol in REAL_TOLERANCE.items():
        assert s[k] is not None and s[k] <= tol, (k, s[k], tol)
    # no defect on no crack: IT+ alone put 48 on the wall's texture (precision 0.09); each component is now kept
    # only where the learned model's mask confirms it (deliverable.CONFIRM_METHOD)
    assert s["unmatched_defects"] == 0 and res.confirm == "learned", s["unmatched_defects"]
    # the class is right for every crack more than one pixel away from a class limit (0.3, 1.3 mm);
    # nearer, a measurement within tolerance may fall on either side
    px_mm = 1e3 * res.mosaic.m_per_px
    clear = [r for r in wide_enough if min(abs(r.truth.width_max_mm - lim) for lim in (0.3, 1.3)) > px_mm]
    assert clear and all(r.class_agrees for r in clear)
    assert s["class_agreement"] >= 0.75
    assert s["below_pixel"] >= 1  # the hairline cracks are there and are counted as not sizeable
    assert "narrower than one pixel" in markdown_accuracy(acc)


def test_graded_cracks_keep_their_width_ranges():
    _, mask = graded_crack_image((600, 900), 5, [(1, 1), (6, 8)], 2, length_px=(200, 300))
    widths = [t.width_max_mm for t in truth_cracks(mask, 0.001)[0]]
    assert min(widths) < 2.0 and max(widths) > 5.0


@pytest.mark.parametrize("surface, message", [
    ({"crack_widths_mm": [[0.5, 0.2]]}, "crack_widths_mm"),
    ({"texture_mm": 0.05}, "exceeds 100 MP"),
    ({"crack_length_m": [0.3, 0.1]}, "crack_length_m"),
])
def test_bad_crack_settings_are_refused_naming_the_field(surface, message):
    sc = load_scenario("real-cracks")
    doc = sc.model_dump(mode="json")
    doc["surface"] = {**doc["surface"], **surface}
    doc["surface"]["corners"] = [[60.0, 65.0, 27.0], [60.0, 55.0, 27.0], [60.0, 55.0, 28.0], [60.0, 65.0, 28.0]]
    with pytest.raises(ScenarioError, match=message):
        validate_scenario(doc)


def test_a_panel_imaged_in_part_is_scored_on_the_part_imaged():
    """A capture 15 cm off its point (the formation's tracking error on a loaded machine) sees 94 % of the
    panel: one crack in part. Scored against the whole crack, its length error was 43 % (the stated worst is
    15 %) though what was imaged was measured right; scored on the imaged part it is within tolerance, the
    crack says how much of it was seen, and a crack no frame saw is counted apart."""
    sc = load_scenario("real-cracks")
    surf = synthetic_surface(sc)
    caps = synthetic_captures(sc, surf, frame_size=sc.camera.resolution, jitter_m=0.15, seed=1)
    o = sc.origin
    res = inspect_frames([PosedFrame(c.meta, decode(c)) for c in caps], Plane.from_corners(surf.corners),
                         (o.lat, o.lon, o.alt))
    s = 1 / surf.px_per_m
    assert res.mosaic.coverage < 0.97
    whole = compare(res.defects, *truth_cracks(surf.mask, s), s, gsd_m=res.mosaic.m_per_px).summary
    assert whole["length_error_worst"] > REAL_TOLERANCE["length_error_worst"]  # the unseen part counted as error
    seen = seen_pixels(res.mosaic.owner, res.mosaic.m_per_px, surf.mask.shape, s)
    truth, labels = truth_cracks(surf.mask, s, seen=seen)
    acc = compare(res.defects, truth, labels, s, gsd_m=res.mosaic.m_per_px, unseen=unseen_cracks(surf.mask, seen))
    assert acc.summary["length_error_worst"] <= REAL_TOLERANCE["length_error_worst"], acc.summary
    assert acc.summary["unseen"] == 0 and 0.3 < min(t.seen for t in truth) < 0.9
    assert "of it seen" in markdown_accuracy(acc) and "Scored on the imaged surface" in markdown_accuracy(acc)


def test_cracks_are_measured_on_their_seen_part_and_the_unseen_ones_counted():
    mask = np.zeros((100, 200), np.uint8)
    mask[20:23, 10:90] = 1  # 80 px long, half of it seen
    mask[60:63, 120:190] = 1  # 70 px long, not seen
    seen = np.zeros_like(mask, bool)
    seen[:, :50] = True
    truth, labels = truth_cracks(mask, 0.001, seen=seen)
    assert len(truth) == 1 and truth[0].seen == pytest.approx(0.5, abs=0.01)
    assert truth[0].length_m == pytest.approx(0.040, abs=0.003)
    assert not labels[~seen].any() and unseen_cracks(mask, seen) == 1
    owner = np.full((10, 20), -1, np.int32)
    owner[:, :5] = 0  # a mosaic at 10 truth pixels a pixel: its left quarter seen
    assert (seen_pixels(owner, 0.01, mask.shape, 0.001) == seen).all()
