"""PX4's mission numbering against ArduPilot's (MAVLink "Mission Protocol").

Design notes: docs/hardware-mavlink.md (edge/vehicle/px4/missions.py).
"""

from __future__ import annotations

from dataclasses import replace

from edge.vehicle.auto_flight import AutoMissionPlan

__all__ = ["without_home"]


def without_home(plan: AutoMissionPlan) -> AutoMissionPlan:
    """``plan`` with item 0 (home) dropped and every item number one lower."""
    items = tuple(replace(it, seq=it.seq - 1) for it in plan.items[1:])
    return AutoMissionPlan(items, tuple(max(0, s - 1) for s in plan.waypoint_seq),
                           {cid: s - 1 for cid, s in plan.capture_seq.items()})
