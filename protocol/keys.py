"""The key space: the only module that spells Zenoh key expressions.

Design notes: docs/bus.md (protocol/keys.py).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

ROOT = "skynet"
DEFAULT_FLEET = "demo"
_CHUNK = re.compile(r"^[A-Za-z0-9_-]+$")
UAV_TOPICS = ("state", "cmd", "camera", "preview", "event", "alive")
RCU_TOPICS = {"planner": "plan", "detector": "defects"}


class KeyError_(ValueError):
    """A key expression that is not part of the key space."""


def _chunk(value: str, what: str) -> str:
    if not isinstance(value, str) or not _CHUNK.match(value):
        raise KeyError_(f"{what} must match [A-Za-z0-9_-]+, got {value!r}")
    return value


def _uav(uav: int | str) -> str:
    if uav == "*":
        return "*"
    if not isinstance(uav, int) or isinstance(uav, bool) or not 1 <= uav <= 255:
        raise KeyError_(f"UAV id must be an int in 1..255, got {uav!r}")
    return str(uav)


def fleet_root(fleet: str) -> str:
    return f"{ROOT}/{_chunk(fleet, 'fleet')}"


def uav_key(fleet: str, uav: int | str, topic: str) -> str:
    """``skynet/<fleet>/uav/<id>/<topic>``; ``uav="*"`` gives the all-UAV wildcard."""
    if topic not in UAV_TOPICS:
        raise KeyError_(f"unknown UAV topic {topic!r}; expected one of {UAV_TOPICS}")
    return f"{fleet_root(fleet)}/uav/{_uav(uav)}/{topic}"


def state(fleet: str, uav: int | str) -> str:
    return uav_key(fleet, uav, "state")


def cmd(fleet: str, uav: int | str) -> str:
    return uav_key(fleet, uav, "cmd")


def camera(fleet: str, uav: int | str) -> str:
    return uav_key(fleet, uav, "camera")


def preview(fleet: str, uav: int | str) -> str:
    """Live preview frames of one camera: small, low-rate, never cached nor recovered.

    A sibling of :func:`camera`, not a sub-key, so ``camera(fleet, "*")`` (the detector's
    subscription) does not match it.
    """
    return uav_key(fleet, uav, "preview")


def event(fleet: str, uav: int | str) -> str:
    return uav_key(fleet, uav, "event")


def alive(fleet: str, uav: int | str) -> str:
    return uav_key(fleet, uav, "alive")


def heartbeat(fleet: str) -> str:
    return f"{fleet_root(fleet)}/gcs/heartbeat"


def gcs_event(fleet: str) -> str:
    return f"{fleet_root(fleet)}/gcs/event"


def planner(fleet: str) -> str:
    return f"{fleet_root(fleet)}/rcu/planner/plan"


def defects(fleet: str) -> str:
    return f"{fleet_root(fleet)}/rcu/detector/defects"


def rcu_alive(fleet: str, name: str) -> str:
    return f"{fleet_root(fleet)}/rcu/{_chunk(name, 'service name')}/alive"


def rcu_event(fleet: str, name: str) -> str:
    return f"{fleet_root(fleet)}/rcu/{_chunk(name, 'service name')}/event"


def rcu_stats(fleet: str, name: str) -> str:
    return f"{fleet_root(fleet)}/rcu/{_chunk(name, 'service name')}/stats"


def rcu_instances(fleet: str, name: str, topic: str) -> str:
    """``rcu/<name>$*/<topic>``: every instance of an RCU (``detector``, ``detector-0``, ``detector-1``, ...;
    services.detector.partition) on its ``alive``, ``event`` or ``stats`` key (``$*``: any characters
    inside one chunk)."""
    if topic not in ("alive", "event", "stats"):
        raise KeyError_(f"rcu instance topic must be alive, event or stats, got {topic!r}")
    return f"{fleet_root(fleet)}/rcu/{_chunk(name, 'service name')}$*/{topic}"


def gateway_stats(fleet: str, gateway_id: str | int = "*") -> str:
    gid = "*" if gateway_id == "*" else _chunk(str(gateway_id), "gateway id")
    return f"{fleet_root(fleet)}/gateway/{gid}/stats"


def all_events(fleet: str) -> str:
    """Every event of the fleet: UAVs, ground station and RCUs."""
    return f"{fleet_root(fleet)}/**/event"


#: the fleet name a recorded mission is replayed under by default (``skynet replay``): beside the live fleet,
#: never on its keys (its command keys above all)
REPLAY_SUFFIX = "-replay"


def replay_fleet(fleet: str) -> str:
    """The fleet a replay of ``fleet``'s recording goes to by default (``demo`` -> ``demo-replay``).

    >>> replay_fleet("demo")
    'demo-replay'
    """
    return _chunk(f"{_chunk(fleet, 'fleet')}{REPLAY_SUFFIX}", "fleet")


def fleet_all(fleet: str) -> str:
    """Every key of the fleet (``**`` does not match ``@``-chunks: see :func:`advanced`)."""
    return f"{fleet_root(fleet)}/**"


def metered(fleet: str) -> tuple[str, ...]:
    """Every key of :func:`fleet_all` except the live previews: what the gateway's traffic meter subscribes to."""
    root = fleet_root(fleet)
    uav = tuple(f"{root}/uav/*/{t}" for t in UAV_TOPICS if t != "preview")
    return (*uav, f"{root}/gcs/**", f"{root}/rcu/**", f"{root}/gateway/**")


def advanced(key: str) -> str:
    """``<key>/@adv/**``: the keys zenoh.ext's advanced publisher and subscriber use beside ``key``.

    A publisher with a recovery cache (``Bus.publisher(..., cache=N)``) puts its sequence-number
    heartbeats on ``<key>/@adv/pub/<zid>/<eid>/_`` and answers recovery queries there. ``@adv`` is
    a verbatim chunk that no wildcard matches, so access-control rules must name it. ``key`` may be
    a wildcard form such as ``camera(fleet, "*")``.
    """
    if not isinstance(key, str) or not key.startswith(f"{ROOT}/") or "@" in key or key.endswith("**"):
        raise KeyError_(f"advanced() wants a SkyNet key without '@' or a trailing '**', got {key!r}")
    return f"{key}/@adv/**"


@dataclass(frozen=True)
class KeyInfo:
    fleet: str
    area: str  # "uav", "gcs", "rcu", "gateway"
    topic: str  # "state", "cmd", ..., "plan", "defects", "stats", "heartbeat"
    uav: int | None = None
    name: str | None = None  # rcu or gateway id


def parse(key: str) -> KeyInfo:
    """Parse a concrete key of the key space; raises :class:`KeyError_` otherwise."""
    parts = str(key).split("/")
    if len(parts) < 4 or parts[0] != ROOT or not _CHUNK.match(parts[1]):
        raise KeyError_(f"not a SkyNet key: {key!r}")
    fleet, area, rest = parts[1], parts[2], parts[3:]
    if area == "uav" and len(rest) == 2 and rest[1] in UAV_TOPICS and rest[0].isdigit():
        uav = int(rest[0])
        if 1 <= uav <= 255:
            return KeyInfo(fleet, "uav", rest[1], uav=uav)
    elif area == "gcs" and rest in (["heartbeat"], ["event"]):
        return KeyInfo(fleet, "gcs", rest[0])
    elif area == "rcu" and len(rest) == 2 and _CHUNK.match(rest[0]):
        if rest[1] in ("alive", "event", "stats") or RCU_TOPICS.get(rest[0]) == rest[1]:
            return KeyInfo(fleet, "rcu", rest[1], name=rest[0])
    elif area == "gateway" and len(rest) == 2 and rest[1] == "stats" and _CHUNK.match(rest[0]):
        return KeyInfo(fleet, "gateway", "stats", name=rest[0])
    raise KeyError_(f"not a SkyNet key: {key!r}")
