"""The ground station's view of a large fleet as a downsampled feed.

Design notes: docs/bus.md (services/gateway/downsample.py).
"""

from __future__ import annotations

import math

from protocol import keys


def state_downsampling(fleet: str, hz: float, uavs: int) -> dict:
    """The Zenoh config fragment that limits each UAV's state leaving the gateway to ``hz`` per second.

    One rule per UAV key: a rule's ``freq`` bounds all the samples matching its key expression
    together (a single ``uav/*/state`` rule at 5 Hz let 5 states a second through for the whole fleet).
    """
    if isinstance(hz, bool) or not isinstance(hz, (int, float)) or not math.isfinite(hz) or hz <= 0:
        raise ValueError(f"downsampled state rate must be a finite rate > 0 Hz, got {hz!r}")
    if isinstance(uavs, bool) or not isinstance(uavs, int) or not 1 <= uavs <= 255:
        raise ValueError(f"fleet size must be an int in 1..255, got {uavs!r}")
    rules = [{"key_expr": keys.state(fleet, u), "freq": float(hz)} for u in range(1, uavs + 1)]
    return {"downsampling": [{"messages": ["put"], "flows": ["egress"], "rules": rules}]}
