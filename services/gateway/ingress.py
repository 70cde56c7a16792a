"""Per-face ingress limits at the gateway: a flood of a state key is cut where it enters.

The receivers' per-source budgets (:mod:`protocol.budget`) drop a flood, but only after each of them
has taken every flood sample through a Python callback: under a 10 s flood of malformed states
(bench/flood.py) the ground station, its recorder, the formation neighbours and the gateway's own
traffic meter each ran a callback per sample, and the good telemetry queued behind them. The gateway
is where the Internet side (RCU and ground-station clients) meets SkyNet, so the limit goes there,
below Python: Zenoh's *downsampling* interceptor on the **ingress** flow runs in the router's Rust
code before routing, with a state of its own per face (per connected session) and per rule. A flood
from one session is cut to the rule's rate before any subscriber, or the gateway's meter, sees it;
another session's samples on the same key (the real UAV's) keep their own interval and pass.

Zenoh's downsampling is a minimum interval, not a token bucket (no burst): a sample passes when at least
``1/freq`` has gone by since the last one that passed on that face and rule, else it is dropped (and not
counted: Zenoh 1.10 exposes no counter for it). So the rate is set ten times above what a UAV sends
(:data:`STATE_INGRESS_HZ`, 200 Hz = 5 ms for 20 Hz states): states that arrive bunched (a board catching
up after a stall, two states in one datagram) still pass unless they come within 5 ms of each other, and
then the one dropped is at most 5 ms newer than the one kept (states are best-effort, the latest value wins).
Only such keys get a rule: a reliable key (events, defect reports, camera frames, whose recovery replays a
cache at once) must not lose a bunched sample, and is left to the receivers' budgets.

One rule per UAV key (a rule bounds every key it matches together, per face: one ``uav/*/state`` rule would
give a session that carries several UAVs' states, such as ``skynet replay``, one interval for all of them).

Pure: builds the config document, no bus code. Zenoh's config: ``downsampling`` in DEFAULT_CONFIG.json5.
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

