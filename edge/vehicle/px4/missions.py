"""PX4's mission numbering against ArduPilot's (MAVLink "Mission Protocol").

ArduPilot stores home as mission item 0 and the first real item as 1; PX4 has no home item: item 0 is the
first real item, and MISSION_CURRENT, MISSION_ITEM_REACHED, DO_SET_MISSION_CURRENT and MISSION_START's
item numbers count from it. :func:`without_home` turns a plan built the ArduPilot way (the project's one
item builder) into PX4's numbering.
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
