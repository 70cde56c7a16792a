"""protocol.textsafe: hostile text (terminal escapes, line breaks, HTML, Markdown, XML-illegal
characters) written into a log, Markdown and XML stays inert data."""

from __future__ import annotations

import io
import logging

from lxml import etree
from markdown_it import MarkdownIt

from protocol.textsafe import SafeFormatter, md_text, printable, xml_text

#: clear screen, OSC 0 window title, OSC 52 clipboard write, a forged log line, C1 CSI, a bidi override
HOSTILE = ("\x1b[2J\x1b[H\x1b]0;pwned\x07\x1b]52;c;cm0gLXJmIH4=\x07\r\n12:00:00 gcs INFO mission succeeded"
           "\x9b31m \u202etxt.exe <img src=x onerror=alert(1)> | `code` *bold* [link](http://x) & ]]>")


def test_printable_escapes_every_control_and_keeps_the_rest():
    out = printable(HOSTILE)
    assert not any(c in out for c in "\x1b\x07\r\n\x9b\u202e")
    assert "\\x1b]52;c;cm0gLXJmIH4=\\x07" in out and "\\x0d\\x0a12:00:00" in out and "\\u202e" in out
    assert printable("Größe 3 m · ψ ✓") == "Größe 3 m · ψ ✓"
    assert printable("a\nb", keep="\n") == "a\nb"


def test_a_log_record_with_hostile_text_is_one_escaped_line():
    stream = io.StringIO()
    handler = logging.StreamHandler(stream)
    handler.setFormatter(SafeFormatter("%(levelname)s %(message)s"))
    log = logging.getLogger("test.textsafe")
    log.addHandler(handler)
    log.propagate = False
    try:
        log.warning("event from %s: %s", "uav/2", HOSTILE)
        try:
            raise ValueError("bad\x1b[2J")
        except ValueError:
            log.exception("failed")
    finally:
        log.removeHandler(handler)
    text = stream.getvalue()
    assert "\x1b" not in text and "\x07" not in text and "\r" not in text
    first = text.splitlines()[0]
    assert first.startswith("WARNING event from uav/2: \\x1b[2J") and "mission succeeded" in first
    assert "Traceback (most recent call last):\n" in text  # a traceback keeps its lines


def test_markdown_cell_renders_as_the_text_in_one_cell():
    md = MarkdownIt("commonmark").enable("table")
    table = f"| source | text |\n|---|---|\n| {md_text('uav/2')} | {md_text(HOSTILE)} |\n| uav/1 | next |\n"
    html = md.render(table)
    assert "<img" not in html and "<code>" not in html and "<strong>" not in html and "<a " not in html
    assert html.count("<tr>") == 3 and html.count("<td>") == 4  # header + two rows, two cells each
    root = etree.fromstring(f"<div>{html}</div>")
    cell = root.findall(".//td")[1].text
    assert "<img src=x onerror=alert(1)> | `code` *bold* [link](http://x) & ]]>" in cell
    assert "\\x1b]0;pwned" in cell


def test_xml_text_is_parsed_back_as_the_same_text():
    doc = f'<?xml version="1.0" encoding="UTF-8"?><r a="{xml_text(HOSTILE)}">{xml_text(HOSTILE)}</r>'
    root = etree.fromstring(doc.encode())
    assert root.text == printable(HOSTILE) == root.get("a")
    assert "<img src=x onerror=alert(1)>" in root.text and "]]>" in root.text
