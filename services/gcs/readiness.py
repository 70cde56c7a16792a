"""The fleet's readiness before takeoff: every UAV's autopilot ready to fly, or a refusal naming who and why.

Design notes: docs/ground-station.md (services/gcs/readiness.py).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from protocol.messages import VehicleState
from protocol.textsafe import printable

__all__ = ["not_ready", "refusal"]


def not_ready(states: Mapping[int, VehicleState | None], uavs: Iterable[int]) -> dict[int, str]:
    """UAV -> why it is not ready to take off (empty: every UAV is ready).

    A UAV without a state yet is not ready ("no state heard"); a state without ``autopilot`` is
    ready (the built-in vehicle); otherwise its ``ready`` flag decides and its ``reason`` says why.
    """
    out: dict[int, str] = {}
    for u in uavs:
        s = states.get(u)
        if s is None:
            out[u] = "no state heard from its edge"
        elif s.autopilot is not None and not s.autopilot.ready:
            out[u] = s.autopilot.reason or "its autopilot is not ready (no reason given)"
    return out


def refusal(waiting: Mapping[int, str], waited_s: float) -> str:
    """The one-line refusal after ``waited_s`` seconds: each waiting UAV and its autopilot's reason (the
    autopilot's text, control characters escaped: :func:`protocol.textsafe.printable`)."""
    parts = "; ".join(f"UAV {u}: {printable(why)}" for u, why in sorted(waiting.items()))
    return f"refused before takeoff: autopilot not ready after {waited_s:.0f} s ({parts})"
