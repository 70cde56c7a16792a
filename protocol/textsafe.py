"""Text from another node is data: how it is written into a terminal, a log, Markdown and XML.

Design notes: docs/security.md (protocol/textsafe.py).
"""

from __future__ import annotations

import logging
import unicodedata

__all__ = ["printable", "md_text", "xml_text", "SafeFormatter"]

_ESCAPED_CATEGORIES = frozenset({"Cc", "Cf", "Zl", "Zp"})
#: Markdown punctuation that acts inside a line, escaped with a backslash (CommonMark: any ASCII
#: punctuation may be): code spans, emphasis, links and images, GFM table cells and strikethrough
_MD_PUNCT = frozenset("\\`*_[]|~")
_MD_ENTITIES = {"&": "&amp;", "<": "&lt;", ">": "&gt;"}
_XML_ENTITIES = {"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&apos;"}


def _escape_char(c: str) -> str:
    o = ord(c)
    return f"\\x{o:02x}" if o < 0x100 else f"\\u{o:04x}" if o < 0x10000 else f"\\U{o:08x}"


def printable(text: object, keep: str = "") -> str:
    """``str(text)`` with every control, format and line/paragraph-separator character escaped as
    ``\\xNN`` / ``\\uNNNN`` (``keep``: characters left as they are, e.g. ``"\\n"`` for a traceback).

    What a terminal shows is then what was sent, and an ECMA-48 escape sequence is inert text."""
    s = str(text)
    if s.isprintable() and not keep:  # fast path: nothing to escape (isprintable is False for Cc/Cf/Zl/Zp)
        return s
    out = []
    for c in s:
        if c in keep or unicodedata.category(c) not in _ESCAPED_CATEGORIES:
            out.append(c)
        else:
            out.append(_escape_char(c))
    return "".join(out)


def md_text(text: object) -> str:
    """``text`` as literal inline Markdown: printable (:func:`printable`: no line break), HTML characters as
    entities, inline Markdown punctuation backslash-escaped; a table cell or a part of a line of prose
    that stays exactly that (not for the start of a line, where ``#``, ``-`` or ``>`` would act)."""
    out = []
    for c in printable(text):
        if c in _MD_ENTITIES:
            out.append(_MD_ENTITIES[c])
        elif c in _MD_PUNCT:
            out.append("\\" + c)
        else:
            out.append(c)
    return "".join(out)


def xml_text(text: object) -> str:
    """``text`` for XML 1.0 element content or a quoted attribute: printable (:func:`printable`, which
    also removes what XML 1.0 cannot carry) with ``& < > " '`` as entities."""
    return "".join(_XML_ENTITIES.get(c, c) for c in printable(text))


class SafeFormatter(logging.Formatter):
    """A :class:`logging.Formatter` whose message is :func:`printable`: a log record is one line and text
    from another node cannot drive the terminal. A traceback keeps its line breaks (and nothing else)."""

    def formatMessage(self, record: logging.LogRecord) -> str:  # noqa: N802 (logging's name)
        saved = record.message
        record.message = printable(saved)
        try:
            return super().formatMessage(record)
        finally:
            record.message = saved

    def formatException(self, ei: logging._SysExcInfoType) -> str:  # noqa: N802
        return printable(super().formatException(ei), keep="\n")

    def formatStack(self, stack_info: str) -> str:  # noqa: N802
        return printable(super().formatStack(stack_info), keep="\n")
