"""The wire codec: msgpack envelope ``[version, type tag, body]``.

Design notes: docs/bus.md (protocol/codec.py).
"""

from __future__ import annotations

import json
import sys
from typing import Any, TypeVar

import msgpack
from pydantic import ValidationError

from .messages import MESSAGE_TYPES, Message

SCHEMA_VERSION = 1
#: decoding refuses payloads larger than this (a mission plan of three long trajectories is ~1 MB)
MAX_MESSAGE_BYTES = 8 * 1024 * 1024

#: the media type of every envelope; the Zenoh encoding adds the schema (see :func:`encoding_name`)
MEDIA_TYPE = "application/msgpack"

M = TypeVar("M", bound=Message)


def encoding_name(type_tag: str) -> str:
    """The Zenoh encoding string of a sample holding a ``type_tag`` message.

    ``application/msgpack;skynet/<version>/<type>``: Zenoh's ``<mime>;<schema>`` form, so generic
    tools (zenoh-cli, a recorder) know the format and which schema of ``skynet schema`` applies.
    """
    return f"{MEDIA_TYPE};skynet/{SCHEMA_VERSION}/{type_tag}"


class CodecError(ValueError):
    """A payload that cannot be decoded into a valid message.

    ``kind`` is one of :data:`CodecError.KINDS`.
    """

    KINDS = ("bad-bytes", "unknown-type", "unsupported-version", "invalid", "oversize", "wrong-type")

    def __init__(self, kind: str, detail: str, type_tag: str | None = None):
        assert kind in self.KINDS, kind
        super().__init__(f"{kind}: {detail}")
        self.kind = kind
        self.detail = detail
        self.type_tag = type_tag


def _default(obj: Any) -> Any:
    # enums are str subclasses and pack natively; anything else is a programming error
    raise TypeError(f"cannot encode {type(obj).__name__}")


_packer_opts = dict(use_bin_type=True, default=_default)


def encode(msg: Message) -> bytes:
    """Encode a message; raises ``TypeError`` for a non-message (a programming error)."""
    if not isinstance(msg, Message) or not msg.TYPE:
        raise TypeError(f"not a wire message: {type(msg).__name__}")
    body = msg.model_dump(mode="json", exclude_defaults=False)
    out: bytes = msgpack.packb([SCHEMA_VERSION, msg.TYPE, body], **_packer_opts)
    return out


def peek_type(data: bytes | bytearray | memoryview) -> str:
    """The type tag of an encoded message, without validating the body."""
    return _unpack(data)[1]


def _unpack(data: bytes | bytearray | memoryview) -> tuple[int, str, Any]:
    try:
        size = len(data)
    except TypeError:
        raise CodecError("bad-bytes", f"expected bytes, got {type(data).__name__}") from None
    if size > MAX_MESSAGE_BYTES:
        raise CodecError("oversize", f"{size} bytes > {MAX_MESSAGE_BYTES}")
    try:
        obj = msgpack.unpackb(data, raw=False, strict_map_key=True, use_list=True)
    except msgpack.StackError:  # deeper than the C unpacker's stack (1024 levels): refused, no recursion
        raise CodecError("bad-bytes", "msgpack nested too deeply") from None
    except Exception as exc:  # msgpack raises several unrelated types on garbage
        raise CodecError("bad-bytes", f"not msgpack: {type(exc).__name__}: {exc}"[:300]) from None
    if not (isinstance(obj, list) and len(obj) == 3 and isinstance(obj[1], str)):
        raise CodecError("bad-bytes", "not a [version, type, body] envelope")
    version, tag, body = obj
    if not isinstance(version, int) or isinstance(version, bool):
        raise CodecError("bad-bytes", f"version must be an int, got {type(version).__name__}")
    if version != SCHEMA_VERSION:
        raise CodecError("unsupported-version", f"schema version {version}, expected {SCHEMA_VERSION}", tag)
    if tag not in MESSAGE_TYPES:
        raise CodecError("unknown-type", f"unknown message type {tag[:64]!r}", tag[:64])
    if not isinstance(body, dict):
        raise CodecError("invalid", f"{tag}: body must be a map", tag)
    return version, tag, body


def decode(data: bytes | bytearray | memoryview, expect: type[M] | tuple[type[M], ...] | None = None) -> M:
    """Decode and validate; ``expect`` restricts the accepted message type(s)."""
    _, tag, body = _unpack(data)
    cls = MESSAGE_TYPES[tag]
    if expect is not None:
        allowed = expect if isinstance(expect, tuple) else (expect,)
        if cls not in allowed:
            names = ", ".join(c.TYPE for c in allowed)
            raise CodecError("wrong-type", f"got {tag!r}, expected {names}", tag)
    try:
        return cls.model_validate(body)  # type: ignore[return-value]
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first.get("loc", ()))
        raise CodecError("invalid", f"{tag}: {where}: {first.get('msg')}"[:500], tag) from None
    except (TypeError, ValueError, RecursionError) as exc:
        raise CodecError("invalid", f"{tag}: {exc}"[:500], tag) from None


def loads_json(text: str | bytes | bytearray) -> Any:
    """:func:`json.loads` for input from outside (a file, a journal line, a message): JSON nested deeper than
    Python's recursion limit is a one-line :class:`ValueError`, like any other bad JSON, never a
    ``RecursionError`` (RFC 8259 section 9: a parser may limit the depth of nesting)."""
    try:
        return json.loads(text)
    except RecursionError:
        raise ValueError(f"JSON nested too deeply (more than about {sys.getrecursionlimit()} levels)") from None
