"""bench/pose_tolerance.py's offsets: along the wall only, one per frame, none at zero."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from edge.world.wall import synthetic_surface
from protocol.scenario import load_scenario
from services.inspection.captures import synthetic_captures
from services.inspection.mosaic import Plane, PosedFrame

_spec = importlib.util.spec_from_file_location("bench_pose_tolerance",
                                               Path(__file__).resolve().parents[2] / "bench" / "pose_tolerance.py")
assert _spec is not None and _spec.loader is not None
pose_tolerance = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(pose_tolerance)


def test_each_frame_moves_along_the_wall_by_its_own_offset():
    sc = load_scenario("monorail")
    surf = synthetic_surface(sc)
    plane = Plane.from_corners(surf.corners)
    frames = [PosedFrame(c.meta, np.zeros((2, 2), np.uint8)) for c in synthetic_captures(sc, surf)[:4]]
    same = pose_tolerance.jittered(frames, plane, 0.0, 0)
    assert [f.meta.cam_pos for f in same] == [f.meta.cam_pos for f in frames]
    moved = pose_tolerance.jittered(frames, plane, 0.05, 1)
    d = np.array([np.subtract(m.meta.cam_pos, f.meta.cam_pos) for m, f in zip(moved, frames)])
    assert np.allclose(d @ plane.normal, 0.0, atol=1e-9)  # along the wall: the range is unchanged
    assert len({tuple(np.round(x, 9)) for x in d}) == len(frames) and 0.001 < np.abs(d).max() < 0.5
    again = pose_tolerance.jittered(frames, plane, 0.05, 1)  # a seed gives the same offsets
    assert [f.meta.cam_pos for f in again] == [f.meta.cam_pos for f in moved]
