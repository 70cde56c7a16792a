"""Bodies bound to keys: a message saying ``uav=N`` must travel on UAV N's key (issue 11, item 4).

With access control by certificate common name a node may put only on its own keys; this check
makes the *body* agree with the key, so that a state (event, image) put on uav2's key that says
``uav=1`` is refused instead of being shown as UAV 1. Readers (edge, ground station, detector)
call :func:`matches` and count a mismatch with ``Bus.counters.reject(key, MISMATCH)``.
"""

from __future__ import annotations

from . import keys

#: the rejection kind counted per key
MISMATCH = "body-mismatch"


def matches(key: str, uav: int | None, source: str | None = None) -> bool:
    """Whether ``uav`` (a body's ``uav`` field) or ``source`` (an event's ``uav/N``) is the UAV of ``key``.

    Keys outside the UAV area (ground station, RCUs) carry no UAV id: a body there must not claim
    one through ``source``.
    """
    try:
        info = keys.parse(key)
    except keys.KeyError_:
        return False
    if uav is not None:
        return info.uav == uav
    if source is not None and source.startswith("uav/"):
        return info.uav is not None and source == f"uav/{info.uav}"
    return True
