"""The published wire contract: what an outside Zenoh user needs to read and command the fleet.

Design notes: docs/bus.md (protocol/contract.py).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from typing import Any

from . import codec, keys
from .links import LINK_CLASSES, LinkClass, class_of_topic
from .messages import (
    COMMAND_TYPES,
    MESSAGE_TYPES,
    CommandAck,
    DefectReport,
    ErrorReply,
    Event,
    Heartbeat,
    LinkStats,
    Message,
    MissionPlan,
    PlanRequest,
    Signed,
    VehicleState,
)

_FLEET = "FLEET"
_NAME = "NAME"
_ID = "ID"


@dataclass(frozen=True)
class KeySpec:
    """One key expression of the key space, as the contract document lists it."""

    pattern: str  # with <fleet>, <id>, <name> placeholders
    topic: str
    kind: str  # "put" (publication), "query" (queryable: request -> reply), "liveliness", "rtp"
    payload: tuple[str, ...]  # message type tags carried (request types for a queryable)
    reply: tuple[str, ...] = ()
    what: str = ""

    @property
    def link(self) -> LinkClass:
        return class_of_topic(self.topic)


def _placeholders(key: str) -> str:
    return (key.replace(_FLEET, "<fleet>").replace("/uav/*/", "/uav/<id>/")
            .replace(f"/{_NAME}/", "/<name>/").replace(f"/{_ID}/", "/<id>/"))


def key_space() -> list[KeySpec]:
    """Every key of the contract, built by calling :mod:`protocol.keys` (its only speller)."""
    f = _FLEET
    cmds = tuple(c.TYPE for c in COMMAND_TYPES)
    rows = [
        (keys.state(f, "*"), "state", "put", (VehicleState.TYPE,), (), "vehicle state, 20 Hz"),
        (keys.cmd(f, "*"), "cmd", "query", cmds, (CommandAck.TYPE, ErrorReply.TYPE),
         "a command to one UAV; the reply is its acknowledgement (reply_err with an ErrorReply when malformed)"),
        (keys.camera(f, "*"), "camera", "rtp", (), (), "capture frames (see 'Imagery frames')"),
        (keys.preview(f, "*"), "preview", "rtp", (), (), "live preview frames, 2 Hz, never recovered"),
        (keys.event(f, "*"), "event", "put", (Event.TYPE,), (), "events of one UAV"),
        (keys.alive(f, "*"), "alive", "liveliness", (), (), "liveliness token of one UAV's board"),
        (keys.heartbeat(f), "heartbeat", "put", (Heartbeat.TYPE,), (), "the ground station's heartbeat (edge failsafe)"),
        (keys.gcs_event(f), "event", "put", (Event.TYPE,), (), "events of the ground station"),
        (keys.planner(f), "plan", "query", (PlanRequest.TYPE,), (MissionPlan.TYPE, Signed.TYPE, ErrorReply.TYPE),
         "the planner RCU: a plan request, answered by the mission plan bound to the request's nonce and "
         "scenario digest, signed by the planner's key with a key set (protocol.planauth)"),
        (keys.defects(f), "defects", "put", (DefectReport.TYPE,), (), "the detector RCU's defect reports"),
        (keys.rcu_alive(f, _NAME), "alive", "liveliness", (), (), "liveliness token of an RCU"),
        (keys.rcu_event(f, _NAME), "event", "put", (Event.TYPE,), (), "events of an RCU"),
        (keys.rcu_stats(f, _NAME), "stats", "put", (LinkStats.TYPE,), (), "statistics of an RCU, 1 Hz"),
        (keys.gateway_stats(f, _ID), "stats", "put", (LinkStats.TYPE,), (), "the gateway's link statistics, 1 Hz"),
    ]
    return [KeySpec(_placeholders(k), topic, kind, payload, reply, what)
            for k, topic, kind, payload, reply, what in rows]


#: one valid example body per message type a user sends or reads first (validated when the document is made)
EXAMPLES: dict[str, dict[str, Any]] = {
    VehicleState.TYPE: dict(uav=1, seq=42, t=12.5, stamp=1767225600.25, pos=(10.0, -3.5, 20.0),
                            vel=(1.2, 0.0, 0.0), att=(0.0, 0.01, 1.5708), rates=(0.0, 0.0, 0.0),
                            mode="mission", armed=True, battery=0.93, wp_index=7, progress=0.2, captures=3,
                            neighbours=2, ref=(10.1, -3.5, 20.0), tau=12.4),
    "cmd.takeoff": dict(uav=1, cmd_id=1, altitude=20.0),
    CommandAck.TYPE: dict(uav=1, cmd_id=1, accepted=True, reason=""),
    Heartbeat.TYPE: dict(source="gcs", seq=7, stamp=1767225600.0),
    Event.TYPE: dict(source="uav/1", stamp=1767225600.0, kind="failsafe", level="warning",
                     text="no ground-station heartbeat for 5.0 s: hold", data={"held_s": 0.0}),
}


def example(tag: str) -> Message | None:
    """The example message of ``tag`` (validated by its model), or None."""
    body = EXAMPLES.get(tag)
    if body is None:
        return None
    cls = MESSAGE_TYPES[tag]
    fields = {k: v for k, v in body.items() if k in cls.model_fields}
    return cls.model_validate(fields)


def schemas() -> dict[str, dict[str, Any]]:
    """JSON Schema of every message type, by wire tag."""
    return {tag: cls.model_json_schema() for tag, cls in sorted(MESSAGE_TYPES.items())}


def as_json() -> dict[str, Any]:
    """The whole contract as one JSON-serialisable object."""
    return {
        "envelope": {"format": "msgpack array [version, type, body]", "version": codec.SCHEMA_VERSION,
                     "max_bytes": codec.MAX_MESSAGE_BYTES,
                     "encoding": codec.encoding_name("<type>")},
        "link_classes": {n: {"reliable": c.reliable, "congestion": c.congestion, "priority": c.priority,
                             "express": c.express} for n, c in LINK_CLASSES.items()},
        "keys": [{"key": k.pattern, "kind": k.kind, "link_class": k.link.name, "payload": list(k.payload),
                  "reply": list(k.reply), "what": k.what} for k in key_space()],
        "schemas": schemas(),
        "examples": {t: example(t).model_dump(mode="json") for t in EXAMPLES},  # type: ignore[union-attr]
    }


def document() -> str:
    """The contract as Markdown (``docs/wire-contract.md`` is this text)."""
    out: list[str] = [
        "# SkyNet wire contract",
        "",
        "Generated by `skynet schema` from `protocol/` (keys, links, codec, messages): do not edit by hand.",
        "",
        "## Key space",
        "",
        "| key | kind | link class | payload | reply | what |",
        "|---|---|---|---|---|---|",
    ]
    for k in key_space():
        payload = ", ".join(f"`{t}`" for t in k.payload) or ("RTP frame" if k.kind == "rtp" else "–")
        reply = ", ".join(f"`{t}`" for t in k.reply) or "–"
        link = "–" if k.kind == "liveliness" else k.link.name
        out.append(f"| `{k.pattern}` | {k.kind} | {link} | {payload} | {reply} | {k.what} |")
    out += [
        "",
        "`<key>/@adv/**` carries what zenoh.ext's advanced publisher adds beside a recoverable key (the",
        "capture frames' sequence heartbeats and recovery queries).",
        "",
        "## Link classes (the paper's TCP / UDP / RTP)",
        "",
        "| class | reliability | congestion | priority | express |",
        "|---|---|---|---|---|",
    ]
    for name, c in LINK_CLASSES.items():
        out.append(f"| {name} | {'reliable' if c.reliable else 'best-effort'} | {c.congestion} | {c.priority} "
                   f"| {'yes' if c.express else 'no'} |")
    out += [
        "",
        "## Envelope",
        "",
        f"Every message is a msgpack array `[version, type, body]`: `version` is {codec.SCHEMA_VERSION}, `type` the",
        "message's tag (below), `body` a map of its fields (SI units; positions in local ENU metres from the",
        "scenario's geodetic origin). Unknown fields, NaN/inf and out-of-range values are refused; a payload",
        f"over {codec.MAX_MESSAGE_BYTES} bytes is refused unread.",
        "",
        f"Every sample and reply carries the Zenoh encoding `{codec.encoding_name('<type>')}`, e.g.",
        f"`{codec.encoding_name(VehicleState.TYPE)}`, so a generic tool knows what it holds.",
        "",
        "## Imagery frames",
        "",
        "`camera` and `preview` samples are one RTP packet each (RFC 3550 fixed header, 90 kHz capture",
        "timestamp, SSRC per camera), whose payload is a big-endian uint16 length, an `image.meta` message",
        "in the envelope above, then the encoded image (JPEG). See `protocol/imagery.py`.",
        "",
        "## Examples",
        "",
    ]
    for tag in EXAMPLES:
        msg = example(tag)
        assert msg is not None
        out += [f"`{tag}` (msgpack, hex: `{codec.encode(msg).hex()}`):", "", "```json",
                json.dumps(msg.model_dump(mode="json"), indent=None), "```", ""]
    out += ["## Message schemas (JSON Schema)", ""]
    for tag, schema in schemas().items():
        out += [f"### `{tag}`", "", "```json", json.dumps(schema, indent=1, sort_keys=True), "```", ""]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="skynet schema", description="print the wire contract")
    p.add_argument("type", nargs="?", help="one message type's JSON Schema (e.g. state, cmd.takeoff)")
    p.add_argument("--json", action="store_true", help="the whole contract as JSON")
    args = p.parse_args(argv)
    if args.type:
        cls = MESSAGE_TYPES.get(args.type)
        if cls is None:
            print(f"skynet schema: unknown message type {args.type!r}; known: {', '.join(sorted(MESSAGE_TYPES))}",
                  file=sys.stderr)
            return 2
        print(json.dumps(cls.model_json_schema(), indent=1, sort_keys=True))
    elif args.json:
        print(json.dumps(as_json(), indent=1, sort_keys=True))
    else:
        print(document())
    return 0
