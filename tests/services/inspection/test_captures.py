"""Captures of a synthetic wall at the planned shots, off the bus: the detector's object-level
precision and recall on them (the mission's scoring, services.gcs.scoring), on walls other than
the mission's own (seed 2024 is never used to choose anything)."""

from __future__ import annotations

import pytest

from edge.world.wall import SURFACE_SEED, synthetic_surface
from protocol.scenario import load_scenario
from services.detector.pipeline import analyse
from services.gcs.scoring import score_defects
from services.inspection.captures import decode, synthetic_captures
from services.recording.record import GroundTruthDefect


@pytest.mark.slow
@pytest.mark.parametrize("seed", [7, 11])
def test_it_plus_is_precise_at_full_recall(seed):
    assert seed != SURFACE_SEED
    sc = load_scenario()
    surf = synthetic_surface(sc, seed=seed)
    caps = synthetic_captures(sc, surf, jitter_m=0.1, jitter_yaw_rad=0.01, seed=seed)
    assert len(caps) == 26 and decode(caps[0]).shape == (480, 640)
    gt = [GroundTruthDefect(id=d.id, pos=d.centroid_world, uv=d.centroid_uv, bbox_uv=d.bbox_uv, area_m2=d.area_m2)
          for d in surf.defects()]
    s = score_defects([analyse(c.meta, c.jpeg, "it+") for c in caps], gt, surf.corners)
    assert s.recall == 1.0
    assert s.precision >= 0.95
    # the old IT+ (guard always on, no contrast floor, bounding-box length rule) was far less precise
    old = dict(guard_contrast=0.0, min_contrast=0.0, min_long_elongation=0.0)
    s_old = score_defects([analyse(c.meta, c.jpeg, "it+", **old) for c in caps], gt, surf.corners)
    assert s_old.precision < 0.6
    # IT+r (the detector service's default): the ridge cue keeps the mission's wall precise
    s_r = score_defects([analyse(c.meta, c.jpeg, "it+r") for c in caps], gt, surf.corners)
    assert s_r.recall == 1.0 and s_r.precision >= 0.95
