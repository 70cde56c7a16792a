"""The mission's record from its log alone: the one loader every consumer uses.

Design notes: docs/recording.md (services/recording/load.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pydantic import BaseModel

from protocol import binding, codec, keys
from protocol.messages import DefectReport, Event, LinkStats, VehicleState
from services.recording.record import CAPS, ITEM_MODELS, DefectRx, EventRx, MissionRecord, StateRx, StatsRx, keep

from .mcap_log import read
from .recorder import FOOTER_TOPIC, GROUND_TOPICS, HEADER_FIELDS, HEADER_TOPIC

__all__ = ["NotAMissionLog", "LogReadout", "load_record", "list_of"]


class NotAMissionLog(ValueError):
    """An MCAP file without a mission record's header (not a mission log)."""


@dataclass
class LogReadout:
    """What :func:`load_record` found in a log besides the record."""

    messages: int = 0  # messages read
    items: int = 0  # list items read (kept or let go by the caps)
    damaged: int = 0  # messages that did not validate: skipped
    footer: bool = False  # the footer was read (the mission ended and closed its log)

    def notes(self, path: str | Path) -> list[str]:
        """What the record read back must say about its log (none for a whole, undamaged one)."""
        out = []
        if self.damaged:
            out.append(f"{path}: {self.damaged} damaged message(s) skipped")
        if not self.footer:
            out.append(f"{path} has no footer (the run did not close its log): the plan, the verdict and the "
                       "counters are not in it")
        return out


def list_of(topic: str, msg) -> str | None:
    """The record's list a bus sample on ``topic`` belongs to (None: none), by the ground station's binding
    rules: a state for its own UAV, an event or statistics for their own source (:mod:`protocol.binding`)."""
    try:
        info = keys.parse(topic)
    except ValueError:
        return None
    if info.topic == "state" and isinstance(msg, VehicleState):
        return "states" if binding.matches(topic, msg.uav) else None
    if info.topic == "defects" and isinstance(msg, DefectReport):
        return "defects"
    if info.topic == "event" and isinstance(msg, Event):
        return "events" if binding.matches(topic, None, msg.source) else None
    if info.topic == "stats" and isinstance(msg, LinkStats) and binding.source_matches(topic, msg.source):
        if info.area == "gateway":
            return "gateway_stats"
        if info.area == "rcu" and (info.name == "detector" or (info.name or "").startswith("detector-")):  # or an instance
            return "detector_stats"
    return None


_WRAP: dict[str, type[BaseModel]] = {"states": StateRx, "defects": DefectRx, "events": EventRx,
                                     "gateway_stats": StatsRx, "detector_stats": StatsRx}
_GROUND = {topic: kind for kind, topic in GROUND_TOPICS.items()}
#: the former recorder's one summary message (header, footer and the ground station's entries in one)
LEGACY_TOPIC = "/skynet/mission-record"


def load_record(path: str | Path, caps: dict[str, int] | None = None,
                ground: str | Path | None = None) -> tuple[MissionRecord, LogReadout]:
    """The mission record of the log ``path`` and what was found (docs/recording.md); ``caps`` default
    :data:`~services.recording.record.CAPS`. Raises :class:`NotAMissionLog` (a ValueError) for a log without a
    header, :class:`~services.recording.mcap_log.McapReadError` (a ValueError) for a damaged file."""
    caps = CAPS if caps is None else caps
    out = LogReadout()
    head: dict | None = None
    foot: dict = {}
    lists = MissionRecord(fleet="", speed=1.0, started=0.0)  # the lists, bounded as they are read
    own = path if ground is None else ground
    for source in ([path] if ground is None else [ground, path]):
        for item in read(source):
            out.messages += 1
            try:
                if source == own and item.topic in (HEADER_TOPIC, FOOTER_TOPIC):
                    doc = codec.loads_json(item.data)
                    if not isinstance(doc, dict):
                        raise ValueError("not an object")
                    if item.topic == HEADER_TOPIC:
                        head = {k: v for k, v in doc.items() if k in HEADER_FIELDS}
                    else:
                        foot = {k: v for k, v in doc.items() if k not in HEADER_FIELDS and k not in ITEM_MODELS}
                        out.footer = True
                elif source == own and item.topic == LEGACY_TOPIC:  # the summary the former recorder wrote last
                    doc = codec.loads_json(item.data)["record"]
                    head = {k: v for k, v in doc.items() if k in HEADER_FIELDS}
                    foot = {k: v for k, v in doc.items() if k not in HEADER_FIELDS and k not in _WRAP}
                    out.footer = True
                elif source == own and item.topic in _GROUND:
                    kind = _GROUND[item.topic]
                    out.items += 1
                    keep(lists, kind, ITEM_MODELS[kind].model_validate_json(item.data), caps)
                elif source == path and item.kind == "sample":
                    msg = item.message()
                    listed = list_of(item.topic, msg) if msg is not None else None
                    if listed is not None:
                        out.items += 1
                        keep(lists, listed, _WRAP[listed](rx=item.rx, msg=msg), caps)
            except ValueError:
                out.damaged += 1
        if ground is not None and source == ground and head is None:
            break
    if head is None:
        raise NotAMissionLog(f"{own}: no mission record header (not a mission log)")
    lists.events.sort(key=lambda e: e.rx)  # the ground station's own and the bus's, in receive order
    try:
        record = MissionRecord.model_validate({**head, **foot})
    except ValueError:  # a header or footer that parses as JSON but not as a record
        out.footer = False
        out.damaged += 1
        try:
            record = MissionRecord.model_validate(head)
        except ValueError:
            raise NotAMissionLog(f"{own}: its mission record header does not validate") from None
    for kind in ITEM_MODELS:
        if kind not in foot:  # a former log's summary holds the ground station's own lists
            setattr(record, kind, getattr(lists, kind))
    record.not_kept = dict(lists.not_kept)  # what this reading let go
    record.recording_errors = [*record.recording_errors, *out.notes(path)]
    return record, out
