"""What the launcher gives a large simulated fleet on one machine: pure policy, no processes.

Design notes: docs/large-fleets.md (services/orchestration/fleet_load.py).
"""

from __future__ import annotations

from dataclasses import dataclass

from edge.board import BoardOptions
from edge.config import PREVIEW_HZ
from protocol.checks import rate

GCS_STATE_BUDGET = 240.0  # states per second the ground station takes from the whole fleet
PREVIEW_BUDGET = 12.0  # preview frames per second for the whole fleet
NICE_ABOVE = 12  # fleets above this many UAVs run their edges niced
EDGE_NICE = 10
STATE_HZ = BoardOptions(uav=1).rate_hz  # what every edge publishes

__all__ = ["EDGE_NICE", "FleetLoad", "GCS_STATE_BUDGET", "NICE_ABOVE", "PREVIEW_BUDGET", "fleet_load"]


@dataclass(frozen=True)
class FleetLoad:
    gcs_state_hz: float  # states per UAV per second the gateway forwards to its clients; 0: all
    preview_hz: float  # live preview frames per UAV per second; 0: off
    edge_nice: int  # the edges' niceness (0: as the services)
    chosen: tuple[str, ...] = ()  # what the fleet's size decided (for the launcher's log line)


def fleet_load(uavs: int, gcs_state_hz: float | None = None, preview_hz: float | None = None,
               edge_nice: int | None = None) -> FleetLoad:
    """The three settings for a fleet of ``uavs``; a given value (not None) is kept as it is.

    >>> fleet_load(3)
    FleetLoad(gcs_state_hz=0.0, preview_hz=2.0, edge_nice=0, chosen=())
    >>> fleet_load(48).gcs_state_hz, fleet_load(48).preview_hz, fleet_load(48).edge_nice
    (5.0, 0.25, 10)
    """
    if isinstance(uavs, bool) or not isinstance(uavs, int) or not 1 <= uavs <= 255:
        raise ValueError(f"fleet size must be an int in 1..255, got {uavs!r}")
    gcs = None if gcs_state_hz is None else rate("gcs state rate", gcs_state_hz)
    preview = None if preview_hz is None else rate("preview rate", preview_hz)
    if edge_nice is not None and (isinstance(edge_nice, bool) or not isinstance(edge_nice, int)
                                  or not 0 <= edge_nice <= 19):
        raise ValueError(f"edge niceness must be an int in 0..19, got {edge_nice!r}")
    chosen = []
    if gcs is None:
        gcs = 0.0 if uavs * STATE_HZ <= GCS_STATE_BUDGET else GCS_STATE_BUDGET / uavs
        if gcs:
            chosen.append(f"the ground station's state feed {gcs:.3g} Hz per UAV (--gcs-state-hz)")
    if preview is None:
        preview = min(PREVIEW_HZ, PREVIEW_BUDGET / uavs)
        if preview < PREVIEW_HZ:
            chosen.append(f"live previews {preview:.3g} Hz per UAV (--preview-hz)")
    if edge_nice is None:
        edge_nice = EDGE_NICE if uavs > NICE_ABOVE else 0
        if edge_nice:
            chosen.append(f"the edges at nice {edge_nice} (--edge-nice)")
    return FleetLoad(gcs_state_hz=gcs, preview_hz=preview, edge_nice=edge_nice, chosen=tuple(chosen))
