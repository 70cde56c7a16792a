"""Mission logs as MCAP files (the ``mcap`` package): what goes on which channel, and how it comes back.

Design notes: docs/recording.md (services/recording/mcap_log.py).
"""

from __future__ import annotations

import base64
import heapq
import io
import json
import struct
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError as _LibError
from mcap.records import Channel, Chunk, ChunkIndex, Footer, Schema
from mcap.records import Message as McapMessage
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import CompressionType, Writer

from protocol import codec, keys
from protocol.messages import MESSAGE_TYPES, Message

FRAME_ENCODING = "x-skynet-frame"
RAW_ENCODING = "x-skynet-raw"
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
        self._channels: dict[tuple[str, str, str, str], int] = {}
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
            msg: Message = codec.decode(data)
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

    def write_json(self, topic: str, schema_name: str, schema, doc: str, t_s: float) -> None:
        """One JSON document on ``topic``; ``schema`` a JSON Schema dict or a callable making one (called once)."""
        self._add(self._channel(topic, "json", schema_name, schema), t_s, doc.encode())

    def metadata(self, name: str, data: Mapping[str, object]) -> None:
        self._w.add_metadata(name, {k: str(v) for k, v in data.items()})

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            try:
                self._w.finish()
            finally:
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


#: the most bytes one chunk may decompress to, and the longest record read: the recorder writes chunks of
#: 1 MiB plus at most one message (:data:`protocol.codec.MAX_MESSAGE_BYTES`, 8 MiB); other writers' chunks
#: are typically 1-4 MiB. A file past it is refused before anything is allocated.
MAX_CHUNK_BYTES = 64 << 20
_FOOTER_SIZE = 1 + 8 + 8 + 8 + 4  # opcode, length, summary_start, summary_offset_start, summary_crc
_MAGIC_SIZE = 8


class McapReadError(ValueError):
    """An MCAP file that cannot be read within the bounds (a damaged or crafted file): one line, no traceback."""


def _chunk_records(chunk: Chunk, where: str, limit: int) -> list[Any]:
    """The records of ``chunk``, decompressed only when its declared sizes are within ``limit``
    (MCAP spec, "Chunk": ``uncompressed_size``; zstd's frame header, RFC 8878 section 3.1.1.1.4)."""
    if chunk.compression not in ("zstd", ""):
        raise McapReadError(f"{where}: chunk compression {chunk.compression!r} is not read (zstd or none)")
    size = chunk.uncompressed_size
    if size > limit:
        raise McapReadError(f"{where}: a chunk declares {size} bytes uncompressed, more than the {limit} bytes "
                            "a chunk may hold here (a damaged or crafted file)")
    if chunk.compression == "zstd":
        try:
            framed = zstandard.frame_content_size(chunk.data)  # -1: not in the frame header
        except zstandard.ZstdError as exc:
            raise McapReadError(f"{where}: a chunk is not zstd data ({exc})") from None
        if framed > size:  # zstd would allocate what the frame says, whatever the chunk record says
            raise McapReadError(f"{where}: a chunk's zstd frame declares {framed} bytes, its record {size} "
                                "(a damaged or crafted file)")
    try:
        return breakup_chunk(chunk)
    except (zstandard.ZstdError, _LibError, struct.error, ValueError, EOFError) as exc:
        raise McapReadError(f"{where}: a chunk does not decode ({type(exc).__name__}: {exc})"[:300]) from None


def _records(stream: IO[bytes], limit: int, skip_magic: bool) -> Iterator[Any]:
    """The file's top-level records from the stream's position, chunks left compressed, each record's length
    checked against ``limit`` before it is read (the mcap library's ``record_size_limit``)."""
    return StreamReader(stream, skip_magic=skip_magic, emit_chunks=True, record_size_limit=limit).records


def _summary(f: IO[bytes], size: int, limit: int) -> tuple[dict[int, Schema], dict[int, Channel], list[ChunkIndex]]:
    """Schemas, channels and chunk indexes of the summary section (MCAP spec, "Summary Section"); empty
    lists when the file has none (a file cut short)."""
    if size < 2 * _MAGIC_SIZE + _FOOTER_SIZE:
        return {}, {}, []
    f.seek(size - _FOOTER_SIZE - _MAGIC_SIZE)
    try:
        footer = next(iter(_records(f, limit, skip_magic=True)), None)
    except (_LibError, struct.error, EOFError, UnicodeDecodeError):  # cut short: no footer, read it linearly
        return {}, {}, []
    if not isinstance(footer, Footer) or not 0 < footer.summary_start < size:
        return {}, {}, []
    f.seek(footer.summary_start)
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    indexes: list[ChunkIndex] = []
    for rec in _records(f, limit, skip_magic=True):
        if isinstance(rec, Schema):
            schemas[rec.id] = rec
        elif isinstance(rec, Channel):
            channels[rec.id] = rec
        elif isinstance(rec, ChunkIndex):
            indexes.append(rec)
        elif isinstance(rec, Footer):
            break
    return schemas, channels, indexes


def _indexed(f: IO[bytes], where: str, size: int, limit: int, schemas, channels, indexes: list[ChunkIndex],
             wanted: set[int] | None = None) -> Iterator[tuple[Schema | None, Channel, McapMessage]]:
    """Messages in log-time order through the chunk index: chunks opened lazily in start-time order and their
    messages merged (what the mcap library's seeking reader does), each chunk checked before it is read;
    ``wanted``: only these channels, skipping the chunks whose message index says they hold none of them."""
    heap: list[tuple[int, int, int, int, Any]] = []
    for ci in indexes:
        if wanted is None or not ci.message_index_offsets or wanted & set(ci.message_index_offsets):
            heapq.heappush(heap, (ci.message_start_time, 0, ci.chunk_start_offset, -1, ci))
    while heap:
        _, kind, offset, index, item = heapq.heappop(heap)
        if kind == 1:
            schema = schemas.get(channels[item.channel_id].schema_id)
            yield schema, channels[item.channel_id], item
            continue
        if not 0 < offset < size or item.chunk_length > limit + 1024:
            raise McapReadError(f"{where}: a chunk index points outside the file or at a chunk of "
                                f"{item.chunk_length} bytes (more than {limit})")
        f.seek(offset)
        head = f.read(9)
        if len(head) < 9 or head[0] != 0x06:  # the Chunk opcode (MCAP spec, "Chunk (op=0x06)")
            raise McapReadError(f"{where}: no chunk at byte {offset}")
        length = struct.unpack("<Q", head[1:])[0]
        if length > limit + 1024 or offset + 9 + length > size:
            raise McapReadError(f"{where}: the chunk at byte {offset} is {length} bytes long (more than {limit}, "
                                "or past the end of the file)")
        chunk = Chunk.read(ReadDataStream(io.BytesIO(f.read(length))))
        for k, rec in enumerate(_chunk_records(chunk, f"{where} (chunk at byte {offset})", limit)):
            if isinstance(rec, McapMessage) and (wanted is None or rec.channel_id in wanted):
                if rec.channel_id not in channels:
                    raise McapReadError(f"{where}: a message on channel {rec.channel_id}, which the file never "
                                        "declares")
                heapq.heappush(heap, (rec.log_time, 1, offset, k, rec))


def _linear(f: IO[bytes], where: str, limit: int) -> Iterator[tuple[Schema | None, Channel, McapMessage]]:
    """Messages in file order, for a file without a chunk index (cut short before its summary)."""
    f.seek(0)
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    for rec in _records(f, limit, skip_magic=False):
        batch = _chunk_records(rec, where, limit) if isinstance(rec, Chunk) else [rec]
        for r in batch:
            if isinstance(r, Schema):
                schemas[r.id] = r
            elif isinstance(r, Channel):
                channels[r.id] = r
            elif isinstance(r, McapMessage) and r.channel_id in channels:
                yield schemas.get(channels[r.channel_id].schema_id), channels[r.channel_id], r
        if isinstance(rec, Footer):
            break


def messages(path: str | Path, max_chunk_bytes: int = MAX_CHUNK_BYTES,
             topics: list[str] | None = None) -> Iterator[tuple[Schema | None, Channel, McapMessage]]:
    """``(schema, channel, message)`` of every message of an MCAP file, in log-time order, streamed chunk by
    chunk; no chunk decompresses to more than ``max_chunk_bytes`` and no record longer than that is read.

    Raises :class:`McapReadError` (a ValueError, one line) for a damaged or crafted file."""
    where = str(path)
    try:
        with open(path, "rb") as f:
            size = f.seek(0, io.SEEK_END)
            f.seek(0)
            if f.read(_MAGIC_SIZE) != b"\x89MCAP0\r\n":
                raise McapReadError(f"{where}: not an MCAP file (no MCAP magic)")
            schemas, channels, indexes = _summary(f, size, max_chunk_bytes)
            if indexes:
                wanted = None if topics is None else {i for i, c in channels.items() if c.topic in topics}
                yield from _indexed(f, where, size, max_chunk_bytes, schemas, channels, indexes, wanted)
            else:
                yield from _linear(f, where, max_chunk_bytes)
    except McapReadError:
        raise
    except (_LibError, struct.error, EOFError, UnicodeDecodeError, KeyError) as exc:
        raise McapReadError(f"{where}: not a readable MCAP file ({type(exc).__name__}: {exc})"[:300]) from None


def read(path: str | Path, topics: list[str] | None = None, max_chunk_bytes: int = MAX_CHUNK_BYTES) -> Iterator[Logged]:
    """Every message of the file in receive-time order (streamed chunk by chunk, each chunk bounded:
    :func:`messages`)."""
    wanted = None if topics is None else set(topics)
    for schema, channel, message in messages(path, max_chunk_bytes, topics):
        if wanted is not None and channel.topic not in wanted:
            continue
        yield Logged(channel.topic, message.log_time / 1e9, channel.message_encoding,
                     schema.name if schema is not None else "", message.data,
                     channel.metadata.get("skynet.kind", "sample"))


def bus_bytes(item: Logged) -> bytes | None:
    """What to put back on the bus for a logged message; None for what is not a bus sample (viewer
    channels, the ground station's entries, and queries and replies: a replay never commands a UAV)."""
    if not item.topic.startswith(f"{keys.ROOT}/") or item.topic.endswith("/jpeg") or item.kind != "sample":
        return None
    if item.encoding in (FRAME_ENCODING, RAW_ENCODING):
        return item.data
    msg = item.message()
    return None if msg is None else codec.encode(msg)


def captures(path: str | Path) -> Iterator[tuple[Any, bytes]]:
    """``(ImageMeta, image bytes)`` of every capture frame the log holds (the ``camera`` key of each UAV), once
    per UAV and capture (a frame recovered from a camera's cache after an outage comes again), in receive order.
    A frame whose metadata does not decode, or names another UAV than its key's, is skipped: the deliverable's
    input, through the bus whatever host the detector runs on."""
    from protocol.imagery import unpack_image

    seen: set[tuple[int, int]] = set()
    for item in read(path):
        if item.encoding != FRAME_ENCODING:
            continue
        try:
            info = keys.parse(item.topic)
            if info.topic != "camera":
                continue
            _, meta, image = unpack_image(item.data)
        except ValueError:
            continue
        if meta.uav != info.uav or (meta.uav, meta.capture_id) in seen or not len(image):
            continue
        seen.add((meta.uav, meta.capture_id))
        yield meta, bytes(image)
