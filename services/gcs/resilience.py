"""What the faults of a run did, read from its record: the report's "Faults and recovery".

Design notes: docs/report.md (services/gcs/resilience.py).
"""

from __future__ import annotations

from collections import defaultdict
from itertools import pairwise
from typing import Any

from protocol.messages import EventKind
from services.recording.record import MissionRecord

__all__ = ["GAP_S", "NEIGHBOUR_EVENTS", "NOT_INJECTED", "SUPERVISION_ACTIONS", "fault_figures", "reception_gaps"]

#: A pause in a UAV's state reception longer than this is listed as a gap, s (states come at 20 Hz).
GAP_S = 1.0
#: The boards' SkyNet events shown (edge.board).
NEIGHBOUR_EVENTS = (EventKind.NEIGHBOUR_LOST, EventKind.NEIGHBOUR_UP, EventKind.NEIGHBOUR_STALE, EventKind.NEIGHBOUR_FRESH)
#: What the launcher's supervisor noted (services.orchestration.launcher): a service it restarted after it ended
#: by itself, one that could not start. Nobody injected them: they are listed apart from the faults, with no
#: recovery figures (a restart of a service that never came up interrupts nothing).
SUPERVISION_ACTIONS = ("supervisor-restart", "start-failed")
#: A scheduled fault the run ended before (services.orchestration.faults): listed apart, it did not happen.
NOT_INJECTED = "not-injected"
#: Fault ends after which the ground station's reception of the fleet is measured -> their beginnings.
_BEGIN_OF = {"restart": ("kill",), "restore": ("cut",)}


def _origin(record: MissionRecord) -> float:
    return record.phases.get("mission", record.started)


def _uav_of(source: str) -> int | None:
    head, _, tail = source.partition("/")
    return int(tail) if head == "uav" and tail.isdigit() else None


def reception_gaps(rx_times: list[float], min_gap_s: float = GAP_S) -> tuple[float, float | None, list[tuple[float, float]]]:
    """``(max_gap, its end, [(start, end) of every gap > min_gap_s])`` of sorted reception times.

    >>> reception_gaps([0.0, 0.05, 0.1, 3.1, 3.15], 1.0)
    (3.0, 3.1, [(0.1, 3.1)])
    """
    best, end, gaps = 0.0, None, []
    for a, b in pairwise(rx_times):
        d = b - a
        if d > best:
            best, end = d, b
        if d > min_gap_s:
            gaps.append((a, b))
    return best, end, gaps


def fault_figures(record: MissionRecord) -> dict[str, Any]:
    """The "faults" object of report.json (docs/report.md); empty lists when nothing happened."""
    t0 = _origin(record)

    def t(x: float) -> float:
        return round(x - t0, 3)

    rows = [{"t_s": t(f.at), "action": f.action, "target": f.target, "text": f.text}
            for f in sorted(record.faults, key=lambda f: f.at)]
    faults = [x for x in rows if x["action"] not in (*SUPERVISION_ACTIONS, NOT_INJECTED)]
    supervision = [x for x in rows if x["action"] in SUPERVISION_ACTIONS]
    incidents = sorted(record.incidents, key=lambda i: i.at)

    # UAVs: token gone -> (lost) -> back
    episodes: list[dict[str, Any]] = []
    open_ep: dict[int, dict[str, Any]] = {}
    for inc in incidents:
        u = inc.uav
        if u is None:
            continue
        if inc.kind == "token-gone":
            open_ep[u] = {"uav": u, "gone_s": t(inc.at), "lost_s": None, "back_s": None}
            episodes.append(open_ep[u])
        elif inc.kind == "uav-lost" and u in open_ep:
            open_ep[u]["lost_s"] = t(inc.at)
        elif inc.kind == "token-back" and u in open_ep:
            open_ep[u]["back_s"] = t(inc.at)
            del open_ep[u]
    links = []
    for inc in incidents:
        if inc.kind == "link-down":
            links.append({"down_s": t(inc.at), "up_s": None})
        elif inc.kind == "link-up" and links and links[-1]["up_s"] is None:
            links[-1]["up_s"] = t(inc.at)

    # failsafes (board events) and resumes (ground station)
    failsafes: list[dict[str, Any]] = []
    for e in record.events:
        if e.msg.kind == EventKind.FAILSAFE:
            failsafes.append({"uav": _uav_of(e.msg.source), "t_s": t(e.msg.stamp), "rx_s": t(e.rx),
                              "action": e.msg.data.get("action"), "silent_s": e.msg.data.get("silent_s")})
    for e in record.events:  # a failsafe whose own event was lost with the link: its "cleared" event tells
        since = e.msg.data.get("since")
        if e.msg.kind == EventKind.FAILSAFE_CLEARED and isinstance(since, (int, float)):
            u = _uav_of(e.msg.source)
            if not any(f["uav"] == u and abs(f["t_s"] - t(since)) < 0.5 for f in failsafes):
                failsafes.append({"uav": u, "t_s": t(since), "rx_s": None, "action": None, "silent_s": None})
    failsafes.sort(key=lambda f: f["t_s"])
    holds = [{"uav": i.uav, "t_s": t(i.at)} for i in incidents if i.kind == "hold-seen"]
    resumes = []
    for inc in incidents:
        if inc.kind not in ("resume", "resume-failed"):
            continue
        before = [f["t_s"] for f in failsafes if f["uav"] == inc.uav and f["t_s"] <= t(inc.at)]
        resumes.append({"uav": inc.uav, "t_s": t(inc.at), "ok": inc.kind == "resume",
                        "after_failsafe_s": round(t(inc.at) - before[-1], 3) if before else None, "text": inc.text})

    # reception per UAV
    rx: dict[int, list[float]] = defaultdict(list)
    for s in record.states:
        rx[s.msg.uav].append(s.rx)
    for times in rx.values():
        times.sort()
    gaps = {}
    for u in sorted(rx):
        times = rx[u]
        best, end, listed = reception_gaps(times)
        gaps[u] = {"last_rx_s": t(times[-1]), "max_gap_s": round(best, 3),
                   "max_gap_ended_s": None if end is None else t(end),
                   "gaps": [[t(a), t(b)] for a, b in listed]}
    seen_again = []
    for f in record.faults:
        if f.action not in _BEGIN_OF:
            continue
        begins = [b for b in record.faults if b.target == f.target and b.action in _BEGIN_OF[f.action] and b.at <= f.at]
        begin = max((b.at for b in begins), default=f.at)
        per_uav: dict[int, float] = {}
        throughout = []
        for u, times in rx.items():
            # the first state after a gap the fault opened (one longer than GAP_S begun before the restart)
            back = next((b for a, b in pairwise(times) if b >= begin and a <= f.at and b - max(a, begin) > GAP_S), None)
            if back is not None:
                per_uav[u] = back
            elif any(x >= f.at for x in times):
                throughout.append(u)  # no such gap: heard through the fault, nothing to be seen again after
        never = sorted(set(rx) - set(per_uav) - set(throughout))
        fleet = max(per_uav.values()) if per_uav else None
        seen_again.append({"after": f.action, "target": f.target, "began_s": t(begin), "t_s": t(f.at),
                           "fleet_seen_s": None if fleet is None else t(fleet),
                           "fleet_s": None if fleet is None else round(fleet - f.at, 3),
                           "blackout_s": round(fleet - begin, 3) if fleet is not None else 0.0 if not never else None,
                           "uavs_s": {u: round(x - f.at, 3) for u, x in sorted(per_uav.items())}, "never": never,
                           "heard_throughout": sorted(throughout)})

    neighbours = [{"t_s": t(e.msg.stamp), "uav": _uav_of(e.msg.source), "kind": e.msg.kind,
                   "neighbour": e.msg.data.get("neighbour")}
                  for e in sorted(record.events, key=lambda e: e.msg.stamp)
                  if e.msg.kind in NEIGHBOUR_EVENTS and e.msg.stamp >= t0]
    failed = [{"uav": c.uav, "kind": c.kind, "cmd_id": c.cmd_id, "acknowledged": c.ok, "attempts": c.attempts,
               "reason": c.reason} for c in record.commands if not (c.ok and c.accepted)]
    return {
        "origin": "mission phase start" if "mission" in record.phases else "record start",
        "faults": faults,
        "supervision": supervision,
        "not_injected": [x["text"] for x in rows if x["action"] == NOT_INJECTED],
        "uavs_lost": episodes,
        "still_lost": sorted(u for u in open_ep if open_ep[u]["lost_s"] is not None),
        "gcs_link": links,
        "failsafes": failsafes,
        "holds_seen": holds,
        "resumes": resumes,
        "seen_again": seen_again,
        "reception": gaps,
        "skynet": neighbours,
        "commands": {"sent": len(record.commands), "acknowledged": sum(c.ok for c in record.commands),
                     "failed": failed},
        "incidents": [{"t_s": t(i.at), "kind": i.kind, "uav": i.uav, "text": i.text} for i in incidents],
    }
