"""Mission logs as MCAP files (the ``mcap`` package): what goes on which channel, and how it comes back.

One MCAP channel per bus key and message type (``topic`` = the Zenoh key, e.g.
``skynet/demo/uav/1/state``), every message with its receive time (``log_time``) and, for
typed messages, its own stamp (``publish_time``; the receive time where it has none):

======================  ===================  ==========================================  ================
what                    message_encoding     schema                                      Foxglove/Lichtblick
======================  ===================  ==========================================  ================
typed messages          ``json``             ``jsonschema`` of the pydantic model,       Raw Messages, Plot,
(states, events,                             name ``skynet.<Model>``                     Table, State
defect reports, stats,                                                                   Transitions
heartbeats)
imagery frames          ``x-skynet-frame``   none (RTP + metadata + JPEG,                none (opaque)
(camera, preview)                            :mod:`protocol.imagery`)
previews, for viewers   ``json``             ``foxglove.CompressedImage`` (topic         Image
                                             ``<key>/jpeg``; JPEG base64 in ``data``)
requests and replies    ``json``             the command / plan request model, and       Raw Messages
(commands, acks, plan)                       CommandAck / MissionPlan / ErrorReply;
                                             channel metadata ``skynet.kind`` =
                                             ``query`` / ``reply``, topic = the key
undecodable samples     ``x-skynet-raw``     none                                        none
the mission record      ``json``             ``skynet.MissionRecordSummary`` (topic      Raw Messages
                                             ``/skynet/mission-record``, written last)
======================  ===================  ==========================================  ================

Typed messages are stored as their JSON, so viewers can read them; a replay validates the JSON
back into the model and encodes it for the bus again (:func:`bus_bytes`): the same message, in
the bus's msgpack envelope. Imagery and undecodable samples go back byte for byte.

The writer streams: chunks of ``chunk_size`` bytes (zstd) go to disk as they fill, so memory is
one chunk plus the index (one entry per chunk and channel), whatever the mission's length.
"""

from __future__ import annotations

import base64
import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from protocol import codec, keys
from protocol.messages import MESSAGE_TYPES, Message

FRAME_ENCODING = "x-skynet-frame"
RAW_ENCODING = "x-skynet-raw"
RECORD_TOPIC = "/skynet/mission-record"
PROFILE = ""  # no well-known profile: our own (MCAP spec, "Profiles")
IMAGERY_TOPICS = ("camera", "preview")

#: foxglove.CompressedImage as JSON Schema (Foxglove's schema: timestamp, frame_id, data, format)
COMPRESSED_IMAGE_SCHEMA = {
    "title": "foxglove.CompressedImage", "type": "object",
    "properties": {
        "timestamp": {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}},
        "frame_id": {"type": "string"},
        "data": {"type": "string", "contentEncoding": "base64"},
        "format": {"type": "string"},
    },
}


def _ns(t_s: float) -> int:
    return max(0, int(round(float(t_s) * 1e9)))


def is_imagery(key: str) -> bool:
    try:
        return keys.parse(key).topic in IMAGERY_TOPICS
    except ValueError:
        return False


class McapLog:
    """Streams bus samples to one MCAP file; not thread-safe (one writer thread)."""

    def __init__(self, path: str | Path, chunk_size: int = 1 << 20, previews_as_images: bool = True):
        self.path = Path(path)
        self._file: IO[bytes] = open(self.path, "wb")
        self._w = Writer(self._file, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self._w.start(profile=PROFILE, library="skynet-inspect")
        self._schemas: dict[str, int] = {}
        self._channels: dict[tuple[str, str, str], int] = {}
        self.previews_as_images = previews_as_images
        self.messages = 0
        self.closed = False

    def _schema(self, name: str, schema: dict) -> int:
        if name not in self._schemas:
            self._schemas[name] = self._w.register_schema(name, "jsonschema", json.dumps(schema).encode())
        return self._schemas[name]

    def _channel(self, topic: str, encoding: str, schema_name: str = "", schema=None, kind: str = "sample") -> int:
        """The channel id; ``schema`` is a JSON Schema dict or a callable making one (called once).

        ``kind`` (channel metadata ``skynet.kind``): ``sample`` (a put on the key), ``query`` (a request
        the ground station sent to the key's queryable) or ``reply`` (its answer).
        """
        k = (topic, encoding, schema_name, kind)
        if k not in self._channels:
            if callable(schema) and schema_name not in self._schemas:
                schema = schema()
            sid = self._schema(schema_name, schema) if schema is not None else 0
            self._channels[k] = self._w.register_channel(topic, encoding, sid, {"skynet.kind": kind})
        return self._channels[k]

    def _add(self, channel: int, log_time_s: float, data: bytes, publish_time_s: float | None = None) -> None:
        t = _ns(log_time_s)
        self._w.add_message(channel, t, data, _ns(publish_time_s) if publish_time_s is not None else t)
        self.messages += 1

    def write_sample(self, key: str, data: bytes, rx_s: float, imagery: bool | None = None) -> str:
        """Log one bus sample; the kind it was logged as: ``json``, ``frame`` or ``raw``
        (``imagery``: :func:`is_imagery` of ``key``, when the caller has worked it out already)."""
        if is_imagery(key) if imagery is None else imagery:
            self._add(self._channel(key, FRAME_ENCODING), rx_s, data)
            if self.previews_as_images and key.endswith("/preview"):
                self._preview_image(key, data, rx_s)
            return "frame"
        try:
            msg = codec.decode(data)
        except codec.CodecError:
            self._add(self._channel(key, RAW_ENCODING), rx_s, data)
            return "raw"
        self.write_message(key, msg, rx_s)
        return "json"

    def write_message(self, topic: str, msg: Message, rx_s: float, kind: str = "sample") -> None:
        cls = type(msg)
        ch = self._channel(topic, "json", f"skynet.{cls.__name__}", cls.model_json_schema, kind)
        stamp = getattr(msg, "stamp", None)
        self._add(ch, rx_s, msg.model_dump_json().encode(), stamp if isinstance(stamp, float) else None)

    def _preview_image(self, key: str, data: bytes, rx_s: float) -> None:
        from protocol.imagery import unpack_image

        try:
            _, meta, jpeg = unpack_image(data)
        except ValueError:
            return  # the announce frame: no picture
        if not len(jpeg):
            return
        t = _ns(meta.stamp)
        doc = {"timestamp": {"sec": t // 10**9, "nsec": t % 10**9}, "frame_id": f"uav{meta.uav}/camera",
               "data": base64.b64encode(bytes(jpeg)).decode(), "format": "jpeg"}
        ch = self._channel(f"{key}/jpeg", "json", "foxglove.CompressedImage", COMPRESSED_IMAGE_SCHEMA)
        self._add(ch, rx_s, json.dumps(doc).encode(), meta.stamp)

    def write_json(self, topic: str, schema_name: str, schema: dict, doc: str, t_s: float) -> None:
        self._add(self._channel(topic, "json", schema_name, schema), t_s, doc.encode())

    def metadata(self, name: str, data: dict[str, str]) -> None:
        self._w.add_metadata(name, {k: str(v) for k, v in data.items()})

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._w.finish()
            self._file.close()


#: message classes by the schema name the log gives them (``skynet.<ClassName>``)
_BY_NAME = {cls.__name__: cls for cls in MESSAGE_TYPES.values()}

@dataclass(frozen=True)
class Logged:
    """One message read back: topic, receive time (s), encoding, schema name, the stored bytes."""

    topic: str
    rx: float
    encoding: str
    schema: str
    data: bytes
    kind: str = "sample"  # or "query" / "reply" (a request of the ground station and its answer)

    def message(self) -> Message | None:
        """The typed message of a ``json`` channel (None for frames, raw samples and viewer channels)."""
        name = self.schema.removeprefix("skynet.")
        if self.encoding != "json" or not self.schema.startswith("skynet."):
            return None
        cls = _BY_NAME.get(name)
        return None if cls is None else cls.model_validate_json(self.data)


def read(path: str | Path, topics: list[str] | None = None) -> Iterator[Logged]:
    """Every message of the file in receive-time order (streamed chunk by chunk)."""
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(topics=topics, log_time_order=True):
            yield Logged(channel.topic, message.log_time / 1e9, channel.message_encoding,
                         schema.name if schema is not None else "", message.data,
                         channel.metadata.get("skynet.kind", "sample"))


def bus_bytes(item: Logged) -> bytes | None:
    """What to put back on the bus for a logged message; None for what is not a bus sample (viewer
    channels, the mission record, and queries and replies: a replay never commands a UAV)."""
    if not item.topic.startswith(f"{keys.ROOT}/") or item.topic.endswith("/jpeg") or item.kind != "sample":
        return None
    if item.encoding in (FRAME_ENCODING, RAW_ENCODING):
        return item.data
    msg = item.message()
    return None if msg is None else codec.encode(msg)
