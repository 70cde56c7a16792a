"""The ground truth of a simulated mission: the cracks really on the synthetic wall.

Design notes: docs/report.md (services/inspection/ground_truth.py).
"""

from __future__ import annotations

from edge.world.wall import synthetic_surface
from protocol.checks import xyz
from services.recording.record import GroundTruthDefect, MissionRecord


def attach_ground_truth(record: MissionRecord) -> None:
    """Fill ``record.ground_truth`` and ``record.surface_corners`` from the scenario's wall."""
    surface = synthetic_surface(record.scenario)
    record.surface_corners = [xyz(c) for c in surface.corners]
    record.ground_truth = [
        GroundTruthDefect(id=d.id, pos=d.centroid_world, uv=d.centroid_uv, bbox_uv=d.bbox_uv, area_m2=d.area_m2)
        for d in surface.defects()
    ]


def truth_surface(record: MissionRecord):
    """The simulated wall the edges rendered (its texture and crack mask), or None without a simulated one."""
    if record.scenario is None or record.scenario.surface is None or not record.ground_truth:
        return None
    return synthetic_surface(record.scenario)
