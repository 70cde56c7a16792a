"""Per-face ingress limits at the gateway: a flood of a state key is cut where it enters.

Design notes: docs/security.md (services/gateway/ingress.py).
"""

from __future__ import annotations

import math

from protocol import keys

#: states per second (a minimum interval of 1/rate) one face may send on one UAV's state key through the gateway
STATE_INGRESS_HZ = 200.0
#: every UAV id of the key space (:mod:`protocol.keys`): the rules do not depend on the fleet's size
UAV_IDS = range(1, 256)


def state_ingress(fleet: str, hz: float = STATE_INGRESS_HZ) -> list[dict]:
    """The ``downsampling`` items that limit each face's states on each UAV key entering the gateway to ``hz``.

    Raises ValueError for a rate that is not finite and > 0 (0, "off", is the caller's to skip).
    """
    if isinstance(hz, bool) or not isinstance(hz, (int, float)) or not math.isfinite(hz) or hz <= 0:
        raise ValueError(f"ingress state rate must be a finite rate > 0 Hz, got {hz!r}")
    rules = [{"key_expr": keys.state(fleet, u), "freq": float(hz)} for u in UAV_IDS]
    return [{"id": "state-ingress", "messages": ["put"], "flows": ["ingress"], "rules": rules}]

