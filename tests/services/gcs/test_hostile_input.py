"""Hostile input at the ground station's outputs: an event's text in report.md, and a journal line nested
deeper than any parser's stack, through ``skynet report`` in its own process."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from lxml import etree
from markdown_it import MarkdownIt

from protocol.messages import Event, Level
from services.recording.record import ITEM_MODELS, EventRx, MissionRecord, Recorder
from tests.protocol.test_textsafe import HOSTILE
from tests.services.gcs.test_report import build_record

HEADER = {"fleet", "scenario", "speed", "started"}


def _journal(tmp_path: Path) -> tuple[Path, MissionRecord]:
    """test_report's synthetic mission journalled the ground station's way, with an event of hostile text."""
    full = build_record()
    full.events.append(EventRx(rx=full.events[-1].rx + 1.0, msg=Event(
        source="uav/2", stamp=full.events[-1].rx + 1.0, kind="note", level=Level.WARNING, text=HOSTILE)))
    live = MissionRecord(**{k: getattr(full, k) for k in HEADER})
    rec = Recorder(live, tmp_path / "record.jsonl")
    for kind in ITEM_MODELS:
        for item in getattr(full, kind):
            rec.add(kind, item)
    for k, v in full:
        if k not in HEADER and k not in ITEM_MODELS:
            setattr(live, k, v)
    rec.close()
    return tmp_path / "record.jsonl", full


def _events_table(md: str) -> list[list[str]]:
    """The cells of report.md's events table, as a Markdown renderer (GFM tables) reads them."""
    html = MarkdownIt("commonmark").enable("table").render(md)
    root = etree.fromstring(f"<div>{html}</div>".encode())
    assert not root.xpath("//*[@onerror]") and not root.xpath("//script")  # only the report's own plots
    heading = next(h for h in root.iter("h2") if h.text == "Events")
    table = heading.getnext()
    assert table.tag == "table"
    return [["".join(td.itertext()) for td in tr.findall("td")] for tr in table.iter("tr") if tr.findall("td")]


def test_skynet_report_keeps_hostile_event_text_in_its_row_and_counts_a_nested_line(tmp_path):
    path, full = _journal(tmp_path)
    lines = path.read_text().splitlines(keepends=True)
    nested = '{"k": "events", "v": ' + "[" * 100_000 + "]" * 100_000 + "}\n"  # deeper than any parser's stack
    path.write_text("".join([*lines[:3], nested, *lines[3:]]))
    proc = subprocess.run([sys.executable, "-m", "services.cli", "report", str(path), "--out", str(tmp_path / "rep")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr and "RecursionError" not in proc.stderr, proc.stderr[-2000:]
    assert "(1 damaged)" in proc.stdout and "line 4" in proc.stdout, proc.stdout
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "\x1b" not in md and "\r" not in md and "<img" not in md and "onerror=" in md
    rows = _events_table(md)
    assert len(rows) == len(full.events) and all(len(r) == 5 for r in rows), rows  # each event one row of 5 cells
    hostile = [r for r in rows if r[3] == "note"]
    assert len(hostile) == 1 and hostile[0][1] == "uav/2"
    text = hostile[0][4]
    assert "<img src=x onerror=alert(1)> | `code` *bold* [link](http://x) & ]]>" in text  # the text, as data
    assert "\\x1b]52;c;cm0gLXJmIH4=\\x07\\x0d\\x0a12:00:00 gcs INFO mission succeeded" in text
    assert json.loads((tmp_path / "rep" / "report.json").read_text())["events"][-1]["text"] == HOSTILE
