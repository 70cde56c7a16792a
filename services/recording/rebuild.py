"""The mission record from an MCAP file alone (:mod:`services.recording.recorder` wrote it).

The summary message gives everything the bus does not carry and, for each received list
(states, defect reports, events, gateway and detector statistics), its first message and its
length; the list is then those messages of the log, in receive order, starting at that first one.
Receive times are the recorder's (the same session as the ground station, microseconds apart).
"""

from __future__ import annotations

from pathlib import Path

from protocol import keys
from protocol.messages import DefectReport, Event, LinkStats, VehicleState
from services.recording.record import DefectRx, EventRx, MissionRecord, StateRx, StatsRx

from .mcap_log import RECORD_TOPIC, read
from .recorder import MissionRecordSummary, Window


class NotAMissionLog(ValueError):
    """An MCAP file without a mission record (not written by the recorder, or cut short)."""


def _list_of(topic: str, msg) -> str | None:
    try:
        info = keys.parse(topic)
    except ValueError:
        return None
    if info.topic == "state" and isinstance(msg, VehicleState):
        return "states"
    if info.topic == "defects" and isinstance(msg, DefectReport):
        return "defects"
    if info.topic == "event" and isinstance(msg, Event):
        return "events"
    if info.topic == "stats" and isinstance(msg, LinkStats):
        if info.area == "gateway":
            return "gateway_stats"
        if info.area == "rcu" and (info.name == "detector" or info.name.startswith("detector-")):  # or an instance
            return "detector_stats"
    return None


_WRAP = {"states": StateRx, "defects": DefectRx, "events": EventRx, "gateway_stats": StatsRx,
         "detector_stats": StatsRx}


def summary_of(path: str | Path) -> MissionRecordSummary:
    """The mission-record message of a log (the record without its received lists)."""
    for item in read(path, topics=[RECORD_TOPIC]):
        return MissionRecordSummary.model_validate_json(item.data)
    raise NotAMissionLog(f"{path}: no {RECORD_TOPIC} message (not a mission log, or the run was cut short)")


def rebuild(path: str | Path) -> MissionRecord:
    summary: MissionRecordSummary | None = None
    lists: dict[str, list] = {name: [] for name in _WRAP}
    for item in read(path):
        if item.topic == RECORD_TOPIC:
            summary = MissionRecordSummary.model_validate_json(item.data)
            continue
        msg = item.message()
        name = _list_of(item.topic, msg) if msg is not None else None
        if name is not None:
            lists[name].append(_WRAP[name](rx=item.rx, msg=msg))
    if summary is None:
        raise NotAMissionLog(f"{path}: no {RECORD_TOPIC} message (not a mission log, or the run was cut short)")
    return with_lists(summary, lists, str(path))


def window(items: list, win: Window, what: str = "list", where: str = "the log") -> list:
    """The part of ``items`` (received in order) that the ground station's record held."""
    start = 0
    if win.first is not None:
        first = type(items[0].msg).model_validate(win.first) if items else None
        start = next((k for k, it in enumerate(items) if it.msg == first), None)
        if start is None:
            raise NotAMissionLog(f"{where}: the first of the record's {what} is not there")
    out = items[start:start + win.n]
    if len(out) != win.n:
        raise NotAMissionLog(f"{where} has {len(out)} of the record's {win.n} {what}")
    return out


def with_lists(summary: MissionRecordSummary, lists: dict[str, list], where: str = "the log") -> MissionRecord:
    """The record of ``summary`` with its received lists cut from ``lists`` (a log's, or a replay's)."""
    update = {name: window(lists.get(name, []), win, name, where) for name, win in summary.windows.items()}
    return summary.record.model_copy(update=update)
