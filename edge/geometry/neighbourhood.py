"""SkyNet neighbourhoods: which UAVs share state with which.

Design notes: docs/edge.md (edge/geometry/neighbourhood.py).
"""

from __future__ import annotations

#: UAVs per formation (the paper's triangle)
FORMATION_SIZE = 3


def _check(uav: int, size: int) -> None:
    if not isinstance(uav, int) or not 1 <= uav <= 255:
        raise ValueError(f"UAV id must be an int in 1..255, got {uav!r}")
    if not isinstance(size, int) or size < 1:
        raise ValueError(f"formation size must be an int >= 1, got {size!r}")


def formation_index(uav: int, size: int = FORMATION_SIZE) -> int:
    """0-based index of the formation UAV ``uav`` flies in."""
    _check(uav, size)
    return (uav - 1) // size


def members(uav: int, size: int = FORMATION_SIZE, fleet: int | None = None) -> tuple[int, ...]:
    """The UAVs of ``uav``'s formation (itself included), in id order; ``fleet`` (the number of
    UAVs, ids 1..fleet) cuts the last formation short."""
    g = formation_index(uav, size)
    hi = g * size + size if fleet is None else min(g * size + size, fleet)
    return tuple(range(g * size + 1, hi + 1))


def neighbours(uav: int, size: int = FORMATION_SIZE, fleet: int | None = None) -> tuple[int, ...]:
    """The UAVs whose states ``uav`` subscribes to: its formation's other members."""
    return tuple(j for j in members(uav, size, fleet) if j != uav)


def formations(fleet: int, size: int = FORMATION_SIZE) -> list[tuple[int, ...]]:
    """The fleet of UAVs 1..``fleet`` split into formations."""
    if not isinstance(fleet, int) or not 1 <= fleet <= 255:
        raise ValueError(f"fleet size must be an int in 1..255, got {fleet!r}")
    _check(1, size)
    return [members(u, size, fleet) for u in range(1, fleet + 1, size)]
