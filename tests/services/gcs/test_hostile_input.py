"""Hostile input at the ground station's outputs: an event's text in report.md, and a log entry nested
deeper than any parser's stack, through ``skynet report`` in its own process."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from lxml import etree
from markdown_it import MarkdownIt

from protocol.messages import Event, Level
from services.recording.record import EventRx, MissionRecord
from tests.protocol.test_textsafe import HOSTILE
from tests.services.gcs.test_report import build_record


def _logged(tmp_path: Path) -> tuple[Path, MissionRecord]:
    """test_report's synthetic mission logged the ground station's way (test_load), with an event of hostile
    text and an entry nested deeper than any parser's stack."""
    from services.recording.recorder import GROUND_TOPICS, MissionLogWriter
    from tests.services.recording.test_load import logged

    full = build_record()
    full.events.append(EventRx(rx=full.events[-1].rx + 1.0, msg=Event(
        source="uav/2", stamp=full.events[-1].rx + 1.0, kind="pilot-mode", level=Level.WARNING, text=HOSTILE)))
    nested = '{"rx": 1.0, "msg": ' + "[" * 100_000 + "]" * 100_000 + "}"
    push = MissionLogWriter.begin

    def begin(self, record):  # the nested entry right after the header
        push(self, record)
        self._ring.push(("json", GROUND_TOPICS["events"], "skynet.record.EventRx", {}, nested, record.started))

    MissionLogWriter.begin = begin
    try:
        logged(tmp_path, full=full)
    finally:
        MissionLogWriter.begin = push
    return tmp_path / "mission.mcap", full


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
    path, full = _logged(tmp_path)
    proc = subprocess.run([sys.executable, "-m", "services.cli", "report", str(path), "--out", str(tmp_path / "rep")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr and "RecursionError" not in proc.stderr, proc.stderr[-2000:]
    assert "(1 damaged)" in proc.stdout, proc.stdout
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "\x1b" not in md and "\r" not in md and "<img" not in md and "onerror=" in md
    rows = _events_table(md)
    assert len(rows) == len(full.events) and all(len(r) == 5 for r in rows), rows  # each event one row of 5 cells
    hostile = [r for r in rows if r[3] == "pilot-mode" and r[1] == "uav/2"]
    assert len(hostile) == 1 and hostile[0][1] == "uav/2"
    text = hostile[0][4]
    assert "<img src=x onerror=alert(1)> | `code` *bold* [link](http://x) & ]]>" in text  # the text, as data
    assert "\\x1b]52;c;cm0gLXJmIH4=\\x07\\x0d\\x0a12:00:00 gcs INFO mission succeeded" in text
    assert json.loads((tmp_path / "rep" / "report.json").read_text())["events"][-1]["text"] == HOSTILE
