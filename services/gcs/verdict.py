"""What a mission must achieve, in one place: its planned capture points and the reached-goal check.

Design notes: docs/report.md (services/gcs/verdict.py).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from protocol.messages import DefectReport, Mode, Trajectory, VehicleState
from services.recording.record import GOAL_RADIUS_M, capture_name

__all__ = ["GOAL_RADIUS_M", "GOAL_SETTLE_S", "GoalCheck", "goal_check", "short_of_goal", "planned_captures",
           "imaged_captures", "not_imaged_text"]


def planned_captures(trajectories: Iterable[Trajectory]) -> set[tuple[int, int]]:
    """``(uav, capture_id)`` of every waypoint with a capture id.

    >>> from protocol.messages import Waypoint
    >>> tr = Trajectory(uav=2, waypoints=[Waypoint(t=0.0, pos=(0, 0, 5)), Waypoint(t=1.0, pos=(1, 0, 5), capture_id=7)])
    >>> planned_captures([tr])
    {(2, 7)}
    """
    return {(t.uav, w.capture_id) for t in trajectories for w in t.waypoints if w.capture_id is not None}


def imaged_captures(reports: Iterable[DefectReport]) -> set[tuple[int, int]]:
    """``(uav, capture_id)`` of every ``ok`` defect report (planned or not)."""
    return {(r.uav, r.capture_id) for r in reports if r.ok}


def not_imaged_text(missing: Iterable[tuple[int, int]], planned: int, reports: Iterable[DefectReport],
                    most: int = 10, reason_chars: int = 120, reasons: dict[tuple[int, int], str] | None = None) -> str:
    """The verdict's line on the capture points not imaged, each with why when ``reasons`` (the ground station's
    own findings) or a failed report says so (the detector's last error for it), cut to ``reason_chars``; at most
    ``most`` named.

    >>> r = DefectReport(uav=1, capture_id=6, stamp_capture=0, stamp_report=0, method="it+", ok=False, error="blank")
    >>> not_imaged_text({(1, 6), (2, 3)}, 26, [r])
    '2 of 26 capture points were not imaged: uav1-00006 (blank), uav2-00003'
    """
    why = {(r.uav, r.capture_id): r.error for r in reports if not r.ok and r.error} | (reasons or {})
    gone = sorted(missing)
    named = [capture_name(u, c) + (f" ({why[(u, c)][:reason_chars]})" if (u, c) in why else "") for u, c in gone[:most]]
    return (f"{len(gone)} of {planned} capture points were not imaged: " + ", ".join(named)
            + (", ..." if len(gone) > most else ""))


@dataclass(frozen=True)
class GoalCheck:
    """Where one UAV's trajectory ended, measured against its goal (docs/report.md)."""

    distance_m: float  # from the end position to the trajectory's last waypoint
    completed: bool  # the end position is one with the trajectory complete (progress 1, MISSION or HOLD)

    @property
    def reached(self) -> bool:
        """Within :data:`GOAL_RADIUS_M` of the goal (for the verdict, only together with ``completed``)."""
        return self.distance_m <= GOAL_RADIUS_M


#: how long (mission seconds) the ground station waits, once every trajectory's clock has run out, for a UAV still
#: short of its goal (a board that fell behind its clock) before it lands the fleet
GOAL_SETTLE_S = 10.0


def short_of_goal(latest: dict[int, VehicleState], trajectories: Iterable[Trajectory]) -> list[int]:
    """The UAVs holding at the end of their trajectory (progress 1, HOLD) farther than :data:`GOAL_RADIUS_M` from its
    last waypoint: still getting there. A UAV in any other mode (landing, returning, lost) is not waited for."""
    out = []
    for t in trajectories:
        s = latest.get(t.uav)
        if s is None or s.mode != Mode.HOLD or s.progress < 1.0:
            continue
        if float(np.linalg.norm(np.asarray(s.pos, float) - np.asarray(t.waypoints[-1].pos, float))) > GOAL_RADIUS_M:
            out.append(t.uav)
    return out


def goal_check(states: Iterable[VehicleState], trajectory: Trajectory) -> GoalCheck | None:
    """The reached-goal check of one UAV's states (any order) against its trajectory; ``None`` without states."""
    ordered = sorted(states, key=lambda s: (s.t, s.seq))
    if not ordered:
        return None
    done = [s for s in ordered if s.progress >= 1.0 and s.mode in (Mode.MISSION, Mode.HOLD)]
    end = done[-1] if done else ordered[-1]
    goal = np.asarray(trajectory.waypoints[-1].pos, dtype=float)
    return GoalCheck(distance_m=float(np.linalg.norm(np.asarray(end.pos, dtype=float) - goal)), completed=bool(done))
